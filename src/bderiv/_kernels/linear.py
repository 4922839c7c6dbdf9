"""What is linear once a query's order is known: the linear fast path (``M v`` for every
query), the own-rates fast path's event times (``-(Dh v)_k / rate_k``, then their order),
a piece ``S_n ... S_1`` as a matrix (mathematics.md section 4) and tangents along given
chains, one saltation factor at a time. Any representation's engine runs them.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit

from ._core import JIT, cached
from ._drivers import batch
from .steps import (
    factors,
    insertion_order,
    merge_order,
    own_rate_times,
    query_exponent,
    saltation_step,
)


class OwnRateTables(NamedTuple):
    """The own-rates fast path's event times (any representation)."""

    #: (d, n) the transposed event Jacobian
    DhT: np.ndarray
    #: (n,) the rates of the region the chains start from
    rate: np.ndarray


class LinearTables(NamedTuple):
    """The linear fast path, and the linear stages of a flow map."""

    #: (d, d) M transposed (forwards)
    MT: np.ndarray
    #: (d, d) M^-1 transposed (backwards)
    MinvT: np.ndarray


class ChainCornerTables(NamedTuple):
    """Tangents along chains found beforehand (:func:`_saltations_block`)."""

    #: (n, d) the event Jacobian
    Dh: np.ndarray
    #: (m, n + 1, d): C[q, j] the corner of the region before the (j+1)-th event of query q
    C: np.ndarray
    #: (m, n) int64: the order of each query's chain
    orders: np.ndarray


@njit(**JIT)
def _own_times_block(tables, V, outs, start, stop, inverse):
    """Event times and orders from own rates (any representation's own-rates fast path),
    for up to :data:`INSERTION_SORT_MAX` events."""
    times, orders = outs
    for q in range(start, stop):
        own_rate_times(tables.DhT, tables.rate, V[q], times[q])
        insertion_order(times[q], orders[q])


@njit(**JIT)
def _own_times_many_block(tables, V, outs, start, stop, inverse):
    """:func:`_own_times_block` for more events (a kernel of its own: the merge sort is
    compiled only where it runs)."""
    times, orders = outs
    for q in range(start, stop):
        own_rate_times(tables.DhT, tables.rate, V[q], times[q])
        merge_order(times[q], orders[q])


@njit(**JIT)
def _linear_block(tables, V, outs, start, stop, inverse):
    """out[q] = M @ V[q] (:class:`LinearTables`), as axpys (vectorises), on V[q] scaled by
    a power of two (:func:`query_exponent`: no product under- or overflows unless the
    result does)."""
    MT = tables.MinvT if inverse else tables.MT
    out = outs[0]
    d = MT.shape[0]
    for q in range(start, stop):
        e = query_exponent(V, q, d)
        a, b = factors(-e)
        for r in range(d):
            out[q, r] = 0.0
        for c in range(d):
            vc = V[q, c] * a * b
            for r in range(d):
                out[q, r] += MT[c, r] * vc
        if e != 0:
            a, b = factors(e)
            for r in range(d):
                out[q, r] = out[q, r] * a * b


#: times and orders of an own-rates fast path: :class:`OwnRateTables`, outs (times,
#: orders); ``own_times`` for up to :data:`INSERTION_SORT_MAX` events, ``own_times_many``
#: above (the engine picks by n).
own_times = batch(_own_times_block)
own_times_many = batch(_own_times_many_block)
#: the linear fast path: :class:`LinearTables`, outs (out,).
linear = batch(_linear_block)


@cached
def piece_from_corners(Dh, Fc, order, out):
    """Linear piece S_n ... S_1 of one order (mathematics.md section 4) into ``out`` (d, d).

    ``Fc[j]`` is the corner of the region before the (j+1)-th event (``Fc[n]`` after the
    last). S_j = I + (Fc[j] - Fc[j-1]) Dh[k_j]^T / rate, rate = Dh[k_j] . Fc[j-1]; applied
    to the running product as M += outer(jump, Dh[k_j] @ M / rate).
    """
    n, d = Dh.shape
    out[:, :] = 0.0
    for i in range(d):
        out[i, i] = 1.0
    row = np.empty(d)
    for j in range(n):
        k = order[j]
        rate = 0.0
        for i in range(d):
            rate += Dh[k, i] * Fc[j, i]
        for c in range(d):
            s = 0.0
            for i in range(d):
                s += Dh[k, i] * out[i, c]
            row[c] = s / rate
        for r in range(d):
            jump = Fc[j + 1, r] - Fc[j, r]
            for c in range(d):
                out[r, c] += jump * row[c]


@njit(**JIT)
def _saltations_block(tables, V, outs, start, stop, transpose):
    """out[q] = M_sigma T[q] (or M_sigma^T T[q]) from the corners along each chain
    (:class:`ChainCornerTables`); ``outs = (out, T)``. The transpose runs the factors
    backwards: M^T = S_1^T ... S_n^T.
    """
    Dh, C, orders = tables.Dh, tables.C, tables.orders
    out, T = outs
    n, d = Dh.shape
    for q in range(start, stop):
        y = out[q]
        for i in range(d):
            y[i] = T[q, i]
        Cq = C[q]
        for s in range(n):
            j = n - 1 - s if transpose else s
            k = orders[q, j]
            rate = 0.0
            for i in range(d):
                rate += Dh[k, i] * Cq[j, i]
            saltation_step(y, Dh, k, Cq, j, j + 1, rate, transpose)


#: tangents from chain corners: :class:`ChainCornerTables`, outs (out, T).
saltations = batch(_saltations_block)
