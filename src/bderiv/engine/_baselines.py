"""What every benchmark measures bderiv against, in one place.

Used by ``bderiv bench`` (:mod:`bderiv.cli.sweep`), the pytest-benchmark suite in
``benchmarks/`` and ``tools/bench_table.py``:

- :func:`random_system`: the random transversal test systems (also those of the tests),
  :func:`benchmark_system` the one of each size that every benchmark runs;
- :func:`numpy_apply`: mathematics.md sections 3 and 6 in batched NumPy, the baseline a NumPy
  user would write;
- :func:`useful_flops`: the work of one query counted as useful, ``n**2 + 2 n d``;
- the BLAS yardstick: :func:`blas_operands`, :func:`blas_yardstick`,
  :func:`measure_blas_rate` and :func:`blas_setting`, a matrix product as the machine's
  peak;
- :func:`best_time`: the best-of-N timer.

Nothing here is public API; it imports nothing of bderiv, so each baseline is independent
of the kernels it is compared with.
"""

from __future__ import annotations

import os
import time
from types import SimpleNamespace
from typing import NamedTuple

import numpy as np
from numba import prange

from .._kernels._cache import checked_njit
from .._limits import BLAS_SIZE, NUMPY_CHUNK


def useful_flops(n: int, d: int) -> int:
    """Flops of one query counted as useful work: n**2 (event times) + 2 n d (g and x).

    Examples
    --------
    >>> useful_flops(8, 16)
    320
    """
    return n * n + 2 * n * d


# --------------------------------------------------------------------------------------
# test systems
# --------------------------------------------------------------------------------------
def random_system(
    rng, n, d, *, dh_scale=1.0, f_scale=1.0, spread=0.9, speed_range=1.5, max_cond=1e3
):
    """A random transversal system (Dh, F) with every rate ``G = F Dh^T > 0``.

    With a random unit direction e and components orthogonal to it,
    ``Dh[k] = dh_scale (e + a_k)``, ``|a_k| <= spread``, and
    ``F[m] = f_scale c_m (e + b_m)``, ``|b_m| <= spread``, ``c_m = exp(U(-speed_range,
    speed_range))``, so ``G[m, k] = dh_scale f_scale c_m (1 + a_k . b_m) >= dh_scale
    f_scale c_m (1 - spread**2) > 0``. The speeds differ by up to ``e**(2 speed_range)``
    (~20x) between regions and the directions ``b_m`` differ per region, so the rates
    change a lot after each event and later events often overtake earlier ones: no fast
    path applies. When ``n <= d``, Dh is redrawn until ``cond(Dh) <= max_cond``; when
    ``n > d`` it is rank deficient.

    Parameters
    ----------
    rng : numpy.random.Generator
        The source of randomness (the arrays are a function of its state).
    n, d : int
        Events and dimension.
    dh_scale, f_scale : float
        Scales of Dh and F.
    spread : float
        Radius of the offsets a_k, b_m, in [0, 1).
    speed_range : float
        Half-width of the log-speeds c_m.
    max_cond : float
        Largest condition number of Dh accepted when ``n <= d``.

    Returns
    -------
    Dh : ndarray, shape (n, d)
    F : ndarray, shape (2**n, d)

    Raises
    ------
    ValueError
        If ``spread`` is not in [0, 1).

    Examples
    --------
    >>> import numpy as np
    >>> Dh, F = random_system(np.random.default_rng(0), 3, 4)
    >>> Dh.shape, F.shape, bool((F @ Dh.T > 0).all())
    ((3, 4), (8, 4), True)
    """
    if not 0 <= spread < 1:
        raise ValueError(f"spread must be in [0, 1) for transversality, got {spread!r}")
    Q = np.linalg.qr(rng.standard_normal((d, d)))[0]  # random rotation, e = Q[:, 0]
    e = Q[:, 0]
    perp = Q[:, 1:]

    def ball(count):
        # points of the (d-1)-dimensional ball of radius spread, in the plane orthogonal to e
        if d == 1:
            return np.zeros((count, 1))
        z = rng.standard_normal((count, d - 1))
        z *= (rng.uniform(0, 1, (count, 1)) ** (1 / (d - 1))) / np.linalg.norm(
            z, axis=1, keepdims=True
        )
        return spread * z @ perp.T

    for _ in range(1000):
        Dh = dh_scale * (e + ball(n))
        if n > d or np.linalg.cond(Dh) <= max_cond:
            break
    else:  # pragma: no cover
        raise RuntimeError(f"could not draw Dh with cond(Dh) <= max_cond = {max_cond:g}")
    c = np.exp(rng.uniform(-speed_range, speed_range, 2**n))
    F = f_scale * c[:, None] * (e + ball(2**n))
    return Dh, F


def benchmark_system(n: int, d: int, seed: int = 0):
    """The benchmarks' system of size (n, d): :func:`random_system` seeded by n, d and seed.

    Returns
    -------
    Dh : ndarray, shape (n, d)
    F : ndarray, shape (2**n, d)
    """
    return random_system(np.random.default_rng(1000 * n + d + seed), n, d)


# --------------------------------------------------------------------------------------
# the NumPy baseline
# --------------------------------------------------------------------------------------
def numpy_apply(Dh, F, G, V, inverse=False, chunk=NUMPY_CHUNK):
    """M(V) (or M^-1(V)) for a batch V, in batched NumPy (mathematics.md sections 3 and 6).

    Vectorised over the queries, looping over the n events. Per step: gather the rates of
    each query's current region (``G[B]``), the masked argmin (argmax for the inverse) of
    the event times over the pending events, then the update of the virtual position x
    and of ``g = Dh x``. It works in chunks of queries so that its temporaries stay in
    cache, with preallocated buffers and in-place ufuncs: a fair, reasonably efficient
    NumPy program, not a strawman. Ties go to the smallest event index, as in the kernels
    and the oracle.

    Parameters
    ----------
    Dh : ndarray, shape (n, d)
    F : ndarray, shape (2**n, d)
    G : ndarray, shape (2**n, n)
        The event rates ``F @ Dh.T``.
    V : ndarray, shape (m, d)
    inverse : bool
        Apply M^-1 (time running backwards from the full region) instead of M.
    chunk : int
        Queries processed together.

    Returns
    -------
    ndarray, shape (m, d)

    Examples
    --------
    >>> import numpy as np
    >>> from bderiv import BDerivative
    >>> Dh, F = random_system(np.random.default_rng(0), 3, 3)
    >>> V = np.random.default_rng(1).standard_normal((10, 3))
    >>> W = numpy_apply(Dh, F, F @ Dh.T, V)
    >>> bool(np.allclose(W, BDerivative(Dh, F)(V)))
    True
    >>> bool(np.allclose(numpy_apply(Dh, F, F @ Dh.T, W, inverse=True), V))
    True
    """
    V = np.ascontiguousarray(V, dtype=np.float64)
    m, d = V.shape
    out = np.empty_like(V)
    n = Dh.shape[0]
    c = min(chunk, max(m, 1))
    buf = _buffers(c, n, d)
    DhT = np.ascontiguousarray(Dh.T)
    start_mask = (1 << n) - 1 if inverse else 0
    for start in range(0, m, c):
        stop = min(start + c, m)
        x = out[start:stop]
        x[...] = V[start:stop]
        q = stop - start  # the last chunk may be shorter
        b = SimpleNamespace(**{name: a[:q] for name, a in buf.items()})
        _numpy_chunk(F, G, DhT, x, b, start_mask, inverse)
    return out


def _buffers(c, n, d):
    """Work arrays of one chunk of :func:`numpy_apply` (c queries), reused by every chunk."""
    return dict(
        B=np.empty(c, dtype=np.int64), B2=np.empty(c, dtype=np.int64),
        bit=np.empty(c, dtype=np.int64), t=np.empty(c), rows=np.arange(c),
        GB=np.empty((c, n)), GB2=np.empty((c, n)), tau=np.empty((c, n)), g=np.empty((c, n)),
        done=np.empty((c, n), dtype=bool), FB=np.empty((c, d)), FB2=np.empty((c, d)),
    )


def _numpy_chunk(F, G, DhT, x, b, start_mask, inverse):
    """The n steps of mathematics.md section 3 (or 6) on the queries x (q, d), in place."""
    np.matmul(x, DhT, out=b.g)
    b.B[...] = start_mask
    b.done[...] = inverse  # "done": the event is not a candidate for the next step
    for _ in range(G.shape[1]):
        np.take(G, b.B, axis=0, out=b.GB)
        np.divide(b.g, b.GB, out=b.tau)
        np.negative(b.tau, out=b.tau)
        if inverse:  # the latest event first among those that have happened
            np.putmask(b.tau, ~b.done, -np.inf)
            k = b.tau.argmax(axis=1)
        else:
            np.putmask(b.tau, b.done, np.inf)
            k = b.tau.argmin(axis=1)
        b.t[...] = b.tau[b.rows, k]
        np.left_shift(1, k, out=b.bit)
        (np.bitwise_xor if inverse else np.bitwise_or)(b.B, b.bit, out=b.B2)
        b.done[b.rows, k] = not inverse
        np.take(G, b.B2, axis=0, out=b.GB2)
        np.take(F, b.B, axis=0, out=b.FB)
        np.take(F, b.B2, axis=0, out=b.FB2)
        # g += t (G[B] - G[B']);  x += t (F[B] - F[B'])
        b.GB -= b.GB2
        b.GB *= b.t[:, None]
        b.g += b.GB
        b.FB -= b.FB2
        b.FB *= b.t[:, None]
        x += b.FB
        b.B[...] = b.B2


# --------------------------------------------------------------------------------------
# the BLAS yardstick
# --------------------------------------------------------------------------------------
def _square_operands(size: int, rng):
    rng = np.random.default_rng(0) if rng is None else rng
    return rng.standard_normal((size, size)), rng.standard_normal((size, size))


def blas_operands(n: int, d: int, m: int, rng=None):
    """Square operands whose product has the flop count of m queries' useful work.

    Parameters
    ----------
    n, d, m : int
        Events, dimension and queries: ``2 N**3 ~ m (n**2 + 2 n d)``.
    rng : numpy.random.Generator, optional

    Returns
    -------
    A, B : ndarray, shape (N, N)
    flops : int
        ``2 N**3``, the product's exact flop count.
    """
    N = max(1, round((m * useful_flops(n, d) / 2) ** (1 / 3)))
    A, B = _square_operands(N, rng)
    return A, B, 2 * N**3


def blas_yardstick(A, B, out):
    """The matrix product of the yardstick (numpy's BLAS, its default threads)."""
    return np.matmul(A, B, out=out)


def measure_blas_rate(rng=None, size: int = BLAS_SIZE, repeat: int = 5) -> float:
    """Flops per second of numpy's BLAS on a ``size`` x ``size`` product (best of repeat).

    One square product large enough to reach the machine's peak: the yardstick's time for
    a flop count f is then ``f / rate`` (a product sized to each small flop count would
    measure call overhead instead).
    """
    A, B = _square_operands(size, rng)
    C = np.empty((size, size))
    return 2 * size**3 / best_time(lambda: blas_yardstick(A, B, C), repeat).wall


@checked_njit(parallel=True)
def copy_yardstick(V, W):
    """W[:] = V on all numba threads: the streaming limit of any map that reads V and
    writes W (the lane kernels' target is a small multiple of it)."""
    for q in prange(V.shape[0]):
        for i in range(V.shape[1]):
            W[q, i] = V[q, i]


def blas_setting() -> str:
    """Which BLAS the yardstick runs and the OPENBLAS_* variables in force."""
    names = ("OPENBLAS_CORETYPE", "OPENBLAS_L2_SIZE", "OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS")
    parts = [f"{k}={os.environ[k]}" for k in names if k in os.environ] or ["no OPENBLAS_* set"]
    try:
        from threadpoolctl import threadpool_info
    except ImportError:
        try:
            cfg = np.show_config(mode="dicts")["Build Dependencies"]["blas"]
            parts.append(f"{cfg.get('name')} {cfg.get('version')}")
        except Exception:  # noqa: BLE001 - informational only, its layout varies by version
            pass
    else:
        parts.extend(
            f"openblas {lib.get('version')} {lib.get('architecture')} "
            f"threads={lib.get('num_threads')}"
            for lib in threadpool_info() if lib.get("internal_api") == "openblas"
        )
    return "; ".join(parts)


# --------------------------------------------------------------------------------------
# the timer
# --------------------------------------------------------------------------------------
class BestTime(NamedTuple):
    """Best wall-clock and best CPU seconds of one call, each the minimum over the runs."""

    wall: float
    cpu: float


def best_time(fn, repeat: int = 3, *, warmup: bool = True) -> BestTime:
    """Time ``fn()`` ``repeat`` times (after one untimed run if ``warmup``); keep the best.

    The minimum is the run least disturbed by other load on the machine. CPU time
    (``time.process_time``, all threads of the process) beside wall time shows how much
    of the machine a parallel call used.

    Examples
    --------
    >>> t = best_time(lambda: sum(range(1000)), repeat=2)
    >>> 0 < t.wall < 1
    True
    """
    if warmup:
        fn()  # compilation, caches, first touch of the output pages
    wall = cpu = np.inf
    for _ in range(repeat):
        t0, c0 = time.perf_counter(), time.process_time()
        fn()
        wall = min(wall, time.perf_counter() - t0)
        cpu = min(cpu, time.process_time() - c0)
    return BestTime(wall, cpu)
