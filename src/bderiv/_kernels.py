"""Numba kernels for dense corner tables. No validation here: callers pass C-contiguous
float64 arrays of consistent shapes (see ``bderivative.py``).

Tables (MATH.md section 1): ``Dh`` (n, d), ``F`` (2**n, d) corner values, ``G`` (2**n, n)
event rates ``F @ Dh.T``. A query is one row of ``V`` (m, d).

Every batch kernel computes each query with the same serial code, so results are bitwise
independent of the thread count and of how the batch is split.
"""

from __future__ import annotations

import numpy as np
from numba import njit, parallel_chunksize, prange

#: queries per parallel task. Threads take tasks one at a time (dynamic schedule), so a
#: thread that the OS delays does not hold the other back; with 256 a batch of
#: ``PARALLEL_MIN_QUERIES`` = 1024 already gives each of 2 threads two tasks, and the
#: scratch arrays a task allocates stay negligible. Measured: at n = 8, 256 to 1024
#: queries take 90 to 360 us on one thread, far above the start-up of the second.
TASK_QUERIES = 256

#: queries evaluated in lockstep by one thread. Each query is a chain of n dependent steps
#: (rates of the region reached -> event times -> next event -> next region), so one query
#: alone leaves the core waiting on latencies (division, table loads); interleaving GROUP
#: independent chains lets the out-of-order core overlap them. Measured on this project's
#: machine (n = d = 8, 16, 20): 1 -> 4 queries per group is 1.6x to 2.3x faster per
#: query; 8 or 16 gain nothing more.
GROUP = 4

# error_model="numpy": a division by zero gives inf instead of a Python exception. Rates
# are positive by construction (checked when the tables are built), and without the
# exception path LLVM vectorises the loops that divide.
_JIT = {"cache": True, "error_model": "numpy"}


@njit(**_JIT)
def _chains(DhT, G, V, q0, pn, inverse, g, tau, times, order, chain):
    """Event chains of the queries ``V[q0:q0 + pn]`` (pn <= GROUP), in lockstep.

    MATH.md section 3 (section 6 when ``inverse``): keep g = Dh x for the virtual
    position x; at each step the next event is the pending k with the smallest time
    -g[k] / G[B, k] *in the current region B* (the largest among the happened ones,
    going backwards). Ties go to the smaller k. An event that is no longer a candidate
    gets g[k] = -inf (+inf backwards), so that its time is never selected again: no bit
    tests in the inner loops, which are plain loops over k.

    Writes, for each p < pn: ``times[p, j]`` (j-th event time; non-decreasing forwards),
    ``order[p, j]`` (its event) and ``chain[p, j]`` (region before the (j+1)-th event,
    chain[p, 0] = 0, chain[p, n] = full mask), all in forward order.
    """
    d, n = DhT.shape
    full = (1 << n) - 1
    for p in range(pn):
        q = q0 + p
        for k in range(n):
            g[p, k] = 0.0
        for i in range(d):
            ui = V[q, i]
            for k in range(n):
                g[p, k] += DhT[i, k] * ui
        chain[p, n if inverse else 0] = full if inverse else 0
    for step in range(n):
        j = n - 1 - step if inverse else step
        for p in range(pn):
            b = chain[p, j + 1] if inverse else chain[p, j]
            for k in range(n):
                tau[p, k] = -g[p, k] / G[b, k]
        for p in range(pn):
            best = tau[p, 0]
            kb = 0
            if inverse:
                for k in range(1, n):
                    tk = tau[p, k]
                    better = tk > best
                    best = tk if better else best
                    kb = k if better else kb
                g[p, kb] = np.inf
                b = chain[p, j + 1]
                b2 = b & ~(1 << kb)
                chain[p, j] = b2
            else:
                for k in range(1, n):
                    tk = tau[p, k]
                    better = tk < best
                    best = tk if better else best
                    kb = k if better else kb
                g[p, kb] = -np.inf
                b = chain[p, j]
                b2 = b | (1 << kb)
                chain[p, j + 1] = b2
            # the virtual position moves by best * (F[b] - F[b2]); so does g = Dh x
            for k in range(n):
                g[p, k] += best * (G[b, k] - G[b2, k])
            times[p, j] = best
            order[p, j] = kb


@njit(**_JIT)
def _map_block(DhT, F, G, V, out, start, stop, inverse):
    d, n = DhT.shape
    g = np.empty((GROUP, n))
    tau = np.empty((GROUP, n))
    times = np.empty((GROUP, n))
    order = np.empty((GROUP, n), dtype=np.int64)
    chain = np.empty((GROUP, n + 1), dtype=np.int64)
    # going back in time the position moves by -t_j (F[B_j] - F[B_{j+1}])
    sign = -1.0 if inverse else 1.0
    for q0 in range(start, stop, GROUP):
        pn = min(GROUP, stop - q0)
        _chains(DhT, G, V, q0, pn, inverse, g, tau, times, order, chain)
        # telescope (MATH.md section 3): x = u + sum_j t_j (F[B_{j-1}] - F[B_j])
        for p in range(pn):
            q = q0 + p
            for i in range(d):
                out[q, i] = V[q, i]
            for j in range(n):
                t = sign * times[p, j]
                Bp = chain[p, j]
                Bn = chain[p, j + 1]
                for i in range(d):
                    out[q, i] += t * (F[Bp, i] - F[Bn, i])


@njit(**_JIT)
def map_serial(Dh, F, G, V, out, inverse):
    """Apply M (or M^-1 when ``inverse``) to every row of ``V``, writing ``out``."""
    DhT = np.ascontiguousarray(Dh.T)
    _map_block(DhT, F, G, V, out, 0, V.shape[0], inverse)


@njit(parallel=True, **_JIT)
def _map_tasks(Dh, F, G, V, out, inverse):
    m = V.shape[0]
    DhT = np.ascontiguousarray(Dh.T)
    n_tasks = (m + TASK_QUERIES - 1) // TASK_QUERIES
    for task in prange(n_tasks):
        start = task * TASK_QUERIES
        _map_block(DhT, F, G, V, out, start, min(start + TASK_QUERIES, m), inverse)


def map_parallel(Dh, F, G, V, out, inverse):
    """Same as :func:`map_serial`, with the batch split into tasks over threads."""
    # dynamic schedule, one task at a time (set outside the jit: inside it, numba
    # could not cache the function)
    with parallel_chunksize(1):
        _map_tasks(Dh, F, G, V, out, inverse)


def event_times_batch(Dh, G, V, times_out, order_out):
    """times_out[q, k] = time of event k; order_out[q, j] = j-th event, for every query."""
    with parallel_chunksize(1):
        _event_times_tasks(Dh, G, V, times_out, order_out)


@njit(parallel=True, **_JIT)
def _event_times_tasks(Dh, G, V, times_out, order_out):
    m = V.shape[0]
    n = Dh.shape[0]
    DhT = np.ascontiguousarray(Dh.T)
    n_tasks = (m + TASK_QUERIES - 1) // TASK_QUERIES
    for task in prange(n_tasks):
        g = np.empty((GROUP, n))
        tau = np.empty((GROUP, n))
        times = np.empty((GROUP, n))
        order = np.empty((GROUP, n), dtype=np.int64)
        chain = np.empty((GROUP, n + 1), dtype=np.int64)
        stop = min((task + 1) * TASK_QUERIES, m)
        for q0 in range(task * TASK_QUERIES, stop, GROUP):
            pn = min(GROUP, stop - q0)
            _chains(DhT, G, V, q0, pn, False, g, tau, times, order, chain)
            for p in range(pn):
                for j in range(n):
                    order_out[q0 + p, j] = order[p, j]
                    times_out[q0 + p, order[p, j]] = times[p, j]


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
