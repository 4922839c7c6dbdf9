"""Baselines that every benchmark group runs beside bderiv's kernels.

- :func:`numpy_apply`: MATH.md section 3 in batched NumPy, vectorised over the queries and
  looping over the n events. Per step: gather the rates of each query's current region
  (``G[B]`` by fancy indexing), the masked argmin of the event times over the pending
  events, then the update of the virtual position and of ``g = Dh x``. It works in chunks
  of queries so that its temporaries stay in cache (the fastest chunk size measured here),
  with preallocated buffers and in-place ufuncs: a fair, reasonably efficient NumPy
  program, not a strawman.
- :func:`reference_apply`: the per-query oracle ``ref_apply`` of ``tests/reference.py``
  (a Python loop per query). ``ref_apply`` rebuilds the whole rate table ``G = F Dh^T``
  on every call, O(2**n n d) work that belongs to construction; to time only the
  evaluation we hand it the prebuilt table (``reference.rates`` answers from a one-entry
  cache while the baseline runs). It is timed on a subset of the queries and reported
  per query.
- :func:`blas_yardstick`: a square matrix product with the same flop count as the useful
  work of m queries, ``m (n**2 + 2 n d)`` flops: the machine's peak as a yardstick.
"""

from __future__ import annotations

import contextlib
import os
import sys

import numpy as np

_TESTS = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "tests")
if _TESTS not in sys.path:
    sys.path.insert(0, _TESTS)

import reference  # noqa: E402  (tests/reference.py, the per-query oracle)

#: queries per chunk of the NumPy baseline; its temporaries are a few (chunk, n) and
#: (chunk, d) arrays, which then stay in L2. Measured best of 1024..65536 on this machine.
NUMPY_CHUNK = 4096


def useful_flops(n: int, d: int) -> int:
    """Flops of one query counted as useful work: n**2 (event times) + 2 n d (g and x)."""
    return n * n + 2 * n * d


def numpy_apply(Dh, F, G, V, inverse=False, chunk=NUMPY_CHUNK):
    """M(V) (or M^-1(V)) for a batch V (m, d), batched NumPy, MATH.md sections 3 and 6.

    Ties go to the smallest event index, as in the kernels and the oracle.
    """
    V = np.ascontiguousarray(V, dtype=np.float64)
    m, d = V.shape
    out = np.empty_like(V)
    n = Dh.shape[0]
    c = min(chunk, max(m, 1))
    # buffers reused by every chunk
    B = np.empty(c, dtype=np.int64)
    B2 = np.empty(c, dtype=np.int64)
    GB = np.empty((c, n))
    GB2 = np.empty((c, n))
    FB = np.empty((c, d))
    FB2 = np.empty((c, d))
    tau = np.empty((c, n))
    g = np.empty((c, n))
    done = np.empty((c, n), dtype=bool)
    t = np.empty(c)
    bit = np.empty(c, dtype=np.int64)
    rows_all = np.arange(c)
    DhT = np.ascontiguousarray(Dh.T)
    full = (1 << n) - 1
    for start in range(0, m, c):
        stop = min(start + c, m)
        q = stop - start
        sl = slice(0, q)
        rows = rows_all[sl]
        x = out[start:stop]
        x[...] = V[start:stop]
        np.matmul(x, DhT, out=g[sl])
        B[sl] = full if inverse else 0
        done[sl] = inverse  # "done": the event is not a candidate for the next step
        for _ in range(n):
            np.take(G, B[sl], axis=0, out=GB[sl])
            np.divide(g[sl], GB[sl], out=tau[sl])
            np.negative(tau[sl], out=tau[sl])
            if inverse:
                # latest event first among those that have happened
                np.putmask(tau[sl], ~done[sl], -np.inf)
                k = tau[sl].argmax(axis=1)
            else:
                np.putmask(tau[sl], done[sl], np.inf)
                k = tau[sl].argmin(axis=1)
            t[sl] = tau[rows, k]
            np.left_shift(1, k, out=bit[sl])
            if inverse:
                np.bitwise_xor(B[sl], bit[sl], out=B2[sl])
                done[rows, k] = False
            else:
                np.bitwise_or(B[sl], bit[sl], out=B2[sl])
                done[rows, k] = True
            np.take(G, B2[sl], axis=0, out=GB2[sl])
            np.take(F, B[sl], axis=0, out=FB[sl])
            np.take(F, B2[sl], axis=0, out=FB2[sl])
            # g += t (G[B] - G[B']);  x += t (F[B] - F[B'])
            GB[sl] -= GB2[sl]
            GB[sl] *= t[sl, None]
            g[sl] += GB[sl]
            FB[sl] -= FB2[sl]
            FB[sl] *= t[sl, None]
            x += FB[sl]
            B[sl] = B2[sl]
    return out


@contextlib.contextmanager
def _prebuilt_rates(G):
    """Let ``reference.rates`` return the prebuilt table (evaluation only, no rebuild)."""
    original = reference.rates
    reference.rates = lambda Dh, F: G
    try:
        yield
    finally:
        reference.rates = original


def reference_apply(Dh, F, G, V, inverse=False):
    """The per-query oracle on every row of V (m, d): a Python loop over the queries."""
    fn = reference.ref_inverse if inverse else reference.ref_apply
    out = np.empty_like(V, dtype=np.float64)
    with _prebuilt_rates(G):
        for i in range(V.shape[0]):
            out[i] = fn(Dh, F, V[i])
    return out


def blas_operands(n: int, d: int, m: int, rng=None):
    """Square matrices A, B (N, N) with 2 N**3 ~ m (n**2 + 2 n d) flops; returns (A, B, flops)."""
    rng = np.random.default_rng(0) if rng is None else rng
    total = m * useful_flops(n, d)
    N = max(1, round((total / 2) ** (1 / 3)))
    A = rng.standard_normal((N, N))
    Bm = rng.standard_normal((N, N))
    return A, Bm, 2 * N**3


def blas_yardstick(A, Bm, out):
    """The matrix product of the yardstick (numpy's BLAS, its default threads)."""
    return np.matmul(A, Bm, out=out)


def blas_setting() -> str:
    """Which BLAS the yardstick runs and the OPENBLAS_* variables in force."""
    env = {k: os.environ.get(k) for k in ("OPENBLAS_CORETYPE", "OPENBLAS_L2_SIZE",
                                         "OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS")}
    parts = [f"{k}={v}" for k, v in env.items() if v is not None] or ["no OPENBLAS_* set"]
    try:
        from threadpoolctl import threadpool_info

        for lib in threadpool_info():
            if lib.get("internal_api") == "openblas":
                parts.append(
                    f"openblas {lib.get('version')} {lib.get('architecture')} "
                    f"threads={lib.get('num_threads')}"
                )
    except ImportError:
        try:
            cfg = np.show_config(mode="dicts")["Build Dependencies"]["blas"]
            parts.append(f"{cfg.get('name')} {cfg.get('version')}")
        except Exception:  # noqa: BLE001 - informational only
            pass
    return "; ".join(parts)
