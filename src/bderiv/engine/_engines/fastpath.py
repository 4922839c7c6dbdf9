"""The fast paths shared by every representation (mathematics.md sections 3 and 4).

- **own rates**: the rate of every event changes at most when that event itself happens
  (``G[mask, k]`` is ``G[0, k]`` or ``G[full, k]`` by bit k). Pending rates then never
  change, so the event times are the first-order times ``-(Dh u)_k / G[0, k]`` and the
  order is a sort.
- **linear**: own rates and additive corners ``F[mask] = F0 + sum_{k in mask} A[k]``. The
  saltation factors ``S_k = I + A[k] Dh[k]^T / G[0, k]`` then commute (``Dh[j] . A[k] = 0``
  for j != k), all n! pieces are one matrix and ``M(u) = (I + A^T diag(1/G[0]) Dh) u``.

A fast path is taken only when it gives the selection's answer to rounding: every entry
that must vanish (or agree) is compared with the rounding scale of that very entry (the
sum of the magnitudes that make it up), never with a scale of the whole table; a rate's
change also with the rate it changes (an event time is ``-(Dh u)_k / G[., k]``, so the
change moves it by its ratio to the rate: near grazing, a rate far below its rounding
scale, a change of 1e-12 of that scale moved a time by 1.6e-3 of itself).
"""

from __future__ import annotations

import numpy as np

from ..._kernels import _core, linear
from ..._limits import FAST_RTOL
from ..._numerics import INSERTION_SORT_MAX
from ..._support import _tables


class FastPath:
    """A fast path: ``kind`` is ``"own-rates"`` or ``"linear"``.

    ``rate0`` / ``ratef`` are the rates of the first / last region (forward / inverse
    times); ``M`` and ``Minv`` the matrices of the linear path.
    """

    def __init__(self, Dh, rate0, ratef, A=None):
        self.kind = "own-rates" if A is None else "linear"
        self.DhT = np.ascontiguousarray(Dh.T)
        self.rate0, self.ratef = rate0, ratef
        if A is not None:
            eye = np.eye(Dh.shape[1])
            self.M = eye + A.T @ (Dh / rate0[:, None])
            self.Minv = eye - A.T @ (Dh / ratef[:, None])
            self._linear = _core.frozen_tables(linear.LinearTables(
                np.ascontiguousarray(self.M.T), np.ascontiguousarray(self.Minv.T)))
        self._own = _core.frozen_tables(linear.OwnRateTables(self.DhT, self.rate0))

    def apply_linear(self, V, out, inverse: bool, launch: int) -> int:
        return linear.linear(self._linear, V, (out,), inverse, launch)

    def event_times(self, V, times, orders, launch: int) -> int:
        few = self.DhT.shape[1] <= INSERTION_SORT_MAX  # the merge sort compiled only for many
        kernel = linear.own_times if few else linear.own_times_many
        return kernel(self._own, V, (times, orders), False, launch)


def dense(F, G, Dh, rtol: float = FAST_RTOL):
    """The fast path of a dense table, or None. Scans block by block, stops at a misfit."""
    with np.errstate(over="ignore", invalid="ignore"):  # an inf scale only admits more
        return _dense(F, G, Dh, rtol)


def _dense(F, G, Dh, rtol):
    n = Dh.shape[0]
    g0, gf = G[0].copy(), G[-1].copy()
    absDhT = np.abs(Dh).T
    s0, sf = np.abs(F[0]) @ absDhT, np.abs(F[-1]) @ absDhT
    F0 = F[0].copy()
    A = F[1 << np.arange(n)] - F0
    dg, ds = gf - g0, sf - s0
    additive = True
    for rows in _tables.blocks(G.shape[0]):
        bits = _tables.block_bits(rows, n)
        absF = np.abs(F[rows])
        # G[mask, k] = F[mask] . Dh[k] is known to ~ |F[mask]| . |Dh[k]| * eps; the rate
        # the fast path reads instead (g0 or gf by bit k) bounds the change it may ignore
        pred = g0 + bits * dg
        scale = np.minimum(absF @ absDhT + s0 + bits * ds, np.abs(pred))
        if np.count_nonzero(np.abs(G[rows] - pred) > rtol * scale):
            return None
        if additive:
            pred = F0 + bits @ A
            size = absF + np.abs(F0) + bits @ np.abs(A)
            additive = not np.count_nonzero(np.abs(F[rows] - pred) > rtol * size)
    return FastPath(Dh, g0, gf, A if additive else None)


def structured(Dh, g0, a, bDh, A, B, rtol: float = FAST_RTOL):
    """The fast path of structured corners, or None.

    Own rates: ``a[i, k] = Dh[k] . A[i]`` vanishes for i != k and ``Dh @ B[p]`` for every
    pair, each compared with its own scale ``|A[i]| . |Dh[k]|`` (``|B[p]| . |Dh[k]|``)
    and with event k's smaller rate, before or after it happens.
    Linear: in addition no pair term (B = 0).
    """
    absDhT = np.abs(Dh).T
    ratef = g0 + np.diag(a)
    rate = np.minimum(np.abs(g0), np.abs(ratef))  # (n,): event k's rate bounds its change
    off = a - np.diag(np.diag(a))
    if (np.abs(off) > rtol * np.minimum(np.abs(A) @ absDhT, rate)).any():
        return None
    if (np.abs(bDh) > rtol * np.minimum(np.abs(B) @ absDhT, rate)).any():
        return None
    return FastPath(Dh, g0.copy(), ratef, A if not B.any() else None)
