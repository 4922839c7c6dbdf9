"""A/B of the kernels against another checkout of bderiv, both in this process.

    python benchmarks/ab.py /work/main/src [--rounds 7] [--queries 1000000] [--cases ...]

A case is a name of the registry or ``<representation>:<n>:<d>:<queries>`` (a size the
registry does not list, e.g. ``structured:32:32:65536``).

The cases and operations are those of ``tests/variants.py`` (every kernel variant listed
once: a variant added there is benchmarked here). The other checkout's package
(``<src>/bderiv``, whose imports are all relative) is copied to a folder of the temporary
directory named by a digest of its sources (so that its compiled kernels are cached there
from one run to the next) and imported as ``bderiv_base``. Both build the same systems and
run the same queries, alternated round by round, after checking that each operation gives
the same bits in both; the table gives the median and the minimum time per query of each
and the ratios this / base (below 1: this checkout is faster). ``BDERIV_KERNELS=plain``
runs the scalar kernels of dense tables in both. The machine is shared: take the medians
of several rounds, and repeat a run whose ratios look odd.
"""

from __future__ import annotations

import argparse
import hashlib
import importlib
import pathlib
import shutil
import statistics
import sys
import tempfile
import time

import numpy as np

HERE = pathlib.Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "tests"))

from variants import OPERATIONS, REPRESENTATIONS, bench_cases  # noqa: E402

#: case name -> (representation, n, d, default queries)
CASES = bench_cases()


def case(name):
    """(representation, n, d, queries) of a registry case or of ``rep:n:d:queries``."""
    if name in CASES:
        return CASES[name]
    kind, *size = name.split(":")
    if kind not in REPRESENTATIONS or len(size) != 3:
        raise SystemExit(f"unknown case {name!r}: expected one of {list(CASES)} or "
                         f"<representation>:<n>:<d>:<queries> with a representation of "
                         f"{list(REPRESENTATIONS)}")
    return (kind, *map(int, size))


def base_package(src: pathlib.Path):
    """The package ``src/bderiv`` imported as ``bderiv_base`` (copied once per version)."""
    pkg = src / "bderiv"
    files = sorted(p for p in pkg.rglob("*.py") if "__pycache__" not in p.parts)
    digest = hashlib.sha256()
    for p in files:
        digest.update(str(p.relative_to(pkg)).encode() + p.read_bytes())
    root = pathlib.Path(tempfile.gettempdir()) / f"bderiv-ab-{digest.hexdigest()[:16]}"
    target = root / "bderiv_base"
    if not target.exists():
        shutil.copytree(pkg, root / "partial", ignore=shutil.ignore_patterns("__pycache__"))
        (root / "partial").rename(target)
    sys.path.insert(0, str(root))
    return importlib.import_module("bderiv_base")


def operations(bd, V):
    """The timed operations of a map on the queries V (tangents: V itself)."""
    return {op: (lambda run=operation.run: run(bd, V, V))
            for op, operation in OPERATIONS.items()}


def _same(a, b, op):
    for x, y in zip(np.atleast_1d(a), np.atleast_1d(b), strict=True):
        np.testing.assert_array_equal(x, y, err_msg=op)


def _difference(a, b):
    """The largest |a - b| relative to max |b| over the arrays of an operation's result."""
    return max(float(np.abs(x - y).max() / max(np.abs(y).max(), 1e-300))
               for x, y in zip(np.atleast_1d(a), np.atleast_1d(b), strict=True))


def main(argv=None):
    import bderiv

    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("base", type=pathlib.Path, help="the other checkout's src folder")
    parser.add_argument("--rounds", type=int, default=7)
    parser.add_argument("--queries", type=int, default=None, help="override per case")
    parser.add_argument("--cases", default=",".join(CASES), help="comma-separated")
    parser.add_argument("--ops", default="apply,inverse,times,jvp", help=f"of {list(OPERATIONS)}")
    parser.add_argument("--threads", type=int, default=None,
                        help="numba threads (default: all; 1 is steadier on a busy machine)")
    parser.add_argument("--unequal", action="store_true",
                        help="time even where the bits differ (an A/B of a change of "
                             "arithmetic), printing the largest difference of each operation")
    parser.add_argument("--base-first", action="store_true",
                        help="build the base's tables first (memory placement can matter "
                             "for tables beyond the caches)")
    parser.add_argument("--clock", choices=("wall", "cpu"), default="wall",
                        help="cpu: the process's CPU time (time.process_time), which time "
                             "spent waiting for a core on a busy machine does not inflate")
    args = parser.parse_args(argv)
    if args.threads:
        import numba

        numba.set_num_threads(args.threads)
    base = base_package(args.base)
    print(f"this: {pathlib.Path(bderiv.__file__).parent}\nbase: {args.base / 'bderiv'}")
    clock = time.process_time if args.clock == "cpu" else time.perf_counter
    print(f"{args.clock} time, median and minimum of the rounds after the first")
    print(f"{'case':>14} {'op':>8} {'this ns/q':>10} {'base ns/q':>10} {'ratio':>6} "
          f"{'this min':>10} {'base min':>10} {'ratio':>6}")
    for name in args.cases.split(","):
        kind, n, d, m = case(name)
        m = args.queries or m
        V = np.random.default_rng(1).standard_normal((m, d))
        order = ("base", "this") if args.base_first else ("this", "base")
        packages = {"this": bderiv, "base": base}
        build = REPRESENTATIONS[kind].build
        maps = {who: build(packages[who], n, d).bd for who in order}
        ops = {who: operations(bd, V) for who, bd in maps.items()}
        for op in args.ops.split(","):  # the same bits, or the timing means nothing
            if args.unequal:
                print(f"{name:>14} {op:>8} largest difference "
                      f"{_difference(ops['this'][op](), ops['base'][op]()):.3g}")
            else:
                _same(ops["this"][op](), ops["base"][op](), op)
        for op in args.ops.split(","):
            times = {"this": [], "base": []}
            for _ in range(args.rounds):
                for who in ("this", "base") if _ % 2 else ("base", "this"):
                    t0 = clock()
                    ops[who][op]()
                    times[who].append(clock() - t0)
            this, that = (statistics.median(times[w][1:]) / m * 1e9 for w in ("this", "base"))
            low, base_low = (min(times[w][1:]) / m * 1e9 for w in ("this", "base"))
            print(f"{name:>14} {op:>8} {this:10.1f} {that:10.1f} {this / that:6.3f} "
                  f"{low:10.1f} {base_low:10.1f} {low / base_low:6.3f}", flush=True)


if __name__ == "__main__":
    main()
