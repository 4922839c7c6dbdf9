"""Lane blocks for dense corner tables: eight queries in lockstep, each step in 8-wide
vectors (the default; ``_core.PLAIN`` runs the scalar blocks of :mod:`.dense` instead).

``tables = (R, DhTp, dims)`` with ``R`` the region records ``[-1/G | G | F]`` of
``_tables.region_records`` (each part padded to a multiple of 8), ``DhTp`` (d, 8 nc)
``Dh.T`` padded with zeros and ``dims`` int64 ``[n, d, nc, dc, far]`` (``far``: the
records exceed the caches, prefetch them). Each step of each query is explicit 8-wide
vector code (``_simd``). A query is one row of ``V`` (m, d).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from . import _simd as vec
from ._core import JIT, batch, write_times

#: queries per lockstep group of the lane blocks (8 independent chains hide the latency
#: of each step's reduction; 12 or more spill registers).
LANES = 8


@njit(**JIT)
def _lane_scratch(tables):
    """H (event values), DT (their times), X (positions), B (regions), T (times so far),
    order and times of the steps, for LANES queries."""
    dims = tables[2]
    n, nc, dc = dims[0], dims[2], dims[3]
    return (np.empty((LANES, 8 * nc)), np.empty((LANES, 8 * nc)), np.empty((LANES, 8 * dc)),
            np.empty(LANES, dtype=np.int64), np.empty(LANES), np.empty((LANES, n), dtype=np.int64),
            np.empty((LANES, n)))


@njit(**JIT)
def _lanes(tables, V, q0, pn, inverse, position, scratch):
    """Run the chains of the queries ``V[q0:q0 + pn]`` (pn <= LANES) in lockstep.

    In *actual* coordinates: ``H`` holds the event values h = Dh x(t) at the time ``T``
    reached so far (not the virtual position of the plain blocks). Forwards, a pending
    event k is due after ``dt_k = h_k * (-1 / G[B, k])``; the smallest wins (ties to the
    smaller k: the lowest set bit of the equality mask), time advances by it, h by
    ``dt G[B]`` and the position by ``dt F[B]``. Backwards (``inverse``) time runs the
    other way from the full region down; with ``H = -h`` there the same two formulas
    hold. Events that are no longer candidates (and the padding) get dt = +inf from the
    region's bits, so no entry of H is ever overwritten. The first step may go back in
    time (events before t = 0). Writes ``order[p, j]`` (the j-th event), ``times[p, j]``
    (its time) and, when ``position``, ``X[p]`` the move from u to the position at the
    last event.
    """
    R, DhTp, dims = tables[0], tables[1], tables[2]
    H, DT, X, B, T, order, times = scratch
    n, d, nc, dc, far = dims[0], dims[1], dims[2], dims[3], dims[4]
    og, of = 8 * nc, 16 * nc
    s = -1.0 if inverse else 1.0
    pad = -1 << n  # the bits of the padding lanes
    for p in range(pn):
        q = q0 + p
        for c in range(nc):
            h = vec.splat(0.0)
            for i in range(d):
                h = vec.fma(vec.splat(s * V[q, i]), vec.load(DhTp, i, 8 * c), h)
            vec.store(H, p, 8 * c, h)
        if position:  # X collects sum_j dt_j F[B_j]: vector stores only (a vector load of
            for c in range(dc):  # scalar stores would stall on store forwarding)
                vec.store(X, p, 8 * c, vec.splat(0.0))
        B[p] = (1 << n) - 1 if inverse else 0
        T[p] = 0.0
    for step in range(n):
        for p in range(pn):
            b = B[p]
            out = ~b if inverse else b | pad  # not candidates: dt = +inf
            # a candidate equal to the smallest time; if none (a time overflowed to inf or
            # NaN: the row is then refused as non-finite) the first candidate, so that k
            # is always a pending event
            k = vec.trailing_zeros(~out)
            if nc == 1:
                dt = vec.where_bits(vec.mul(vec.load(H, p, 0), vec.load(R, b, 0)), out, np.inf)
                best = vec.smallest(dt)
                hit = vec.equal_mask(dt, best) & ~out
                if hit != 0:
                    k = vec.trailing_zeros(hit)
            else:
                best = np.inf
                for c in range(nc):
                    dt = vec.where_bits(vec.mul(vec.load(H, p, 8 * c), vec.load(R, b, 8 * c)),
                                        out >> (8 * c), np.inf)
                    vec.store(DT, p, 8 * c, dt)
                    best = min(best, vec.smallest(dt))
                for c in range(nc):
                    hit = vec.equal_mask(vec.load(DT, p, 8 * c), best) & (~out >> (8 * c))
                    if hit != 0:
                        k = 8 * c + vec.trailing_zeros(hit)
                        break
            step_h = vec.splat(best)
            for c in range(nc):
                vec.store(H, p, 8 * c, vec.fma(step_h, vec.load(R, b, og + 8 * c),
                                               vec.load(H, p, 8 * c)))
            if position:
                move = vec.splat(s * best)
                for c in range(dc):
                    vec.store(X, p, 8 * c, vec.fma(move, vec.load(R, b, of + 8 * c),
                                                   vec.load(X, p, 8 * c)))
            T[p] += best
            order[p, step] = k
            times[p, step] = s * T[p]
            b ^= 1 << k
            B[p] = b
            if far:  # the next record is needed after the other lanes' steps: fetch it now
                for c in range(2 * nc + (dc if position else 0)):
                    vec.prefetch(R, b, 8 * c)


@njit(**JIT)
def _lane_apply_block(tables, V, outs, start, stop, inverse):
    """out = M(V) (M^-1 when ``inverse``): the position at the last event, moved back to
    time 0 along the final region's field, ``x - T F[end]``."""
    R, dims = tables[0], tables[2]
    out = outs[0]
    n, d, of = dims[0], dims[1], 16 * dims[2]
    scratch = _lane_scratch(tables)
    X, T = scratch[2], scratch[4]
    end = 0 if inverse else (1 << n) - 1
    s = -1.0 if inverse else 1.0
    for q0 in range(start, stop, LANES):
        pn = min(LANES, stop - q0)
        _lanes(tables, V, q0, pn, inverse, True, scratch)
        for p in range(pn):
            t = s * T[p]
            for i in range(d):
                out[q0 + p, i] = V[q0 + p, i] + X[p, i] - t * R[end, of + i]


@njit(**JIT)
def _lane_times_block(tables, V, outs, start, stop, inverse):
    times_out, order_out = outs
    scratch = _lane_scratch(tables)
    order, times = scratch[5], scratch[6]
    for q0 in range(start, stop, LANES):
        pn = min(LANES, stop - q0)
        _lanes(tables, V, q0, pn, False, False, scratch)
        write_times(order, times, q0, pn, order_out, times_out)


@njit(**JIT)
def _lane_tangent_block(tables, V, outs, start, stop, transpose):
    """out[q] = M_sigma T[q] (or its transpose), sigma the order v = V[q] selects:
    the saltation factors of MATH.md section 4 along the chain, in 8-wide vectors,
    ``S y = y + (F[after] - F[before]) (Dh[k] . y) / G[before, k]`` and
    ``S^T y = y + Dh[k] ((F[after] - F[before]) . y) / G[before, k]`` (backwards).
    ``tables = (R, DhTp, dims, Dhp)`` with ``Dhp`` (n, 8 dc) the rows of Dh padded;
    ``outs = (out, T)`` (T is read)."""
    R, dims, Dhp = tables[0], tables[2], tables[3]
    out, T = outs
    n, d, og, of, dc = dims[0], dims[1], 8 * dims[2], 16 * dims[2], dims[3]
    scratch = _lane_scratch(tables)
    order = scratch[5]
    Y = np.zeros((LANES, 8 * dc))  # the padding lanes stay 0 (so do F's and Dhp's)
    for q0 in range(start, stop, LANES):
        pn = min(LANES, stop - q0)
        _lanes(tables, V, q0, pn, False, False, scratch)
        for p in range(pn):
            vec.store(Y, p, 8 * (dc - 1), vec.splat(0.0))  # padding: 0 whatever came before
            for i in range(d):
                Y[p, i] = T[q0 + p, i]
            region = (1 << n) - 1 if transpose else 0  # walk the chain either way
            for st in range(n):
                k = order[p, n - 1 - st] if transpose else order[p, st]
                other = region ^ (1 << k)
                before, after = (other, region) if transpose else (region, other)
                dot = 0.0
                for c in range(dc):
                    along = (vec.sub(vec.load(R, after, of + 8 * c),
                                     vec.load(R, before, of + 8 * c)) if transpose
                             else vec.load(Dhp, k, 8 * c))
                    dot += vec.total(vec.mul(along, vec.load(Y, p, 8 * c)))
                m = vec.splat(dot / R[before, og + k])
                for c in range(dc):
                    along = (vec.load(Dhp, k, 8 * c) if transpose
                             else vec.sub(vec.load(R, after, of + 8 * c),
                                          vec.load(R, before, of + 8 * c)))
                    vec.store(Y, p, 8 * c, vec.fma(m, along, vec.load(Y, p, 8 * c)))
                region = other
            for i in range(d):
                out[q0 + p, i] = Y[p, i]


#: M(V) or M^-1(V): tables (R, DhTp, dims), outs (out,).
apply = batch(_lane_apply_block)
#: event times and orders: outs (times, orders).
event_times = batch(_lane_times_block)
#: M_sigma(V) T or its transpose: tables (R, DhTp, dims, Dhp), outs (out, T).
tangents = batch(_lane_tangent_block)
