"""The engine of a dense (2**n, d) corner table and its (2**n, n) rate table."""

from __future__ import annotations

import numpy as np

from .. import _tables
from .._format import MASK_MEANING, format_mask
from .._kernels import dense as kernels
from .._validate import check_matrix, check_number, memory_limit_bytes
from . import fastpath
from .base import Engine


class DenseEngine(Engine):
    """``F`` (2**n, d) and ``G = F @ Dh.T`` (2**n, n), both checked by the caller;
    ``rate_spread``: the largest ratio of one event's rates (``_check_spread``)."""

    def __init__(self, Dh, F, G, fast_paths: bool = True, rate_spread: float = 1.0):
        self.Dh, self.F, self.G = Dh, F, G
        self.rate_spread = rate_spread
        self.n, self.d = Dh.shape
        self._tables = (np.ascontiguousarray(Dh.T), F, G)
        self.fast = fastpath.dense(F, G, Dh) if fast_paths else None

    @classmethod
    def build(cls, Dh, F, transversality_tol, memory_limit, fast_paths: bool = True):
        """Validate a user's table F for Dh (size before anything is allocated, shape,
        finiteness, transversality of every rate) and build the engine on a copy."""
        n, d = Dh.shape
        limit = (_tables.available_memory() if memory_limit is None
                 else memory_limit_bytes(memory_limit))
        need = _tables.dense_table_bytes(n, d)
        if n > 40 or need > limit:
            raise ValueError(
                f"dense corner tables for n={n} events in dimension d={d} need 2**{n} rows, "
                f"{_tables.human_bytes(need)}, more than the memory limit of "
                f"{_tables.human_bytes(limit)}; use fewer simultaneous events or a corner "
                f"model that does not store 2**n rows"
            )
        F = check_matrix(F, "F", (None, d))
        if F.shape[0] != 1 << n:
            raise ValueError(
                f"F must have 2**n = {1 << n} rows (one per mask of n={n} events, n from "
                f"Dh's {n} rows), got {F.shape[0]} rows"
            )
        check_number(transversality_tol, "transversality_tol", strict=False)

        G = _tables.event_rates(F, Dh)
        bad = _tables.find_transversality_violation(G, F, Dh, transversality_tol)
        if bad is not None:
            mask, k, kind, scale = bad
            where = (
                f"event {k} in region mask {format_mask(mask, n)} ({MASK_MEANING}): rate "
                f"G[{mask}, {k}] = F[{mask}] . Dh[{k}] = {G[mask, k]:.3g}"
            )
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
        return cls(Dh, F, G, fast_paths, spread)

    @staticmethod
    def _check_spread(G, n, tol) -> float:
        """Refuse an event whose rate varies by more than ``1 / tol`` over the regions
        where it is pending; returns the largest such ratio (the documented bound)."""
        ratio, k, slow, fast = kernels.widest_rate_spread(G)
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
        return kernels.apply(self._tables, V, (out,), inverse, launch=self.launch)

    def _apply_own_rates(self, V, out, inverse) -> int:
        rate = self.fast.ratef if inverse else self.fast.rate0
        return kernels.apply_sorted((self._tables[0], self.F, rate), V, (out,), inverse,
                             launch=self.launch)

    def _event_times(self, V, times, orders, offset) -> int:
        return kernels.event_times(self._tables, V, (times, orders), launch=self.launch)

    def tangents(self, VT, out, transpose: bool, offset: int = 0) -> int:
        return kernels.tangents(self._tables + (self.Dh,), VT, (out,), transpose,
                                launch=self.launch)

    def corners(self, happened) -> np.ndarray:
        bits = np.asarray(happened, dtype=np.int64)
        return self.F[bits @ (1 << np.arange(self.n, dtype=np.int64))]

    def dense_table(self) -> np.ndarray:
        return self.F
