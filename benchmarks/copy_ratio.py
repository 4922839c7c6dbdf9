"""Issue 10's targets: ``bd(V)`` as a multiple of a parallel copy of V into W, interleaved.

The sweep of ``test_bench_dense.py`` times each contender's rounds one after the other; on
a shared machine whose speed drifts over seconds (a VM's second core comes and goes) the
ratio then compares different moments. Here every round times the copy, ``bd(V)`` and
``bd.inverse(V)`` back to back, and each keeps its minimum over the rounds::

    python benchmarks/copy_ratio.py [--ns 8 16 20] [--m 1000000] [--rounds 15]

The lane kernels compile for the CPU numba targets; to measure another instruction set
on the same machine (a 256-bit AVX2 build, say), choose it and a fresh cache::

    NUMBA_CPU_NAME=haswell NUMBA_CACHE_DIR=/tmp/avx2 python benchmarks/copy_ratio.py

Prints one Markdown row per n (d = n): times per query and the ratios to the copy;
``--record`` writes the rows of docs/benchmarks.md's table to
``benchmarks/results/copy_ratio.json`` (``_record.py``).
"""

from __future__ import annotations

import argparse
import os
import time

import _record
import numba
import numpy as np

from bderiv import BDerivative
from bderiv.engine._baselines import benchmark_system, copy_yardstick

TARGETS = {8: 5, 16: 20, 20: 40}  # issue 10: apply within this many copies


def _seconds(fn) -> float:
    t = time.perf_counter()
    fn()
    return time.perf_counter() - t


def measure(n: int, m: int, rounds: int) -> dict:
    """Minimum seconds per query of the copy, ``bd(V)`` and ``bd.inverse(V)`` (d = n)."""
    bd = BDerivative(*benchmark_system(n, n))
    V = np.random.default_rng(0).standard_normal((m, n))
    W = np.empty_like(V)
    runs = {"copy": lambda: copy_yardstick(V, W), "apply": lambda: bd(V, out=W),
            "inverse": lambda: bd.inverse(V, out=W)}
    best = {}
    for fn in runs.values():  # compiled and every page touched
        fn()
    for _ in range(rounds):
        for name, fn in runs.items():
            best[name] = min(best.get(name, np.inf), _seconds(fn) / m)
    return best


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--ns", type=int, nargs="+", default=[8, 16, 20])
    ap.add_argument("--m", type=int, default=10**6)
    ap.add_argument("--rounds", type=int, default=15)
    _record.add_argument(ap, "copy_ratio")
    args = ap.parse_args(argv)
    cpu = os.environ.get("NUMBA_CPU_NAME", "host")
    print(f"numba target: {cpu}; {numba.get_num_threads()} threads; m = {args.m}; min of "
          f"{args.rounds} interleaved rounds\n")
    print("| n = d | copy | apply | inverse | apply / copy | inverse / copy |")
    print("|---:|---:|---:|---:|---:|---:|")
    rows = []
    for n in args.ns:
        t = measure(n, args.m, args.rounds)
        print(f"| {n} | {t['copy'] * 1e9:.2f} ns | {t['apply'] * 1e9:.1f} ns | "
              f"{t['inverse'] * 1e9:.1f} ns | {t['apply'] / t['copy']:.1f}x | "
              f"{t['inverse'] / t['copy']:.1f}x |", flush=True)
        rows.append(dict(n=n, **t, apply_copy=t["apply"] / t["copy"],
                         target=TARGETS.get(n)))
    if args.record:
        _record.record("copy_ratio", {"main": rows}, path=args.record,
                       meta={"note": f"min of {args.rounds} rounds, m = {args.m}, "
                                     f"{numba.get_num_threads()} threads, numba target {cpu}"})


if __name__ == "__main__":
    main()
