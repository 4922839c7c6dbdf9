"""The command line: each subcommand, --json output, and one-line errors with exit 2."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from bderiv import load_triangulation
from bderiv.cli import main

HAVE_MODELS = True
try:
    import bderiv.examples  # noqa: F401
except ImportError:  # pragma: no cover - the models are part of the package
    HAVE_MODELS = False

needs_models = pytest.mark.skipif(not HAVE_MODELS, reason="bderiv.examples not available")
SMALL = ["--batch", "2000", "--no-progress"]


def run(argv, capsys):
    """(exit status, stdout, stderr) of ``bderiv argv`` run in-process."""
    try:
        code = main(argv)
    except SystemExit as exc:  # argparse's own exits (errors, --help, --version)
        code = exc.code
    out, err = capsys.readouterr()
    return code, out, err


@needs_models
def test_demo_text(capsys):
    code, out, err = run(["demo", *SMALL, "--check", "2"], capsys)
    assert code == 0, err
    assert out.startswith("bderiv demo: chair")
    for text in ("event group", "simultaneous", "pieces:", "det =", "|D|_2 =",
                 "ns per vector", "eps = 1e-04", "eps = 1e-06", "O(eps) expected"):
        assert text in out, text


@needs_models
def test_demo_json_and_fd_convergence(capsys):
    code, out, _ = run(["demo", *SMALL, "--check", "2", "--json"], capsys)
    assert code == 0
    res = json.loads(out)
    assert res["example"] == "chair" and (res["dim"], res["n_events"]) == (6, 2)
    assert res["groups"][0]["events"] == [0, 1]
    assert res["n_pieces"] == 2 and all(p["det"] > 0 for p in res["pieces"])
    assert res["batch"]["size"] == 2000 and res["batch"]["ns_per_vector"] > 0
    err = res["check"]["max_rel_error"]
    assert len(err) == 3 and err[-1] < 1e-3
    assert all(r > 5 for r in res["check"]["error_ratios"])  # O(eps): 10x per decade


@needs_models
@pytest.mark.parametrize(
    "argv, n, d",
    [(["--example", "network", "--n", "4"], 4, 4), (["--n", "2", "--extended"], 2, 4)],
)
def test_demo_network(capsys, argv, n, d):
    code, out, _ = run(["demo", *argv, *SMALL, "--check", "1", "--eps", "1e-4", "1e-5",
                        "--json"], capsys)
    assert code == 0
    res = json.loads(out)
    assert (res["n_events"], res["dim"]) == (n, d)
    assert res["check"]["max_rel_error"][1] < res["check"]["max_rel_error"][0]


def test_demo_corner_table(capsys):
    code, out, _ = run(["demo", "--example", "corners", *SMALL], capsys)
    assert code == 0
    assert "order=[0, 2, 1]" in out and "pieces: 6" in out
    code, out, _ = run(["demo", "--example", "corners", *SMALL, "--json"], capsys)
    res = json.loads(out)
    assert res["vectors"][0]["Mu"] == pytest.approx([-2.9, -3.8, -6.8])
    assert res["check"]["inverse_round_trip"] < 1e-12


def test_bench(capsys, tmp_path):
    png = tmp_path / "scaling.png"
    code, out, _ = run(["bench", "--n", "2", "3", "--batch", "500", "--repeat", "1",
                        "--no-progress", "--plot", str(png)], capsys)
    assert code == 0
    assert "speed-up" in out and png.stat().st_size > 1000
    code, out, _ = run(["bench", "--n", "2", "--batch", "300", "--repeat", "1",
                        "--no-progress", "--json"], capsys)
    rows = json.loads(out)
    assert {r["method"] for r in rows} == {"bderiv", "numpy", "blas"}
    assert all(r["seconds_per_query"] > 0 for r in rows)
    # the rows feed the scaling figure of `bderiv plot`
    path = tmp_path / "rows.json"
    path.write_text(out)
    code, out, _ = run(["plot", "--figure", "scaling", "--bench-json", str(path), "--out",
                        str(tmp_path / "figs"), "--json"], capsys)
    assert code == 0 and json.loads(out)["files"][0].endswith("scaling.png")


@pytest.mark.parametrize("fmt", ["png", "pdf"])
def test_plot_2d(capsys, tmp_path, fmt):
    code, out, _ = run(["plot", "--example", "planar", "--out", str(tmp_path), "--format",
                        fmt, "--dpi", "40"], capsys)
    assert code == 0
    for name in ("field", "triangulation", "circle", "pieces"):
        assert (tmp_path / f"{name}.{fmt}").stat().st_size > 1000
    assert "wrote" in out


@needs_models
def test_plot_default_and_chair(capsys, tmp_path):
    code, out, _ = run(["plot", "--out", str(tmp_path / "a"), "--dpi", "30", "--json"],
                       capsys)
    assert code == 0
    assert json.loads(out)["dim"] == 2 and len(json.loads(out)["files"]) == 4
    code, out, _ = run(["plot", "--example", "chair", "--out", str(tmp_path / "b"),
                        "--dpi", "30"], capsys)
    assert code == 0 and "need a 2-D system" in out
    assert [p.name for p in (tmp_path / "b").iterdir()] == ["pieces.png"]


@pytest.mark.parametrize("example", ["corners", "chair"])
def test_export(capsys, tmp_path, example):
    if example == "chair" and not HAVE_MODELS:
        pytest.skip("bderiv.examples not available")
    base = tmp_path / "tri"
    code, out, _ = run(["export", "--example", example, "--out", str(base), "--json"], capsys)
    assert code == 0
    summary = json.loads(out)
    assert [f["format"] for f in summary["files"]] == ["npz", "json"]
    assert all(f["max_error_reloaded"] < 1e-9 for f in summary["files"])
    a = load_triangulation(f"{base}.npz")
    b = load_triangulation(f"{base}.json")
    np.testing.assert_array_equal(a.post, b.post)
    assert a.simplices.shape == (summary["simplices"], summary["n_events"] + 1)
    code, out, _ = run(["export", "--example", example, "--out", f"{base}2.json",
                        "--format", "json"], capsys)
    assert code == 0 and "wrote" in out and (tmp_path / "tri2.json").exists()


BAD = [
    (["frobnicate"], "invalid choice"),
    (["demo", "--example", "nope"], "invalid choice"),
    (["demo", "--batch", "0"], "positive integer"),
    (["demo", "--batch", "lots"], "positive integer"),
    (["demo", "--eps", "-1"], "positive number"),
    (["demo", "--check", "-2"], "integer >= 0"),
    (["demo", "--unknown-flag"], "unrecognized arguments"),
    (["demo", "--example", "corners", "--n", "3"], "--n applies to --example network"),
    (["bench", "--plot", "out.txt", "--n", "2"], "must end in .png"),
    (["bench", "--plot", "/nonexistent/dir/s.png", "--n", "2"], "does not exist"),
    (["plot", "--example", "corners", "--figure", "field"], "need a 2-D system"),
    (["plot", "--figure", "scaling", "--bench-json", "/nonexistent/rows.json"],
     "cannot read benchmark rows"),
    (["export", "--example", "corners", "--out", "/nonexistent/dir/tri"], "does not exist"),
    (["export", "--example", "corners", "--max-pieces", "2"], "--max-pieces=2"),
]
if HAVE_MODELS:
    BAD += [
        (["demo", "--example", "network", "--n", "50"], "--n must be between 1 and 20"),
        (["export", "--example", "table"], "rank 3 < n"),
    ]


@pytest.mark.parametrize("argv, message", BAD, ids=lambda v: " ".join(v) if isinstance(
    v, list) else None)
def test_bad_arguments_one_line_exit_2(capsys, argv, message):
    code, out, err = run(argv, capsys)
    assert code == 2
    assert out == ""
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("bderiv") and "error:" in lines[0]
    assert message in lines[0]
    assert "Traceback" not in err


def test_python_m_bderiv_subprocess():
    """``python -m bderiv`` is the same command; a bad argument: one line, status 2."""
    bad = subprocess.run([sys.executable, "-m", "bderiv", "demo", "--example", "nope"],
                         capture_output=True, text=True)
    assert bad.returncode == 2
    assert len(bad.stderr.strip().splitlines()) == 1 and "Traceback" not in bad.stderr
    ok = subprocess.run([sys.executable, "-m", "bderiv", "--version"], capture_output=True,
                        text=True)
    assert ok.returncode == 0 and ok.stdout.startswith("bderiv ")
    demo = subprocess.run([sys.executable, "-m", "bderiv", "demo", "--example", "corners",
                           "--batch", "100"], capture_output=True, text=True)
    assert demo.returncode == 0 and "pieces: 6" in demo.stdout
