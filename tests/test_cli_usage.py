"""The command line's refusals of bad input, each before any work, file or line of output: one
line on stderr naming the argument, exit status 2 (a review of the CLI: huge sizes, tiny
--dpi, options an example ignores, --eps out of order, --bench-json rows of the wrong type,
a directory where a file goes, the bench table above n = 16, the docs' examples)."""

from __future__ import annotations

import json
import math
import os

import pytest

from bderiv._support._tables import human_bytes
from bderiv.cli import main, usage
from bderiv.cli.names import DEMO_DIMS, GAIT_EXAMPLES, MIN_DPI, demo_dim

DOCS = os.path.join(os.path.dirname(__file__), os.pardir, "docs", "cli.md")


def run(argv, capsys):
    """(exit status, stdout, stderr) of ``bderiv argv`` run in-process."""
    try:
        code = main(argv)
    except SystemExit as exc:  # argparse's own exits
        code = exc.code
    out, err = capsys.readouterr()
    return code, out, err


def refused(argv, capsys, *messages, command=None):
    """Run ``argv``; assert one line on stderr with each of ``messages``, nothing on stdout,
    exit status 2; return the line."""
    code, out, err = run(argv, capsys)
    assert (code, out) == (2, ""), (code, out, err)
    assert err.count("\n") == 1 and "Traceback" not in err, err
    assert err.startswith(f"bderiv {command or argv[0]}: error: "), err
    for message in messages:
        assert message in err, err
    return err


# -- 1. sizes beyond floats --------------------------------------------------------------------


def test_human_bytes_any_int():
    """Sizes beyond a float (2**1024) print in PiB with an exponent; normal sizes as before."""
    assert [human_bytes(b) for b in (0, 1023, 1536, 5 << 30, 1 << 60)] == [
        "0 B", "1023 B", "1.5 KiB", "5.0 GiB", "1024.0 PiB"]
    assert human_bytes(10**4 << 50) == "1.0e+04 PiB"
    assert human_bytes(1 << 1023) == "8.0e+292 PiB"  # a float still: its exponent
    assert human_bytes((1 << 5000) * 5000) == "6.3e+1493 PiB"  # an int no float holds
    assert human_bytes(1 << (1 << 20)) == "6.0e+315637 PiB"
    assert human_bytes(10**301 * 2**50 - 1) == "1.0e+301 PiB"  # 9.99.. rounds to 10: 1.0e+301


@pytest.mark.parametrize("argv, message", [
    (["--n", "5000", "--batch", "10"], "--n 5000 (d = 5000) with --batch 10 needs about 2.0e+1495 "
                                       "PiB of memory, but only"),
    (["--n", "100000"], "--n 100000 (d = 100000) with --batch 100000 needs about 2.8e+30094 PiB"),
    (["--n", "2", "1000", "--batch", "10"], "--n 1000 (d = 1000) with --batch 10 needs about "
                                            "3.0e+290 PiB"),
    (["--n", "1e12", "--batch", "10"], "--n 1000000000000 (d = 1000000000000) with --batch 10 "
                                       "needs more than 2**1000000000000 B of memory"),
])
def test_bench_huge_n_is_a_memory_error(capsys, argv, message):
    """n >= 1024 overflowed a float in the message (a traceback); n = 10**12 made 2**n."""
    line = refused(["bench", *argv, "--no-progress"], capsys, message, "ask for less")
    assert len(line) < 200, line


# -- 2. --dpi too small for the figures' text --------------------------------------------------


@pytest.mark.parametrize("dpi", ["1", "5", str(MIN_DPI - 1)])
def test_tiny_dpi_refused_before_the_directory(capsys, tmp_path, dpi):
    out = tmp_path / "figs"
    refused(["plot", "--dpi", dpi, "--out", str(out)], capsys,
            f"argument --dpi: expected an integer >= {MIN_DPI}", f"got '{dpi}'")
    assert not out.exists()


def test_smallest_dpi_draws_every_figure(capsys, tmp_path):
    code, out, err = run(["plot", "--dpi", str(MIN_DPI), "--out", str(tmp_path), "--json"],
                         capsys)
    assert code == 0, err
    assert len(json.loads(out)["files"]) == 5


def test_text_made_small_by_matplotlibs_settings_is_refused(capsys, tmp_path):
    """Fonts of 3 pt (an rc setting) at the smallest --dpi: refused before the directory is
    made, not FreeType's 'invalid ppem value' after it."""
    import matplotlib

    small = {key: 3 for key in ("font.size", "xtick.labelsize", "ytick.labelsize",
                                "axes.labelsize", "axes.titlesize", "legend.fontsize")}
    with matplotlib.rc_context(small):
        refused(["plot", "--figure", "pieces", "--dpi", str(MIN_DPI), "--out",
                 str(tmp_path / "figs")], capsys,
                f"--dpi {MIN_DPI} makes the smallest text of the figure pieces (3 pt) 0.42 "
                f"pixel high", "at least --dpi 22")
    assert not (tmp_path / "figs").exists()


# -- 3. and 4. the demo's options: only where they mean something, --eps largest first --------


@pytest.mark.parametrize("argv, message", [
    (["--example", "pronking", "--eps", "1e-3", "--check", "1", "--full", "--batch", "7"],
     "--batch, --check and --full mean nothing for --example pronking, whose demo is "
     "a summary of its own; it takes --eps, --python, --seed and --json"),
    (["--example", "rimless-wheel", "--batch", "5"], "--batch means nothing for --example "
                                                     "rimless-wheel"),
    (["--example", "rimless-wheel", "--check", "0"], "--check means nothing"),
    (["--example", "landing", "--full"], "--full means nothing for --example landing"),
    (["--example", "compass-gait", "--eps", "1e-4"], "--eps means nothing for --example "
                                                     "compass-gait"),
    (["--example", "solo12", "--full"], "it takes --eps, --seed and --json"),
    (["--example", "corners", "--check", "5", "--eps", "1e-3"],
     "--check and --eps mean nothing for --example corners, a corner table without a model"),
    (["--example", "planar", "--check", "0"], "--check means nothing for --example planar"),
    (["--check", "0", "--eps", "1e-4"], "--eps sets the steps of the check against finite "
                                        "differences, which --check 0 leaves out"),
    (["--example", "quadruped", "--python"], "quadruped has no compiled version"),
    (["--eps", "1e-6", "1e-4"], "--eps: the steps must decrease, largest first (the check "
                                "says how much the error shrinks from each step to the next), "
                                "got 0.0001 after 1e-06"),
    (["--eps", "1e-4", "1e-4"], "got 0.0001 after 0.0001"),
    (["--eps", "1e-3", "1e-5", "1e-4"], "got 0.0001 after 1e-05"),
], ids=lambda v: " ".join(v) if isinstance(v, list) else None)
def test_demo_options_an_example_ignores(capsys, argv, message):
    refused(["demo", *argv, "--no-progress"], capsys, message)


def test_demo_options_an_example_uses(capsys):
    """--batch, --full and --seed with a corner table; --eps largest first with a model."""
    code, out, err = run(["demo", "--example", "corners", "--batch", "50", "--full", "--seed",
                          "3", "--no-progress"], capsys)
    assert code == 0 and "M's piece" in out, err
    code, out, err = run(["demo", "--batch", "500", "--check", "1", "--eps", "1e-4", "1e-6",
                          "--no-progress", "--json"], capsys)
    assert code == 0, err
    assert json.loads(out)["check"]["eps"] == [1e-4, 1e-6]


# -- 5. --bench-json rows of the wrong type ------------------------------------------------------


@pytest.fixture(scope="module")
def bench_rows():
    """Rows as `bderiv bench --json` writes them (two sizes, three methods each)."""
    row = {"d": 2, "m": 500, "seconds": 1e-4, "seconds_per_query": 2e-7, "gflops": 0.1}
    rows = [dict(row, n=n, d=n, method=m) for n in (2, 3) for m in ("bderiv", "numpy", "blas")]
    machine = {"cpu": "X", "cpus": 2, "numba_threads": 2, "blas": "openblas",
               "thread_variables": {}}
    return {"d_factor": 1, "batch": 500, "repeat": 1, "machine": machine, "rows": rows}


@pytest.mark.parametrize("row, key, value, message", [
    (1, "seconds_per_query", "0.5", """rows[1]['seconds_per_query'] is "0.5", not a positive"""),
    (2, "seconds_per_query", float("nan"), "rows[2]['seconds_per_query'] is NaN"),
    (0, "seconds_per_query", 0, "rows[0]['seconds_per_query'] is 0, not a positive number"),
    (3, "n", "3", """rows[3]['n'] is "3", not a positive integer"""),
    (3, "n", True, "rows[3]['n'] is true"),
    (4, "method", None, "rows[4]['method'] is null, not a string"),
    (5, "m", [500], "rows[5]['m'] is [500], not a positive integer"),
    (4, "d", 7, "rows mix sweeps: rows[4] has d = 7 at n = 3, rows[3] has d = 3"),
])
def test_bench_json_of_the_wrong_type(capsys, tmp_path, bench_rows, row, key, value, message):
    data = json.loads(json.dumps(bench_rows))
    data["rows"][row][key] = value
    path = tmp_path / "rows.json"
    path.write_text(json.dumps(data))
    refused(["plot", "--figure", "scaling", "--bench-json", str(path), "--out",
             str(tmp_path / "figs")], capsys, f"--bench-json: {str(path)!r}", message)
    assert not (tmp_path / "figs").exists()


def test_bench_json_row_that_is_no_object(capsys, tmp_path, bench_rows):
    data = dict(bench_rows, rows=[*bench_rows["rows"], [2, "bderiv"]])
    path = tmp_path / "rows.json"
    path.write_text(json.dumps(data))
    refused(["plot", "--figure", "scaling", "--bench-json", str(path)], capsys,
            """rows[6] must be a dict with the keys n, method and seconds_per_query, got """
            """[2, "bderiv"]""")


# -- 6. every output file checked before the work -----------------------------------------------


def test_plot_refuses_a_directory_in_the_way_before_drawing(capsys, tmp_path):
    (tmp_path / "note.png").mkdir()
    refused(["plot", "--out", str(tmp_path), "--dpi", "20"], capsys,
            f"--out: cannot write {str(tmp_path / 'note.png')!r}: a directory of that name is "
            f"in the way")
    assert sorted(os.listdir(tmp_path)) == ["note.png"]  # no figure written before it


def test_bench_and_export_refuse_a_directory_in_the_way(capsys, tmp_path):
    (tmp_path / "s.png").mkdir()
    refused(["bench", "--n", "2", "--batch", "100", "--repeat", "1", "--no-progress", "--plot",
             str(tmp_path / "s.png")], capsys, "--plot: cannot write", "a directory of that")
    (tmp_path / "tri.json").mkdir()
    refused(["export", "--example", "corners", "--out", str(tmp_path / "tri")], capsys,
            f"--out: cannot write {str(tmp_path / 'tri.json')!r}: a directory of that name")
    assert not (tmp_path / "tri.npz").exists()  # the .npz not written before the refusal


def test_unwritable_figure_file_refused(capsys, tmp_path, monkeypatch):
    """A figure file this process may not write (root may write any: os.access answers as
    for another user here) is refused before the figures are drawn."""
    path = tmp_path / "pieces.png"
    path.write_bytes(b"")
    monkeypatch.setattr(usage.os, "access", lambda p, mode: os.fspath(p) != str(path))
    refused(["plot", "--figure", "pieces", "--out", str(tmp_path)], capsys,
            f"--out: cannot write {str(path)!r}: the file there is not writable")
    assert path.read_bytes() == b""


def test_export_checks_n_before_counting_its_pieces(capsys):
    """--n 1e9 computed 10**9! (for ever) before the range of --n was checked."""
    refused(["export", "--n", "1e9"], capsys, "--n must be between 1 and 20, got 1000000000")
    refused(["export", "--n", "25"], capsys, "--n must be between 1 and 20, got 25")


# -- 7. the bench table above n = 16 -----------------------------------------------------------


def test_bench_says_where_numpy_was_not_timed(capsys):
    code, out, err = run(["bench", "--n", "2", "17", "--batch", "200", "--repeat", "1",
                          "--no-progress"], capsys)
    assert code == 0, err
    assert not {"nan", "nanx", "nan%"} & set(out.split()), out
    line = next(ln for ln in out.splitlines() if ln.startswith(" 17  17"))
    assert line.split()[5:7] == ["-", "-"], line  # numpy ns/q, speed-up
    assert ("numpy ns/q and speed-up '-' at n = 17: the NumPy baseline is timed up to n = 16 "
            "only") in out
    code, out, err = run(["bench", "--n", "2", "--batch", "200", "--repeat", "1",
                          "--no-progress"], capsys)
    assert "'-'" not in out  # the note only when a size lacks the baseline


def test_bench_json_is_strict_json(capsys):
    code, out, _ = run(["bench", "--n", "2", "17", "--batch", "200", "--repeat", "1",
                        "--no-progress", "--json"], capsys)

    def no_constant(name):
        raise AssertionError(f"{name} is not JSON")

    rows = json.loads(out, parse_constant=no_constant)["rows"]
    assert {r["method"] for r in rows if r["n"] == 17} == {"bderiv", "blas"}
    assert all(math.isfinite(r["seconds_per_query"]) for r in rows)


# -- 8. the memory of a batch checked before the demo's first line -------------------------------


@pytest.mark.parametrize("argv", [[], ["--example", "network", "--n", "20", "--extended"],
                                  ["--example", "table"]])
def test_demo_batch_refused_before_its_first_line(capsys, argv):
    refused(["demo", *argv, "--batch", "10000000000000"], capsys, "--batch 10000000000000 (d = ",
            "of memory")


def test_demo_dims_known_before_loading():
    """The table the early check reads agrees with the examples themselves."""
    from bderiv.cli.systems import load_example

    cases = [(name, None, False) for name in DEMO_DIMS] + [
        ("network", None, False), ("network", 5, False), ("network", 4, True)]
    for name, n, extended in cases:
        assert demo_dim(name, n, extended) == load_example(name, n, extended)[1].dim, name


def test_a_bad_integrator_policy_is_every_commands_usage_error(capsys, monkeypatch):
    """``BDERIV_INTEGRATOR=fast`` came as a 36-line traceback from the demo's first
    compiled run, and ``compile integrator`` accepted it where the integrator was cached."""
    monkeypatch.setenv("BDERIV_INTEGRATOR", "fast")
    for argv in (["demo"], ["compile", "integrator"], ["export", "--example", "corners"]):
        refused(argv, capsys, "the environment variable BDERIV_INTEGRATOR must be one of "
                              "auto, compiled, scipy, got 'fast'")


def test_demo_solo12_without_pinocchio_is_a_usage_error(capsys, monkeypatch):
    from bderiv.robots import _files

    def missing():
        raise ImportError(f"bderiv.robots needs Pinocchio: {_files.INSTALL}")

    monkeypatch.setattr(_files, "require_pinocchio", missing)
    refused(["demo", "--example", "solo12"], capsys,
            "--example solo12: bderiv.robots needs Pinocchio: pip install 'bderiv[robots]'")


def test_demo_solo12_takes_eps_as_its_checks_steps(capsys, monkeypatch):
    """--eps reaches solo12_summary (its check's steps; the summary itself runs in the
    slow test of tests/test_robots.py, a minute on a loaded machine)."""
    pytest.importorskip("pinocchio")
    from bderiv.robots import demo

    given = {}

    def summary(**kwargs):
        given.clear()
        given.update(kwargs)
        return {"name": "solo12"}

    monkeypatch.setattr(demo, "solo12_summary", summary)
    code, out, err = run(["demo", "--example", "solo12", "--eps", "1e-4", "1e-5", "--json"],
                         capsys)
    assert code == 0, err
    assert given == {"seed": 0, "eps": (1e-4, 1e-5)}
    run(["demo", "--example", "solo12", "--json"], capsys)
    assert given == {"seed": 0}  # the summary's own steps


# -- 9. the docs list every example the command offers -------------------------------------------


def test_docs_list_every_demo_example():
    """docs/cli.md's synopsis of demo names every --example it takes, and its row says what
    each is (solo12 was missing)."""
    from bderiv.cli.parser import build_parser

    choices = build_parser().commands["demo"]._option_string_actions["--example"].choices
    with open(DOCS, encoding="utf-8") as fh:
        row = next(line for line in fh if line.startswith("| `bderiv demo [--example"))
    listed = row.split("--example ", 1)[1].split("]", 1)[0].replace("\\", "").split("|")
    assert sorted(listed) == sorted(choices)
    for name in GAIT_EXAMPLES:  # each a summary of its own, said in the row
        assert f"`{name}`" in row, name


def test_memory_refusal_names_the_headroom(capsys, monkeypatch):
    """The huge-n refusal reads the same headroom as every other (tests patch it)."""
    monkeypatch.setattr(usage, "memory_headroom", lambda: 4 << 30)
    refused(["bench", "--n", "1e7", "--no-progress"], capsys, "needs more than 2**10000000 B",
            "only 4.0 GiB is available")


def test_figure_names_and_sizes_in_scientific_notation_are_read_as_written(capsys, tmp_path):
    """Three refusals that said the wrong thing (a review): ``--plot ""`` was taken as no
    plot, silently; ``--plot .png`` (a hidden file's name) "must end in .png"; and
    ``--batch 1e20`` "expected a positive integer" where the same size in digits got the
    memory message. An integral size in scientific notation is now read exactly."""
    refused(["bench", "--n", "2", "--batch", "100", "--repeat", "1", "--no-progress",
             "--plot", ""], capsys, "--plot: figure file '' must end in .png, .pdf or .svg")
    code, out, err = run(["bench", "--n", "2", "--batch", "100", "--repeat", "1",
                          "--no-progress", "--plot", str(tmp_path / ".png")], capsys)
    assert code == 0, err
    assert (tmp_path / ".png").stat().st_size > 1000
    refused(["demo", "--batch", "1e20"], capsys,
            "--batch 100000000000000000000 (d = 6) needs about", "ask for less")
