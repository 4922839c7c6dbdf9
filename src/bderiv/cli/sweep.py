"""A small dimension sweep for ``bderiv bench``: bderiv against its baselines, one process.

The full benchmark suite lives in the repository's ``benchmarks/`` (pytest-benchmark);
this module is the part an installed package can run on its own, with the same baselines
and test systems (:mod:`bderiv.engine._baselines`):

- ``bderiv``: :meth:`BDerivative.__call__` on the batch (the compiled kernels);
- ``numpy``: mathematics.md section 3 in batched NumPy
  (:func:`~bderiv.engine._baselines.numpy_apply`);
- ``blas``: the time a BLAS matrix product would take for the flop count of the useful
  work, ``m (n**2 + 2 n d)``, at the rate of a 512 x 512 product measured beside each n
  (so that a load that comes and goes moves both): a yardstick of the machine's peak.

The systems are :func:`~bderiv.engine._baselines.benchmark_system` (rates change after every
event, so no fast path applies). Each time is the best of ``repeat`` runs after one
warm-up run; construction (building the tables) is timed apart, the same way.
"""

from __future__ import annotations

import numpy as np

from .._limits import BENCH_BATCH, BENCH_NS, BENCH_REPEAT
from ..engine._baselines import (
    benchmark_system,
    best_time,
    measure_blas_rate,
    numpy_apply,
    useful_flops,
)
from ..engine.bderivative import BDerivative
from .systems import random_vectors

#: the largest n at which :func:`sweep` times the NumPy baseline by default
NUMPY_MAX_N = 16


def sweep(ns=BENCH_NS, *, d_factor: int = 1, batch: int = BENCH_BATCH, repeat: int = BENCH_REPEAT,
          numpy_max_n: int = NUMPY_MAX_N, seed: int = 0, progress=None):
    """Time bderiv, the NumPy baseline and the BLAS yardstick for each n.

    Parameters
    ----------
    ns : sequence of int
        Numbers of events.
    d_factor : int
        Dimension ``d = d_factor * n``.
    batch : int
        Queries per batch m.
    repeat : int
        Timed runs per entry (the best is kept).
    numpy_max_n : int
        Skip the NumPy baseline above this n.
    seed : int
        Seeds the systems (:func:`~bderiv.engine._baselines.benchmark_system`) and the queries.
    progress : callable, optional
        ``progress(done, total)`` after each n.

    Returns
    -------
    list of dict
        One row per (n, method): ``n``, ``d``, ``m``, ``method``, ``seconds`` (batch),
        ``seconds_per_query``, ``gflops`` (useful work rate), ``build_seconds`` (bderiv
        rows: table construction) and ``speedup`` (bderiv rows: NumPy time / bderiv time).

    Examples
    --------
    >>> rows = sweep(ns=(2,), batch=1000, repeat=1)
    >>> sorted({r["method"] for r in rows})
    ['bderiv', 'blas', 'numpy']
    """
    rows = []
    ns = list(ns)
    rng = np.random.default_rng(seed)
    for i, n in enumerate(ns):
        blas_rate = measure_blas_rate(rng)
        d = d_factor * n
        Dh, F = benchmark_system(n, d, seed)
        bd = BDerivative(Dh, F)  # untimed: the first build compiles or loads its kernels
        build = best_time(lambda Dh=Dh, F=F: BDerivative(Dh, F), repeat, warmup=False).wall
        V = random_vectors(rng, batch, d)
        out = np.empty_like(V)
        flops = batch * useful_flops(n, d)
        common = dict(n=n, d=d, m=batch)

        def row(method, seconds, common=common, flops=flops, **extra):
            return dict(common, method=method, seconds=seconds,
                        seconds_per_query=seconds / batch, gflops=flops / seconds / 1e9,
                        **extra)

        t_bd = best_time(lambda bd=bd, V=V, out=out: bd(V, out=out), repeat).wall
        entry = [row("bderiv", t_bd, build_seconds=build)]
        if n <= numpy_max_n:
            # contiguous copies: F and the rates are views into the region records
            args = (bd.Dh, np.ascontiguousarray(bd.F), np.ascontiguousarray(bd.rates), V)
            t_np = best_time(lambda args=args: numpy_apply(*args), max(1, repeat - 1)).wall
            entry.append(row("numpy", t_np))
            entry[0]["speedup"] = t_np / t_bd
        entry.append(row("blas", flops / blas_rate))
        rows.extend(entry)
        if progress is not None:
            progress(i + 1, len(ns))
    return rows


def format_table(rows) -> str:
    """A plain-text table of :func:`sweep` rows (one line per n); ``-`` where a row has no
    NumPy baseline (n above ``numpy_max_n``), no speed-up nor BLAS yardstick."""
    by_n = {}
    for r in rows:
        by_n.setdefault((r["n"], r["d"], r["m"]), {})[r["method"]] = r
    head = (
        f"{'n':>3} {'d':>3} {'m':>9} {'build':>9} {'bderiv ns/q':>12} {'numpy ns/q':>11} "
        f"{'speed-up':>9} {'GFLOP/s':>8} {'% of BLAS':>9}"
    )
    lines = [head, "-" * len(head)]
    for (n, d, m), r in sorted(by_n.items()):
        b = r["bderiv"]
        np_ = r.get("numpy")
        blas = r.get("blas")
        numpy_ns = f"{np_['seconds_per_query'] * 1e9:>11.1f}" if np_ else f"{'-':>11}"
        speedup = f"{b['speedup']:>8.1f}x" if "speedup" in b else f"{'-':>9}"
        of_blas = f"{100 * b['gflops'] / blas['gflops']:>8.1f}%" if blas else f"{'-':>9}"
        lines.append(
            f"{n:>3} {d:>3} {m:>9,} {b['build_seconds'] * 1e3:>7.2f}ms "
            f"{b['seconds_per_query'] * 1e9:>12.1f} {numpy_ns} {speedup} {b['gflops']:>8.2f} "
            f"{of_blas}"
        )
    return "\n".join(lines)
