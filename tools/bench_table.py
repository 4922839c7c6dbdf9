"""Turn the JSON of ``benchmarks/test_bench_dense.py`` into docs/benchmarks.md's tables and a plot.

Usage::

    python tools/bench_table.py bench.json [--plot bench.png] [--stat min|median]

Prints Markdown: time per query of every contender for each (n, d, m), the speed-up of
bderiv over each baseline (batched NumPy, per-query reference) and its useful work rate
(n**2 + 2 n d flops per query) as a percentage of the BLAS rate measured in the same
group; then construction times, the 1 -> 2 thread speed-up and the targets of issues 2
and 4 with the measured value. Ratios are always between entries of one run.

``--plot`` writes the log-log figure of time per query against n (d = n, largest batch)
of ``bderiv.plot.scaling``, the one of ``bderiv bench --plot`` (needs matplotlib), with
the machine in small print. Given a Markdown file instead of the JSON (docs/benchmarks.md),
the tool reads back the time-per-query table it printed there and only redraws the figure:
the figure of the recorded run is remade from that page alone (3 significant digits; the BLAS
time per query from the "% of BLAS" column, 2 digits)::

    python tools/bench_table.py docs/benchmarks.md --plot docs/bench_dense.png
"""

from __future__ import annotations

import argparse
import json
import sys
from collections import defaultdict

from bderiv.engine._baselines import useful_flops

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
    return evals, builds, threads, info


def load_markdown(path: str):
    """(evals, info) read back from the Markdown of :func:`markdown` (in docs/benchmarks.md): the
    time per query of each contender by (n, d, m), the BLAS product's from the apply
    time and its percentage of the BLAS rate, and the "Measured ..." line's machine."""
    units = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "ns": 1e-9}

    def seconds(cell):
        value, unit = cell.split()
        return float(value) * units[unit]

    evals, info = defaultdict(dict), {}
    with open(path) as fh:
        lines = fh.read().splitlines()
    header = eval_table({})[0]
    start = lines.index(header) + 2  # after the header and its alignment row
    for line in lines[:start]:
        if line.startswith("Measured "):
            info["machine"] = line.removeprefix("Measured ").rstrip(".")
    for line in lines[start:]:
        if not line.startswith("|"):
            break
        cells = [c.strip() for c in line.strip("|").split("|")]
        n, d, m = int(cells[0]), int(cells[1]), int(float(cells[2]))
        row = evals[(n, d, m)]
        for contender, cell in zip((APPLY, INVERSE, NUMPY, REF), cells[3:7], strict=True):
            if cell != "-":
                row[contender] = seconds(cell)
        if cells[11] != "-":
            row[COPY] = seconds(cells[11])
        if APPLY in row and cells[10] != "-":
            row[BLAS] = row[APPLY] * float(cells[10].rstrip("%")) / 100.0
    if not evals:
        raise ValueError(f"{path}: no row under the time-per-query table's header")
    return evals, info


def fmt_time(seconds: float | None) -> str:
    if seconds is None:
        return "-"
    for unit, scale in (("s", 1.0), ("ms", 1e-3), ("us", 1e-6), ("ns", 1e-9)):
        if seconds >= scale or unit == "ns":
            value = seconds / scale
            return f"{value:.3g} {unit}"
    raise AssertionError("unreachable")


def fmt_ratio(a: float | None, b: float | None) -> str:
    return "-" if a is None or b is None else f"{b / a:.3g}x"


def blas_percent(row: dict, n: int, d: int) -> float | None:
    t = row.get(APPLY)
    rate = row.get("blas_rate")
    if t is None or rate is None:
        return None
    return 100.0 * useful_flops(n, d) / t / rate


def eval_table(evals) -> list[str]:
    lines = [
        "| n | d | m | bderiv apply | bderiv inverse | batched NumPy | per-query ref* | "
        "vs NumPy | vs ref | useful GFLOP/s | % of BLAS | copy | apply / copy |",
        "|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for (n, d, m) in sorted(evals):
        row = evals[(n, d, m)]
        t = row.get(APPLY)
        pct = blas_percent(row, n, d)
        rate = None if t is None else useful_flops(n, d) / t / 1e9
        lines.append(
            f"| {n} | {d} | {m:.0e} | {fmt_time(t)} | {fmt_time(row.get(INVERSE))} | "
            f"{fmt_time(row.get(NUMPY))} | {fmt_time(row.get(REF))} | "
            f"{fmt_ratio(t, row.get(NUMPY))} | {fmt_ratio(t, row.get(REF))} | "
            f"{'-' if rate is None else f'{rate:.3g}'} | "
            f"{'-' if pct is None else f'{pct:.2g}%'} | {fmt_time(row.get(COPY))} | "
            f"{fmt_ratio(row.get(COPY), t)} |".replace("e+0", "e")
        )
    return lines


def build_table(builds) -> list[str]:
    lines = ["| n | d | tables | build time |", "|---:|---:|---:|---:|"]
    for (n, d), (t, nbytes) in sorted(builds.items()):
        lines.append(f"| {n} | {d} | {nbytes / 2**20:.3g} MiB | {fmt_time(t)} |")
    return lines


def thread_table(threads) -> list[str]:
    lines = ["| n | d | m | 1 thread | 2 threads | speed-up |", "|---:|---:|---:|---:|---:|---:|"]
    for (n, d, m), row in sorted(threads.items()):
        lines.append(
            f"| {n} | {d} | {m:.0e} | {fmt_time(row.get(1))} | {fmt_time(row.get(2))} | "
            f"{fmt_ratio(row.get(2), row.get(1))} |".replace("e+0", "e")
        )
    return lines


def targets(evals, builds, threads) -> list[str]:
    """Each target of issues 2, 4 and 10 with the measured value (dense tables)."""
    lines = ["| target | measured | met |", "|---|---:|:---:|"]

    def add(label, value, goal, fmt="{:.3g}x", below=False):
        if value is None:
            lines.append(f"| {label} | not measured | - |")
            return
        ok = value < goal if below else value >= goal
        lines.append(f"| {label} | {fmt.format(value)} | {'yes' if ok else 'no'} |")

    def ratio(key, base):
        row = evals.get(key, {})
        if APPLY in row and base in row:
            return row[base] / row[APPLY]
        return None

    for n in (8, 16):
        add(f"n=d={n}, m=1e5: >= 200x per-query ref", ratio((n, n, 10**5), REF), 200)
        add(f"n=d={n}, m=1e5: >= 5x batched NumPy", ratio((n, n, 10**5), NUMPY), 5)
    for n in (8, 16):
        add(f"n=d={n}, m=1e6: >= 20x batched NumPy", ratio((n, n, 10**6), NUMPY), 20)
        add(f"n=d={n}, m=1e6: >= 2000x per-query ref", ratio((n, n, 10**6), REF), 2000)
        row = threads.get((n, n, 10**6), {})
        add(f"n=d={n}, m=1e6: 1 -> 2 threads >= 1.7x",
            row[1] / row[2] if 1 in row and 2 in row else None, 1.7)
    for n, goal in ((8, 5), (16, 20), (20, 40)):  # issue 10: apply within a few copies
        row = evals.get((n, n, 10**6), {})
        add(f"n=d={n}, m=1e6: apply <= {goal}x the parallel copy",
            row[APPLY] / row[COPY] if APPLY in row and COPY in row else None, goal,
            below=True)
    key = (8, 8, 10**6) if (8, 8, 10**6) in evals else (8, 8, 10**5)
    add(f"n=d=8, m={key[2]:.0e}: useful work >= 2% of BLAS".replace("e+0", "e"),
        blas_percent(evals.get(key, {}), 8, 8), 2.0, fmt="{:.2g}%")
    build = builds.get((20, 20))
    add("n=d=20 dense tables built in < 1 s", None if build is None else build[0], 1.0,
        fmt="{:.3g} s", below=True)
    return lines


def markdown(evals, builds, threads, info, stat: str) -> str:
    out = [
        f"Measured {machine_note(info, stat)}.",
        "",
        "Time per query (BLAS: time of the same-flop product / m). *The per-query reference "
        "(`tests/reference.py`, a Python loop) is timed on the first 200 queries (20 for "
        "the smoke runs) and scaled per query; it gets the prebuilt rate table.",
        "",
        *eval_table(evals),
        "",
        "Construction (validation, rate table, transversality check):",
        "",
        *build_table(builds),
        "",
        "Threads (`numba.set_num_threads`):",
        "",
        *thread_table(threads),
        "",
        "Targets (issues 2, 4 and 10, dense tables):",
        "",
        *targets(evals, builds, threads),
    ]
    return "\n".join(out) + "\n"


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
    p.add_argument("json", help="pytest-benchmark JSON (--benchmark-json), or a Markdown "
                   "file with the table this tool printed (docs/benchmarks.md: redraw --plot "
                   "only)")
    p.add_argument("--plot", help="write a log-log PNG of time per query against n")
    p.add_argument("--stat", default="min", choices=("min", "median", "mean"),
                   help="statistic of the rounds (default min: least disturbed by other load)")
    args = p.parse_args(argv)
    if args.json.endswith(".md"):
        if not args.plot:
            p.error("a Markdown input only redraws the figure: give --plot")
        evals, info = load_markdown(args.json)
        plot(evals, args.plot, info.get("machine"))
        return 0
    evals, builds, threads, info = load(args.json, args.stat)
    sys.stdout.write(markdown(evals, builds, threads, info, args.stat))
    if args.plot:
        plot(evals, args.plot, machine_note(info, args.stat))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
