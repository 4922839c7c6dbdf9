"""The command line: each subcommand, --json output, and one-line errors with exit 2."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from bderiv import BDerivative, load_triangulation
from bderiv.cli import main, usage

SMALL = ["--batch", "2000", "--no-progress"]


def run(argv, capsys):
    """(exit status, stdout, stderr) of ``bderiv argv`` run in-process."""
    try:
        code = main(argv)
    except SystemExit as exc:  # argparse's own exits (errors, --help, --version)
        code = exc.code
    out, err = capsys.readouterr()
    return code, out, err


def test_demo_text(capsys):
    code, out, err = run(["demo", *SMALL, "--check", "2"], capsys)
    assert code == 0, err
    assert out.startswith("bderiv demo: chair")
    for text in ("event group", "simultaneous", "pieces:", "det =", "|D|_2 =",
                 "ns per vector", "eps = 1e-04", "eps = 1e-06", "O(eps) expected",
                 "mask 0b00 -> 0b11", "g0=(0,1)", "g0=(1,0)"):
        assert text in out, text


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
    # keys added with the CLI package (the text report reads them)
    assert res["build_seconds"] > 0 and res["pieces_sample"] == 2000
    assert res["batch"]["max_abs_output"] > 0


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
    assert "order=(0,2,1)" in out and "pieces: 6" in out
    code, out, _ = run(["demo", "--example", "corners", *SMALL, "--json"], capsys)
    res = json.loads(out)
    assert res["vectors"][0]["Mu"] == pytest.approx([-2.9, -3.8, -6.8])
    assert res["check"]["inverse_round_trip"] < 1e-12
    assert res["batch"]["max_abs_output"] > 0


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


def test_plot_default_and_chair(capsys, tmp_path):
    code, out, _ = run(["plot", "--out", str(tmp_path / "a"), "--dpi", "30", "--json"],
                       capsys)
    assert code == 0
    summary = json.loads(out)
    assert (summary["dim"], summary["n_events"]) == (2, 2) and len(summary["files"]) == 4
    code, out, _ = run(["plot", "--example", "chair", "--out", str(tmp_path / "b"),
                        "--dpi", "30"], capsys)
    assert code == 0 and "need a 2-D system" in out
    assert [p.name for p in (tmp_path / "b").iterdir()] == ["pieces.png"]


@pytest.mark.parametrize("example", ["corners", "chair"])
def test_export(capsys, tmp_path, example):
    base = tmp_path / "tri"
    code, out, _ = run(["export", "--example", example, "--out", str(base), "--json"], capsys)
    assert code == 0
    summary = json.loads(out)
    assert [f["format"] for f in summary["files"]] == ["npz", "json"]
    assert all(f["max_error_reloaded"] < 1e-9 for f in summary["files"])
    assert summary["check_vectors"] == 200
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
    (["export", "--example", "corners", "--out", ""], "--out must be a file path"),
    (["export", "--example", "corners", "--out", "somewhere/"], "got 'somewhere/'"),
    (["demo", "--example", "network", "--n", "50"], "--n must be between 1 and 20"),
    (["export", "--example", "table"], "rank 3 < n"),
    (["plot", "--example", "planar", "--figure", "pieces", "--dpi", "100000"],
     "pixels per side"),
    # sizes from the command line, checked against the memory before allocating
    (["bench", "--n", "40", "--no-progress"], "--n 40 (d = 40) with --batch 100000 needs"),
    (["demo", "--batch", "1_000_000_000_000", "--no-progress"], "--batch 1000000000000"),
    (["demo", "--example", "corners", "--batch", "1_000_000_000_000"], "of memory"),
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


def test_bench_n26_refused_before_allocating(capsys, monkeypatch):
    """--n 26 needs tens of GiB; with 4 GiB available it is a usage error, not a try."""
    monkeypatch.setattr(usage, "available_memory", lambda: 4 << 30)
    code, out, err = run(["bench", "--n", "2", "26", "--no-progress"], capsys)
    assert (code, out) == (2, "")
    assert err.count("\n") == 1 and "--n 26 (d = 26)" in err and "GiB of memory" in err
    assert "4.0 GiB is available" in err


def test_unwritable_output_is_a_usage_error(capsys, tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("")
    code, out, err = run(["plot", "--example", "planar", "--out", str(blocker / "figs")],
                         capsys)
    assert (code, out) == (2, "") and err.count("\n") == 1
    assert "--out: cannot make the directory" in err


@pytest.mark.parametrize("error", [ValueError, TypeError, OSError])
def test_library_errors_are_not_usage_errors(monkeypatch, error):
    """A library failure keeps its type and traceback (exit status 1), not exit 2."""

    def broken(self, max_pieces=None):
        raise error("library bug")

    monkeypatch.setattr(BDerivative, "pieces", broken)
    with pytest.raises(error, match="library bug"):
        main(["demo", "--example", "corners", "--batch", "100"])


def test_library_error_traceback_subprocess():
    script = (
        "from bderiv import BDerivative\n"
        "from bderiv.cli import main\n"
        "def broken(self, max_pieces=None):\n"
        "    raise ValueError('library bug')\n"
        "BDerivative.pieces = broken\n"
        "raise SystemExit(main(['demo', '--example', 'corners', '--batch', '100']))\n"
    )
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True)
    assert proc.returncode == 1
    assert "Traceback" in proc.stderr and "ValueError: library bug" in proc.stderr


def test_dpi_refused_before_writing(capsys, tmp_path):
    out_dir = tmp_path / "figs"
    code, out, err = run(["plot", "--example", "planar", "--dpi", "100000", "--out",
                          str(out_dir)], capsys)
    assert (code, out) == (2, "") and "--dpi 100000 makes the figure field" in err
    assert not out_dir.exists()
