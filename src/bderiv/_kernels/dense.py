"""Plain blocks for dense corner tables, and a table scan of their rates.

The tables are a :class:`DenseTables` (the own-rates fast path: :class:`SortedTables`);
scalar loops only, so any numba target compiles them. They run when ``_core.PLAIN``
(``BDERIV_KERNELS=plain``); the default is the same selection in explicit vectors,
:mod:`.lanes`. A query is one row of ``V`` (m, d).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit

from ._core import JIT, cached
from ._drivers import batch
from .selection import advance, earliest, pending_times, retire
from .steps import (
    factors,
    insertion_order,
    own_rate_times,
    query_exponent,
    saltation_step,
    write_times,
)

#: queries evaluated in lockstep by one thread. Each query is a chain of n dependent steps
#: (rates of the region reached -> event times -> next event -> next region), so one query
#: alone leaves the core waiting on latencies (division, table loads); interleaving GROUP
#: independent chains lets the out-of-order core overlap them: 4 per group is faster per
#: query than 1, and 8 or 16 gain nothing more (docs/benchmarks.md, "Kernel design
#: choices, measured").
GROUP = 4


class DenseTables(NamedTuple):
    """A dense corner table (mathematics.md section 1) as the plain blocks read it."""

    #: (d, n) the transposed event Jacobian, Dh.T
    DhT: np.ndarray
    #: (2**n, d) the corners, row ``mask``: the field in the region where the events of
    #: ``mask`` happened
    F: np.ndarray
    #: (2**n, n) the rates ``F @ Dh.T``
    G: np.ndarray
    #: (n, d) the event Jacobian (the tangents' saltation factors)
    Dh: np.ndarray


class SortedTables(NamedTuple):
    """The own-rates fast path of a dense table: times from the start region's rates."""

    #: (d, n) the transposed event Jacobian, Dh.T
    DhT: np.ndarray
    #: (2**n, d) the corners
    F: np.ndarray
    #: (n,) the rates of the region the chains start from (``G[0]`` forwards, ``G[-1]``
    #: backwards)
    rate: np.ndarray


@cached
def _chains(DhT, G, V, q0, pn, inverse, g, tau, times, order, chain):
    """Event chains of the queries ``V[q0:q0 + pn]`` (pn <= GROUP), in lockstep.

    mathematics.md section 3 (section 6 when ``inverse``), in the steps of
    :mod:`.selection`: keep g = Dh x for the virtual position x; at each step the next
    event is the pending k with the smallest time -g[k] / G[B, k] *in the current region
    B* (the largest among the happened ones, going backwards), ties to the smaller k.

    Each query outside the query band runs scaled by a power of two, ``u = 2**-e V[q]``
    with its largest entry in [0.5, 1) (``steps.query_exponent``): the times are then
    those of u, ``2**-e`` times those of V[q].

    Writes, for each p < pn: ``times[p, j]`` (j-th event time; non-decreasing forwards),
    ``order[p, j]`` (its event) and ``chain[p, j]`` (region before the (j+1)-th event,
    chain[p, 0] = 0, chain[p, n] = full mask), all in forward order.
    """
    d, n = DhT.shape
    full = (1 << n) - 1
    for p in range(pn):  # g = Dh @ u, written out: views of V and g cost ~2x at small n
        q = q0 + p
        for k in range(n):
            g[p, k] = 0.0
        a, b = factors(-query_exponent(V, q, d))  # u = 2**-e V[q] (steps.query_exponent)
        for i in range(d):
            ui = V[q, i] * a * b
            for k in range(n):
                g[p, k] += DhT[i, k] * ui
        chain[p, n if inverse else 0] = full if inverse else 0
    for step in range(n):
        j = n - 1 - step if inverse else step
        for p in range(pn):
            pending_times(g, p, G, chain[p, j + 1] if inverse else chain[p, j], tau)
        for p in range(pn):
            kb, best = earliest(tau, p, inverse)
            retire(g, p, kb, inverse)
            if inverse:
                b = chain[p, j + 1]
                b2 = b & ~(1 << kb)
                chain[p, j] = b2
            else:
                b = chain[p, j]
                b2 = b | (1 << kb)
                chain[p, j + 1] = b2
            advance(g, p, best, G, b, b2)
            times[p, j] = best
            order[p, j] = kb


@cached
def _scratch(n):
    """g, tau, times, order, chain for GROUP queries of n events."""
    return (np.empty((GROUP, n)), np.empty((GROUP, n)), np.empty((GROUP, n)),
            np.empty((GROUP, n), dtype=np.int64), np.empty((GROUP, n + 1), dtype=np.int64))


@njit(**JIT)
def _apply_block(tables, V, outs, start, stop, inverse):
    DhT, F, G = tables.DhT, tables.F, tables.G
    out = outs[0]
    d, n = DhT.shape
    g, tau, times, order, chain = _scratch(n)
    # going back in time the position moves by -t_j (F[B_j] - F[B_{j+1}])
    sign = -1.0 if inverse else 1.0
    for q0 in range(start, stop, GROUP):
        pn = min(GROUP, stop - q0)
        _chains(DhT, G, V, q0, pn, inverse, g, tau, times, order, chain)
        # telescope (mathematics.md section 3): x = u + sum_j t_j (F[B_{j-1}] - F[B_j])
        # on u = 2**-e V[q], the chain's query; the result scaled back by 2**e
        for p in range(pn):
            q = q0 + p
            e = query_exponent(V, q, d)
            a, b = factors(-e)
            for i in range(d):
                out[q, i] = V[q, i] * a * b
            for j in range(n):
                t = sign * times[p, j]
                Bp = chain[p, j]
                Bn = chain[p, j + 1]
                for i in range(d):
                    out[q, i] += t * (F[Bp, i] - F[Bn, i])
            if e != 0:
                a, b = factors(e)
                for i in range(d):
                    out[q, i] = out[q, i] * a * b


@njit(**JIT)
def _times_block(tables, V, outs, start, stop, inverse):
    DhT, G = tables.DhT, tables.G
    times_out, order_out = outs
    n = DhT.shape[1]
    g, tau, times, order, chain = _scratch(n)
    for q0 in range(start, stop, GROUP):
        pn = min(GROUP, stop - q0)
        # inverse as a literal: the chains' copy with it folded away runs 4-6 % faster
        _chains(DhT, G, V, q0, pn, False, g, tau, times, order, chain)  # literal: kept
        write_times(order, times, q0, pn, order_out, times_out)


@njit(**JIT)
def _sorted_block(tables, V, outs, start, stop, inverse):
    """Own-rates fast path (:class:`SortedTables`): times from the rates of the start
    region, order by a sort."""
    DhT, F, rate = tables.DhT, tables.F, tables.rate
    out = outs[0]
    d, n = DhT.shape
    tev = np.empty(n)
    u = np.empty(d)
    order = np.empty(n, dtype=np.int64)
    sign = 1.0 if inverse else -1.0
    for q in range(start, stop):
        e = query_exponent(V, q, d)  # u = 2**-e V[q], the result scaled back by 2**e
        a, b = factors(-e)
        for i in range(d):
            u[i] = V[q, i] * a * b
        own_rate_times(DhT, rate, u, tev)
        insertion_order(tev, order)  # n <= 40: a dense table
        # x = u -+ sum_j t_j (F[B_j] - F[B_{j-1}])
        for i in range(d):
            out[q, i] = u[i]
        B = 0
        for j in range(n):
            k = order[j]
            B2 = B | (1 << k)
            c = sign * tev[k]
            for i in range(d):
                out[q, i] += c * (F[B2, i] - F[B, i])
            B = B2
        if e != 0:
            a, b = factors(e)
            for i in range(d):
                out[q, i] = out[q, i] * a * b



@njit(**JIT)
def _tangent_block(tables, V, outs, start, stop, transpose):
    """out[q] = M_sigma T[q], or M_sigma^T T[q] when ``transpose``, with sigma the order
    that v = V[q] selects (the chain of :func:`_chains`); ``outs = (out, T)``."""
    DhT, F, G, Dh = tables.DhT, tables.F, tables.G, tables.Dh
    out, T = outs
    d, n = DhT.shape
    g, tau, times, order, chain = _scratch(n)
    for q0 in range(start, stop, GROUP):
        pn = min(GROUP, stop - q0)
        _chains(DhT, G, V, q0, pn, False, g, tau, times, order, chain)  # literal: kept
        for p in range(pn):
            y = out[q0 + p]
            for i in range(d):
                y[i] = T[q0 + p, i]
            for s in range(n):
                j = n - 1 - s if transpose else s
                k = order[p, j]
                saltation_step(y, Dh, k, F, chain[p, j], chain[p, j + 1],
                               G[chain[p, j], k], transpose)



#: M(V) or M^-1(V): outs (out,).
apply = batch(_apply_block)
#: event times and orders: outs (times, orders).
event_times = batch(_times_block)
#: the own-rates fast path: :class:`SortedTables`, outs (out,).
apply_sorted = batch(_sorted_block)
#: M_sigma(V) T or its transpose: outs (out, T).
tangents = batch(_tangent_block)


@cached
def widest_rate_spread(G):
    """(ratio, k, slow_mask, fast_mask): the event k whose rate varies most over the
    regions where it is pending, ``G[fast_mask, k] / G[slow_mask, k]`` (rates positive,
    checked before). One pass over the table."""
    N, n = G.shape
    lo = np.full(n, np.inf)
    hi = np.zeros(n)
    lo_at = np.zeros(n, dtype=np.int64)
    hi_at = np.zeros(n, dtype=np.int64)
    for B in range(N):
        for k in range(n):
            if (B >> k) & 1:
                continue
            g = G[B, k]
            if g < lo[k]:
                lo[k], lo_at[k] = g, B
            if g > hi[k]:
                hi[k], hi_at[k] = g, B
    worst, kw = 0.0, 0
    for k in range(n):
        if hi[k] / lo[k] > worst:
            worst, kw = hi[k] / lo[k], k
    return worst, kw, lo_at[kw], hi_at[kw]
