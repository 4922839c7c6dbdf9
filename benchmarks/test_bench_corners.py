"""Corner-model benchmarks: structured corners up to n = 128 events, no 2**n table.

Groups (pytest-benchmark ``group``):

- ``structured n=.. m=..``: ``bd(V)`` and ``bd.inverse(W)`` for structured corners whose
  rates depend on the other events (the general kernel), beside the same model with own
  rates on the ``linear`` fast path, the dense-table kernel on the model's table (n <= 16
  only) and a BLAS matrix product of the useful flop count ``m (n**2 + 2 n d)``.
- ``structured build n=..``: the constructor, timed apart.

With the default ``--benchmark-disable`` the small cases run once as smoke tests (a few
seconds). The sweep (n = 16, 32, 64, 128; big cases are marked ``slow``)::

    python -m pytest benchmarks/test_bench_corners.py -n 0 -m "slow or not slow" \\
        --benchmark-enable --benchmark-json=corners.json

or, for the table of time per query up to n = 256 and the growth exponent from n = 16 to
128 (the issue 4 targets: exponent <= 2.2, n = 128 at >= 1e5 queries/s on 2 cores; issue
10: n = 128 at >= 1.2e5 queries/s)::

    python benchmarks/test_bench_corners.py [--queries 100000] [--record]

(``--record``: the rows of docs/benchmarks.md's table to ``benchmarks/results/corners.json``.)
"""

from __future__ import annotations

import argparse

import _record
import numpy as np
import pytest
from numba import get_num_threads

from bderiv import BDerivative
from bderiv.engine._baselines import best_time, blas_operands, blas_yardstick
from bderiv.geometry.corners import StructuredCorners

NS_SMOKE = (16, 128)
NS_SLOW = (32, 64)


def contact_system(n, d=None, seed=0, pairs_per_event=2):
    """Structured corners like a multi-contact system, transversal by construction.

    Dh = I + O(1/n) coupling, F0 with unit rates; each contact's jump A[k] and each pair's
    jump B[p] change the rates of all events a little (the bound on every rate stays
    >= 0.6, so transversality is proved and the kernel skips its checks), enough that later
    events overtake earlier ones: the general selection kernel is needed.
    """
    d = n if d is None else d
    rng = np.random.default_rng(seed)
    Dh = np.eye(n, d) + 0.3 / n * rng.uniform(-1, 1, (n, d))
    F0 = np.linalg.lstsq(Dh, np.ones(n), rcond=None)[0]
    A = 0.4 / n * rng.uniform(-1, 1, (n, d))
    p = n * pairs_per_event // 2
    i = rng.integers(0, n, p)
    j = (i + rng.integers(1, n, p)) % n
    B = 0.2 / n * rng.uniform(-1, 1, (p, d))
    return Dh, StructuredCorners(F0, A, np.stack([i, j], axis=1), B)


def own_rate_system(n, seed=0):
    """The same size with own rates and no pairs: the ``linear`` fast path."""
    rng = np.random.default_rng(seed)
    Dh = np.eye(n) + 0.3 / n * rng.uniform(-1, 1, (n, n))
    A = rng.uniform(-0.4, 1.0, n)[:, None] * np.linalg.inv(Dh).T
    return Dh, StructuredCorners(np.linalg.solve(Dh, np.ones(n)), A)


def _queries(n, m, seed=1):
    return np.random.default_rng(seed).standard_normal((m, n))


def _cases():
    for n in NS_SMOKE + NS_SLOW:
        marks = [pytest.mark.slow] if n in NS_SLOW else []
        yield pytest.param(n, 512, id=f"n{n}-m512", marks=marks)
        yield pytest.param(n, 1 << 15, id=f"n{n}-m32768", marks=[pytest.mark.slow])


@pytest.mark.parametrize("n, m", list(_cases()))
@pytest.mark.parametrize("contender", ["apply", "inverse", "linear", "dense", "blas"])
def test_structured_eval(benchmark, n, m, contender):
    benchmark.group = f"structured n={n} m={m}"
    benchmark.extra_info.update(queries=m, n=n, d=n, threads=get_num_threads())
    V = _queries(n, m)
    out = np.empty_like(V)
    if contender in ("apply", "inverse"):
        Dh, model = contact_system(n)
        bd = BDerivative(Dh, model)
        assert bd.fast_path is None  # the general kernel
        fn = bd.apply if contender == "apply" else bd.inverse
        fn(V[:8], out=out[:8])  # warm (compiled kernels are cached on disk)
        benchmark(fn, V, out=out)
    elif contender == "linear":
        Dh, model = own_rate_system(n)
        bd = BDerivative(Dh, model)
        assert bd.fast_path == "linear"
        bd(V[:8], out=out[:8])
        benchmark(bd, V, out=out)
    elif contender == "dense":
        if n > 16:
            pytest.skip("the dense table has 2**n rows")
        Dh, model = contact_system(n)
        bd = BDerivative(Dh, model.table(), fast_paths=False)
        bd(V[:8], out=out[:8])
        benchmark(bd, V, out=out)
    else:  # BLAS yardstick: a square product of m (n^2 + 2 n d) flops
        A, B, flops = blas_operands(n, n, m)
        benchmark.extra_info["flops"] = flops
        benchmark(blas_yardstick, A, B, np.empty_like(A))


@pytest.mark.parametrize("n", [16, pytest.param(128, marks=pytest.mark.slow)])
def test_structured_build(benchmark, n):
    benchmark.group = f"structured build n={n}"
    Dh, model = contact_system(n)
    benchmark(BDerivative, Dh, model)


def test_contenders_agree():
    """The structured kernel and the dense kernel on the model's table give one map."""
    n = 10
    Dh, model = contact_system(n)
    assert (model.table() @ Dh.T).min() >= 0.6  # the rate bound contact_system promises
    V = _queries(n, 2000)
    np.testing.assert_allclose(BDerivative(Dh, model)(V),
                               BDerivative(Dh, model.table(), fast_paths=False)(V), atol=1e-11)


# ----------------------------------------------------------------------------------------
# script: the time-per-query table and the growth exponent
# ----------------------------------------------------------------------------------------
def measure(n, m, repeat=3):
    """Best wall time per query of bd(V) (all threads) and CPU time per query."""
    Dh, model = contact_system(n)
    bd = BDerivative(Dh, model)
    V = _queries(n, m)
    out = np.empty_like(V)
    bd(V[:1024], out=out[:1024])  # warm on a part: compiled kernels, threads started
    best = best_time(lambda: bd(V, out=out), repeat, warmup=False)
    return best.wall / m, best.cpu / m


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--queries", type=int, default=50_000)
    parser.add_argument("--ns", type=int, nargs="+", default=[16, 32, 64, 128, 256])
    _record.add_argument(parser, "corners")
    args = parser.parse_args(argv)
    print(f"structured corners, d = n, {args.queries} queries, {get_num_threads()} threads")
    print("| n | us/query (wall) | queries/s | CPU us/query |")
    print("|---|---|---|---|")
    res = {}
    for n in args.ns:
        res[n] = measure(n, args.queries)
        wall, cpu = res[n]
        print(f"| {n} | {wall * 1e6:.2f} | {1 / wall:.3g} | {cpu * 1e6:.2f} |", flush=True)
    lo, hi = min(res), (128 if 128 in res else max(res))  # the targets' range
    if hi > lo:
        for i, what in ((0, "wall"), (1, "CPU")):
            k = np.log(res[hi][i] / res[lo][i]) / np.log(hi / lo)
            print(f"growth exponent n={lo}..{hi} ({what} time): {k:.2f} (target <= 2.2)")
    if args.record:
        rows = [dict(n=n, wall=wall, rate=1 / wall, cpu=cpu) for n, (wall, cpu) in res.items()]
        _record.record("corners", {"main": rows}, path=args.record, meta={
            "note": f"d = n, {args.queries} queries, {get_num_threads()} threads"})


if __name__ == "__main__":
    main()
