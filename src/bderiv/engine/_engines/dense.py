"""The engine of a dense (2**n, d) corner table and its (2**n, n) rate table."""

from __future__ import annotations

import functools
import math

import numpy as np

from ..._kernels import dense as kernels
from ..._kernels import lanes, scaling
from ..._kernels._core import PLAIN, frozen_tables
from ..._limits import BLOCK_ROWS, FAR_BYTES, TABLE_BAND
from ..._support import _tables
from ..._support._format import MASK_MEANING, format_mask, format_region
from ..._support._validate import check_matrix, check_number, memory_limit_for
from . import fastpath
from .base import Engine, unit_rows


class DenseEngine(Engine):
    """The region records ``R`` of ``_tables.region_records`` (checked by the caller), with
    ``F`` (2**n, d) and ``G = F @ Dh.T`` (2**n, n) as views into them; ``rate_spread``:
    the largest ratio of one event's rates (``_check_spread``). Runs the lane kernels, or
    the plain ones when ``_core.PLAIN`` or d > ``lanes.MAX_D``."""

    # the kernels of _map scale their queries as they load them (the lane kernels: those
    # outside the query band, see _apply)
    scales_queries = True

    def __init__(self, Dh, R, fast_paths: bool = True, rate_spread: float = 1.0,
                 exps=None):
        self.Dh, self.R = Dh, R
        self.n, self.d = Dh.shape
        self.rate_spread = rate_spread
        # the caller's Dh[k] is 2**dh_exps[k] Dh[k], its F 2**f_exp F (table_exponents)
        if exps is None:
            exps = (np.zeros(self.n, dtype=np.int64), 0)
        self.dh_exps, self.f_exp = exps
        self.time_shift = self.f_exp
        self._views()
        self.fast = fastpath.dense(self.F, self.G, Dh) if fast_paths else None
        self._sorted = self._sorted_tables()

    def _sorted_tables(self):
        """The own-rates fast path's tables, forwards and backwards (None without it)."""
        if self.fast is None or self.fast.kind != "own-rates":
            return None
        return tuple(frozen_tables(kernels.SortedTables(self.fast.DhT, self.F, rate))
                     for rate in (self.fast.rate0, self.fast.ratef))

    @property
    def scaled(self) -> bool:
        """Whether the tables were scaled at build (then F, G differ from the caller's)."""
        return bool(self.f_exp or np.count_nonzero(self.dh_exps))

    def caller_tables(self):
        """F (2**n, d) and G (2**n, n) in the caller's units: views of the records, or
        for scaled tables new arrays (G may then hold inf or 0 where the caller's rates
        are beyond float64; the kernels never read these)."""
        if not self.scaled:
            return self.F, self.G
        with np.errstate(over="ignore", under="ignore"):
            return (np.ldexp(self.F, self.f_exp),
                    np.ldexp(self.G, self.f_exp + self.dh_exps[None, :]))

    def corner_points(self):
        """(pre, post) corner points (mathematics.md section 5), from the records: a point scales
        with F and not with the rows of Dh, so the scaled tables give them times
        ``2**-f_exp``."""
        with np.errstate(over="ignore", under="ignore"):
            return tuple(np.ldexp(P, self.f_exp)
                         for P in _tables.corner_points(self.F, self.Dh, self.G))

    def _views(self) -> None:
        """F and G, views of R; whether the records lie beyond the caches (the lane
        kernels' prefetching variant)."""
        nc = _tables.record_layout(self.n, self.d)[0]
        self.G = self.R[:, 8 * nc : 8 * nc + self.n]
        self.F = self.R[:, 16 * nc : 16 * nc + self.d]
        self._far = int(self.R.nbytes > FAR_BYTES)

    @functools.cached_property
    def _selection_tables(self):
        """(lane tables or None, lane kernels or None, plain tables): what the selection
        kernels read, built on first use (a map on a fast path never runs them)."""
        n, d = self.n, self.d
        nc, dc, _ = _tables.record_layout(n, d)
        plain = frozen_tables(kernels.DenseTables(np.ascontiguousarray(self.Dh.T), self.F, self.G,
                                           self.Dh))
        if PLAIN or d > lanes.MAX_D:
            return None, None, plain
        return (lanes.lane_tables(self.R, _tables.padded(self.Dh.T, 8 * nc),
                                  _tables.padded(self.Dh, 8 * dc), n, d, nc, dc),
                lanes.kernels(8 * nc, 8 * dc, self._far), plain)

    @property
    def _lanes(self):
        """The lane kernels' tables (None when the plain kernels run)."""
        return self._selection_tables[0]

    @property
    def _lane_kernels(self):
        return self._selection_tables[1]

    @property
    def _plain(self):
        """The plain kernels' tables."""
        return self._selection_tables[2]

    def __getstate__(self):
        state = self.__dict__.copy()
        for name in ("F", "G", "_selection_tables", "_sorted"):  # rebuilt
            state.pop(name, None)
        return state

    def __setstate__(self, state):
        self.__dict__.update(state)
        if self.R.ctypes.data % 64:  # unpickled anywhere in memory: back on cache lines
            R = _tables.aligned_empty(self.R.shape)
            R[...] = self.R
            self.R = R
        self._views()
        self._sorted = self._sorted_tables()

    @classmethod
    def build(cls, Dh, F, transversality_tol, memory_limit, fast_paths: bool = True,
              scale: bool = True, pending_only: bool = False, checked: bool = False):
        """Validate a user's table F for Dh (size before anything is allocated, shape,
        finiteness, transversality of every rate, or of the rates of pending events only
        when ``pending_only``: a table with resets) and build the engine on a copy, scaled
        by powers of two when ``scale`` and its entries are beyond ``TABLE_BAND``.
        ``checked``: F (2**n, d) float64 and finite and the tolerance a number >= 0 are
        known (the caller made them), not checked again."""
        n, d = Dh.shape
        need = _tables.dense_table_bytes(n, d)
        limit = memory_limit_for(need, memory_limit)
        if n > 40 or need > limit:
            raise ValueError(
                f"dense corner tables for n={n} events in dimension d={d} need 2**{n} rows, "
                f"{_tables.human_bytes(need)}, more than the memory limit of "
                f"{_tables.human_bytes(limit)}; use fewer simultaneous events or a corner "
                f"model that does not store 2**n rows"
            )
        if not checked:
            F = check_matrix(F, "F", (None, d), copy=False)
            if F.shape[0] != 1 << n:
                raise ValueError(
                    f"F must have 2**n = {1 << n} rows (one per mask of n={n} events, n "
                    f"from Dh's {n} rows), got {F.shape[0]} rows"
                )
            check_number(transversality_tol, "transversality_tol", strict=False)

        maxima = _tables.table_maxima(Dh, F)
        dh_exps, f_exp = table_exponents(*maxima) if scale else (np.zeros(n, np.int64), 0)
        scaled = bool(f_exp or np.count_nonzero(dh_exps))
        if scaled:
            Dh = np.ldexp(Dh, -dh_exps[:, None])
        R = _tables.region_records(F, Dh, -f_exp)
        nc = _tables.record_layout(n, d)[0]
        G, F = R[:, 8 * nc : 8 * nc + n], R[:, 16 * nc : 16 * nc + d]
        bad = _tables.find_transversality_violation(G, F, Dh, transversality_tol,
                                                    pending_only, None if scaled else maxima)
        if bad is not None:
            mask, k, kind, scale = bad
            rate = np.ldexp(G[mask, k], f_exp + int(dh_exps[k]))  # in the caller's units
            where = (
                f"event {k} in {format_region(mask, n)}: rate "
                f"G[{mask}, {k}] = F[{mask}] . Dh[{k}] = {rate:.3g}"
            )
            if kind == "zero":
                row = (f"Dh[{k}] is a row of zeros: event {k}'s surface has no normal"
                       if not Dh[k].any() else
                       f"F[{mask}] is a row of zeros: the flow stands still in that region")
                raise ValueError(f"transversality fails at {where}: {row}, so the event "
                                 f"is never crossed")
            if kind == "underflow":
                raise ValueError(
                    f"the rate of {where} underflows float64: |F[{mask}]| |Dh[{k}]| = "
                    f"1e{scale:.0f}, below the float64 range; rescale the state or time units"
                )
            if kind == "overflow":
                raise ValueError(
                    f"the rate of {where} overflows float64 (|F[{mask}]| |Dh[{k}]| = "
                    f"{scale:.3g}); rescale the state or time units"
                )
            if kind == "violated":
                raise ValueError(
                    f"transversality violated at {where}, expected > 0: the flow must cross "
                    f"every event surface from h_k < 0 to h_k > 0 in every region"
                )
            raise ValueError(
                f"grazing rate at {where}, tiny relative to |F[{mask}]| |Dh[{k}]| = "
                f"{scale:.3g} (transversality_tol={transversality_tol:g}); the surface is "
                f"nearly tangent to the flow"
            )
        spread = cls._check_spread(G, n, transversality_tol)
        return cls(Dh, R, fast_paths, spread, (dh_exps, f_exp))

    @staticmethod
    def _check_spread(G, n, tol) -> float:
        """Refuse an event whose rate varies by more than ``1 / tol`` over the regions
        where it is pending; returns the largest such ratio (the documented bound)."""
        ratio, k, slow, fast = (rate_spread(G, n) if G.shape[0] <= BLOCK_ROWS
                                else kernels.widest_rate_spread(G))
        if tol > 0 and not ratio * tol <= 1.0:
            raise ValueError(
                f"ill-conditioned event times: the rate of event {k} is "
                f"G[{fast}, {k}] = {G[fast, k]:.3g} in region mask {format_mask(fast, n)} but "
                f"G[{slow}, {k}] = {G[slow, k]:.3g} in region mask {format_mask(slow, n)} "
                f"({MASK_MEANING}), {ratio:.3g} times slower, more than "
                f"1 / transversality_tol = {1.0 / tol:.3g}: a time gap that the fast "
                f"region leaves in rounding is stretched that much in the slow one, so "
                f"results near ties would be rounding noise; rescale the regions' fields "
                f"or pass a smaller transversality_tol to accept it"
            )
        return ratio

    def _apply(self, V, out, inverse, name, offset) -> int:
        if self._lanes is None:
            return kernels.apply(self._plain, V, (out,), inverse, launch=self.launch)
        bad = self._lane_kernels[0](self._lanes, V, (out,), inverse, launch=self.launch)
        if not bad:
            return 0
        # groups outside the query band came back NaN: run them scaled (and any overflow
        # again, which stays non-finite)
        rows = np.flatnonzero(~np.isfinite(out).all(axis=1))
        U, exps = unit_rows(V[rows])
        res = np.empty_like(U)
        self._lane_kernels[0](lanes.unchecked(self._lanes), U, (res,), inverse,
                              launch=self.launch)
        bad = scaling.unscale_rows(res, exps, 0)
        out[rows] = res
        return bad

    def _apply_own_rates(self, V, out, inverse) -> int:
        return kernels.apply_sorted(self._sorted[inverse], V, (out,), inverse,
                                    launch=self.launch)

    def _event_times(self, V, times, orders, offset) -> int:
        if self._lanes is None:
            return kernels.event_times(self._plain, V, (times, orders), launch=self.launch)
        return self._lane_kernels[1](self._lanes, V, (times, orders), launch=self.launch)

    def tangents(self, V, T, out, transpose: bool, offset: int = 0) -> int:
        if self.fast is not None:  # the fast path's orders, as orders() gives them
            return super().tangents(V, T, out, transpose, offset)
        if self._lanes is None:
            return kernels.tangents(self._plain, V, (out, T), transpose, launch=self.launch)
        return self._lane_kernels[2](self._lanes, V, (out, T), transpose, launch=self.launch)

    def corners(self, happened) -> np.ndarray:
        bits = np.asarray(happened, dtype=np.int64)
        return self.F[bits @ (1 << np.arange(self.n, dtype=np.int64))]

    def dense_table(self) -> np.ndarray:
        return self.F


def table_exponents(dh_big, f_big):
    """(dh_exps (n,), f_exp): the binary exponents (``math.frexp``) of the largest entry of
    each row of Dh and of F as a whole (``dh_big``, ``f_big``: ``_tables.table_maxima``),
    each replaced by 0 within ``+-TABLE_BAND``.

    The kernels run on ``2**-dh_exps[k] Dh[k]`` and ``2**-f_exp F``, which have the same
    B-derivative (each piece is a product of ``I + (F[a] - F[b]) Dh[k]^T / (Dh[k] . F[b])``,
    unchanged by either scaling; mathematics.md "How the kernels round"); the event times are
    ``2**f_exp`` times the caller's.
    """
    dh = [math.frexp(v)[1] for v in dh_big]
    f = math.frexp(f_big)[1]
    return (np.array([e if abs(e) > TABLE_BAND else 0 for e in dh], dtype=np.int64),
            f if abs(f) > TABLE_BAND else 0)


def rate_spread(G, n):
    """:func:`bderiv._kernels.dense.widest_rate_spread` of a table of one block, in NumPy
    (the same ratio, event and masks: first minimum and maximum of each event's pending
    rates, the first event of the largest ratio): a small table's first build compiles
    no kernel for it."""
    pending = _tables.block_bits(slice(0, G.shape[0]), n) == 0
    slow = np.argmin(np.where(pending, G, np.inf), axis=0)
    fast = np.argmax(np.where(pending, G, 0.0), axis=0)  # rates of pending events are > 0
    events = np.arange(n)
    ratios = G[fast, events] / G[slow, events]
    k = int(np.argmax(ratios))
    return float(ratios[k]), k, int(slow[k]), int(fast[k])
