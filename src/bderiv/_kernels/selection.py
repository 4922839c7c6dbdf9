"""The selection of mathematics.md section 3, written once: the steps of every scalar chain.

A chain keeps ``g = Dh x`` for its virtual position x (``g[p]``: row p of a lockstep
group). In a region whose rates are ``r`` (a row of a rate table, or the rates a corner
model's region gives), a pending event k is due at ``-g_k / r_k``; the next event is the
earliest (the latest going backwards), ties to the smaller k. An event that is no longer
a candidate is :func:`retire`-d, ``g_k = -inf`` (``+inf`` backwards): while its rates are
positive its time is then ``+inf`` (``-inf``) and it is never selected again, so the
loops are plain loops over k with no bit tests. Where the rates of events that happened
may be negative (resets: a bounce) the chain :func:`exclude`-s them from each region's
times instead. Moving the position by ``t (F[before] - F[after])`` moves g by
``t (r_before - r_after)``.

Used by the plain dense chains (:mod:`.dense`, four queries in lockstep), the corner
functions' chain (:mod:`.function`) and the chain with resets (:mod:`.resets`). Not by
two specialisations, for which these steps were measured slower, beyond the 5 % issue 26
allowed, so each keeps a selection of its own: the lanes (:mod:`.lanes`: actual
coordinates in vector registers, a stored ``-1 / G``) and structured corners
(:mod:`.structured`: division-free comparisons ``g_k r_b > g_b r_k`` in 8-wide vectors
fused into the update of g and r). The commands and the numbers are in docs/benchmarks.md,
"Kernel design choices, measured". The lanes are tested against the chain of :mod:`.dense`
on the same tables (``tests/test_lanes.py``), both against ``tests/reference.py``.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from ._core import JIT


@njit(inline="always", **JIT)
def pending_times(g, p, rates, b, tau):
    """``tau[p, k] = -g[p, k] / rates[b, k]`` for every event k (the times in region b)."""
    for k in range(tau.shape[1]):
        tau[p, k] = -g[p, k] / rates[b, k]


@njit(inline="always", **JIT)
def earliest(tau, p, inverse):
    """``(k, tau[p, k])``: the smallest time of row p (the largest when ``inverse``), ties
    to the smaller k. Branch-free selects: the outcome is random, a branch mispredicts."""
    best = tau[p, 0]
    # an int64 0, not a literal: a callee given k would be compiled for both while the
    # caller's loop is typed (resets' reset_move and _rank_update were)
    kb = np.int64(0)
    if inverse:
        for k in range(1, tau.shape[1]):
            tk = tau[p, k]
            better = tk > best
            best = tk if better else best
            kb = k if better else kb
    else:
        for k in range(1, tau.shape[1]):
            tk = tau[p, k]
            better = tk < best
            best = tk if better else best
            kb = k if better else kb
    return kb, best


@njit(inline="always", **JIT)
def retire(g, p, k, inverse):
    """Event k of row p is no longer a candidate: its time is never selected again (its
    rates in the later regions must be positive)."""
    g[p, k] = np.inf if inverse else -np.inf


@njit(inline="always", **JIT)
def exclude(tau, p, k, inverse):
    """Event k of row p is no candidate in this region: its time ``tau[p, k]`` is never
    the earliest (whatever the sign of its rate)."""
    tau[p, k] = -np.inf if inverse else np.inf


@njit(inline="always", **JIT)
def advance(g, p, t, rates, before, after):
    """``g[p] += t (rates[before] - rates[after])``: the position moved by
    ``t (F[before] - F[after])``."""
    for k in range(g.shape[1]):
        g[p, k] += t * (rates[before, k] - rates[after, k])
