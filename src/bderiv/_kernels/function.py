"""Blocks for corners computed by a user's njit function ``func``: ``tables = (DhT,)``.

``func(happened, out)`` writes the corner of the region ``happened`` (uint8 flags,
``happened[k] = 1`` iff event k happened) into ``out`` (d,); it is evaluated on the n + 1
regions of each query's chain and the rates are recomputed as ``Dh @ F[region]``.

These blocks are compiled once per corner function and per process and are not cached on
disk: the function is part of their signature, and numba keys it by an object that is new
in every process.
"""

from __future__ import annotations

import functools

import numpy as np
from numba import njit

from ._core import batch, impacts

#: status of a query whose chain met a corner with a non-finite (or unwritten) entry.
NON_FINITE = -2


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
def chain(func, DhT, u, inverse, x, g, r, r2, f, f2, hap, tev, order):
    """One query; x = M(u) (or M^-1(u)), ``tev[k]`` the time of event k, ``order``.

    The next event is the candidate with the smallest time -g[k] / r[k] in the current
    region (the largest going backwards), ties to the smaller event; on switching, the
    position moves by t (F[before] - F[after]) and so does g = Dh x. Returns -1, or (the
    chain stops there, ``hap`` its region) the event whose rate is <= 0 or NON_FINITE.
    """
    d, n = DhT.shape
    impacts(DhT, u, g)
    for k in range(n):
        hap[k] = 1 if inverse else 0
    for i in range(d):
        x[i] = u[i]
    bad = _region(func, DhT, hap, f, r)
    if bad != -1:
        return bad
    want = 1 if inverse else 0
    for j in range(n):
        best = 0.0
        kb = -1
        for k in range(n):
            if hap[k] == want:
                tau = -g[k] / r[k]
                if kb < 0 or (tau > best if inverse else tau < best):
                    best = tau
                    kb = k
        hap[kb] = 1 - want
        tev[kb] = best
        order[n - 1 - j if inverse else j] = kb
        bad = _region(func, DhT, hap, f2, r2)
        if bad != -1:
            return bad
        for i in range(d):
            x[i] += best * (f[i] - f2[i])
            f[i] = f2[i]
        for k in range(n):
            g[k] += best * (r[k] - r2[k])
            r[k] = r2[k]
    return -1


@njit
def _scratch(n, d):
    """x, g, r, r2, f, f2, hap, tev, order: the per-query work arrays of :func:`chain`."""
    return (np.empty(d), np.empty(n), np.empty(n), np.empty(n), np.empty(d), np.empty(d),
            np.zeros(n, dtype=np.uint8), np.empty(n), np.empty(n, dtype=np.int64))


def _blocks(func):
    """The apply and event-times blocks of one corner function (closures: numba then calls
    ``func`` directly, not as a first-class function value)."""

    @njit(error_model="numpy")
    def apply_block(tables, V, outs, start, stop, inverse):
        DhT = tables[0]
        out, status = outs
        d, n = DhT.shape
        x, g, r, r2, f, f2, hap, tev, order = _scratch(n, d)
        for q in range(start, stop):
            status[q] = chain(func, DhT, V[q], inverse, x, g, r, r2, f, f2, hap, tev, order)
            out[q, :] = x

    @njit(error_model="numpy")
    def times_block(tables, V, outs, start, stop, inverse):
        DhT = tables[0]
        times, orders, status = outs
        d, n = DhT.shape
        x, g, r, r2, f, f2, hap, _, _ = _scratch(n, d)
        for q in range(start, stop):
            status[q] = chain(func, DhT, V[q], False, x, g, r, r2, f, f2, hap, times[q],
                              orders[q])

    return apply_block, times_block


@functools.lru_cache(maxsize=64)
def batches(func):
    """``(apply, event_times)`` :class:`~bderiv._kernels._core.Batch` of a corner function
    (``tables = (DhT,)``; outs ``(out, status)`` and ``(times, orders, status)``), compiled
    once per function."""
    apply_block, times_block = _blocks(func)
    return batch(apply_block, cache=False), batch(times_block, cache=False)


@njit
def diagnose(func, DhT, u, inverse, hap, r):
    """Re-run one query; returns the bad event (or -1), ``hap`` and ``r`` at that point."""
    d, n = DhT.shape
    x, g, _, r2, f, f2, _, tev, order = _scratch(n, d)
    bad = chain(func, DhT, u, inverse, x, g, r, r2, f, f2, hap, tev, order)
    if bad >= 0:  # rates of the region where the chain stopped
        _region(func, DhT, hap, f, r)
    return bad


@njit
def corners(func, happened, out):
    """out[i] = F[happened[i]] for each row of 0/1 flags (tables, chains, checks)."""
    for i in range(happened.shape[0]):
        func(happened[i], out[i])
