"""``tools/bench_table.py``: the time-per-query table it prints reads back into the same
numbers (so the figure of docs/benchmarks.md is remade from its table), and that table does."""

from __future__ import annotations

import importlib.util
import pathlib

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def tool():
    spec = importlib.util.spec_from_file_location("bderiv_bench_table", ROOT / "tools" /
                                                  "bench_table.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_printed_table_reads_back(tool, tmp_path):
    # times per query in seconds; the BLAS product's is 2.5 % and 40 % of the apply time
    rows = {(2, 2, 10**6): (5.27e-9, 5.59e-9, 64.3e-9, 13.2e-6, 0.13175e-9, 0.836e-9),
            (20, 20, 10**3): (421e-9, 428e-9, 5.35e-6, 239e-6, 168.4e-9, 5.09e-9)}
    evals = {}
    for (n, d, m), (apply, inverse, numpy, ref, blas, copy) in rows.items():
        evals[(n, d, m)] = {tool.APPLY: apply, tool.INVERSE: inverse, tool.NUMPY: numpy,
                            tool.REF: ref, tool.BLAS: blas, tool.COPY: copy,
                            "blas_rate": (n * n + 2 * n * d) / blas}
    info = {"datetime": "2026-11-25T18:00:00", "cpu": "CPU X", "cores": 2, "blas": "b"}
    path = tmp_path / "printed_table.txt"
    path.write_text("# A run\n\n" + tool.markdown(evals, {}, {}, info, "min"))
    back, back_info = tool.load_markdown(str(path))
    assert set(back) == set(rows)
    for key, times in rows.items():
        for contender, t in zip(tool.CONTENDERS, times, strict=True):
            digits = 2e-2 if contender == tool.BLAS else 5e-3  # printed with 2 and 3 digits
            assert back[key][contender] == pytest.approx(t, rel=digits), (key, contender)
    assert back_info["machine"] == "2026-11-25T18:00 on CPU X (2 cores, shared with other " \
                                   "work), min over rounds; BLAS: b"


def test_benchmarks_page_table_redraws_the_figure(tool, tmp_path):
    pytest.importorskip("matplotlib")
    evals, info = tool.load_markdown(str(ROOT / "docs" / "benchmarks.md"))
    assert evals[(8, 8, 10**6)][tool.APPLY] > 0 and "machine" in info
    tool.main([str(ROOT / "docs" / "benchmarks.md"), "--plot", str(tmp_path / "bench.png")])
    assert (tmp_path / "bench.png").stat().st_size > 10_000
