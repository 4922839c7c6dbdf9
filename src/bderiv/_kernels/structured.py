"""Blocks for structured corners (:class:`bderiv.StructuredCorners`).

``F[mask] = F0 + sum_{k in mask} A[k] + sum_{pairs in mask} B[p]``: the rates of the
current region are updated incrementally along each query's chain; the result is
``u -+ (A^T t + B^T s)`` with ``t`` the event times and ``s[p]`` the time at which pair p
switched on (the later of its two event times).

``tables = (DhT, g0, gfull, a, bDh, ptr, other, pidx, A, B, check)`` (see
``_engines.structured``). A query whose chain meets a rate <= 0 stops and writes the
offending event into ``status[q]`` (else -1); the caller re-runs that query alone with
:func:`diagnose` to name the region.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from ._core import JIT, batch, impacts, own_rate_times

INT_MAX = np.iinfo(np.int64).max
INT_MIN = np.iinfo(np.int64).min


@njit(**JIT)
def chain(DhT, g0, gfull, a, bDh, ptr, other, pidx, u, inverse, check,
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

    One function of about 75 lines on purpose: the per-query hot loop, whose steps share
    the position bookkeeping (``perm``, ``posof``, ``npos``) that a split would have to
    pass around; each step is marked by a comment.
    """
    n = g.shape[0]
    impacts(DhT, u, jump)
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



@njit(**JIT)
def output(A, Bm, u, tev, s, inverse, x):
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



@njit(**JIT)
def _scratch(n, npairs):
    """g, r, tau, key, perm, posof, jump, hap, s: the per-query work arrays of :func:`chain`."""
    return (np.empty(n), np.empty(n), np.empty(n), np.empty(n, dtype=np.int64),
            np.empty(n, dtype=np.int64), np.empty(n, dtype=np.int64), np.empty(n),
            np.empty(n, dtype=np.uint8), np.zeros(npairs))


@njit(**JIT)
def _apply_block(tables, V, outs, start, stop, inverse):
    DhT, g0, gfull, a, bDh, ptr, other, pidx, A, Bm, check = tables
    out, status = outs
    n = DhT.shape[1]
    g, r, tau, key, perm, posof, jump, hap, s = _scratch(n, Bm.shape[0])
    tev = np.empty(n)
    order = np.empty(n, dtype=np.int64)
    for q in range(start, stop):
        bad = chain(DhT, g0, gfull, a, bDh, ptr, other, pidx, V[q], inverse, check,
                    g, r, tau, key, perm, posof, jump, hap, tev, order, s)
        status[q] = bad
        if bad < 0:
            output(A, Bm, V[q], tev, s, inverse, out[q])


@njit(**JIT)
def _times_block(tables, V, outs, start, stop, inverse):
    DhT, g0, gfull, a, bDh, ptr, other, pidx, A, Bm, check = tables
    times, orders, status = outs
    g, r, tau, key, perm, posof, jump, hap, s = _scratch(DhT.shape[1], Bm.shape[0])
    for q in range(start, stop):
        status[q] = chain(DhT, g0, gfull, a, bDh, ptr, other, pidx, V[q], False, check,
                          g, r, tau, key, perm, posof, jump, hap, times[q], orders[q], s)


@njit(**JIT)
def diagnose(tables, u, inverse, hap, r):
    """Re-run one query; returns the bad event (or -1), ``hap`` and ``r`` at that point."""
    DhT, g0, gfull, a, bDh, ptr, other, pidx, A, Bm, check = tables
    n = DhT.shape[1]
    g, _, tau, key, perm, posof, jump, _, s = _scratch(n, Bm.shape[0])
    tev = np.empty(n)
    order = np.empty(n, dtype=np.int64)
    bad = chain(DhT, g0, gfull, a, bDh, ptr, other, pidx, u, inverse, True,
                g, r, tau, key, perm, posof, jump, hap, tev, order, s)
    if bad >= 0:  # rates back in event order for the message
        for i in range(n):
            tau[perm[i]] = r[i]
        for k in range(n):
            r[k] = tau[k]
    return bad


@njit(**JIT)
def _pair_times(pairs, tev, s):
    for p in range(pairs.shape[0]):
        s[p] = max(tev[pairs[p, 0]], tev[pairs[p, 1]])



@njit(**JIT)
def _own_block(tables, V, outs, start, stop, inverse):
    """Own-rates fast path: ``tables = (DhT, rate, pairs, A, B)``, ``rate`` the rates of the
    start region; the times are first-order times, pairs switch on at the later one."""
    DhT, rate, pairs, A, Bm = tables
    out = outs[0]
    tev = np.empty(DhT.shape[1])
    s = np.empty(pairs.shape[0])
    for q in range(start, stop):
        own_rate_times(DhT, rate, V[q], tev)
        _pair_times(pairs, tev, s)
        output(A, Bm, V[q], tev, s, inverse, out[q])


#: M(V) or M^-1(V): outs (out, status).
apply = batch(_apply_block)
#: event times and orders: outs (times, orders, status).
event_times = batch(_times_block)
#: the own-rates fast path: outs (out,).
apply_own_rates = batch(_own_block)


def corner_function(F0, A, pairs, B):
    """An njit ``func(happened, out)`` of structured corners (compiled per model: the
    arrays become constants of the function)."""

    @njit
    def func(happened, out):
        for i in range(out.shape[0]):
            out[i] = F0[i]
        for k in range(A.shape[0]):
            if happened[k]:
                for i in range(out.shape[0]):
                    out[i] += A[k, i]
        for p in range(pairs.shape[0]):
            if happened[pairs[p, 0]] and happened[pairs[p, 1]]:
                for i in range(out.shape[0]):
                    out[i] += B[p, i]

    return func
