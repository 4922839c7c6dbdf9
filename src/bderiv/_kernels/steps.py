"""The arithmetic steps the blocks of several representations share: a query's binary
exponent and exact power-of-two factors (mathematics.md section 3, "Scale"), event values
``Dh u`` and own-rate event times, stable orders of event times, the rows of
``event_times`` from a group's steps, and one saltation factor applied to a tangent.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from .._numerics import INSERTION_SORT_MAX, QUERY_BAND
from ._core import JIT, cached
from ._simd import bits_float, float_bits


@njit(inline="always", **JIT)
def row_exponent(V, q, d):
    """e with ``max_i |V[q, i]|`` in [2**(e - 1), 2**e) (0 for a zero row), as
    ``math.frexp`` gives it: the query ``2**-e V[q]`` has its largest entry in [0.5, 1)
    (see :mod:`.scaling`). Read from the bits of a normal float (a libm call per query
    cost the lane kernels half their time)."""
    big = 0.0
    for i in range(d):
        big = max(big, abs(V[q, i]))
    biased = (float_bits(big) >> 52) & 0x7FF
    if biased == 0:  # 0 or subnormal
        return math.frexp(big)[1]
    return biased - 1022


@njit(inline="always", **JIT)
def query_exponent(V, q, d):
    """:func:`row_exponent`, or 0 for a row within the query band (``QUERY_BAND``): such
    a row runs as given, which gives the scaled row's bits, scaled."""
    e = row_exponent(V, q, d)
    return 0 if -QUERY_BAND <= e <= QUERY_BAND else e


@njit(inline="always", **JIT)
def _pow2(k):
    """2.0**k for -1022 <= k <= 1023, from its bits."""
    return bits_float((k + 1023) << 52)


@njit(inline="always", **JIT)
def factors(e):
    """Two floats whose product is 2**e, for |e| <= 2044: ``(2**e, 1)`` when 2**e is a
    normal float (one multiplication rounds once, into the subnormals too), else two
    halves (the first product is exact, the second rounds only into the subnormals)."""
    if -1022 <= e <= 1023:
        return _pow2(e), 1.0
    return _pow2(e // 2), _pow2(e - e // 2)


@cached
def impacts(DhT, u, g):
    """g = Dh @ u from DhT = Dh.T (d, n), as axpys over the rows of DhT (vectorises)."""
    d, n = DhT.shape
    for k in range(n):
        g[k] = 0.0
    for i in range(d):
        ui = u[i]
        for k in range(n):
            g[k] += DhT[i, k] * ui


@cached
def own_rate_times(DhT, rate, u, tev):
    """tev[k] = -(Dh u)_k / rate[k]: the event times when no pending rate ever changes."""
    impacts(DhT, u, tev)
    for k in range(tev.shape[0]):
        tev[k] = -tev[k] / rate[k]


@cached
def insertion_order(t, order):
    """order = stable argsort of t (ties keep the smaller event first), by insertion: the
    order of up to a few dozen events (:data:`INSERTION_SORT_MAX`; a dense table's n <= 40)."""
    n = t.shape[0]
    for k in range(n):
        order[k] = k
    # the bound i >= 0 lets LLVM drop the negative-index test of order[i] (a bound passed
    # in, as merge_order's runs have, cost 10-20 % at n = 2..16)
    for j in range(1, n):
        k = order[j]
        v = t[k]
        i = j - 1
        while i >= 0 and t[order[i]] > v:
            order[i + 1] = order[i]
            i -= 1
        order[i + 1] = k


@cached
def merge_order(t, order):
    """order = stable argsort of t (ties keep the smaller event first) for more than
    :data:`INSERTION_SORT_MAX` events: runs of that length by insertion, merged pairwise,
    bottom up (``np.argsort``'s merge sort compiled into the kernels cost seconds of
    compile time each)."""
    n = t.shape[0]
    for k in range(n):
        order[k] = k
    run = INSERTION_SORT_MAX
    for lo in range(0, n, run):
        for j in range(lo + 1, min(lo + run, n)):
            k = order[j]
            v = t[k]
            i = j - 1
            while i >= lo and t[order[i]] > v:
                order[i + 1] = order[i]
                i -= 1
            order[i + 1] = k
    src, dst = order, np.empty(n, dtype=np.int64)
    moved = False
    while run < n:
        for lo in range(0, n, 2 * run):
            mid, hi = min(lo + run, n), min(lo + 2 * run, n)
            i, j = lo, mid
            for o in range(lo, hi):  # the left run first on ties: stable
                if j >= hi or (i < mid and not t[src[i]] > t[src[j]]):
                    dst[o] = src[i]
                    i += 1
                else:
                    dst[o] = src[j]
                    j += 1
        src, dst = dst, src
        moved = not moved
        run *= 2
    if moved:  # the last pass wrote the scratch
        for k in range(n):
            order[k] = src[k]


@cached
def write_times(order, times, q0, pn, order_out, times_out):
    """Rows q0.. of the outputs of ``event_times`` from a group's steps: ``order[p, j]``
    the j-th event of query q0 + p and ``times[p, j]`` its time."""
    for p in range(pn):
        for j in range(order.shape[1]):
            order_out[q0 + p, j] = order[p, j]
            times_out[q0 + p, order[p, j]] = times[p, j]




@cached
def saltation_step(y, Dh, k, Fc, before, after, rate, transpose):
    """y <- S y, or S^T y when ``transpose``, in place (mathematics.md section 4).

    S = I + (Fc[after] - Fc[before]) Dh[k]^T / rate, the factor of event k leaving the
    region whose corner is ``Fc[before]`` (``rate`` = Dh[k] . Fc[before] > 0). O(d).
    """
    d = y.shape[0]
    c = 0.0
    if transpose:  # S^T y = y + Dh[k] (jump . y) / rate
        for i in range(d):
            c += (Fc[after, i] - Fc[before, i]) * y[i]
        c /= rate
        for i in range(d):
            y[i] += c * Dh[k, i]
    else:  # S y = y + jump (Dh[k] . y) / rate
        for i in range(d):
            c += Dh[k, i] * y[i]
        c /= rate
        for i in range(d):
            y[i] += c * (Fc[after, i] - Fc[before, i])
