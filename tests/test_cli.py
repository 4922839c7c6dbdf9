"""The command line: each subcommand, --json output, and one-line errors with exit 2."""

from __future__ import annotations

import json
import os
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
    for text in ("event group", "simultaneous", "pieces of D (the flow map):", "det D =",
                 "|D|_2 =", "det M =", "ns per vector", "best of 3 runs", "eps = 1e-04",
                 "eps = 1e-06", "O(eps) expected", "mask 0b00 -> 0b11", "g0=(0,1)",
                 "g0=(1,0)", "B-derivative at the event point", "B-derivative of the flow",
                 "measured on", "numba threads", "OPENBLAS_NUM_THREADS", "over [0, 0.15]",
                 "numba-compiled functions: every simulation runs on the compiled"):
        assert text in out, text


def test_demo_says_when_the_compiled_model_ran_on_scipy(capsys, monkeypatch):
    monkeypatch.setenv("BDERIV_INTEGRATOR", "scipy")
    code, out, err = run(["demo", *SMALL, "--check", "1", "--json"], capsys)
    assert code == 0, err
    assert json.loads(out)["integrator"] == "scipy"
    code, out, err = run(["demo", *SMALL, "--check", "1"], capsys)
    assert "the compiled integrator is not ready on this machine" in out
    assert "every simulation runs on the compiled" not in out
    # the check's speed-up is against simulations on scipy, and its line says so
    assert "one simulation per vector (on scipy: the compiled integrator not ready" in out


def test_demo_says_when_the_checks_simulations_changed_integrator(capsys, monkeypatch):
    """The integrator ready during the check: its time per simulation is a mean of both
    (a review: the line named only where the last ones ran)."""
    from bderiv.cli import demo

    where = iter(["scipy", "scipy", "compiled"])  # the flow map, the check's start, end
    monkeypatch.setattr(demo, "_running_on", lambda system: next(where))
    code, out, err = run(["demo", *SMALL, "--check", "1"], capsys)
    assert code == 0, err
    assert ("one simulation per vector (first on scipy, then the compiled integrator, "
            "ready meanwhile: a mean of both)") in out


def test_demo_python_model_agrees_with_the_compiled_default(capsys):
    """--python: the chair's Python functions on solve_ivp; the same pieces as the compiled
    default (the same equations on the other integrator), and each says which it ran."""
    runs = {}
    for flag in ([], ["--python"]):
        code, out, _ = run(["demo", *SMALL, "--check", "0", "--json", *flag], capsys)
        assert code == 0
        runs[bool(flag)] = json.loads(out)
    py, cc = runs[True], runs[False]
    assert (py["compiled"], cc["compiled"]) == (False, True)
    assert cc["description"] == py["description"] + ", numba-compiled"
    assert [g["time"] for g in cc["groups"]] == pytest.approx([g["time"] for g in py["groups"]],
                                                              abs=1e-10)
    for a, b in zip(py["pieces"]["most_visited"], cc["pieces"]["most_visited"], strict=True):
        assert a["orders"] == b["orders"] and b["det"] == pytest.approx(a["det"], rel=1e-8)


def test_demo_json_and_fd_convergence(capsys):
    code, out, _ = run(["demo", *SMALL, "--check", "2", "--json"], capsys)
    assert code == 0
    assert '"t_final": 0.15,' in out  # 0.1 + 0.05 as asked for, not 0.15000000000000002
    res = json.loads(out)
    assert set(res) == {"example", "description", "dim", "n_events", "x0", "t_final",
                        "compiled", "integrator", "build_seconds", "groups", "pieces", "batch",
                        "check", "total_seconds", "phases"}
    assert res["compiled"] is True  # the chair's compiled version is the default
    assert res["integrator"] == "compiled"  # the tests wait for it (BDERIV_INTEGRATOR)
    # the phases account for the total; compilation is counted apart, not in the timings
    phases = res["phases"]
    assert list(phases) == ["loading the example", "flow map", "pieces", "batch", "check"]
    assert sum(p["seconds"] for p in phases.values()) <= res["total_seconds"]
    assert all(0 <= p["compiling_seconds"] <= p["seconds"] for p in phases.values())
    assert res["build_seconds"] == pytest.approx(
        phases["flow map"]["seconds"] - phases["flow map"]["compiling_seconds"])
    assert res["example"] == "chair" and (res["dim"], res["n_events"]) == (6, 2)
    assert res["groups"][0]["events"] == [0, 1]
    pieces = res["pieces"]
    assert (pieces["count"], pieces["sample"], pieces["distinct"]) == (2, 2000, 2)
    assert len(pieces["most_visited"]) == 2
    assert sum(e["share"] for e in pieces["most_visited"]) == pytest.approx(1.0)
    assert all(e["det"] > 0 and e["event_dets"][0] > 0 for e in pieces["most_visited"])
    b = res["batch"]
    assert b["size"] == 2000 and b["ns_per_vector"] > 0 and len(b["runs_seconds"]) == 3
    assert b["ns_per_vector"] == pytest.approx(min(b["runs_seconds"]) / 2000 * 1e9)
    assert b["max_abs_output"] > 0 and b["machine"]["numba_threads"] >= 1
    assert "OPENBLAS_NUM_THREADS" in b["machine"]["thread_variables"]
    err = res["check"]["max_rel_error"]
    assert len(err) == 3 and err[-1] < 1e-3
    assert all(r > 5 for r in res["check"]["error_ratios"])  # O(eps): 10x per decade
    assert res["build_seconds"] > 0


def test_demo_full_matrices(capsys):
    """--full: each group's tables, the linear stages and the pieces' matrices."""
    from bderiv import examples

    code, out, _ = run(["demo", *SMALL, "--check", "0", "--full", "--json"], capsys)
    assert code == 0
    res = json.loads(out)
    ex = examples.chair()
    fb = ex.system.flow_bderivative(ex.x0, ex.t_final)
    group = res["groups"][0]
    # closed forms at rho (examples/chair.py): h_k = -(z + a_k sin th + b_k cos th), so
    # row k of Dh is (0, -1, -(a_k cos th - b_k sin th), 0, 0, 0); before the touchdown
    # the field is free flight
    th, a, b0 = 0.1, np.array([-0.5, 0.6]), -0.4
    b = np.array([b0, b0 + (a[0] - a[1]) * np.tan(th)])
    Dh = np.zeros((2, 6))
    Dh[:, 1], Dh[:, 2] = -1.0, -(a * np.cos(th) - b * np.sin(th))
    np.testing.assert_allclose(group["Dh"], Dh, atol=1e-6)
    np.testing.assert_allclose(group["F"][0], [0.5, -2.0, 0.3, 0.0, -9.81, 0.0], atol=1e-6)
    assert np.array(group["F"]).shape == (4, 6) and len(res["linear"]) == 2
    rng = np.random.default_rng(3)
    for entry in res["pieces"]["most_visited"]:
        D, (M,) = np.array(entry["matrix"]), entry["event_matrices"]
        assert np.linalg.det(M) == pytest.approx(entry["event_dets"][0])
        assert np.linalg.det(D) == pytest.approx(entry["det"])
        # a vector of this piece: D's piece applied to it is the flow map's value
        V = rng.standard_normal((400, 6))
        inside = V[(fb.orders(V)[0] == entry["orders"][0]).all(axis=1)]
        np.testing.assert_allclose(inside @ D.T, fb(inside), rtol=1e-9, atol=1e-9)
    code, out, _ = run(["demo", *SMALL, "--check", "0", "--full"], capsys)
    for text in ("Dh of group 0", "F of group 0", "L_0 (linear stage 0)", "D's piece",
                 "M's piece, group 0"):
        assert text in out, text


def test_demo_many_events_shows_ranges(capsys):
    """n = 12: every vector meets its own piece; the ranges and the spread are shown."""
    argv = ["demo", "--example", "network", "--n", "12", "--batch", "3000", "--check", "0",
            "--no-progress"]
    code, out, _ = run(argv, capsys)
    assert code == 0
    assert "no piece holds 1 % of the vectors" in out and "share" not in out
    assert "spread of the event times" in out and "met by the first 1,000 vectors: det D" in out
    code, out, _ = run([*argv, "--json"], capsys)
    p = json.loads(out)["pieces"]
    assert p["count"] == 479001600 and p["most_visited"] == []
    assert p["distinct"] > 2900 and p["ranges"]["vectors"] == 1000
    assert 900 < p["ranges"]["pieces"] <= 1000
    lo, hi = p["ranges"]["det"]
    assert 0 < lo < hi
    (spread,) = p["time_spread"]
    assert spread["quantiles"] == [5, 50, 95]
    assert 0 < spread["values"][0] < spread["values"][1] < spread["values"][2]


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
    from bderiv.examples import three_event_table

    code, out, _ = run(["demo", "--example", "corners", *SMALL], capsys)
    assert code == 0
    for text in ("order (0,2,1)", "pieces of M: 6", "Dh (event Jacobian",
                 "0b001  [1, 0.1, 1]", "M(u) = [-2.9, -3.8, -6.8]", "times [1, 3, 3.8]"):
        assert text in out, text
    code, out, _ = run(["demo", "--example", "planar", *SMALL], capsys)
    assert "M(u) = [-0.926007, -1.57564]" in out  # 6 significant digits, as for corners
    code, out, _ = run(["demo", "--example", "corners", *SMALL, "--json", "--full"], capsys)
    res = json.loads(out)
    Dh, F = three_event_table()
    np.testing.assert_array_equal(res["Dh"], Dh)
    np.testing.assert_array_equal(res["F"], F)
    assert res["vectors"][0]["Mu"] == pytest.approx([-2.9, -3.8, -6.8])
    assert res["check"]["inverse_round_trip"] < 1e-12
    assert res["batch"]["max_abs_output"] > 0
    bd = BDerivative(Dh, F)
    for p in res["pieces"]:
        np.testing.assert_allclose(p["matrix"], bd.piece(p["order"]))
    assert len(res["pieces"]) == 6


def test_bench(capsys, tmp_path):
    png = tmp_path / "new" / "scaling.png"  # its directory is made, as plot's and export's
    code, out, _ = run(["bench", "--n", "2", "3", "--batch", "500", "--repeat", "1",
                        "--no-progress", "--plot", str(png)], capsys)
    assert code == 0
    assert "speed-up" in out and png.stat().st_size > 1000
    assert f"made the directory {tmp_path / 'new'}\nplot written to {png}\n" in out
    assert out.startswith("bderiv bench: d = n, batch m = 500") and "measured on" in out
    code, out, _ = run(["bench", "--n", "2", "--batch", "300", "--repeat", "1", "--d-factor",
                        "2", "--no-progress", "--json"], capsys)
    result = json.loads(out)
    assert (result["d_factor"], result["batch"], result["repeat"]) == (2, 300, 1)
    rows = result["rows"]
    assert {r["method"] for r in rows} == {"bderiv", "numpy", "blas"}
    assert all(r["seconds_per_query"] > 0 and r["d"] == 4 for r in rows)
    assert result["machine"]["cpus"] >= 1
    # the output feeds the scaling figure of `bderiv plot`
    path = tmp_path / "rows.json"
    path.write_text(out)
    code, out, _ = run(["plot", "--figure", "scaling", "--bench-json", str(path), "--out",
                        str(tmp_path / "figs"), "--json"], capsys)
    assert code == 0 and json.loads(out)["files"][0].endswith("scaling.png")
    code, out, err = run(["bench", "--n", "2", "--batch", "300", "--repeat", "1",
                          "--d-factor", "2", "--no-progress"], capsys)
    assert out.startswith("bderiv bench: d = 2n,")


def test_plot_default_and_chair(capsys, tmp_path):
    code, out, _ = run(["plot", "--out", str(tmp_path / "a"), "--dpi", "30", "--json"],
                       capsys)
    assert code == 0
    summary = json.loads(out)
    assert summary["example"] == "planar"  # the default, as --help says
    assert (summary["dim"], summary["n_events"]) == (2, 2) and len(summary["files"]) == 5
    for name in ("field", "triangulation", "circle", "note", "pieces"):
        assert (tmp_path / "a" / f"{name}.png").stat().st_size > 1000
    code, out, _ = run(["plot", "--example", "chair", "--out", str(tmp_path / "b"),
                        "--dpi", "30"], capsys)
    assert code == 0 and "not drawn: field, which draws the plane (needs d = 2)" in out
    assert [p.name for p in (tmp_path / "b").iterdir()] == ["pieces.png"]
    code, out, _ = run(["plot", "--n", "2", "--figure", "note", "--out", str(tmp_path / "c"),
                        "--dpi", "30", "--json"], capsys)
    assert json.loads(out)["example"] == "network"  # --n alone means the network family


def test_plot_help_states_the_defaults(capsys):
    code, out, _ = run(["plot", "--help"], capsys)
    assert code == 0
    text = " ".join(out.split())
    assert "(default: planar)" in text and "default 3" in text  # --example, and --n's own
    assert "svg" in text and "planar" in text


@pytest.mark.parametrize("example", ["corners", "chair"])
def test_export(capsys, tmp_path, example):
    base = tmp_path / "tri"
    code, out, _ = run(["export", "--example", example, "--out", str(base), "--json"], capsys)
    assert code == 0
    summary = json.loads(out)
    assert summary["map"] == "event"
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
    assert "the B-derivative at the event point" in out


def test_export_flow_map(capsys, tmp_path):
    """--map flow: the file is the flow map D from x0 over [0, t_final], not M."""
    from bderiv import examples

    base = tmp_path / "flow"
    code, out, _ = run(["export", "--map", "flow", "--out", str(base)], capsys)
    assert code == 0
    assert "the B-derivative of the flow from x0 over [0, 0.15]" in out
    assert "max |tri(V) - D(V)|" in out
    ex = examples.chair()
    D = ex.system.flow_bderivative(ex.x0, ex.t_final)
    M = ex.system.bderivative(ex.rho)
    V = np.random.default_rng(7).standard_normal((300, 6))
    for path in (f"{base}.npz", f"{base}.json"):
        tri = load_triangulation(path)
        np.testing.assert_allclose(tri(V), D(V), atol=1e-10 * np.abs(D(V)).max())
        assert np.abs(tri(V) - M(V)).max() > 1.0  # not the map at the event point


def test_flow_triangulation_needs_one_group():
    from bderiv import FlowBDerivative
    from bderiv.cli.export import flow_triangulation

    bd = BDerivative(np.eye(2), np.array([[1.0, 1], [2, 1], [1, 3], [2, 2]]))
    two = FlowBDerivative([np.eye(2)] * 3, [bd, bd])
    with pytest.raises(usage.UsageError, match="meets 2 event groups.*exactly one group"):
        flow_triangulation(two, 100)
    with pytest.raises(usage.UsageError, match="meets 0 event groups"):
        flow_triangulation(FlowBDerivative([np.eye(2)], []), 100)


BAD = [
    (["frobnicate"], "invalid choice"),
    (["demo", "--example", "nope"], "invalid choice"),
    (["demo", "--batch", "0"], "positive integer"),
    (["demo", "--batch", "lots"], "positive integer"),
    (["demo", "--eps", "-1"], "the steps must be positive, got '-1'"),
    (["demo", "--eps", "-1e-4"], "the steps must be positive, got '-1e-4'"),
    (["demo", "--eps", "1e-4", "1e-20"], "between 1e-12 and 0.1, got '1e-20'"),
    (["demo", "--eps", "10"], "between 1e-12 and 0.1, got '10'"),
    (["demo", "--batch", "2.5"], "positive integer, got '2.5'"),
    (["demo", "--batch", "1e300"], "positive integer, got '1e300'"),
    (["--example", "nope"], "invalid choice"),
    (["plot", "--example", "planar", "--figure", "pieces", "--dpi", "5000"],
     "image viewers and libraries refuse more than"),
    (["demo", "--check", "-2"], "integer >= 0"),
    (["demo", "--unknown-flag"], "unrecognized arguments"),
    (["demo", "--example", "corners", "--n", "3"], "--n applies to --example network"),
    (["bench", "--plot", "out.txt", "--n", "2"], "must end in .png"),
    (["bench", "--plot", "/proc/dir/s.png", "--n", "2"],
     "cannot make the directory '/proc/dir': output directory '/proc' is not writable"),
    (["plot", "--example", "corners", "--figure", "field"], "figure field draws the plane"),
    (["plot", "--example", "network", "--n", "3", "--extended", "--figure", "note"],
     "needs d = 2"),
    (["plot", "--figure", "scaling"], "pass --bench-json rows.json"),
    (["export", "--example", "corners", "--map", "flow"], "--map flow needs a model"),
    (["export", "--map", "both"], "invalid choice"),
    (["plot", "--figure", "scaling", "--bench-json", "/nonexistent/rows.json"],
     "cannot read benchmark rows"),
    (["export", "--example", "corners", "--out", "/proc/dir/tri"],
     "cannot make the directory '/proc/dir': output directory '/proc' is not writable"),
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
    # nothing on stdout: the memory a batch takes is checked before the demo's first line
    assert out == "", out
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    # one prefix for argparse's errors and the later ones: the command's name
    command = "demo" if argv[0].startswith("-") else argv[0]  # no command: the demo
    prefix = "bderiv: error:" if argv[0] == "frobnicate" else f"bderiv {command}: error:"
    assert lines[0].startswith(prefix), lines[0]
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
    assert demo.returncode == 0 and "pieces of M: 6" in demo.stdout


def test_bench_n26_refused_before_allocating(capsys, monkeypatch):
    """--n 26 needs tens of GiB; with 4 GiB available it is a usage error, not a try."""
    monkeypatch.setattr(usage, "memory_headroom", lambda: 4 << 30)
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
    assert "--out: cannot make the directory" in err and "not writable" in err


def test_output_directories_are_made_and_replaced_files_named(capsys, tmp_path, monkeypatch):
    """plot, export and bench make a missing output directory (with its parents) and say
    so; a file written over an earlier one is named; plot's default folder is the
    example's own, so that one example's figures never replace another's."""
    base = tmp_path / "a" / "b" / "tri"
    argv = ["export", "--example", "corners", "--out", str(base)]
    code, out, _ = run(argv, capsys)
    assert code == 0 and f"  made the directory {tmp_path / 'a'}\n" in out
    assert out.count("(replacing the file there)") == 0
    assert (tmp_path / "a" / "b" / "tri.npz").is_file()
    code, out, _ = run(argv, capsys)
    assert code == 0 and "made the directory" not in out
    assert f"wrote {base}.npz" in out and out.count("(replacing the file there)") == 2
    monkeypatch.chdir(tmp_path)
    plot = ["plot", "--figure", "pieces", "--dpi", "20"]
    for example in ("planar", "chair"):
        code, out, _ = run([*plot, "--example", example, "--json"], capsys)
        summary = json.loads(out)
        assert summary["files"] == [os.path.join("bderiv-figures", example, "pieces.png")]
        assert summary["replaced"] == [] and summary["created"] is not None
    code, out, _ = run([*plot, "--example", "chair"], capsys)
    path = os.path.join("bderiv-figures", "chair", "pieces.png")
    assert f"  wrote {path} (replacing the file there)\n" in out
    assert "made the directory" not in out
    assert sorted(os.listdir("bderiv-figures")) == ["chair", "planar"]


@pytest.mark.skipif(not os.path.isdir("/proc"), reason="needs Linux's /proc")
@pytest.mark.parametrize("argv", [
    ["export", "--example", "corners", "--out", "/proc/tri"],
    ["plot", "--example", "planar", "--figure", "pieces", "--out", "/proc"],
    ["bench", "--n", "2", "--no-progress", "--plot", "/proc/scaling.png"],
])
def test_directory_that_refuses_files_is_not_writable(capsys, argv):
    """A directory that exists but takes no file (/proc) is named as not writable, before
    any work, and never as 'No such file or directory' alone."""
    code, out, err = run(argv, capsys)
    assert (code, out) == (2, "") and err.count("\n") == 1
    assert "'/proc' is not writable" in err, err


def test_broken_pipe_stops_quietly():
    """`bderiv demo | head -1`: the reader leaves; no traceback."""
    proc = subprocess.run(
        f"{sys.executable} -m bderiv demo --example corners --batch 100 | head -1",
        shell=True, capture_output=True, text=True)
    assert proc.stdout.startswith("bderiv demo: corners") and proc.stdout.count("\n") == 1
    assert "Traceback" not in proc.stderr and "BrokenPipe" not in proc.stderr


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


def test_demo_gait(capsys):
    """``demo --example pronking``: the gait's orbit, groups crossed up then down, the
    verdict and its checks (their numbers are tested in tests/test_gaits.py)."""
    assert main(["demo", "--example", "pronking", "--json"]) == 0
    out, err = capsys.readouterr()
    res = json.loads(out)
    # what it computes is said as it starts (it printed nothing for 5-11 s)
    assert err.startswith("bderiv demo: pronking: the orbit by Newton's method"), err
    assert res["orbit"]["residual"] < 1e-10
    dirs = [g["directions"] for g in res["groups"]]
    assert dirs == [[1, 1], [-1, -1]], dirs
    assert res["stability"]["stable"] is True
    assert main(["demo", "--example", "pronking", "--n", "3"]) == 2
    assert "options of --example network" in capsys.readouterr().err


def test_demo_impact(capsys):
    """``demo --example landing``: the double touchdown with resets, its FD check, and the
    coupled variant refused (numbers tested in tests/test_impacts.py)."""
    assert main(["demo", "--example", "landing"]) == 0
    out, err = capsys.readouterr()
    assert "resets: u0 0.6 -> 0, u1 -0.6 -> 0" in out
    assert err.startswith("bderiv demo: landing: the double touchdown"), err
    assert "refused" in out and "do not commute" in out


def test_sizes_in_scientific_notation_and_options_without_a_command(capsys):
    """``--batch 1e3`` is the integer 1000; options with no command run the demo."""
    from bderiv.cli.parser import build_parser

    args = build_parser().parse_args(["demo", "--batch", "1e3", "--check", "2E0"])
    assert (args.batch, args.check) == (1000, 2) and type(args.batch) is int
    code, out, _ = run(["--example", "corners", "--batch", "1e2"], capsys)
    assert code == 0 and out.startswith("bderiv demo: corners")


def test_phases_count_a_compilation_apart():
    """numba compiling inside a phase is counted in its compiling seconds."""
    import numba

    from bderiv.cli.timing import Phases

    @numba.njit(cache=False)
    def fresh(x):  # a new function: compiled at its first call, inside the phase
        return x + 1

    phases = Phases()
    with phases("first call"):
        assert fresh(1) == 2
    with phases("second call"):
        assert fresh(2) == 3
    assert 0 < phases.compiling["first call"] <= phases.seconds["first call"]
    assert phases.compiling["second call"] == 0.0
