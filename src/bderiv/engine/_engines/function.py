"""The engine of corners computed by an njit function on each region a query visits."""

from __future__ import annotations

import numba
import numpy as np
from numba.core.registry import CPUDispatcher

from ..._kernels import function as kernels
from ..._kernels._core import frozen_tables
from ..._support._format import error_text
from .base import Engine


class FunctionEngine(Engine):
    """``func(happened, out)``: the corner of one region. No fast path is detected (that
    would need all 2**n corners); every region a query visits is checked instead."""

    transversal_proved = False
    timed_launches = True

    def __init__(self, Dh, func):
        self.Dh, self.func = Dh, func
        self.n, self.d = Dh.shape
        self._link()

    def _link(self):
        # the kernels call func at an address of this process (kernels.entry); the
        # wrapper compiled there lives as long as the engine
        self._entry, at = kernels.entry(self.func)
        self._tables = frozen_tables(kernels.tables(self.Dh, at))

    def __getstate__(self):
        state = self.__dict__.copy()
        state.pop("_entry"), state.pop("_tables")  # an address of this process
        return state

    def __setstate__(self, state):
        self.__dict__.update(state)
        self._link()

    @classmethod
    def from_model(cls, Dh, model):
        """The engine of a corner model's ``corner_function()``, checked on two regions."""
        return cls(Dh, checked_function(model, *Dh.shape))

    def _apply(self, V, out, inverse, name, offset) -> int:
        return self._run_checked(kernels.apply, V, (out,), inverse, name, offset)

    def _event_times(self, V, times, orders, offset) -> int:
        return self._run_checked(kernels.event_times, V, (times, orders), False, "V", offset)

    def _diagnose(self, u, inverse, hap, r):
        return kernels.diagnose(self._tables.at[0], self._tables.DhT, u, inverse, hap, r)

    def corners(self, happened) -> np.ndarray:
        """F on regions given as (m, n) 0/1 flags; NaN where ``func`` wrote nothing."""
        h = np.asarray(happened)  # kernels.corners gives func its own uint8 copy
        out = np.full((h.shape[0], self.d), np.nan)
        kernels.corners(self.func, h, out)
        return out


def checked_function(model, n: int, d: int):
    """The model's ``corner_function()``, run once on the first and the last region: it
    must be callable as ``func(happened, out)`` and write finite values; a plain Python
    function is compiled with ``numba.njit``, as :class:`~bderiv.CornerFunction` does."""
    func = model.corner_function()
    if callable(func) and not isinstance(func, CPUDispatcher):
        func = numba.njit(func)
    ends = np.ascontiguousarray([np.zeros(n), np.ones(n)], dtype=np.uint8)
    out = np.full((2, d), np.nan)
    try:
        kernels.corners(func, ends, out)
    except Exception as exc:  # numba typing errors come in many classes
        raise TypeError(
            f"the corner function of {model!r} could not be called as func(happened, out) "
            f"with happened a uint8 array of {n} flags and out a float64 array of shape "
            f"({d},): {error_text(exc)}"
        ) from exc
    if not np.isfinite(out).all():
        raise ValueError(
            f"the corner function of {model!r} must write all {d} entries of out with finite "
            f"values; on the region with no event it gave {out[0]}, with all events {out[1]}"
        )
    return func
