"""Blocks for structured corners (:class:`bderiv.StructuredCorners`).

``F[mask] = F0 + sum_{k in mask} A[k] + sum_{pairs in mask} B[p]``: the rates of the
current region are updated incrementally along each query's chain; the result is
``u -+ (A^T t + B^T s)`` with ``t`` the event times and ``s[p]`` the time at which pair p
switched on (the later of its two event times).

The tables are a :class:`StructuredTables` (built by ``_engines.structured``; the event
axis padded to ``8 nc``, the coordinates to ``8 dc``); the own-rates fast path reads an
:class:`StructuredOwnTables`.

A block takes its queries in groups of :data:`~.structured_chains.GROUP` and runs the
chains of :mod:`.structured_chains`; a query whose chain meets a rate that is not > 0
stops and writes the offending event into ``status[q]`` (else -1); the caller re-runs it
with :func:`diagnose` to name the region.

The sizes stay int fields: unlike ``lanes.LaneTables``, an int64 array of them measured
no difference beyond the noise (docs/benchmarks.md, "Kernel design choices, measured").
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit

from ._core import JIT, cached
from ._drivers import batch
from .steps import own_rate_times
from .structured_chains import GROUP, chain_group, group_scratch, products


class StructuredTables(NamedTuple):
    """Structured corners as the chains read them."""

    #: (d, 8 nc) Dh.T
    DhTp: np.ndarray
    #: (2, 8 nc) the rates of region 0 and of the full region (padding 1)
    rates: np.ndarray
    #: (n, 8 nc) the rate jumps of the events, ``a[i, k] = Dh[k] . A[i]``
    ap: np.ndarray
    #: (p, 8 nc) the rate jumps of the pairs, ``bDh[p, k] = Dh[k] . B[p]``
    bDhp: np.ndarray
    #: (n + 1,) int64: the pairs touching event i are ``pidx[ptr[i]:ptr[i + 1]]``
    ptr: np.ndarray
    #: int64: the partner event of each such pair
    other: np.ndarray
    #: int64: the index of each such pair
    pidx: np.ndarray
    #: (n + p, 8 dc) the stacked jumps ``[A; B]``
    ABp: np.ndarray
    #: (1, 8 nc) the event indices as floats (padding inf)
    iota: np.ndarray
    #: the number of events
    n: int
    #: the dimension
    d: int
    #: vectors of 8 per event row (``8 nc >= n``)
    nc: int
    #: vectors of 8 per position (``8 dc >= d``)
    dc: int
    #: the number of pairs
    npairs: int
    #: the most pairs of one event
    deg: int
    #: 1: test every rate of every region on the chain (transversality not proved)
    check: int


class StructuredOwnTables(NamedTuple):
    """The own-rates fast path of structured corners."""

    #: (d, n) Dh.T
    DhT: np.ndarray
    #: (n,) the rates of the region the chains start from
    rate: np.ndarray
    #: (p, 2) int64: the events of each pair
    pairs: np.ndarray
    #: (n, d) the jumps of the events
    A: np.ndarray
    #: (p, d) the jumps of the pairs
    B: np.ndarray


@njit(**JIT)
def _apply_block(tables, V, outs, start, stop, inverse):
    out, status = outs
    scratch = group_scratch(tables)
    for q0 in range(start, stop, GROUP):
        pn = min(GROUP, stop - q0)
        chain_group(tables, V, q0, pn, inverse, tables.check != 0, status, scratch)
        products(tables.ABp, scratch[1], np.int64(0), pn, 1.0 if inverse else -1.0, V, q0, out, q0)


@njit(**JIT)
def _times_block(tables, V, outs, start, stop, inverse):
    times, orders, status = outs
    n = tables.n
    scratch = group_scratch(tables)
    TS, ORD = scratch[1], scratch[2]
    for q0 in range(start, stop, GROUP):
        pn = min(GROUP, stop - q0)
        chain_group(tables, V, q0, pn, np.bool_(False), tables.check != 0, status, scratch)
        for p in range(pn):
            for k in range(n):
                times[q0 + p, k] = TS[p, k]
                orders[q0 + p, k] = ORD[p, k]


@cached
def diagnose(tables, U, inverse, hap, r):
    """Re-run the query ``U[0]`` (U: (1, d)) checking every rate; returns the bad event (or
    -1) and writes ``hap`` (the region's flags) and ``r`` (its rates) where it stopped."""
    scratch = group_scratch(tables)
    status = np.empty(1, dtype=np.int64)
    chain_group(tables, U, np.int64(0), np.int64(1), inverse, np.bool_(True), status, scratch)
    R, HAP = scratch[3][0], scratch[3][1]
    for k in range(hap.shape[0]):
        hap[k], r[k] = HAP[0, k], R[0, k]
    return status[0]


@cached
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


@cached
def _pair_times(pairs, tev, s):
    for p in range(pairs.shape[0]):
        s[p] = max(tev[pairs[p, 0]], tev[pairs[p, 1]])


@njit(**JIT)
def _own_block(tables, V, outs, start, stop, inverse):
    """Own-rates fast path (:class:`StructuredOwnTables`): the times are first-order times, pairs
    switch on at the later one."""
    DhT, rate, pairs, A, Bm = tables.DhT, tables.rate, tables.pairs, tables.A, tables.B
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
