"""Numba kernels for dense corner tables. No validation here: callers pass C-contiguous
float64 arrays of consistent shapes (see ``bderivative.py``).

Tables (MATH.md section 1): ``Dh`` (n, d), ``F`` (2**n, d) corner values, ``G`` (2**n, n)
event rates ``F @ Dh.T``. A query is one row of ``V`` (m, d).

Every batch kernel computes each query with the same serial code, so results are bitwise
independent of the thread count and of how the batch is split.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

#: queries per parallel task; small enough to balance 2 threads, large enough that the
#: per-task scratch allocation is negligible.
TASK_QUERIES = 256


@njit(cache=True)
def forward_chain(Dh, G, u, g, times, order, chain):
    """Event times of one pre-event vector ``u`` by selection with re-read rates.

    MATH.md section 3: keep g = Dh x for the virtual position x; at each step the next
    event is the pending k with the smallest time -g[k] / G[B, k] *in the current region
    B* (ties go to the smaller k; by continuity the result does not depend on that
    choice). Writes ``times[j]`` (j-th event time, non-decreasing), ``order[j]`` (its
    event) and ``chain[j]`` (region mask after j events, chain[0] = 0).
    """
    n, d = Dh.shape
    for k in range(n):
        s = 0.0
        for i in range(d):
            s += Dh[k, i] * u[i]
        g[k] = s
    B = 0
    chain[0] = 0
    for j in range(n):
        best = 0.0
        kb = -1
        for k in range(n):
            if (B >> k) & 1 == 0:
                tau = -g[k] / G[B, k]
                if kb < 0 or tau < best:
                    best = tau
                    kb = k
        B2 = B | (1 << kb)
        # the virtual position moves by best * (F[B] - F[B2]); so does g = Dh x
        for k in range(n):
            if (B2 >> k) & 1 == 0:
                g[k] += best * (G[B, k] - G[B2, k])
        times[j] = best
        order[j] = kb
        chain[j + 1] = B2
        B = B2


@njit(cache=True)
def backward_chain(Dh, G, w, g, times, order, chain):
    """Event times of one post-event vector ``w``, latest event first (MATH.md section 6).

    Fills the same arrays as :func:`forward_chain` in forward order: ``chain[n]`` is the
    full mask and ``chain[j]`` the region before the (j+1)-th event.
    """
    n, d = Dh.shape
    for k in range(n):
        s = 0.0
        for i in range(d):
            s += Dh[k, i] * w[i]
        g[k] = s
    B = (1 << n) - 1
    chain[n] = B
    for j in range(n - 1, -1, -1):
        best = 0.0
        kb = -1
        for k in range(n):
            if (B >> k) & 1 == 1:
                tau = -g[k] / G[B, k]
                if kb < 0 or tau > best:
                    best = tau
                    kb = k
        B2 = B & ~(1 << kb)
        for k in range(n):
            if (B2 >> k) & 1 == 1:
                g[k] += best * (G[B, k] - G[B2, k])
        times[j] = best
        order[j] = kb
        chain[j] = B2
        B = B2


@njit(cache=True)
def telescope(F, u, times, chain, x):
    """x = u + sum_j times[j] * (F[chain[j]] - F[chain[j+1]]) (MATH.md section 3)."""
    n = times.shape[0]
    d = u.shape[0]
    for i in range(d):
        x[i] = u[i]
    for j in range(n):
        t = times[j]
        Bp = chain[j]
        Bn = chain[j + 1]
        for i in range(d):
            x[i] += t * (F[Bp, i] - F[Bn, i])


@njit(cache=True)
def _map_block(Dh, F, G, V, out, start, stop, inverse):
    n = Dh.shape[0]
    g = np.empty(n)
    times = np.empty(n)
    order = np.empty(n, dtype=np.int64)
    chain = np.empty(n + 1, dtype=np.int64)
    for q in range(start, stop):
        if inverse:
            backward_chain(Dh, G, V[q], g, times, order, chain)
            # going back in time: x = w + sum_j t_j (F[B_{j+1}] - F[B_j])
            for j in range(n):
                times[j] = -times[j]
        else:
            forward_chain(Dh, G, V[q], g, times, order, chain)
        telescope(F, V[q], times, chain, out[q])


@njit(cache=True)
def map_serial(Dh, F, G, V, out, inverse):
    """Apply M (or M^-1 when ``inverse``) to every row of ``V``, writing ``out``."""
    _map_block(Dh, F, G, V, out, 0, V.shape[0], inverse)


@njit(cache=True, parallel=True)
def map_parallel(Dh, F, G, V, out, inverse):
    """Same as :func:`map_serial`, with the batch split into tasks over threads."""
    m = V.shape[0]
    n_tasks = (m + TASK_QUERIES - 1) // TASK_QUERIES
    for task in prange(n_tasks):
        start = task * TASK_QUERIES
        _map_block(Dh, F, G, V, out, start, min(start + TASK_QUERIES, m), inverse)


@njit(cache=True, parallel=True)
def event_times_batch(Dh, G, V, times_out, order_out):
    """times_out[q, k] = time of event k; order_out[q, j] = j-th event, for every query."""
    m = V.shape[0]
    n = Dh.shape[0]
    n_tasks = (m + TASK_QUERIES - 1) // TASK_QUERIES
    for task in prange(n_tasks):
        g = np.empty(n)
        times = np.empty(n)
        chain = np.empty(n + 1, dtype=np.int64)
        for q in range(task * TASK_QUERIES, min((task + 1) * TASK_QUERIES, m)):
            forward_chain(Dh, G, V[q], g, times, order_out[q], chain)
            for j in range(n):
                times_out[q, order_out[q, j]] = times[j]


@njit(cache=True)
def piece_matrix(Dh, F, G, order, out):
    """Linear piece of one event order: S_n ... S_1 (MATH.md section 4), into ``out`` (d, d).

    S_j = I + (F[B_j] - F[B_{j-1}]) Dh[k_j]^T / G[B_{j-1}, k_j]; applied to the running
    product M as M += outer(F[B_j] - F[B_{j-1}], Dh[k_j] @ M) / G[B_{j-1}, k_j].
    """
    n, d = Dh.shape
    out[:, :] = 0.0
    for i in range(d):
        out[i, i] = 1.0
    row = np.empty(d)
    B = 0
    for j in range(n):
        k = order[j]
        B2 = B | (1 << k)
        inv_rate = 1.0 / G[B, k]
        for c in range(d):
            s = 0.0
            for i in range(d):
                s += Dh[k, i] * out[i, c]
            row[c] = s * inv_rate
        for r in range(d):
            jump = F[B2, r] - F[B, r]
            for c in range(d):
                out[r, c] += jump * row[c]
        B = B2
