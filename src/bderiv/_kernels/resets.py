"""Blocks for dense corner tables with resets at the events (mathematics.md section 9).

The tables are a :class:`ResetTables`: the corners and rates of a dense table and the
reset Jacobians of the crossings (b, k), k not in b, stored transposed so that every
product is a run of contiguous axpys (which vectorise; dot products would wait on each
addition):

- ``low == 0``: ``P[b, k]`` (d, d) is ``R[b, k]^T``; ``Q``, ``DhP`` unused;
- ``low == 1``: ``R[b, k] = I + U V^T`` with ``P[b, k] = U^T``, ``Q[b, k] = V^T`` (r, d)
  and ``DhP[b, k] = (Dh U)^T`` (r, n), which updates g = Dh x in O(n r).

For the inverse map the caller passes the inverse resets in the same form, stored at the
entry (b, k) of the crossing they undo. Plain loops, one query at a time.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit

from ._core import JIT, cached
from ._drivers import batch
from .selection import advance, earliest, exclude, pending_times
from .steps import impacts


class ResetTables(NamedTuple):
    """A dense corner table with reset Jacobians (see the module's docstring)."""

    #: (d, n) the transposed event Jacobian
    DhT: np.ndarray
    #: (2**n, d) the corners
    F: np.ndarray
    #: (2**n, n) the rates ``F @ Dh.T``
    G: np.ndarray
    #: (2**n, n, d, d) the transposed resets, or (2**n, n, r, d) U^T when ``low``
    P: np.ndarray
    #: (2**n, n, r, d) V^T when ``low`` (unused otherwise)
    Q: np.ndarray
    #: (2**n, n, r, n) (Dh U)^T when ``low`` (unused otherwise)
    DhP: np.ndarray
    #: 1: the resets are I + U V^T; 0: dense
    low: int


@cached
def _rank_update(left, right, b, k, y, out, w):
    """out += y + left[b, k]^T (right[b, k] y): (I + U V^T) y with (left, right) = (U^T,
    V^T), its transpose with (V^T, U^T); ``w``: scratch of length r."""
    d, r = y.shape[0], left.shape[2]
    for s in range(r):
        c = 0.0
        for i in range(d):
            c += right[b, k, s, i] * y[i]
        w[s] = c
    for i in range(d):
        out[i] += y[i]
    for s in range(r):
        ws = w[s]
        for i in range(d):
            out[i] += left[b, k, s, i] * ws


@cached
def reset_move(P, Q, low, b, k, y, out, w):
    """out += R[b, k] y (``w``: scratch of length r). O(d^2) dense, O(d r) low rank."""
    if low:
        _rank_update(P, Q, b, k, y, out, w)
        return
    d = y.shape[0]
    for j in range(d):
        yj = y[j]
        for i in range(d):
            out[i] += P[b, k, j, i] * yj


@cached
def reset_move_t(P, Q, low, b, k, z, out, w):
    """out = R[b, k]^T z (``w``: scratch of length r)."""
    d = z.shape[0]
    if low:  # (I + U V^T)^T z = z + V (U^T z)
        for i in range(d):
            out[i] = 0.0
        _rank_update(Q, P, b, k, z, out, w)
        return
    for j in range(d):
        c = 0.0
        for i in range(d):
            c += P[b, k, j, i] * z[i]
        out[j] = c


@cached
def _scratch(n, d, P):
    """x, g (1, n), tau (1, n), y, w, times, order, regions for one query."""
    r = max(P.shape[2], 1)
    return (np.empty(d), np.empty((1, n)), np.empty((1, n)), np.empty(d), np.empty(r),
            np.empty(n), np.empty(n, dtype=np.int64), np.empty(n + 1, dtype=np.int64))


@cached
def chain(tables, u, inverse, scratch):
    """The event chain of one query, leaving M(u) (M^-1(u) when ``inverse``) in ``x``.

    mathematics.md section 9, in the steps of :mod:`.selection`: the next event is the
    pending k with the smallest time t = -g[k] / G[B, k] (the largest happened one
    backwards; ties to the smaller k); it moves the virtual position by
    x' = R[B, k] (x + t F[B]) - t F[B'], and backwards by x' = R[B', k]^-1 (x + t F[B]) -
    t F[B'] (B' the region after the step); g = Dh x follows (recomputed for dense
    resets, updated by Dh U for low-rank ones). The events that are no candidates are
    excluded from each region's times: after a bounce their rates may be negative.
    Fills times[j], order[j] (the j-th event in forward order) and regions[j] (the
    region before it; regions[n] = full).
    """
    DhT, F, G, P, Q, DhP, low = (tables.DhT, tables.F, tables.G, tables.P, tables.Q,
                                 tables.DhP, tables.low)
    x, g, tau, y, w, times, order, regions = scratch
    d, n = DhT.shape
    # an int64 0, not a literal: the callees would be compiled for both while the loop is
    # typed
    B = (1 << n) - 1 if inverse else np.int64(0)
    for i in range(d):
        x[i] = u[i]
    impacts(DhT, x, g[0])
    regions[n if inverse else 0] = B
    for step in range(n):
        pending_times(g, 0, G, B, tau)
        for k in range(n):
            if ((B >> k) & 1) != inverse:
                exclude(tau, 0, k, inverse)
        kb, best = earliest(tau, 0, inverse)
        B2 = B & ~(1 << kb) if inverse else B | (1 << kb)
        e = B2 if inverse else B  # the entry of the crossing
        for i in range(d):
            y[i] = x[i] + best * F[B, i]
            x[i] = -best * F[B2, i]
        reset_move(P, Q, low, e, kb, y, x, w)
        if low:  # Dh x' = g + t G[B] + (Dh U) w - t G[B']
            advance(g, 0, best, G, B, B2)
            for s in range(P.shape[2]):
                ws = w[s]
                for k in range(n):
                    g[0, k] += DhP[e, kb, s, k] * ws
        else:
            impacts(DhT, x, g[0])
        j = n - 1 - step if inverse else step
        times[j] = best
        order[j] = kb
        regions[j if inverse else j + 1] = B2
        B = B2


@njit(**JIT)
def _apply_block(tables, V, outs, start, stop, inverse):
    out = outs[0]
    d, n = tables.DhT.shape
    scratch = _scratch(n, d, tables.P)
    x = scratch[0]
    for q in range(start, stop):
        chain(tables, V[q], inverse, scratch)
        for i in range(d):
            out[q, i] = x[i]


@njit(**JIT)
def _times_block(tables, V, outs, start, stop, inverse):
    times_out, order_out = outs
    d, n = tables.DhT.shape
    scratch = _scratch(n, d, tables.P)
    times, order = scratch[5], scratch[6]
    for q in range(start, stop):
        chain(tables, V[q], np.bool_(False), scratch)
        for j in range(n):
            order_out[q, j] = order[j]
            times_out[q, order[j]] = times[j]


@cached
def saltation_reset_step(tables, y, k, b, a, transpose, tmp, w):
    """y <- S y (S^T y when ``transpose``), S the saltation matrix with reset of event k
    from region b to region a (mathematics.md section 9), in place. With R = R[b, k] and
    c = Dh[k] . y / G[b, k]: S y = R (y - c F[b]) + c F[a];
    S^T z = R^T z + Dh[k] (F[a] . z - F[b] . R^T z) / G[b, k]. O(d^2) dense, O(d r) low."""
    DhT, F, G, P, Q, low = tables.DhT, tables.F, tables.G, tables.P, tables.Q, tables.low
    d = y.shape[0]
    rate = G[b, k]
    if transpose:
        s = 0.0
        for i in range(d):
            s += F[a, i] * y[i]
        reset_move_t(P, Q, low, b, k, y, tmp, w)
        for i in range(d):
            s -= F[b, i] * tmp[i]
        s /= rate
        for i in range(d):
            y[i] = tmp[i] + s * DhT[i, k]
    else:
        c = 0.0
        for i in range(d):
            c += DhT[i, k] * y[i]
        c /= rate
        for i in range(d):
            tmp[i] = y[i] - c * F[b, i]
            y[i] = c * F[a, i]
        reset_move(P, Q, low, b, k, tmp, y, w)


@njit(**JIT)
def _tangent_block(tables, V, outs, start, stop, transpose):
    """out[q] = M_sigma T[q] (M_sigma^T T[q] when ``transpose``), sigma the order that
    V[q] selects; ``outs = (out, T)``. The transpose runs the factors backwards."""
    out, T = outs
    d, n = tables.DhT.shape
    scratch = _scratch(n, d, tables.P)
    w, order, regions = scratch[4], scratch[6], scratch[7]
    tmp = np.empty(d)
    for q in range(start, stop):
        chain(tables, V[q], np.bool_(False), scratch)
        z = out[q]
        for i in range(d):
            z[i] = T[q, i]
        for s in range(n):
            j = n - 1 - s if transpose else s
            saltation_reset_step(tables, z, order[j], regions[j], regions[j + 1], transpose,
                                 tmp, w)


#: M(V) or M^-1(V): tables as above (inverse resets for the inverse), outs (out,).
apply = batch(_apply_block)
#: event times and orders: outs (times, orders).
event_times = batch(_times_block)
#: jvp / vjp: outs (out, T).
tangents = batch(_tangent_block)
