"""Turn the JSON of ``benchmarks/test_bench_dense.py`` into docs/benchmarks.md's tables and a plot.

Usage::

    python tools/bench_table.py bench.json [--record [PATH]] [--plot bench.png] [--stat min|median]

Prints Markdown: time per query of every contender for each (n, d, m), the speed-up of
bderiv over each baseline (batched NumPy, per-query reference) and its useful work rate
(n**2 + 2 n d flops per query) as a percentage of the BLAS rate measured in the same
group; then construction times, the 1 -> 2 thread speed-up and the targets of issues 2
and 4 with the measured value. Ratios are always between entries of one run.
``--record`` writes these rows, with the run's date, machine and load, to
``benchmarks/results/dense.json`` (``benchmarks/_record.py``), from which
``python tools/render_benchmarks.py`` writes docs/benchmarks.md's tables.

``--plot`` writes the log-log figure of time per query against n (d = n, largest batch)
of ``bderiv.plot.scaling``, the one of ``bderiv bench --plot`` (needs matplotlib), with
the machine in small print. Given the record instead of the pytest-benchmark JSON, the
tool only redraws the figure from the recorded rows (3 significant digits; the BLAS time
per query from the "% of BLAS" column, 2 digits)::

    python tools/bench_table.py benchmarks/results/dense.json --plot docs/bench_dense.png
"""

from __future__ import annotations

import argparse
import json
import pathlib
import sys
from collections import defaultdict

from bderiv.engine._baselines import useful_flops

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1] / "benchmarks"))
import _layouts  # noqa: E402
import _record  # noqa: E402

CONTENDERS = APPLY, INVERSE, NUMPY, REF, BLAS, COPY = (
    "bderiv apply", "bderiv inverse", "numpy batched", "reference per-query", "BLAS matmul",
    "parallel copy")


def load(path: str, stat: str = "min"):
    """(evals, builds, threads, machine) from a pytest-benchmark JSON file.

    ``evals[(n, d, m)][contender]`` is the time per query in seconds (for BLAS: the time
    of the product divided by m), ``builds[(n, d)]`` the construction time and table
    bytes, ``threads[(n, d, m)][t]`` the time per query on t threads.
    """
    with open(path) as fh:
        data = json.load(fh)
    evals = defaultdict(dict)
    builds = {}
    threads = defaultdict(dict)
    info = {"blas": None}
    for b in data["benchmarks"]:
        x = b["extra_info"]
        t = b["stats"][stat]
        group = b["group"] or ""
        if group.startswith("eval"):
            key = (x["n"], x["d"], x["m"])
            evals[key][x["contender"]] = t / x["queries"]
            if x["contender"] == BLAS:
                evals[key]["blas_rate"] = x["blas_flops"] / t
                info["blas"] = x.get("blas", info["blas"])
        elif group.startswith("build"):
            builds[(x["n"], x["d"])] = (t, x["table_bytes"])
        elif group.startswith("threads"):
            threads[(x["n"], x["d"], x["m"])][x["threads"]] = t / x["queries"]
    machine = data.get("machine_info", {})
    info["cpu"] = machine.get("cpu", {}).get("brand_raw", "?")
    info["cores"] = machine.get("cpu", {}).get("count", "?")
    info["datetime"] = data.get("datetime", "?")
    info["load"] = machine.get("load")  # conftest.py (the root): at start and end
    return evals, builds, threads, info


def tables(evals, builds, threads) -> dict[str, list[dict]]:
    """The rows of the dense tables (``benchmarks/_layouts.py``, ``dense``): times in
    seconds, ratios between entries of one run, the targets of issues 2, 4 and 10."""
    out = {"eval": [], "build": [], "threads": []}
    for (n, d, m) in sorted(evals):
        row = evals[(n, d, m)]
        t = row.get(APPLY)
        out["eval"].append(dict(
            n=n, d=d, m=m, apply=t, inverse=row.get(INVERSE), numpy=row.get(NUMPY),
            ref=row.get(REF), vs_numpy=ratio(t, row.get(NUMPY)), vs_ref=ratio(t, row.get(REF)),
            gflops=None if t is None else useful_flops(n, d) / t / 1e9,
            blas_pct=blas_percent(row, n, d), copy=row.get(COPY),
            apply_copy=ratio(row.get(COPY), t)))
    for (n, d), (t, nbytes) in sorted(builds.items()):
        out["build"].append(dict(n=n, d=d, mib=nbytes / 2**20, seconds=t))
    for (n, d, m), row in sorted(threads.items()):
        out["threads"].append(dict(n=n, d=d, m=m, t1=row.get(1), t2=row.get(2),
                                   speedup=ratio(row.get(2), row.get(1))))
    out["targets"] = targets(out)
    return out


def ratio(a: float | None, b: float | None) -> float | None:
    return None if a is None or b is None else b / a


def blas_percent(row: dict, n: int, d: int) -> float | None:
    t = row.get(APPLY)
    rate = row.get("blas_rate")
    if t is None or rate is None:
        return None
    return 100.0 * useful_flops(n, d) / t / rate


def targets(rows: dict[str, list[dict]]) -> list[dict]:
    """Each target of issues 2, 4 and 10 with the measured value, from the rows of
    :func:`tables` (so a recorded run's targets are those of its table)."""
    evals = {(r["n"], r["d"], r["m"]): r for r in rows["eval"]}
    threads = {(r["n"], r["d"], r["m"]): r for r in rows["threads"]}
    builds = {(r["n"], r["d"]): r for r in rows["build"]}
    out = []

    def add(label, value, goal, unit="x", below=False):
        met = "-" if value is None else "yes" if (value < goal if below else value >= goal) \
            else "no"
        out.append(dict(target=label, value="not measured" if value is None else value,
                        unit=unit, met=met))

    def get(table, key, column):
        return table.get(key, {}).get(column)

    for n in (8, 16):
        add(f"n=d={n}, m=1e5: >= 200x per-query ref", get(evals, (n, n, 10**5), "vs_ref"), 200)
        add(f"n=d={n}, m=1e5: >= 5x batched NumPy", get(evals, (n, n, 10**5), "vs_numpy"), 5)
    for n in (8, 16):
        add(f"n=d={n}, m=1e6: >= 20x batched NumPy", get(evals, (n, n, 10**6), "vs_numpy"), 20)
        add(f"n=d={n}, m=1e6: >= 2000x per-query ref", get(evals, (n, n, 10**6), "vs_ref"),
            2000)
        add(f"n=d={n}, m=1e6: 1 -> 2 threads >= 1.7x",
            get(threads, (n, n, 10**6), "speedup"), 1.7)
    for n, goal in ((8, 5), (16, 20), (20, 40)):  # issue 10: apply within a few copies
        add(f"n=d={n}, m=1e6: apply <= {goal}x the parallel copy",
            get(evals, (n, n, 10**6), "apply_copy"), goal, below=True)
    key = (8, 8, 10**6) if (8, 8, 10**6) in evals else (8, 8, 10**5)
    add(f"n=d=8, m={key[2]:.0e}: useful work >= 2% of BLAS".replace("e+0", "e"),
        get(evals, key, "blas_pct"), 2.0, unit="%")
    add("n=d=20 dense tables built in < 1 s", get(builds, (20, 20), "seconds"), 1.0,
        unit="s", below=True)
    return out


def markdown(rows: dict[str, list[dict]], note: str) -> str:
    """The dense tables as docs/benchmarks.md shows them, under "Measured ``note``"."""
    layout = _layouts.LAYOUTS["dense"]
    out = [f"Measured {note}.", ""]
    for name, title in (("eval", "Time per query"), ("build", "Construction"),
                        ("threads", "Threads"), ("targets", "Targets")):
        out += [f"{title}:", "", *_layouts.markdown_table(layout[name], rows[name]), ""]
    return "\n".join(out)


def load_record(path: str):
    """(evals, machine) from a record of :func:`tables` (benchmarks/results/dense.json):
    each contender's time per query by (n, d, m), the BLAS product's from the apply time
    and its percentage of the BLAS rate, and where it was measured."""
    with open(path) as fh:
        data = json.load(fh)
    evals = defaultdict(dict)
    for r in data["tables"]["eval"]:
        row = evals[(r["n"], r["d"], r["m"])]
        for contender, key in ((APPLY, "apply"), (INVERSE, "inverse"), (NUMPY, "numpy"),
                               (REF, "ref"), (COPY, "copy")):
            if isinstance(r.get(key), float | int):
                row[contender] = r[key]
        if APPLY in row and isinstance(r.get("blas_pct"), float | int):
            row[BLAS] = row[APPLY] * r["blas_pct"] / 100.0
    if not evals:
        raise ValueError(f"{path}: no row in its table 'eval'")
    meta = data["meta"]
    machine = f"{meta.get('date')} on {meta['machine']['cpu']}; {meta.get('note', '')}"
    return evals, machine


def plot(evals, path: str, machine: str | None = None) -> None:
    """Write ``bderiv.plot.scaling`` of the d = n entries (largest batch per point), with
    ``machine`` in small print."""
    from bderiv.plot import scaling

    rows = [
        dict(n=n, d=d, m=m, method=contender, seconds_per_query=row[contender])
        for (n, d, m), row in sorted(evals.items()) if d == n
        for contender in CONTENDERS if contender in row
    ]
    scaling(rows, machine=machine).savefig(path, dpi=110)


def machine_note(info, stat: str) -> str:
    """Where and how the run was measured, as the "Measured ..." line says it."""
    return (f"{info['datetime'][:16]} on {info['cpu']} ({info['cores']} cores, shared "
            f"with other work), {stat} over rounds; BLAS: {info['blas']}")


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("json", help="pytest-benchmark JSON (--benchmark-json), or a record of "
                   "this tool (benchmarks/results/dense.json: redraw --plot only)")
    p.add_argument("--plot", help="write a log-log PNG of time per query against n")
    p.add_argument("--stat", default="min", choices=("min", "median", "mean"),
                   help="statistic of the rounds (default min: least disturbed by other load)")
    _record.add_argument(p, "dense")
    args = p.parse_args(argv)
    with open(args.json) as fh:
        recorded = "tables" in json.load(fh)
    if recorded:
        if not args.plot:
            p.error("a record only redraws the figure: give --plot")
        evals, machine = load_record(args.json)
        plot(evals, args.plot, machine)
        return 0
    evals, builds, threads, info = load(args.json, args.stat)
    rows = tables(evals, builds, threads)
    sys.stdout.write(markdown(rows, machine_note(info, args.stat)))
    if args.record:
        _record.record("dense", rows, path=args.record, meta={
            "date": info["datetime"][:16].replace("T", " ") + " UTC",
            "machine": {"cpu": info["cpu"], "cores": info["cores"]},
            "load": info["load"],
            "note": f"{args.stat} over rounds; BLAS: {info['blas']}",
            "command": "python -m pytest benchmarks/test_bench_dense.py -n 0 -m \"slow or not "
                       "slow\" --benchmark-enable --benchmark-json=bench.json && python "
                       f"tools/bench_table.py {' '.join(sys.argv[1:] if argv is None else argv)}"})
    if args.plot:
        plot(evals, args.plot, machine_note(info, args.stat))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
