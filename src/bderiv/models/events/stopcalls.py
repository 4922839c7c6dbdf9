"""The model at a stop: its checked calls made once per state (:class:`StopCalls`), and the
events' values, gradients and rates in the local orientation of a region
(:func:`local_view`, :func:`local_rates`; their arithmetic is
:func:`bderiv.models.compiled.rules.local_rates`, the compiled run's too)."""

from __future__ import annotations

from functools import lru_cache
from typing import NamedTuple

import numpy as np

from ..._support._validate import scratch
from ._python_rules import rules

__all__ = ["LocalView", "StopCalls", "local_rates", "local_view", "orientation"]


@lru_cache(maxsize=4096)
def orientation(mask, n) -> np.ndarray:
    """The signs of the events' local orientation in region ``mask``: shape (n,), -1.0
    where bit k is set (event k is watched downward, its function negated), else 1.0.
    Kept per ``(mask, n)``, so read-only.

    Examples
    --------
    >>> orientation(0b10, 3)
    array([ 1., -1.,  1.])
    """
    sign = np.array([-1.0 if mask >> k & 1 else 1.0 for k in range(n)])
    sign.flags.writeable = False
    return sign


class StopCalls:
    """A model's checked evaluations at the stops of one run, each kept for the last state
    it was asked at (and mask, for the field).

    At a stop the excursion screen, :func:`.locate.settle`, :func:`.crossings.switch` and the
    final time look at the same state: the event Jacobian (numerical where not given: tens
    of calls of ``events``), the events and the region's field are evaluated there once.
    With a compiled model (``system.compiled``) the events and the fields are its compiled
    functions called and checked in compiled code (the same values), the events and the
    region's field of :meth:`local_view` in one call. The arrays given out are shared, so
    they are read-only. Everything else is the model's own (``calls.dim``,
    ``calls.eval_reset``, ...).

    Parameters
    ----------
    system : ModelCalls
        The model's checked calls (``HybridSystem.calls``; any object with the checked
        evaluations).

    Examples
    --------
    >>> from bderiv.analysis.system import HybridSystem
    >>> seen = []
    >>> s = HybridSystem(lambda x, mask: -x, lambda x: seen.append(1) or x[:1], n_events=1,
    ...                  dim=2)
    >>> calls = StopCalls(s.calls)
    >>> a = calls.eval_events(np.ones(2)); b = calls.eval_events(np.ones(2))
    >>> a is b, len(seen), calls.dim
    (True, 1, 2)
    """

    def __init__(self, system):
        self.system = system
        self._kept = {}  # (name, mask) -> (the state's bytes, the value)
        self._compiled = getattr(system, "compiled", None)
        # read at every stop: plain attributes, not a __getattr__ each time
        self.n_events, self.dim = system.n_events, system.dim
        self.has_resets = getattr(system, "has_resets", False)

    def __getattr__(self, name):
        return getattr(self.system, name)

    def _kept_value(self, name, x, evaluate):
        x = np.asarray(x, dtype=np.float64)
        key, state = name, x.tobytes()
        kept = self._kept.get(key)
        if kept is not None and kept[0] == state:
            return kept[1]
        value = evaluate(x)
        self._keep(key, state, value)
        return value

    def _keep(self, key, state, value):
        for a in value if isinstance(value, tuple) else (value,):
            if isinstance(a, np.ndarray):
                a.flags.writeable = False  # shared by every caller at this stop
        self._kept[key] = (state, value)

    def eval_events(self, x):
        """The checked event values at ``x``: shape (n,)."""
        if self._compiled is None:
            return self._kept_value("events", x, self.system.eval_events)
        return self._kept_value("events", x, lambda y: self._compiled.events_rows(y[None])[0])

    def eval_event_jacobian(self, x):
        """The checked event Jacobian at ``x``: shape (n, d)."""
        at = getattr(self.system, "event_jacobian_at", self.system.eval_event_jacobian)
        return self._kept_value("event_jacobian", x, at)

    def eval_field(self, x, mask):
        """The checked field of region ``mask`` at ``x``: shape (d,)."""
        if self._compiled is None:
            evaluate = lambda y: self.system.eval_field(y, mask)  # noqa: E731
        else:
            evaluate = lambda y: self._compiled.fields(y, [mask])[0]  # noqa: E731
        return self._kept_value(("field", int(mask)), x, evaluate)

    def local_view(self, mask, x):
        """:func:`local_view` at ``x`` in region ``mask``, kept as the evaluations are."""
        return self._kept_value(("view", int(mask)), x, lambda y: self._view(mask, y))

    def _view(self, mask, x):
        if self._compiled is not None:  # the events and the field in one compiled call
            state, kept = x.tobytes(), self._kept.get("events")
            if kept is None or kept[0] != state:
                h, F = self._compiled.events_and_field(x, mask)
                self._keep("events", state, h)
                self._keep(("field", int(mask)), state, F)
        return _local_view(self, mask, x)


class LocalView(NamedTuple):
    """The events at a state in the local orientation of a region (:func:`local_view`).

    Attributes
    ----------
    sign : ndarray, shape (n,)
    h : ndarray, shape (n,)
    Dh : ndarray, shape (n, d)
    F : ndarray, shape (d,)
        The field of region ``mask``.
    rate : ndarray, shape (n,)
        ``Dh @ F``.
    """

    sign: np.ndarray
    h: np.ndarray
    Dh: np.ndarray
    F: np.ndarray
    rate: np.ndarray


def local_view(system, mask, x) -> LocalView:
    """Event values, gradients, field and rates at ``x`` in the local orientation of
    region ``mask`` (an event whose bit is set has its function negated); through
    ``system``'s own ``local_view`` when it keeps them (:class:`StopCalls`).

    Returns
    -------
    LocalView
    """
    if isinstance(system, StopCalls):
        return system.local_view(mask, x)
    return _local_view(system, mask, x)


def _local_view(system, mask, x):
    sign = orientation(int(mask), system.n_events)
    F = system.eval_field(x, mask)
    Dh, rate = local_rates(sign, system.eval_event_jacobian(x), F)
    return LocalView(sign, sign * system.eval_events(x), Dh, F, rate)


def local_rates(sign, J, F):
    """The gradients ``Dh = sign J`` (n, d) in the local orientation ``sign`` (n,) and the
    rates ``Dh . F`` (n,) of the event Jacobian ``J`` (n, d) in the field ``F`` (d,)."""
    J = scratch(J)
    Dh, rate = np.empty(J.shape), np.empty(J.shape[0])
    rules.local_rates(scratch(sign), J, scratch(F), Dh, rate)
    return Dh, rate
