"""Messages that point at the right thing (users' fourth pass, items 3 and 6)."""

from __future__ import annotations

import io

import pytest

from bderiv._progress import TqdmCallback
from bderiv.cli import main
from bderiv.cli.render import bench_text


@pytest.mark.parametrize("example", ["corners", "quadruped", "rimless-wheel"])
def test_python_is_refused_where_it_means_nothing(example, capsys):
    assert main(["demo", "--example", example, "--python"]) == 2
    err = capsys.readouterr().err
    assert f"{example} has no compiled version, so it means nothing there" in err
    assert "chair, network, pronking, landing" in err


def _rows(bderiv_gflops, blas_gflops):
    common = {"n": 4, "d": 4, "m": 1000, "seconds": 1e-3, "seconds_per_query": 1e-6}
    return [dict(common, method="bderiv", gflops=bderiv_gflops, build_seconds=1e-4,
                 speedup=3.0),
            dict(common, method="blas", gflops=blas_gflops)]


@pytest.mark.parametrize("bderiv_gflops, noted", [(2.0, True), (0.5, False)])
def test_bench_says_why_it_can_exceed_blas(bderiv_gflops, noted):
    result = {"d_factor": 1, "batch": 1000, "repeat": 3, "rows": _rows(bderiv_gflops, 1.0),
              "machine": {"cpu": "X", "cpus": 2, "numba_threads": 2, "blas": "b",
                          "thread_variables": {}}}
    text = bench_text(result)
    assert ("200.0%" in text) is noted
    assert ("above 100 % of BLAS, the yardstick product ran slower" in text) is noted


def test_progress_counts_small_totals_plainly():
    out = io.StringIO()
    bar = TqdmCallback("bench", unit="size", file=out)
    for done in range(1, 6):
        bar(done, 5)
    assert "5/5" in out.getvalue() and "5.00" not in out.getvalue()
    out = io.StringIO()
    bar = TqdmCallback("demo", file=out)
    bar(20_000, 20_000)
    assert "20.0k/20.0k" in out.getvalue()
