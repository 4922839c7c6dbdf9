"""The chains of structured corners (:mod:`.structured`): event values, the lockstep
selection along each query's chain, and the outputs as matrix products.

A block takes its queries in groups of :data:`GROUP`: the event values ``Dh u`` of the
group as one matrix product, the chains :data:`LOCK` queries in lockstep, then the
outputs as one product with ``[A; B]``. Every query runs the same serial arithmetic in
whatever group it falls (the products keep each entry's order of summation, the lockstep
only interleaves independent chains), so results do not depend on the split of a batch.
A query whose chain meets a rate that is not > 0 stops and writes the offending event into
``status[q]`` (else -1).

The chains select with their own arithmetic, not :mod:`.selection`'s steps: the scan for
the next event (k beats b iff ``g_k r_b > g_b r_k``, no division) runs in 8-wide vectors
inside the pass that updates g and r. The nearest chain over the shared steps (the same
vector update, then ``pending_times``, ``earliest`` and ``retire`` on each lane's rows;
the same bits on the benchmark's queries) was measured against it (docs/benchmarks.md,
"Kernel design choices, measured"): slower at n = 128, faster at n = 32. At n = 128 each
step's 128 scalar divisions and the serial scan cost more than the fused vector pass,
beyond the 5 % issue 26 allowed, so the vector selection stays. (At small n the shared
steps were faster; a switch by size would compare quotients where this compares products,
which can order near ties differently, so the results would no longer be the same bits:
not done.)
"""

from __future__ import annotations

import numpy as np
from numba import njit

from . import _simd as vec
from ._core import JIT, cached

#: queries whose event values and outputs are computed as one matrix product
GROUP = 32
#: chains run in lockstep (independent chains hide each step's reduction latency)
LOCK = 4
#: the width of every vector here
W8 = vec.static(8)


@cached
def products(M, X, x0, pn, s, B, b0, Y, y0):
    """``Y[y0 + p] = B[b0 + p] + s X[x0 + p] @ M`` for p < pn (the first ``Y.shape[1]``
    columns; M's rows padded to a multiple of 8), four rows of X per pass over M. Entry i
    sums over k in order with fused multiply-adds: the same bits in any group (a short
    group repeats its last row)."""
    m, cols = M.shape[0], Y.shape[1]
    for p0 in range(0, pn, 4):
        pb, pc, pd = min(p0 + 1, pn - 1), min(p0 + 2, pn - 1), min(p0 + 3, pn - 1)
        for c in range(M.shape[1] // 8):
            count = min(cols - 8 * c, 8)
            ya = vec.load_first(B, b0 + p0, 8 * c, count, W8)
            yb = vec.load_first(B, b0 + pb, 8 * c, count, W8)
            yc = vec.load_first(B, b0 + pc, 8 * c, count, W8)
            yd = vec.load_first(B, b0 + pd, 8 * c, count, W8)
            for k in range(m):
                row = vec.load(M, k, 8 * c, W8)
                ya = vec.fma(vec.splat(s * X[x0 + p0, k], W8), row, ya)
                yb = vec.fma(vec.splat(s * X[x0 + pb, k], W8), row, yb)
                yc = vec.fma(vec.splat(s * X[x0 + pc, k], W8), row, yc)
                yd = vec.fma(vec.splat(s * X[x0 + pd, k], W8), row, yd)
            vec.store_first(Y, y0 + p0, 8 * c, count, ya)
            vec.store_first(Y, y0 + pb, 8 * c, count, yb)
            vec.store_first(Y, y0 + pc, 8 * c, count, yc)
            vec.store_first(Y, y0 + pd, 8 * c, count, yd)


@njit(inline="always", **JIT)
def _block(G, p, R, lane, J, row, c, ct, cs, best, idx):
    """Vector c of one lane (row p of G, ``lane`` of R): ``g -= t jump``, ``r += sigma
    jump`` with the jump ``J[row]`` (``ct = -t``, ``cs = sigma``), then the lane-wise best
    of ``best`` and these candidates: k beats b iff ``g_k r_b > g_b r_k`` (the earlier
    ``-g / r``; rates are positive, no division), so the first of equal ones stays."""
    gb, rb, ib = best
    jump = vec.load(J, row, 8 * c, W8)
    g = vec.fma(ct, jump, vec.load(G, p, 8 * c, W8))
    r = vec.fma(cs, jump, vec.load(R, lane, 8 * c, W8))
    vec.store(G, p, 8 * c, g)
    vec.store(R, lane, 8 * c, r)
    new, old = vec.mul(g, rb), vec.mul(gb, r)
    return (vec.where_greater(new, old, g, gb), vec.where_greater(new, old, r, rb),
            vec.where_greater(new, old, idx, ib))


@njit(inline="always", **JIT)
def _pass(G, p0, R, J, ROW, T, BEST, iota, nc, sigma):
    """One fused pass of the LOCK lanes (rows p0.. of G) over their events: the update of
    each lane's previous step and the scan for its next one, four independent chains of
    compare-and-select. The jump of lane i is ``J[ROW[i]]``; the eight vector lanes'
    winners (g, r, index) of lane i go to ``BEST[i]``."""
    cs = vec.splat(sigma, W8)
    ta, tb = vec.splat(-T[0], W8), vec.splat(-T[1], W8)
    tc, td = vec.splat(-T[2], W8), vec.splat(-T[3], W8)
    ja, jb, jc, jd = ROW[0], ROW[1], ROW[2], ROW[3]
    ba = bb = bc = bd = (vec.splat(-np.inf, W8), vec.splat(1.0, W8), vec.splat(np.inf, W8))
    for c in range(nc):
        idx = vec.load(iota, 0, 8 * c, W8)
        ba = _block(G, p0, R, 0, J, ja, c, ta, cs, ba, idx)
        bb = _block(G, p0 + 1, R, 1, J, jb, c, tb, cs, bb, idx)
        bc = _block(G, p0 + 2, R, 2, J, jc, c, tc, cs, bc, idx)
        bd = _block(G, p0 + 3, R, 3, J, jd, c, td, cs, bd, idx)
    for lane, best in ((0, ba), (1, bb), (2, bc), (3, bd)):
        for i in range(3):
            vec.store(BEST, lane, 8 * i, best[i])


@njit(inline="always", **JIT)
def _beats(a, b):
    """The better of candidates a and b, each (g, r, index); equal products: the smaller
    index."""
    new, old = b[0] * a[1], a[0] * b[1]
    take = (new > old) | ((new == old) & (b[2] < a[2]))  # no branch: the outcome is random
    return (b[0] if take else a[0]), (b[1] if take else a[1]), (b[2] if take else a[2])


@njit(inline="always", **JIT)
def _pair(BEST, lane, i):
    """The better of vector lanes i and i + 4 of ``BEST[lane]``."""
    return _beats((BEST[lane, i], BEST[lane, 8 + i], BEST[lane, 16 + i]),
                  (BEST[lane, i + 4], BEST[lane, 12 + i], BEST[lane, 20 + i]))


@njit(inline="always", **JIT)
def _winner(BEST, lane, HAP, cand, n):
    """The winner of the eight vector lanes of ``BEST[lane]``, as a tree; if none (every
    candidate's g is NaN or -inf: the row is refused as non-finite) the first candidate,
    so that the winner is always a candidate."""
    b0, b1 = _pair(BEST, lane, 0), _pair(BEST, lane, 1)
    b2, b3 = _pair(BEST, lane, 2), _pair(BEST, lane, 3)
    i = _beats(_beats(b0, b2), _beats(b1, b3))[2]
    if i < n:
        return int(i)
    for k in range(n):
        if HAP[lane, k] == cand:
            return k
    return 0


@njit(inline="always", **JIT)
def _first_bad_rate(R, lane, n):
    """The first event whose rate ``R[lane, k]`` is not > 0, or -1."""
    for k in range(n):
        if not R[lane, k] > 0.0:
            return k
    return -1


@njit(inline="always", **JIT)
def _jump_row(J, bDhp, kb, PL, na, nc, row):
    """J[row] = J[kb] (= a[kb]) + the rows ``bDhp[PL[:na]]`` (in that order)."""
    for c in range(nc):
        vec.store(J, row, 8 * c, vec.add(vec.load(J, kb, 8 * c, W8),
                                         vec.load(bDhp, PL[0], 8 * c, W8)))
    for e in range(1, na):
        pe = PL[e]
        for c in range(nc):
            vec.store(J, row, 8 * c, vec.add(vec.load(J, row, 8 * c, W8),
                                             vec.load(bDhp, pe, 8 * c, W8)))


@njit(inline="always", **JIT)
def _start(rates, G, p0, ln, cand, n, nc, status, q0, R, HAP, ROW, T):
    """Rates of the start region, no candidates beyond n (nor in lanes beyond ``ln``), no
    update pending (the zero jump row ``J[n + LOCK]``)."""
    for lane in range(LOCK):
        p = p0 + lane
        for c in range(nc):
            vec.store(R, lane, 8 * c, vec.load(rates, cand, 8 * c, W8))
        for k in range(n if lane < ln else 0, 8 * nc):
            G[p, k] = -np.inf
        ROW[lane], T[lane] = n + LOCK, 0.0
        if lane < ln:
            status[q0 + p] = -1
            for k in range(n):
                HAP[lane, k] = cand


@cached
def _chains(tables, G, p0, ln, inverse, check, TS, ORD, status, q0, work):
    """The chains of the group rows ``p0 .. p0 + ln - 1`` (ln <= LOCK) in lockstep.

    ``G[p]`` holds g = s Dh u (s = -1 backwards), updated along the chain so that event
    k's time in the current region is ``-g_k / r_k`` forwards, where the earliest wins,
    and ``g_k / r_k`` backwards, where the latest wins: both ways the smallest
    ``-g_k / r_k`` wins, ties to the smaller event. Events that are no candidates hold
    g = -inf. A tie is ``g_k / r_k = g_b / r_b`` exactly for the stored values: it makes
    the two products equal, so they round alike. Each product is rounded once (relative
    error <= 2**-53), so a comparison can differ from the exact one, and from comparing
    rounded quotients as the previous kernel did, only when the two times agree to within
    2**-52 of the larger; through the lane-wise scan and the tree the selected time is
    within a few such units of the earliest. The fused updates of g and r round
    differently from separate products and sums too, which likewise matters only at such
    near ties. So the order is that of exact arithmetic on the rounded g, r except among
    times a few ulps apart, across which M is continuous. The jump rows ``J`` are ``a``
    (rows 0..n-1), the jumps with pairs (row n + lane) and zeros (row n + LOCK): lanes
    beyond ``ln`` and stopped lanes run on the zero row, touching only their own rows.
    Writes ``TS[p, k]`` (time of event k), ``TS[p, n + pair]``, ``ORD[p, j]`` (the j-th
    event) and ``status[q0 + p]``.
    """
    rates, bDhp, ptr, other, pidx, iota = (tables.rates, tables.bDhp, tables.ptr,
                                           tables.other, tables.pidx, tables.iota)
    R, HAP, J, ROW, T, BEST, PL, K = work
    n, nc = tables.n, tables.nc
    cand = 1 if inverse else 0  # HAP of a candidate (happened: 1)
    sigma = -1.0 if inverse else 1.0  # the rates gain the jumps forwards, lose them back
    _start(rates, G, p0, ln, cand, n, nc, status, q0, R, HAP, ROW, T)
    for j in range(n + 1 if check else n):  # with check: the last update is checked too
        _pass(G, p0, R, J, ROW, T, BEST, iota, nc, sigma)
        for lane in range(ln):  # the lanes' next events and times (independent chains)
            p = p0 + lane
            K[lane] = -1
            if status[q0 + p] >= 0:
                continue
            bad = _first_bad_rate(R, lane, n) if check else -1
            if bad >= 0 or j == n:
                status[q0 + p] = bad
                ROW[lane], T[lane] = n + LOCK, 0.0  # stop: R stays for diagnose
                continue
            kb = _winner(BEST, lane, HAP, cand, n)
            K[lane], T[lane] = kb, (G[p, kb] if inverse else -G[p, kb]) / R[lane, kb]
        for lane in range(ln):  # their bookkeeping
            kb, t, p = K[lane], T[lane], p0 + lane
            if kb < 0:
                continue
            TS[p, kb] = t
            ORD[p, n - 1 - j if inverse else j] = kb
            HAP[lane, kb] = 1 - cand
            G[p, kb] = -np.inf
            na = 0
            for e in range(ptr[kb], ptr[kb + 1]):  # pairs switched on (backwards: off)
                pe = pidx[e]
                on = HAP[lane, other[e]] == 1
                TS[p, n + pe] = t if on else TS[p, n + pe]
                PL[na] = pe
                na += on
            if na:
                _jump_row(J, bDhp, kb, PL, na, nc, n + lane)
            ROW[lane] = n + lane if na else kb


@cached
def group_scratch(tables):
    """G (and zeros of its shape), TS, ORD of a group and the lockstep work arrays R, HAP, J,
    ROW, T, BEST, PL, K (``J``: the jump rows of :func:`_chains`, with a copy of ``a``)."""
    n, nc, npairs, deg = tables.n, tables.nc, tables.npairs, tables.deg
    J = np.zeros((n + LOCK + 1, 8 * nc))
    for k in range(n):  # a loop: an array into a slice compiles numba's shape error
        for i in range(8 * nc):
            J[k, i] = tables.ap[k, i]
    work = (np.empty((LOCK, 8 * nc)), np.empty((LOCK, n), dtype=np.uint8), J,
            np.empty(LOCK, dtype=np.int64), np.empty(LOCK), np.empty((LOCK, 24)),
            np.empty(max(deg, 1), dtype=np.int64), np.empty(LOCK, dtype=np.int64))
    return (np.empty((GROUP, 8 * nc)), np.empty((GROUP, n + npairs)),
            np.empty((GROUP, n), dtype=np.int64), work, np.zeros((GROUP, 8 * nc)))


@cached
def chain_group(tables, V, q0, pn, inverse, check, status, scratch):
    """Event values, then the chains, of the queries ``V[q0:q0 + pn]`` (pn <= GROUP)."""
    G, TS, ORD, work, zeros = scratch
    zero = np.int64(0)
    products(tables.DhTp, V, q0, pn, -1.0 if inverse else 1.0, zeros, zero, G, zero)  # s Dh u
    for p0 in range(0, pn, LOCK):
        _chains(tables, G, p0, min(LOCK, pn - p0), inverse, check, TS, ORD, status, q0, work)
