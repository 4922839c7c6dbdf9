"""What every engine shares: the fast-path dispatch, status checks, pieces."""

from __future__ import annotations

import functools

import numpy as np

from ..._kernels import _core, linear, scaling
from ..._limits import CHAIN_BYTES
from ..._support._errors import ChainStop, refusal
from ..._support._format import format_happened, format_order, transversality_message
from ..._support._tables import chain_regions, tabulate


class Engine:
    """One corner representation's tables and kernels, behind the interface that
    ``BDerivative`` uses. Subclasses set ``Dh``, ``n``, ``d``, ``fast`` (a
    :class:`~bderiv.engine._engines.fastpath.FastPath` or None) and implement ``_apply``,
    ``_apply_own_rates``, ``_event_times`` and ``corners``; model engines also
    ``_diagnose``.

    Every method takes clean C-contiguous float64 arrays; ``offset`` is the index of the
    first row of ``V`` in the caller's batch (for messages).
    """

    fast = None
    #: whether the kernels of :meth:`_map` scale each query themselves (the dense ones,
    #: ``steps.row_exponent``); otherwise :meth:`map` scales the batch around them
    scales_queries = False
    #: event times of the engine's tables are ``2**time_shift`` those of the caller's
    #: (a dense table scaled at build, ``_engines.dense.table_exponents``)
    time_shift = 0

    def caller_tables(self):
        """F and G in the caller's units (the engine's own unless scaled at build)."""
        return self.F, self.G

    #: the launches sized by their time (``_drivers.Batch``): the cost per query is not
    #: known (a user's function)
    timed_launches = False

    @functools.cached_property
    def launch(self) -> int:
        """Queries per kernel launch (see ``_kernels._core.launch_queries``)."""
        return _core.launch_queries(self.n, self.d)

    @property
    def fast_path(self):
        return None if self.fast is None else self.fast.kind

    def map(self, V, out, inverse: bool, name: str = "V", offset: int = 0) -> int:
        """out = M(V), or M^-1(V) when ``inverse``, each query run scaled by a power of two
        to a largest entry in [0.5, 1) (:mod:`.._kernels.scaling`); returns the number of
        non-finite rows of ``out`` (overflow: the caller reports them)."""
        if self.scales_queries:
            return self._map(V, out, inverse, name, offset)
        U, exps = unit_rows(V)
        self._map(U, out, inverse, name, offset)
        return scaling.unscale_rows(out, exps, 0)

    def _map(self, V, out, inverse: bool, name: str, offset: int) -> int:
        if self.fast is None:
            return self._apply(V, out, inverse, name, offset)
        if self.fast.kind == "linear":
            return self.fast.apply_linear(V, out, inverse, self.launch)
        return self._apply_own_rates(V, out, inverse)

    def event_times(self, V, times, orders, offset: int = 0, exact: bool = True) -> int:
        """times[q, k]: time of event k; orders[q, j]: the j-th event. Returns the number
        of rows of ``times`` that are not finite.

        The chains run on the queries scaled to a largest entry in [0.5, 1) and the times
        are scaled back (``times(c v) = c times(v)``); a time that is then beyond the
        normal float64 range is refused (ValueError naming the query and the event),
        unless ``exact`` is False (only ``orders`` is wanted; ``times`` is then scratch).
        """
        U, exps = unit_rows(V)
        bad = self._times(U, times, orders, offset)
        if exact and not bad:
            unscale_times(times, exps - self.time_shift, offset)
        return bad

    def _times(self, V, times, orders, offset: int) -> int:
        if self.fast is None:
            return self._event_times(V, times, orders, offset)
        return self.fast.event_times(V, times, orders, self.launch)

    def tangents(self, V, T, out, transpose: bool, offset: int = 0) -> int:
        """out[q] = M_sigma(q) T[q] (``M_sigma(q)^T T[q]`` when ``transpose``) for
        V, T (m, d), sigma(q) the order that V[q] selects; returns the number
        of non-finite rows of ``out``. Generic: the orders by :meth:`event_times`, the
        corners along them by :meth:`corners` (chunks of about ``CHAIN_BYTES``), then one
        saltation factor per event (``linear.saltations``)."""
        n, d = self.n, self.d
        # per row: the corners C, the region flags and the model's float copy of them
        rows = int(min(max(CHAIN_BYTES // ((n + 1) * (8 * d + 9 * n)), 64), 1 << 16))
        bad = 0
        for s in range(0, V.shape[0], rows):
            e = min(s + rows, V.shape[0])
            orders = np.empty((e - s, n), dtype=np.int64)
            self.event_times(V[s:e], np.empty((e - s, n)), orders, offset + s, exact=False)
            C = np.ascontiguousarray(
                self.corners(chain_regions(orders, n).reshape(-1, n)), dtype=np.float64
            ).reshape(e - s, n + 1, d)
            bad += linear.saltations(linear.ChainCornerTables(self.Dh, C, orders), V[s:e],
                                     (out[s:e], T[s:e]), transpose, launch=e - s)
        return bad

    def chain_corners(self, order) -> np.ndarray:
        """F on the n + 1 regions of an order, shape (n + 1, d)."""
        return self.corners(chain_regions(order, self.n))

    def piece(self, order) -> np.ndarray:
        """The (d, d) piece of one order; refuses a rate <= 0 on its chain."""
        Fc = np.ascontiguousarray(self.chain_corners(order))
        regions = chain_regions(order, self.n)
        where = f"on the chain of order {format_order(order)}"
        if not np.isfinite(Fc).all():
            j = int(np.flatnonzero(~np.isfinite(Fc).all(axis=1))[0])
            raise ValueError(
                f"the corner model gave a non-finite value for region mask "
                f"{format_happened(regions[j])} {where}; corners must be finite"
            )
        rates = np.einsum("jd,jd->j", Fc[:-1], self.Dh[order])
        bad = np.flatnonzero(~(rates > 0))
        if bad.size:
            j = int(bad[0])
            raise ValueError(transversality_message(int(order[j]), format_happened(regions[j]),
                                                    float(rates[j]), where))
        out = np.empty((self.d, self.d))
        linear.piece_from_corners(_core.read_only(self.Dh), _core.read_only(Fc),
                                  _core.read_only(np.asarray(order, dtype=np.int64)), out)
        return out

    def dense_table(self) -> np.ndarray:
        """The (2**n, d) table (callers check the size first)."""
        return tabulate(self.corners, self.n, self.d)

    def _run_checked(self, batch, V, outs, inverse, name, offset) -> int:
        """Run a model kernel that reports a status per query, then :meth:`_check` it."""
        status = np.empty(V.shape[0], dtype=np.int64)
        bad = batch(self._tables, V, (*outs, status), inverse, launch=self.launch,
                    timed=self.timed_launches)
        self._check(status, V, inverse, name, offset)
        return bad

    def _check(self, status, V, inverse, name, offset) -> None:
        """Raise for the first query whose chain stopped (status != -1), re-run alone
        (:meth:`_diagnose`) to find the region and the rate."""
        bad = np.flatnonzero(status != -1)
        if not bad.size:
            return
        q = int(bad[0])
        hap = np.empty(self.n, dtype=np.uint8)
        r = np.empty(self.n)
        k = int(self._diagnose(_core.read_only(V[q]), inverse, hap, r))
        stop = (ChainStop("corner", q, -1, format_happened(hap), np.nan) if k < 0 else
                ChainStop("rate", q, k, format_happened(hap), float(r[k])))
        raise refusal(stop, name, offset, inverse)


def unit_rows(V):
    """(U, exps): ``U[q] = 2**-exps[q] V[q]``, each row's largest entry in [0.5, 1)."""
    U = np.empty_like(V)
    exps = np.empty(V.shape[0], dtype=np.int64)
    scaling.scale_rows(V, U, exps)
    return U, exps


def unscale_times(times, exps, offset: int) -> None:
    """``times[q] *= 2**exps[q]`` in place, refusing a nonzero time that leaves the normal
    float64 range (overflow, or underflow into the subnormals or to 0)."""
    with np.errstate(over="ignore", under="ignore"):
        t = np.ldexp(times, exps[:, None])
    bad = ~np.isfinite(t) | ((times != 0) & ~(np.abs(t) >= np.finfo(np.float64).tiny))
    if bad.any():
        q, k = (int(i) for i in np.argwhere(bad)[0])
        e = int(np.frexp(times[q, k])[1] + exps[q])
        raise refusal(ChainStop("time", q, k, "", e), "V", offset)
    times[...] = t
