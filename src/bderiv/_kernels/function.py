"""Blocks for corners computed by a user's njit function ``func`` (tables: a
:class:`FunctionTables`).

``func(happened, out)`` writes the corner of the region ``happened`` (uint8 flags,
``happened[k] = 1`` iff event k happened) into ``out`` (d,); it is evaluated on the n + 1
regions of each query's chain and the rates are recomputed as ``Dh @ F[region]``.

These blocks are compiled once per corner function and per process and are not cached on
disk: the function is part of their signature, and numba keys it by an object that is new
in every process.
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import numpy as np
from numba import njit

from ._core import batch
from .selection import advance, earliest, pending_times, retire
from .steps import impacts

#: status of a query whose chain met a corner with a non-finite (or unwritten) entry.
NON_FINITE = -2


class FunctionTables(NamedTuple):
    """What the blocks read besides the corner function."""

    #: (d, n) the transposed event Jacobian
    DhT: np.ndarray


@njit(error_model="numpy")
def _region(func, DhT, hap, f, r):
    """f = F[hap] and r = Dh @ f; returns -1, NON_FINITE when ``func`` left an entry
    unwritten or non-finite (``f`` is NaN-filled before the call), or the first event
    whose rate is <= 0."""
    f[:] = np.nan
    func(hap, f)
    for i in range(f.shape[0]):
        if not np.isfinite(f[i]):
            return NON_FINITE
    impacts(DhT, f, r)
    for k in range(r.shape[0]):
        if not r[k] > 0.0:
            return k
    return -1


@njit
def chain(func, DhT, u, inverse, x, g, tau, R, C, hap, tev, order):
    """One query; x = M(u) (or M^-1(u)), ``tev[k]`` the time of event k, ``order``.

    The steps of :mod:`.selection` on row 0 of ``g`` and ``tau`` (1, n), with the rates
    and corners of the current and the next region in the rows of ``R`` (2, n) and ``C``
    (2, d), taken in turn; on switching, the position moves by t (F[before] - F[after]).
    Returns -1, or (the chain stops there, ``hap`` its region) the event whose rate is
    <= 0 or NON_FINITE.
    """
    d, n = DhT.shape
    impacts(DhT, u, g[0])
    for k in range(n):
        hap[k] = 1 if inverse else 0
    for i in range(d):
        x[i] = u[i]
    now = 0
    bad = _region(func, DhT, hap, C[now], R[now])
    if bad != -1:
        return bad
    for j in range(n):
        pending_times(g, 0, R, now, tau)
        kb, best = earliest(tau, 0, inverse)
        retire(g, 0, kb, inverse)
        hap[kb] = 0 if inverse else 1
        tev[kb] = best
        order[n - 1 - j if inverse else j] = kb
        bad = _region(func, DhT, hap, C[1 - now], R[1 - now])
        if bad != -1:
            return bad
        for i in range(d):
            x[i] += best * (C[now, i] - C[1 - now, i])
        advance(g, 0, best, R, now, 1 - now)
        now = 1 - now
    return -1


@njit
def _scratch(n, d):
    """x, g, tau, R, C, hap, tev, order: the per-query work arrays of :func:`chain`."""
    return (np.empty(d), np.empty((1, n)), np.empty((1, n)), np.empty((2, n)),
            np.empty((2, d)), np.zeros(n, dtype=np.uint8), np.empty(n),
            np.empty(n, dtype=np.int64))


def _blocks(func):
    """The apply and event-times blocks of one corner function (closures: numba then calls
    ``func`` directly, not as a first-class function value)."""

    @njit(error_model="numpy")
    def apply_block(tables, V, outs, start, stop, inverse):
        DhT = tables.DhT
        out, status = outs
        d, n = DhT.shape
        x, g, tau, R, C, hap, tev, order = _scratch(n, d)
        for q in range(start, stop):
            status[q] = chain(func, DhT, V[q], inverse, x, g, tau, R, C, hap, tev, order)
            out[q, :] = x

    @njit(error_model="numpy")
    def times_block(tables, V, outs, start, stop, inverse):
        DhT = tables.DhT
        times, orders, status = outs
        d, n = DhT.shape
        x, g, tau, R, C, hap, _, _ = _scratch(n, d)
        for q in range(start, stop):
            status[q] = chain(func, DhT, V[q], np.bool_(False), x, g, tau, R, C, hap, times[q],
                              orders[q])

    return apply_block, times_block


@functools.lru_cache(maxsize=64)
def batches(func):
    """``(apply, event_times)`` :class:`~bderiv._kernels._core.Batch` of a corner function
    (tables: a :class:`FunctionTables`; outs ``(out, status)`` and ``(times, orders,
    status)``), compiled once per function."""
    apply_block, times_block = _blocks(func)
    return batch(apply_block, cache=False), batch(times_block, cache=False)


@njit
def diagnose(func, DhT, u, inverse, hap, r):
    """Re-run one query; returns the bad event (or -1), ``hap`` and ``r`` at that point."""
    d, n = DhT.shape
    x, g, tau, R, C, _, tev, order = _scratch(n, d)
    bad = chain(func, DhT, u, inverse, x, g, tau, R, C, hap, tev, order)
    if bad >= 0:  # rates of the region where the chain stopped
        _region(func, DhT, hap, C[0], r)
    return bad


@njit
def corners(func, happened, out):
    """out[i] = F[happened[i]] for each row of 0/1 flags (tables, chains, checks)."""
    for i in range(happened.shape[0]):
        func(happened[i], out[i])
