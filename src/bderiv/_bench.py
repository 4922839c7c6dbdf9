"""A small dimension sweep for ``bderiv bench``: bderiv against its baselines, one process.

The full benchmark suite lives in the repository's ``benchmarks/`` (pytest-benchmark);
this module is the part an installed package can run on its own:

- ``bderiv``: :meth:`BDerivative.__call__` on the batch (the compiled kernels);
- ``numpy``: MATH.md section 3 in batched NumPy, vectorised over the queries and looping
  over the n events (:func:`numpy_apply`, the same algorithm as the suite's baseline);
- ``blas``: the time a BLAS matrix product would take for the flop count of the useful
  work, ``m (n**2 + 2 n d)``, at the rate of a 512 x 512 product measured once per sweep:
  a yardstick of the machine's peak.

Each time is the best of ``repeat`` runs after one warm-up run; construction (building the
tables) is timed apart.
"""

from __future__ import annotations

import time

import numpy as np

from .bderivative import BDerivative

#: queries per chunk of the NumPy baseline (its temporaries stay in cache)
NUMPY_CHUNK = 4096
#: side of the BLAS yardstick's square matrices
BLAS_SIZE = 512


def useful_flops(n: int, d: int) -> int:
    """Flops of one query counted as useful work: n**2 (event times) + 2 n d (g and x)."""
    return n * n + 2 * n * d


def random_system(n: int, d: int, seed: int = 0):
    """A transversal random system: Dh (n, d), F (2**n, d) with every rate positive.

    ``Dh = [I | 0] + 0.02 |N(0, 1)|`` and ``F`` uniform in [0.5, 1.5], so that
    ``G = F Dh^T > 0`` everywhere.
    """
    rng = np.random.default_rng(seed)
    Dh = np.zeros((n, d))
    Dh[:, :n] = np.eye(n)
    Dh += 0.02 * np.abs(rng.standard_normal((n, d)))
    F = rng.uniform(0.5, 1.5, size=(1 << n, d))
    return Dh, F


def numpy_apply(Dh, F, G, V, chunk: int = NUMPY_CHUNK):
    """M(V) for a batch V (m, d) in batched NumPy (MATH.md section 3); ties to the lowest k.

    Parameters
    ----------
    Dh : ndarray, shape (n, d)
    F : ndarray, shape (2**n, d)
    G : ndarray, shape (2**n, n)
        The event rates ``F @ Dh.T``.
    V : ndarray, shape (m, d)
    chunk : int
        Queries processed together.

    Returns
    -------
    ndarray, shape (m, d)

    Examples
    --------
    >>> import numpy as np
    >>> from bderiv import BDerivative
    >>> Dh, F = random_system(3, 3)
    >>> V = np.random.default_rng(1).standard_normal((10, 3))
    >>> bool(np.allclose(numpy_apply(Dh, F, F @ Dh.T, V), BDerivative(Dh, F)(V)))
    True
    """
    V = np.ascontiguousarray(V, dtype=np.float64)
    m, d = V.shape
    n = Dh.shape[0]
    out = np.empty_like(V)
    DhT = np.ascontiguousarray(Dh.T)
    for start in range(0, m, chunk):
        x = out[start : start + chunk]
        x[...] = V[start : start + chunk]
        rows = np.arange(x.shape[0])
        g = x @ DhT
        B = np.zeros(x.shape[0], dtype=np.int64)
        done = np.zeros((x.shape[0], n), dtype=bool)
        for _ in range(n):
            tau = -g / G[B]
            tau[done] = np.inf
            k = tau.argmin(axis=1)
            t = tau[rows, k][:, None]
            B2 = B | (1 << k)
            done[rows, k] = True
            g += t * (G[B] - G[B2])
            x += t * (F[B] - F[B2])
            B = B2
    return out


def measure_blas_rate(rng=None, size: int = BLAS_SIZE, repeat: int = 5) -> float:
    """Flops per second of numpy's BLAS on a ``size`` x ``size`` product (best of repeat).

    One square product large enough to reach the machine's peak, measured once per sweep:
    the yardstick's time for a flop count F is then ``F / rate`` (a product sized to each
    row's flop count would be tiny for small n and measure call overhead instead).
    """
    rng = np.random.default_rng(0) if rng is None else rng
    A, Bm = rng.standard_normal((size, size)), rng.standard_normal((size, size))
    C = np.empty((size, size))
    return 2 * size**3 / _best_time(lambda: np.matmul(A, Bm, out=C), repeat)


def _best_time(fn, repeat: int) -> float:
    fn()  # warm-up (compilation, caches)
    best = np.inf
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def sweep(ns=(2, 4, 8, 12, 16), *, d_factor: int = 1, batch: int = 100_000, repeat: int = 3,
          numpy_max_n: int = 16, seed: int = 0, progress=None):
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
    blas_rate = measure_blas_rate(rng)
    for i, n in enumerate(ns):
        d = d_factor * n
        Dh, F = random_system(n, d, seed)
        t0 = time.perf_counter()
        bd = BDerivative(Dh, F)
        build = time.perf_counter() - t0
        V = rng.standard_normal((batch, d))
        out = np.empty_like(V)
        flops = batch * useful_flops(n, d)
        common = dict(n=n, d=d, m=batch)

        def row(method, seconds, common=common, flops=flops, **extra):
            return dict(common, method=method, seconds=seconds,
                        seconds_per_query=seconds / batch, gflops=flops / seconds / 1e9,
                        **extra)

        t_bd = _best_time(lambda bd=bd, V=V, out=out: bd(V, out=out), repeat)
        entry = [row("bderiv", t_bd, build_seconds=build)]
        if n <= numpy_max_n:
            args = (bd.Dh, bd.F, np.asarray(bd.rates), V)
            t_np = _best_time(lambda args=args: numpy_apply(*args), max(1, repeat - 1))
            entry.append(row("numpy", t_np))
            entry[0]["speedup"] = t_np / t_bd
        entry.append(row("blas", flops / blas_rate))
        rows.extend(entry)
        if progress is not None:
            progress(i + 1, len(ns))
    return rows


def format_table(rows) -> str:
    """A plain-text table of :func:`sweep` rows (one line per n)."""
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
        lines.append(
            f"{n:>3} {d:>3} {m:>9,} {b['build_seconds'] * 1e3:>7.2f}ms "
            f"{b['seconds_per_query'] * 1e9:>12.1f} "
            f"{np_['seconds_per_query'] * 1e9 if np_ else float('nan'):>11.1f} "
            f"{b.get('speedup', float('nan')):>8.1f}x {b['gflops']:>8.2f} "
            f"{100 * b['gflops'] / blas['gflops'] if blas else float('nan'):>8.1f}%"
        )
    return "\n".join(lines)
