"""A/B of the kernels against another checkout of bderiv, both in this process.

    python benchmarks/ab.py /work/main/src [--rounds 7] [--queries 1000000] [--cases ...]

The other checkout's package (``<src>/bderiv``, whose imports are all relative) is copied
to a folder of the temporary directory named by a digest of its sources (so that its
compiled kernels are cached there from one run to the next) and imported as
``bderiv_base``. Both build the same systems and run the same queries, alternated round
by round, after checking that each operation gives the same bits in both; the table
gives the median and the minimum time per query of each and the ratios this / base
(below 1: this checkout is faster). ``BDERIV_KERNELS=plain`` runs the scalar kernels of
dense tables in both. The machine is shared: take the medians of several rounds, and
repeat a run whose ratios look odd.
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

#: case name -> (representation, n, d, default queries)
CASES = {
    "dense8": ("dense", 8, 8, 10**6),
    "dense16": ("dense", 16, 16, 10**6),
    "dense20": ("dense", 20, 20, 2 * 10**5),
    "structured128": ("structured", 128, 128, 1 << 15),
    "function8": ("function", 8, 8, 1 << 16),
    "resets6": ("resets", 6, 8, 1 << 17),
}


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


def system(kind: str, n: int, d: int, package):
    """The map of one case built by ``package`` (the same arrays for both checkouts)."""
    from bderiv._baselines import benchmark_system

    if kind == "structured":
        sys.path.insert(0, str(HERE))
        from test_bench_corners import contact_system

        Dh, model = contact_system(n, d)
        corners = package.corners.StructuredCorners(model.F0, model.A, model.pairs, model.B)
        return package.BDerivative(Dh, corners, fast_paths=False)
    Dh, F = benchmark_system(n, d)
    if kind == "dense":
        return package.BDerivative(Dh, F, fast_paths=False)
    if kind == "function":
        return package.BDerivative(Dh, package.CornerFunction(_table_function(F)),
                                   fast_paths=False)
    # resets that scale the last coordinate (beyond the events' Jacobian, so that they
    # commute and keep the surfaces): the reset kernels' dense update
    Dh = np.eye(n, d)
    resets = np.broadcast_to(np.eye(d), (1 << n, n, d, d)).copy()
    resets[..., d - 1, d - 1] = 0.5
    return package.BDerivative(Dh, np.abs(F) + 1.0, resets=resets)


def _table_function(F):
    """An njit corner function that reads a dense table (the function engine's kernels on
    a known model)."""
    from numba import njit

    @njit
    def func(happened, out):
        b = 0
        for k in range(happened.shape[0]):
            b |= np.int64(happened[k]) << k
        for i in range(out.shape[0]):
            out[i] = F[b, i]

    return func


def operations(bd, V):
    """The timed operations of a map on the queries V."""
    W = bd(V)
    return {"apply": lambda: bd(V), "inverse": lambda: bd.inverse(W),
            "orders": lambda: bd.orders(V), "jvp": lambda: bd.jvp(V, V)}


def main(argv=None):
    import bderiv

    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("base", type=pathlib.Path, help="the other checkout's src folder")
    parser.add_argument("--rounds", type=int, default=7)
    parser.add_argument("--queries", type=int, default=None, help="override per case")
    parser.add_argument("--cases", default=",".join(CASES), help="comma-separated")
    parser.add_argument("--ops", default="apply,inverse,orders,jvp")
    parser.add_argument("--threads", type=int, default=None,
                        help="numba threads (default: all; 1 is steadier on a busy machine)")
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
        kind, n, d, m = CASES[name]
        m = args.queries or m
        V = np.random.default_rng(1).standard_normal((m, d))
        order = ("base", "this") if args.base_first else ("this", "base")
        packages = {"this": bderiv, "base": base}
        maps = {who: system(kind, n, d, packages[who]) for who in order}
        ops = {who: operations(bd, V) for who, bd in maps.items()}
        for op in args.ops.split(","):  # the same bits, or the timing means nothing
            np.testing.assert_array_equal(ops["this"][op](), ops["base"][op](), err_msg=op)
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
