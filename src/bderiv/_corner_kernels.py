"""Numba kernels for corner models and fast paths. No validation here: callers pass
C-contiguous float64 / int64 / uint8 arrays of consistent shapes (see ``_engines.py``).

Three families, each with a per-query chain function and batch drivers:

- **structured** corners (``F[mask] = F0 + sum_{k in mask} A[k] + sum_{pairs in mask} B[p]``):
  the rates of the current region are updated incrementally along each query's chain;
  the result is ``u -+ (A^T t + B^T s)`` with ``t`` the event times and ``s[p]`` the time
  at which pair p switched on (``max`` of its two event times).
- **function** corners: a user njit function ``func(happened, out)`` (``happened`` a uint8
  array of n flags, 1 = event happened) evaluated on the n + 1 regions of each chain.
- **fast paths**: rates that depend only on the event's own bit (times are then the
  first-order times, the order a plain sort) and linear maps (additive corners too).

A query whose chain meets a rate <= 0 stops and writes the offending event into
``status[q]`` (else -1); the caller re-runs that query alone to name the region.

Every batch kernel computes each query with the same serial code, so results are bitwise
independent of the thread count and of how the batch is split into tasks or chunks.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

#: queries per parallel task (same trade-off as ``_kernels.TASK_QUERIES``).
TASK_QUERIES = 256

#: below this many events the fast-path order is found by insertion sort.
INSERTION_SORT_MAX = 24

INT_MAX = np.iinfo(np.int64).max
INT_MIN = np.iinfo(np.int64).min


# ----------------------------------------------------------------------------------------
# shared helpers
# ----------------------------------------------------------------------------------------
@njit(cache=True)
def stable_order(t, order):
    """order = stable argsort of t (ties keep the smaller event first)."""
    n = t.shape[0]
    if n <= INSERTION_SORT_MAX:
        for k in range(n):
            order[k] = k
        for j in range(1, n):
            k = order[j]
            v = t[k]
            i = j - 1
            while i >= 0 and t[order[i]] > v:
                order[i + 1] = order[i]
                i -= 1
            order[i + 1] = k
    else:
        order[:] = np.argsort(t, kind="mergesort")


@njit(cache=True)
def linear_map(MT, V, out, start, stop):
    """out[q] = M @ V[q] for q in [start, stop), from MT = M.T, as axpys (vectorises)."""
    d = MT.shape[0]
    for q in range(start, stop):
        for r in range(d):
            out[q, r] = 0.0
        for c in range(d):
            vc = V[q, c]
            for r in range(d):
                out[q, r] += MT[c, r] * vc


@njit(cache=True)
def linear_map_serial(MT, V, out):
    linear_map(MT, V, out, 0, V.shape[0])


@njit(cache=True, parallel=True)
def linear_map_parallel(MT, V, out):
    m = V.shape[0]
    n_tasks = (m + TASK_QUERIES - 1) // TASK_QUERIES
    for task in prange(n_tasks):
        start = task * TASK_QUERIES
        linear_map(MT, V, out, start, min(start + TASK_QUERIES, m))


# ----------------------------------------------------------------------------------------
# structured corners
# ----------------------------------------------------------------------------------------
@njit(cache=True, error_model="numpy")
def _impacts_t(DhT, u, g):
    """g = Dh @ u from DhT = Dh.T (d, n), as axpys over the rows of DhT (vectorises)."""
    d, n = DhT.shape
    for k in range(n):
        g[k] = 0.0
    for i in range(d):
        ui = u[i]
        for k in range(n):
            g[k] += DhT[i, k] * ui


@njit(cache=True, error_model="numpy")
def structured_chain(DhT, g0, gfull, a, bDh, ptr, other, pidx, u, inverse, check,
                     g, r, tau, key, perm, posof, jump, hap, tev, order, s):
    """Event times of one query for structured corners (MATH.md section 3 / 6).

    ``DhT = Dh.T``; ``a[i, k] = Dh[k] . A[i]`` and ``bDh[p, k] = Dh[k] . B[p]`` are the
    rate jumps; the pairs touching event i are ``pidx[ptr[i]:ptr[i+1]]`` with partner
    ``other[...]``. Writes ``tev[k]`` (time of event k), ``order[j]`` (j-th event),
    ``s[p]`` (time pair p switches on) and leaves ``hap`` = the final region. With
    ``check``, every rate of every region on the chain must be > 0: returns -1, or the
    first event whose rate is <= 0 in region ``hap`` (the chain stops there). Without
    ``check`` (transversality proved for all regions) returns -1.

    ``g`` and ``r`` are kept in *position* order: event ``perm[i]`` sits at position i and
    the events that can be next (pending forward, happened backward) fill positions
    ``0..np-1``; a selected event is swapped to position ``np - 1`` and dropped, so step j
    works on n - j positions (half the work of scanning all n). Each step's loops
    vectorise (hence ``error_model="numpy"``: a division that may raise does not): the
    candidate times ``tau = -g / r``; an integer min (max backward) over ``key``, the bits
    of tau mapped to int64 in the same order; the smallest event holding that key (ties to
    the smaller event); the update of ``g`` and ``r`` by the jump of the selected event
    and its active pairs, gathered into position order once (``jump``).
    """
    n = g.shape[0]
    _impacts_t(DhT, u, jump)
    c_sign = 1.0 if inverse else -1.0
    for k in range(n):
        g[k] = jump[k]
        r[k] = gfull[k] if inverse else g0[k]
        hap[k] = 1 if inverse else 0
        perm[k] = k
        posof[k] = k
    tbits = tau.view(np.int64)
    npos = n
    for j in range(n):
        if check:
            bad = 0
            for i in range(n):
                bad |= r[i] <= 0.0
            if bad:
                worst = n
                for i in range(n):
                    worst = min(worst, perm[i] if not r[i] > 0.0 else n)
                return worst
        for i in range(npos):
            tau[i] = -g[i] / r[i]
        # float order == int64 order of b ^ ((b >> 63) & 0x7ff...f) for finite doubles
        if inverse:
            best = INT_MIN
            for i in range(npos):
                b = tbits[i]
                kk = b ^ ((b >> 63) & INT_MAX)
                key[i] = kk
                best = max(best, kk)
        else:
            best = INT_MAX
            for i in range(npos):
                b = tbits[i]
                kk = b ^ ((b >> 63) & INT_MAX)
                key[i] = kk
                best = min(best, kk)
        kb = n
        for i in range(npos):
            kb = min(kb, perm[i] if key[i] == best else n)
        ib = posof[kb]
        t = tau[ib]
        tev[kb] = t
        if inverse:
            order[n - 1 - j] = kb
            hap[kb] = 0
        else:
            order[j] = kb
            hap[kb] = 1
        # drop kb: swap it to the last candidate position
        npos -= 1
        last = perm[npos]
        perm[ib], perm[npos] = last, kb
        posof[last], posof[kb] = ib, npos
        g[ib], g[npos] = g[npos], g[ib]
        r[ib], r[npos] = r[npos], r[ib]
        # the jump of the rates: a[kb] plus the rows of the pairs kb switches on (off)
        m = n if check else npos
        for i in range(m):
            jump[i] = a[kb, perm[i]]
        for e in range(ptr[kb], ptr[kb + 1]):
            if hap[other[e]] == 1:
                p = pidx[e]
                s[p] = t
                for i in range(m):
                    jump[i] += bDh[p, perm[i]]
        c = c_sign * t
        for i in range(m):
            g[i] += c * jump[i]
            r[i] -= c_sign * jump[i]
    if check:
        for i in range(n):
            if not r[i] > 0.0:
                return perm[i]
    return -1


@njit(cache=True)
def structured_output(A, Bm, u, tev, s, inverse, x):
    """x = u - A^T t - B^T s (forward) or u + A^T t + B^T s (inverse)."""
    n, d = A.shape
    sign = 1.0 if inverse else -1.0
    for i in range(d):
        x[i] = u[i]
    for k in range(n):
        c = sign * tev[k]
        for i in range(d):
            x[i] += c * A[k, i]
    for p in range(Bm.shape[0]):
        c = sign * s[p]
        for i in range(d):
            x[i] += c * Bm[p, i]


@njit(cache=True)
def _structured_block(DhT, g0, gfull, a, bDh, ptr, other, pidx, A, Bm, V, out, status,
                      start, stop, inverse, check):
    n = DhT.shape[1]
    g = np.empty(n)
    r = np.empty(n)
    tau = np.empty(n)
    key = np.empty(n, dtype=np.int64)
    perm = np.empty(n, dtype=np.int64)
    posof = np.empty(n, dtype=np.int64)
    jump = np.empty(n)
    hap = np.empty(n, dtype=np.uint8)
    tev = np.empty(n)
    order = np.empty(n, dtype=np.int64)
    s = np.zeros(Bm.shape[0])
    for q in range(start, stop):
        bad = structured_chain(DhT, g0, gfull, a, bDh, ptr, other, pidx, V[q], inverse,
                               check, g, r, tau, key, perm, posof, jump, hap, tev, order, s)
        status[q] = bad
        if bad < 0:
            structured_output(A, Bm, V[q], tev, s, inverse, out[q])


@njit(cache=True)
def structured_map_serial(DhT, g0, gfull, a, bDh, ptr, other, pidx, A, Bm, V, out, status,
                          inverse, check):
    _structured_block(DhT, g0, gfull, a, bDh, ptr, other, pidx, A, Bm, V, out, status,
                      0, V.shape[0], inverse, check)


@njit(cache=True, parallel=True)
def structured_map_parallel(DhT, g0, gfull, a, bDh, ptr, other, pidx, A, Bm, V, out, status,
                            inverse, check):
    m = V.shape[0]
    n_tasks = (m + TASK_QUERIES - 1) // TASK_QUERIES
    for task in prange(n_tasks):
        start = task * TASK_QUERIES
        _structured_block(DhT, g0, gfull, a, bDh, ptr, other, pidx, A, Bm, V, out, status,
                          start, min(start + TASK_QUERIES, m), inverse, check)


@njit(cache=True, parallel=True)
def structured_times(DhT, g0, gfull, a, bDh, ptr, other, pidx, npairs, V, times, orders,
                     status, check):
    m = V.shape[0]
    n = DhT.shape[1]
    n_tasks = (m + TASK_QUERIES - 1) // TASK_QUERIES
    for task in prange(n_tasks):
        g = np.empty(n)
        r = np.empty(n)
        tau = np.empty(n)
        key = np.empty(n, dtype=np.int64)
        perm = np.empty(n, dtype=np.int64)
        posof = np.empty(n, dtype=np.int64)
        jump = np.empty(n)
        hap = np.empty(n, dtype=np.uint8)
        s = np.zeros(npairs)
        for q in range(task * TASK_QUERIES, min((task + 1) * TASK_QUERIES, m)):
            status[q] = structured_chain(DhT, g0, gfull, a, bDh, ptr, other, pidx, V[q],
                                         False, check, g, r, tau, key, perm, posof, jump,
                                         hap, times[q], orders[q], s)


@njit(cache=True)
def structured_diagnose(DhT, g0, gfull, a, bDh, ptr, other, pidx, npairs, u, inverse, hap,
                        r):
    """Re-run one query; returns the bad event (or -1), ``hap`` and ``r`` at that point."""
    n = DhT.shape[1]
    g = np.empty(n)
    tau = np.empty(n)
    key = np.empty(n, dtype=np.int64)
    perm = np.empty(n, dtype=np.int64)
    posof = np.empty(n, dtype=np.int64)
    jump = np.empty(n)
    tev = np.empty(n)
    order = np.empty(n, dtype=np.int64)
    s = np.zeros(npairs)
    bad = structured_chain(DhT, g0, gfull, a, bDh, ptr, other, pidx, u, inverse, True,
                           g, r, tau, key, perm, posof, jump, hap, tev, order, s)
    if bad >= 0:  # rates back in event order for the message
        for i in range(n):
            tau[perm[i]] = r[i]
        for k in range(n):
            r[k] = tau[k]
    return bad


# -- structured, rates independent of the other events -------------------------------------
@njit(cache=True, error_model="numpy")
def _own_rate_times(DhT, rate, u, tev):
    """tev[k] = -(Dh u)_k / rate[k]: first-order times are exact when the rate of each
    pending event does not change when others happen."""
    _impacts_t(DhT, u, tev)
    for k in range(tev.shape[0]):
        tev[k] = -tev[k] / rate[k]


@njit(cache=True)
def _pair_times(pairs, tev, s):
    for p in range(pairs.shape[0]):
        s[p] = max(tev[pairs[p, 0]], tev[pairs[p, 1]])


@njit(cache=True)
def _structured_own_block(DhT, rate, pairs, A, Bm, V, out, start, stop, inverse):
    n = DhT.shape[1]
    tev = np.empty(n)
    s = np.empty(pairs.shape[0])
    for q in range(start, stop):
        _own_rate_times(DhT, rate, V[q], tev)
        _pair_times(pairs, tev, s)
        structured_output(A, Bm, V[q], tev, s, inverse, out[q])


@njit(cache=True)
def structured_own_map_serial(DhT, rate, pairs, A, Bm, V, out, inverse):
    _structured_own_block(DhT, rate, pairs, A, Bm, V, out, 0, V.shape[0], inverse)


@njit(cache=True, parallel=True)
def structured_own_map_parallel(DhT, rate, pairs, A, Bm, V, out, inverse):
    m = V.shape[0]
    n_tasks = (m + TASK_QUERIES - 1) // TASK_QUERIES
    for task in prange(n_tasks):
        start = task * TASK_QUERIES
        _structured_own_block(DhT, rate, pairs, A, Bm, V, out, start,
                              min(start + TASK_QUERIES, m), inverse)


@njit(cache=True, parallel=True)
def own_rate_times(DhT, rate, V, times, orders):
    """Event times and orders when every rate depends only on its own event (any model)."""
    m = V.shape[0]
    n_tasks = (m + TASK_QUERIES - 1) // TASK_QUERIES
    for task in prange(n_tasks):
        for q in range(task * TASK_QUERIES, min((task + 1) * TASK_QUERIES, m)):
            _own_rate_times(DhT, rate, V[q], times[q])
            stable_order(times[q], orders[q])


# ----------------------------------------------------------------------------------------
# dense tables, rates independent of the other events (sort path)
# ----------------------------------------------------------------------------------------
@njit(cache=True)
def _dense_sorted_block(DhT, F, rate, V, out, start, stop, inverse):
    d, n = DhT.shape
    tev = np.empty(n)
    order = np.empty(n, dtype=np.int64)
    sign = 1.0 if inverse else -1.0
    for q in range(start, stop):
        _own_rate_times(DhT, rate, V[q], tev)
        stable_order(tev, order)
        # x = u -+ sum_j t_j (F[B_j] - F[B_{j-1}])
        for i in range(d):
            out[q, i] = V[q, i]
        B = 0
        for j in range(n):
            k = order[j]
            B2 = B | (1 << k)
            c = sign * tev[k]
            for i in range(d):
                out[q, i] += c * (F[B2, i] - F[B, i])
            B = B2


@njit(cache=True)
def dense_sorted_map_serial(DhT, F, rate, V, out, inverse):
    _dense_sorted_block(DhT, F, rate, V, out, 0, V.shape[0], inverse)


@njit(cache=True, parallel=True)
def dense_sorted_map_parallel(DhT, F, rate, V, out, inverse):
    m = V.shape[0]
    n_tasks = (m + TASK_QUERIES - 1) // TASK_QUERIES
    for task in prange(n_tasks):
        start = task * TASK_QUERIES
        _dense_sorted_block(DhT, F, rate, V, out, start, min(start + TASK_QUERIES, m),
                            inverse)


# ----------------------------------------------------------------------------------------
# corner functions
# ----------------------------------------------------------------------------------------
# These take the user's njit function as an argument, so numba compiles them once per
# corner function. They are not cached on disk: the cache index is keyed by the function
# object, which is new in every process, so cache=True would only grow the index.
@njit(cache=True, error_model="numpy")
def _rates_of(DhT, f, r):
    """r = DhT @ f (from DhT = DhT.T); returns the first event with r <= 0, or -1."""
    _impacts_t(DhT, f, r)
    for k in range(r.shape[0]):
        if not r[k] > 0.0:
            return k
    return -1


@njit
def function_chain(func, DhT, u, inverse, x, g, r, r2, f, f2, hap, tev, order):
    """One query with corners from ``func(hap, out)``; x = M(u) (or M^-1(u)).

    Evaluates the n + 1 regions of the chain; rates are recomputed as Dh @ F[region].
    Returns -1, or the event whose rate is <= 0 in region ``hap`` (the chain stops).
    """
    d, n = DhT.shape
    _impacts_t(DhT, u, g)
    for k in range(n):
        hap[k] = 1 if inverse else 0
    for i in range(d):
        x[i] = u[i]
    func(hap, f)
    bad = _rates_of(DhT, f, r)
    if bad >= 0:
        return bad
    want = 1 if inverse else 0
    for j in range(n):
        best = 0.0
        kb = -1
        for k in range(n):
            if hap[k] == want:
                tau = -g[k] / r[k]
                if kb < 0 or (tau > best if inverse else tau < best):
                    best = tau
                    kb = k
        hap[kb] = 1 - want
        tev[kb] = best
        if inverse:
            order[n - 1 - j] = kb
        else:
            order[j] = kb
        func(hap, f2)
        bad = _rates_of(DhT, f2, r2)
        if bad >= 0:
            return bad
        t = best
        for i in range(d):
            x[i] += t * (f[i] - f2[i])
        for k in range(n):
            g[k] += t * (r[k] - r2[k])
        for i in range(d):
            f[i] = f2[i]
        for k in range(n):
            r[k] = r2[k]
    return -1


@njit
def _function_block(func, DhT, V, out, times, orders, status, start, stop, inverse):
    d, n = DhT.shape
    g = np.empty(n)
    r = np.empty(n)
    r2 = np.empty(n)
    f = np.empty(d)
    f2 = np.empty(d)
    hap = np.empty(n, dtype=np.uint8)
    tev = np.empty(n)
    order = np.empty(n, dtype=np.int64)
    x = np.empty(d)
    for q in range(start, stop):
        status[q] = function_chain(func, DhT, V[q], inverse, x, g, r, r2, f, f2, hap, tev,
                                   order)
        if out.shape[0] > 0:
            out[q, :] = x
        if times.shape[0] > 0:
            times[q, :] = tev
            orders[q, :] = order


@njit
def function_map_serial(func, DhT, V, out, times, orders, status, inverse):
    """``out`` and/or ``times``/``orders`` may have 0 rows to skip writing them."""
    _function_block(func, DhT, V, out, times, orders, status, 0, V.shape[0], inverse)


@njit(parallel=True)
def function_map_parallel(func, DhT, V, out, times, orders, status, inverse):
    m = V.shape[0]
    n_tasks = (m + TASK_QUERIES - 1) // TASK_QUERIES
    for task in prange(n_tasks):
        start = task * TASK_QUERIES
        _function_block(func, DhT, V, out, times, orders, status, start,
                        min(start + TASK_QUERIES, m), inverse)


@njit
def function_diagnose(func, DhT, u, inverse, hap, r):
    """Re-run one query; returns the bad event (or -1), ``hap`` and ``r`` at that point."""
    d, n = DhT.shape
    x = np.empty(d)
    g = np.empty(n)
    r2 = np.empty(n)
    f = np.empty(d)
    f2 = np.empty(d)
    tev = np.empty(n)
    order = np.empty(n, dtype=np.int64)
    bad = function_chain(func, DhT, u, inverse, x, g, r, r2, f, f2, hap, tev, order)
    if bad >= 0:  # rates of the region where the chain stopped
        func(hap, f)
        _rates_of(DhT, f, r)
    return bad


@njit
def function_corners(func, hap_rows, out):
    """out[i] = func(hap_rows[i]) for each row of 0/1 flags (tables, chains, checks)."""
    for i in range(hap_rows.shape[0]):
        func(hap_rows[i], out[i])
