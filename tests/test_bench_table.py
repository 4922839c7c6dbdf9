"""``tools/bench_table.py``: the rows it records read back into the same times (so the figure
of docs/benchmarks.md is remade from ``benchmarks/results/dense.json``), the table it prints
shows them, and the recorded run's targets are those of its own rows."""

from __future__ import annotations

import importlib.util
import json
import pathlib

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1]
RECORD = ROOT / "benchmarks" / "results" / "dense.json"


@pytest.fixture(scope="module")
def tool():
    spec = importlib.util.spec_from_file_location("bderiv_bench_table", ROOT / "tools" /
                                                  "bench_table.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_recorded_rows_read_back(tool, tmp_path):
    # times per query in seconds; the BLAS product's is 2.5 % and 40 % of the apply time
    rows = {(2, 2, 10**6): (5.27e-9, 5.59e-9, 64.3e-9, 13.2e-6, 0.13175e-9, 0.836e-9),
            (20, 20, 10**3): (421e-9, 428e-9, 5.35e-6, 239e-6, 168.4e-9, 5.09e-9)}
    evals = {}
    for (n, d, m), (apply, inverse, numpy, ref, blas, copy) in rows.items():
        evals[(n, d, m)] = {tool.APPLY: apply, tool.INVERSE: inverse, tool.NUMPY: numpy,
                            tool.REF: ref, tool.BLAS: blas, tool.COPY: copy,
                            "blas_rate": (n * n + 2 * n * d) / blas}
    tables = tool.tables(evals, {(20, 20): (0.369, 576 * 2**20)}, {})
    path = tool._record.record("dense", tables, path=tmp_path / "dense.json",
                               meta={"note": "min over rounds"})
    back, machine = tool.load_record(str(path))
    assert set(back) == set(rows)
    for key, times in rows.items():
        for contender, t in zip(tool.CONTENDERS, times, strict=True):
            assert back[key][contender] == pytest.approx(t, rel=1e-12), (key, contender)
    assert "min over rounds" in machine
    text = tool.markdown(tables, "here")
    assert "| 2 | 2 | 1e6 | 5.27 ns | 5.59 ns | 64.3 ns | 13.2 us | 12.2x | 2.5e3x |" in text
    assert "| n=d=20 dense tables built in < 1 s | 0.369 s | yes |" in text


def test_the_recorded_targets_are_those_of_its_rows(tool):
    tables = json.loads(RECORD.read_text(encoding="utf-8"))["tables"]
    assert tool.targets(tables) == tables["targets"]


def test_the_record_redraws_the_figure(tool, tmp_path):
    pytest.importorskip("matplotlib")
    evals, machine = tool.load_record(str(RECORD))
    assert evals[(8, 8, 10**6)][tool.APPLY] > 0 and "AMD EPYC" in machine
    tool.main([str(RECORD), "--plot", str(tmp_path / "bench.png")])
    assert (tmp_path / "bench.png").stat().st_size > 10_000


def test_a_pytest_benchmark_run_is_recorded_with_its_machine(tool, tmp_path, capsys):
    def bench(group, t, **extra):
        return {"group": group, "stats": {"min": t, "median": t}, "extra_info": extra}

    run = {"datetime": "2026-11-28T23:00:00.123", "benchmarks": [
        bench("eval n=8", 2e-5, n=8, d=8, m=1000, queries=1000, contender=tool.APPLY),
        bench("eval n=8", 6e-4, n=8, d=8, m=1000, queries=1000, contender=tool.NUMPY),
        bench("eval n=8", 5e-6, n=8, d=8, m=1000, queries=1000, contender=tool.BLAS,
              blas_flops=1e6, blas="openblas"),
        bench("build n=8", 1.5e-4, n=8, d=8, table_bytes=2**20),
        bench("threads n=8", 6e-2, n=8, d=8, m=10**6, queries=10**6, threads=1),
        bench("threads n=8", 3e-2, n=8, d=8, m=10**6, queries=10**6, threads=2)],
        "machine_info": {"cpu": {"brand_raw": "CPU X", "count": 2},
                         "load": {"start": [1.0, 1.0, 1.0], "end": [2.0, 1.5, 1.0]}}}
    path = tmp_path / "bench.json"
    path.write_text(json.dumps(run))
    tool.main([str(path), "--record", str(tmp_path / "dense.json")])
    assert "| 8 | 8 | 1e3 | 20 ns | - | 600 ns | - | 30x | - |" in capsys.readouterr().out
    data = json.loads((tmp_path / "dense.json").read_text())
    meta = data["meta"]
    assert meta["date"] == "2026-11-28 23:00 UTC" and meta["machine"] == {"cpu": "CPU X",
                                                                          "cores": 2}
    assert meta["load"] == run["machine_info"]["load"] and "BLAS: openblas" in meta["note"]
    assert data["tables"]["threads"] == [dict(n=8, d=8, m=10**6, t1=6e-8, t2=3e-8,
                                              speedup=2.0)]
