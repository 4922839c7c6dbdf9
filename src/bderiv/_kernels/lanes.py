"""Lane blocks for dense corner tables: eight queries in lockstep, each query's state in
vector registers (the default; ``_core.PLAIN`` runs the scalar blocks of :mod:`.dense`
instead).

A block gets ``(tables, shape)``: the :class:`LaneTables` of the engine and the
:class:`LaneShape` its drivers are compiled for (:func:`kernels`): the widths ``wh`` and
``wx`` of the event values' and of the position's vectors (so d <= 64 here:
``_engines.dense`` runs the plain blocks above), ``far`` (1 when the records exceed the
caches: see :func:`_step`) and ``carry`` (1: the chain carries the position, see
:func:`_assemble`; 0: it records its steps, and ``wx`` is 8 whatever d: such a chain never
reads it). A query is one row of ``V`` (m, d).

The sizes are an int64 array, ``LaneTables.dims``, not four int fields: on two threads
the int fields were slower (measured: docs/benchmarks.md, "Kernel design choices,
measured"). The flag ``check`` rides in it as a run-time value (1: apply tests the query
band, see :func:`_lane_apply_block`; 0 in the tables of :func:`unchecked`), so that apply
compiles once for both; compiled in, it doubled apply's drivers of a width pair. ``far``
stays compiled in: as a run-time branch in each step the chains beyond the caches ran
13 to 27 % slower (``benchmarks/ab.py``, n = 20).

The lanes select with arithmetic of their own, not the scalar chain's (:mod:`.selection`,
run by :mod:`.dense`): actual coordinates (h = Dh x(t), one record row read per step), a
stored ``-1 / G`` (a multiplication on each step's critical path, not a division), fused
updates and tree sums. A prototype with the scalar chain's arithmetic in the same vectors
(virtual g, ``-g / G[B]`` by division, ``g += t (G[B] - G[B'])`` and the position
likewise by products and sums, the tangents' dot products summed in order) gave the plain
kernels' bits for apply, times, jvp and vjp, and cost far beyond the 5 % the issue
allowed (docs/benchmarks.md, "Kernel design choices, measured"), so the lanes keep their
arithmetic. ``tests/test_lanes.py`` holds them to the scalar chain on the same tables: the
same orders exactly, apply, inverse and times within 4 n eps of their chains' scales,
jvp and vjp within 4 n (d + 2) eps of the sizes their factors sum; at an exact tie of
``-g / G`` the product ``h * (-1 / G)`` may break it the other way (the map is continuous
there: values within the same bound).
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import numpy as np
from numba import njit

from .._numerics import QUERY_BAND
from . import _simd as vec
from ._core import JIT, cached, frozen_tables
from ._drivers import batch
from .steps import write_times

#: queries per lockstep group: eight independent chains hide the latency of each step's
#: reduction (the lanes are written out in :func:`_lanes`: their state lives in registers).
LANES = 8

#: the largest d of the lane blocks (a query's position is one vector of 8 dc <= 64 lanes)
MAX_D = 64

#: positions wider than this are summed after the chain (:func:`_lane_apply_block`)
WIDE_X = 32

#: the width of the loops over 8 coordinates
W8 = vec.static(8)

#: the query band of ``_numerics.QUERY_BAND``
LOW, HIGH = 2.0**-QUERY_BAND, 2.0**QUERY_BAND


class LaneTables(NamedTuple):
    """A dense corner table as the lane blocks read it (built by ``_engines.dense``)."""

    #: (2**n, 24 nc + 8 dc) the region records ``[-1/G | G | F]`` of
    #: ``_tables.region_records``, each part padded to a multiple of 8
    R: np.ndarray
    #: (d, 8 nc) Dh.T, each row padded with zeros
    DhTp: np.ndarray
    #: (n, 8 dc) Dh, each row padded with zeros
    Dhp: np.ndarray
    #: int64 [n, d, nc, dc, check]: the events, the dimension, vectors of 8 per event row
    #: (``8 nc >= n``) and per position (``8 dc >= d``), and the flag :data:`CHECK`; an
    #: array, see the module docstring
    dims: np.ndarray


class LaneShape(NamedTuple):
    """The :func:`~._simd.static` values a lane batch is compiled for."""

    #: the width of the event values' vectors, 8 nc
    wh: tuple
    #: the width of the position's vectors, 8 dc (8 in the blocks whose chains record their
    #: steps, which never read it: :func:`kernels`)
    wx: tuple
    #: 1: prefetch the next record (records beyond the caches)
    far: tuple
    #: 1: the chain carries the position; 0: it records its steps
    carry: tuple


#: where ``LaneTables.dims`` holds the flag ``check`` (1: apply tests the query band)
CHECK = 4


def lane_tables(R, DhTp, Dhp, n: int, d: int, nc: int, dc: int) -> LaneTables:
    """The :class:`LaneTables` of a dense table, read-only, apply checking the band."""
    dims = np.array([n, d, nc, dc, 1], dtype=np.int64)
    return frozen_tables(LaneTables(R, DhTp, Dhp, dims))


def unchecked(tables: LaneTables) -> LaneTables:
    """The same tables with ``check`` off: apply runs every group as given (for queries
    the caller scaled into the band)."""
    dims = tables.dims.copy()
    dims[CHECK] = 0
    return frozen_tables(tables._replace(dims=dims))


@cached
def _start(DhTp, V, q, d, s, wh):
    """s Dh V[q]: the event values at time 0 (negated backwards), in a vector."""
    h = vec.splat(0.0, wh)
    for i in range(d):
        h = vec.fma(vec.splat(s * V[q, i], wh), vec.load(DhTp, i, 0, wh), h)
    return h


@cached
def _step(R, h, x, t, b, out, wh, wx, far, carry):
    """One event of one lane: the smallest pending ``dt_k = h_k * (-1 / G[b, k])`` (ties
    to the smaller k, the lowest bit of the equality mask), then ``h += dt G[b]`` and, when
    ``carry``, ``x += dt F[b]``. ``out``: the bits of the events that are not candidates
    (they get dt = +inf, so no entry of h is ever overwritten). If no candidate equals the smallest
    time (a time overflowed to inf or NaN: the row is refused as non-finite) the first
    candidate is taken, so that k is always a pending event. Returns (h, x, t, b) after
    the event and k; when ``far`` (records beyond the caches), fetches the lines of the next
    record it will read now (they are read after the other lanes' steps).
    """
    og = vec.value(wh)
    dt = vec.where_bits(vec.mul(h, vec.load(R, b, 0, wh)), out, np.inf)
    best = vec.smallest(dt)
    hit = vec.equal_mask(dt, best) & ~out
    k = vec.trailing_zeros(hit if hit != 0 else ~out)
    h = vec.fma(vec.splat(best, wh), vec.load(R, b, og, wh), h)
    if vec.value(carry):
        x = vec.fma(vec.splat(best, wx), vec.load(R, b, 2 * og, wx), x)
    b ^= 1 << k
    if vec.value(far):
        for c in range((2 * og + vec.value(carry) * vec.value(wx)) // 8):
            vec.prefetch(R, b, 8 * c)
    return h, x, t + best, b, k


@cached
def _record(order, times, j, k, t, s, carry):
    """The j-th event of a lane and its time (``order``, ``times``: the lane's rows),
    unless the chain carries the position. (Rows, not a lane index: each literal index
    would compile a copy of this function.)"""
    if not vec.value(carry):
        order[j], times[j] = k, s * t


@njit(inline="always", **JIT)
def _lanes(args, V, q0, last, inverse, X, T, order, times):
    """Run the chains of the queries ``V[q0:q0 + 8]`` in lockstep (queries past ``last``
    repeat it: their results are not used).

    In *actual* coordinates: ``h`` holds the event values h = Dh x(t) at the time ``t``
    reached so far. Forwards, a pending event k is due after ``dt_k = h_k * (-1 / G[B, k])``;
    the smallest wins, time advances by it, h by ``dt G[B]`` and the position by
    ``dt F[B]``. Backwards (``inverse``) time runs the other way from the full region down;
    with ``h = -Dh x`` there the same formulas hold. The first step may go back in time
    (events before t = 0). Writes ``T[p]`` the time of the last event (signed) and, when
    ``carry``, ``X[p]`` the sum of ``dt F[B]`` over the steps (s X is the move from v to the
    position at the last event, s = -1 backwards), else ``order[p, j]`` the j-th event and
    ``times[p, j]`` its time. One line per lane, on purpose: each lane's vectors are
    local variables, kept in registers.
    """
    tables, shape = args
    R, DhTp, n, d = tables.R, tables.DhTp, tables.dims[0], tables.dims[1]
    wh, wx, far, carry = shape.wh, shape.wx, shape.far, shape.carry
    s = -1.0 if inverse else 1.0
    # not candidates: the events that happened (forwards) or did not (backwards), and the
    # padding lanes: out = (b ^ flip) | pad
    flip, pad = (-1, 0) if inverse else (0, -1 << n)
    # an int64 0, not a literal: _step would be compiled for both while the loop is typed
    b = (1 << n) - 1 if inverse else np.int64(0)
    q1, q2, q3 = min(q0 + 1, last), min(q0 + 2, last), min(q0 + 3, last)
    q4, q5, q6, q7 = min(q0 + 4, last), min(q0 + 5, last), min(q0 + 6, last), min(q0 + 7, last)
    h0, h1 = _start(DhTp, V, q0, d, s, wh), _start(DhTp, V, q1, d, s, wh)
    h2, h3 = _start(DhTp, V, q2, d, s, wh), _start(DhTp, V, q3, d, s, wh)
    h4, h5 = _start(DhTp, V, q4, d, s, wh), _start(DhTp, V, q5, d, s, wh)
    h6, h7 = _start(DhTp, V, q6, d, s, wh), _start(DhTp, V, q7, d, s, wh)
    # event values at time 0 out of the band (no branch here: one spent 10 %)
    bad = (vec.outside_mask(h0, LOW, HIGH) | vec.outside_mask(h1, LOW, HIGH)
           | vec.outside_mask(h2, LOW, HIGH) | vec.outside_mask(h3, LOW, HIGH)
           | vec.outside_mask(h4, LOW, HIGH) | vec.outside_mask(h5, LOW, HIGH)
           | vec.outside_mask(h6, LOW, HIGH) | vec.outside_mask(h7, LOW, HIGH))
    x0 = x1 = x2 = x3 = x4 = x5 = x6 = x7 = vec.splat(0.0, wx)
    t0 = t1 = t2 = t3 = t4 = t5 = t6 = t7 = 0.0
    b0 = b1 = b2 = b3 = b4 = b5 = b6 = b7 = b
    for j in range(n):
        h0, x0, t0, b0, k = _step(R, h0, x0, t0, b0, (b0 ^ flip) | pad, wh, wx,
                                  far, carry)
        _record(order[0], times[0], j, k, t0, s, carry)
        h1, x1, t1, b1, k = _step(R, h1, x1, t1, b1, (b1 ^ flip) | pad, wh, wx,
                                  far, carry)
        _record(order[1], times[1], j, k, t1, s, carry)
        h2, x2, t2, b2, k = _step(R, h2, x2, t2, b2, (b2 ^ flip) | pad, wh, wx,
                                  far, carry)
        _record(order[2], times[2], j, k, t2, s, carry)
        h3, x3, t3, b3, k = _step(R, h3, x3, t3, b3, (b3 ^ flip) | pad, wh, wx,
                                  far, carry)
        _record(order[3], times[3], j, k, t3, s, carry)
        h4, x4, t4, b4, k = _step(R, h4, x4, t4, b4, (b4 ^ flip) | pad, wh, wx,
                                  far, carry)
        _record(order[4], times[4], j, k, t4, s, carry)
        h5, x5, t5, b5, k = _step(R, h5, x5, t5, b5, (b5 ^ flip) | pad, wh, wx,
                                  far, carry)
        _record(order[5], times[5], j, k, t5, s, carry)
        h6, x6, t6, b6, k = _step(R, h6, x6, t6, b6, (b6 ^ flip) | pad, wh, wx,
                                  far, carry)
        _record(order[6], times[6], j, k, t6, s, carry)
        h7, x7, t7, b7, k = _step(R, h7, x7, t7, b7, (b7 ^ flip) | pad, wh, wx,
                                  far, carry)
        _record(order[7], times[7], j, k, t7, s, carry)
    if vec.value(carry):
        vec.store(X, 0, 0, x0), vec.store(X, 1, 0, x1), vec.store(X, 2, 0, x2)
        vec.store(X, 3, 0, x3), vec.store(X, 4, 0, x4), vec.store(X, 5, 0, x5)
        vec.store(X, 6, 0, x6), vec.store(X, 7, 0, x7)
    T[0], T[1], T[2], T[3], T[4], T[5], T[6], T[7] = (s * t0, s * t1, s * t2, s * t3, s * t4,
                                                      s * t5, s * t6, s * t7)
    return bad == 0


@cached
def _lane_scratch(tables):
    """X (moves), T (times of the last events), order and times of the steps of one
    lockstep group."""
    n, dc = tables.dims[0], tables.dims[3]
    return (np.empty((LANES, 8 * dc)), np.empty(LANES), np.empty((LANES, n), dtype=np.int64),
            np.empty((LANES, n)))


@njit(**JIT)
def _lane_apply_block(args, V, outs, start, stop, inverse):
    """out = M(V) (M^-1 when ``inverse``), eight queries at a time (:func:`_assemble`).

    When ``check``, a group whose event values at time 0 (``Dh v``, the tables scaled
    at build) are not all 0 or within ``2**+-_numerics.QUERY_BAND`` gets NaN rows: the
    engine runs them again scaled by powers of two (M is positively homogeneous; the event
    times of a query near the ends of the float64 range would under- or overflow). The
    test, on vectors in registers and without a branch in the chains, costs about 2 %;
    scaling every query in the kernel cost 1.3x to 2x.
    """
    tables, shape = args
    d, check = tables.dims[1], tables.dims[CHECK]
    out = outs[0]
    X, T, order, times = _lane_scratch(tables)
    for q0 in range(start, stop, LANES):
        pn = min(LANES, stop - q0)
        if _lanes(args, V, q0, q0 + pn - 1, inverse, X, T, order, times) or not check:
            _assemble(tables, shape.wx, shape.carry, V, q0, pn, inverse, out, q0, X, T, order,
                      times)
        else:
            for p in range(pn):
                for i in range(d):
                    out[q0 + p, i] = np.nan


# not inlined: its copy into the apply block, after the lanes', took a fifth of a width
# pair's compilation and gained nothing at run time (design.md, "The drivers compiled once");
# it gets the two static values it reads, not the shape: one compilation per wx and carry,
# not per width pair
@cached
def _assemble(tables, wx, carry, V, r0, pn, inverse, out, q0, X, T, order, times):
    """out[q0 + p] = M(V[r0 + p]) for p < pn from the chains of :func:`_lanes`:
    ``v + s X - T F[end]``, the position at the last event moved back to time 0 along the
    final region's field. Unless ``carry`` (d > 32: the lanes' positions would not fit
    the registers) the chain only records its steps and
    ``v + sum_j t_j (F[before_j] - F[after_j])`` (mathematics.md section 3) is summed afterwards,
    8 coordinates at a time."""
    R = tables.R
    n, d, dc, of = tables.dims[0], tables.dims[1], tables.dims[3], 16 * tables.dims[2]
    end = 0 if inverse else (1 << n) - 1
    s = -1.0 if inverse else 1.0
    for p in range(pn):
        if not vec.value(carry):
            for c in range(dc):
                count = min(d - 8 * c, 8)
                x = vec.load_first(V, r0 + p, 8 * c, count, W8)
                before = (1 << n) - 1 if inverse else 0
                for j in range(n):
                    after = before ^ (1 << order[p, j])
                    jump = vec.sub(vec.load(R, before, of + 8 * c, W8),
                                   vec.load(R, after, of + 8 * c, W8))
                    x = vec.fma(vec.splat(times[p, j], W8), jump, x)
                    before = after
                vec.store_first(out, q0 + p, 8 * c, count, x)
        else:
            v = vec.fma(vec.splat(s, wx), vec.load(X, p, 0, wx),
                        vec.load_first(V, r0 + p, 0, d, wx))
            y = vec.fma(vec.splat(-T[p], wx), vec.load(R, end, of, wx), v)
            vec.store_first(out, q0 + p, 0, d, y)


@njit(**JIT)
def _lane_times_block(args, V, outs, start, stop, inverse):
    times_out, order_out = outs
    X, T, order, times = _lane_scratch(args[0])
    for q0 in range(start, stop, LANES):
        _lanes(args, V, q0, stop - 1, False, X, T, order, times)
        write_times(order, times, q0, min(LANES, stop - q0), order_out, times_out)


@njit(**JIT)
def _lane_tangent_block(args, V, outs, start, stop, transpose):
    """out[q] = M_sigma T[q] (or its transpose), sigma the order v = V[q] selects:
    the saltation factors of mathematics.md section 4 along the chain,
    ``S y = y + (F[after] - F[before]) (Dh[k] . y) / G[before, k]`` and
    ``S^T y = y + Dh[k] ((F[after] - F[before]) . y) / G[before, k]`` (backwards), with
    y in a vector, the eight lanes' factors in turn (their chains overlap);
    ``outs = (out, T)`` (T is read)."""
    tables, shape = args
    R, Dhp, wx = tables.R, tables.Dhp, shape.wx
    # the chain records its steps: it never reads wx (its steps compile as the event times')
    chain = (tables, LaneShape(shape.wh, W8, shape.far, shape.carry))
    out, T = outs
    n, d, og, of = tables.dims[0], tables.dims[1], 8 * tables.dims[2], 16 * tables.dims[2]
    X, times, order, steps = _lane_scratch(tables)
    Y = np.empty_like(X)
    region = np.empty(LANES, dtype=np.int64)
    for q0 in range(start, stop, LANES):
        _lanes(chain, V, q0, stop - 1, False, X, times, order, steps)
        for p in range(LANES):  # the padding lanes of y stay 0
            vec.store(Y, p, 0, vec.load_first(T, min(q0 + p, stop - 1), 0, d, wx))
            region[p] = (1 << n) - 1 if transpose else 0  # walk the chain either way
        for st in range(n):
            for p in range(LANES):
                k = order[p, n - 1 - st] if transpose else order[p, st]
                other = region[p] ^ (1 << k)
                before, after = (other, region[p]) if transpose else (region[p], other)
                jump = vec.sub(vec.load(R, after, of, wx), vec.load(R, before, of, wx))
                dh = vec.load(Dhp, k, 0, wx)
                along, onto = (jump, dh) if transpose else (dh, jump)
                y = vec.load(Y, p, 0, wx)
                m = vec.total(vec.mul(along, y)) / R[before, og + k]
                vec.store(Y, p, 0, vec.fma(vec.splat(m, wx), onto, y))
                region[p] = other
        for p in range(min(LANES, stop - q0)):
            vec.store_first(out, q0 + p, 0, d, vec.load(Y, p, 0, wx))


@functools.cache
def kernels(wh: int, wx: int, far: int):
    """The batches ``(apply, event_times, tangents)`` compiled for vectors of ``wh`` and
    ``wx`` lanes and ``far``; each takes a :class:`LaneTables` and outs ``(out,)`` (M(V) or
    M^-1(V)), ``(times, orders)``, ``(out, T)`` (M_sigma(V) T or its transpose). Only apply carries
    the position along the chain (``carry``), and only while it fits the registers; the
    others record the steps. ``apply`` gives NaN rows for groups outside the query band
    unless the tables are :func:`unchecked` (see :func:`_lane_apply_block`).

    A chain that records its steps never reads ``wx`` (the sums after it go 8 coordinates
    at a time), so those blocks are compiled for ``wx = 8`` whatever d: one driver per
    ``wh`` and ``far`` serves every width of the position."""
    carry = int(wx <= WIDE_X)
    return (_batch(_lane_apply_block, _shape(wh, wx if carry else 8, far, carry)),
            _batch(_lane_times_block, _shape(wh, 8, far, 0)),
            _batch(_lane_tangent_block, _shape(wh, wx, far, 0)))


def _shape(wh: int, wx: int, far: int, carry: int) -> LaneShape:
    return LaneShape(vec.static(wh), vec.static(wx), vec.static(far), vec.static(carry))


@functools.cache
def _batch(block, shape: LaneShape):
    """One batch per block and shape (widths that share a shape share its drivers)."""
    return batch(block, statics=shape)
