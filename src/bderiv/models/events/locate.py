"""Event location at a stop of the integrator: how well each event is known, and when.

The rules here are plain functions of arrays (the state's error bound, the event values,
their gradients ``Dh`` and rates ``Dh . F``), written once for any integrator: their
arithmetic is :mod:`bderiv.models.compiled.rules`, which the compiled run calls too (the
same bits on both paths); only :func:`settle` and :func:`on_side_at_start` deal with
:func:`scipy.integrate.solve_ivp` (docs/mathematics.md, section 11).

At a stop ``x`` (the located crossing of the events that ``fired``):

- the state is trusted to ``err_i = GLOBAL_ERROR_FACTOR (atol + rtol s_i)`` per component
  (:func:`state_error`; ``s_i`` the largest ``|x_i|`` of the run so far), so event k's
  value to ``sigma_k = sum_i |Dh_ki| err_i``: only the components it depends on count;
- the stop's time is uncertain by ``u = max_j sigma_j / rate_j`` over the fired events;
- event k is **at the stop** when ``|h_k| <= window_k = sigma_k + |rate_k| u``
  (:func:`windows`), and its time is then known to ``U_k = window_k / rate_k``.

Events at the stop are grouped: the integrator cannot order them. Those with ``U_k`` above
``simultaneity_tol`` are **undecided**: they may be simultaneous or further apart than the
tolerance. Where a derivative is computed, :func:`settle` integrates the stretch again
with tighter tolerances until each is decided (at the stop within the tolerance, or
clearly apart) or solve_ivp's floor is reached.
"""

from __future__ import annotations

from functools import lru_cache
from typing import NamedTuple

import numpy as np

from ..._numerics import GLOBAL_ERROR_FACTOR, MIN_RTOL, REFINE_FACTOR
from ..._support._format import format_mask
from ..._support._validate import frozen, scratch
from ..compiled import rules

__all__ = [
    "GLOBAL_ERROR_FACTOR",
    "Classes",
    "Settled",
    "Stop",
    "StopCalls",
    "check_carried",
    "check_sides",
    "classify",
    "examine",
    "flags_of",
    "local_rates",
    "local_view",
    "on_side_at_start",
    "orientation",
    "settle",
    "state_error",
    "tightened",
    "windows",
]


def state_error(atol, rtol, scale, carried=0.0) -> np.ndarray:
    """Bound on the error of the state at a stop, per component: shape (d,).

    Parameters
    ----------
    atol : float or ndarray, shape (d,)
    rtol : float
        The tolerances of the stretch that ends at the stop.
    scale : float or ndarray, shape (d,)
        Largest ``|x_i|`` of the run up to the stop.
    carried : float or ndarray, shape (d,)
        Bound at the start of the stretch (0 at the run's start point, which is exact): a
        stretch integrated more tightly than the run before it is no better than its start.

    Examples
    --------
    >>> state_error(1e-12, 1e-10, np.array([500.0, 1e-3]))
    array([5.0001e-07, 1.1000e-11])
    """
    scale = frozen(scale)
    carried = frozen(np.broadcast_to(carried, scale.shape))
    out = np.empty(scale.shape)
    rules.state_error(float(atol), float(rtol), scale, carried, out)
    return out


def windows(Dh, rate, err, fired):
    """Largest ``|h_k|`` at which event k is at the stop, and the stop's time uncertainty.

    Parameters
    ----------
    Dh : ndarray, shape (n, d)
        Event gradients at the stop.
    rate : ndarray, shape (n,)
        ``Dh . F`` in the region before the stop (in the events' local orientation).
    err : ndarray, shape (d,)
        The state's error bound (:func:`state_error`).
    fired : sequence of int
        The events whose crossing the integrator located at the stop.

    Returns
    -------
    window : ndarray, shape (n,)
        ``sigma_k + |rate_k| u``: event k's value is known to ``sigma_k = |Dh_k| . err``,
        and the stop's time to ``u``, which moves ``h_k`` by ``|rate_k| u``.
    u : float
        ``max sigma_j / rate_j`` over the fired events crossing (rate > 0); 0 if none.

    Examples
    --------
    A slow event (rate 1e-4) that stopped the integrator makes its time uncertain, and with
    it the value of a fast event at the stop:

    >>> w, u = windows(np.eye(2), np.array([1.0, 1e-4]), np.array([1e-9, 1e-11]), [1])
    >>> float(u), w.tolist()
    (1e-07, [1.01e-07, 2e-11])
    """
    window = np.empty(rate.size)
    u = rules.windows(frozen(Dh), frozen(rate), frozen(err), flags_of(fired, rate.size), window)
    return window, float(u)


def flags_of(events, n) -> np.ndarray:
    """The bool flags (n,) of the event indices ``events``."""
    flags = np.zeros(n, dtype=np.bool_)
    flags[list(events)] = True
    return flags


class Classes:
    """The events at a stop sorted by :func:`classify` (lists of event indices).

    Attributes
    ----------
    group : list of int
        Switched at the stop: fired, crossed (``h_k > window_k``), or at the stop and
        crossing (``|h_k| <= window_k``).
    near : list of int
        Within ``simultaneity_tol`` of crossing but not at the stop: switching them here
        would switch them early, so each stops the integrator at its own time (a flow map
        merges the groups: :func:`bderiv.analysis.assembly.flow_map_along`).
    undecided : list of int
        At the stop and crossing, with a time uncertainty ``window_k / rate_k`` above
        ``simultaneity_tol``: whether they belong to the group is not known.
    """

    def __init__(self, group, near, undecided):
        self.group, self.near, self.undecided = group, near, undecided

    @classmethod
    def of(cls, codes):
        """The classes of the codes (n,) of :func:`bderiv.models.compiled.rules.classify`."""
        codes = codes.tolist()
        return cls([k for k, c in enumerate(codes) if c & rules.GROUP],
                   [k for k, c in enumerate(codes) if c & rules.NEAR],
                   [k for k, c in enumerate(codes) if c & rules.UNDECIDED])


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


def classify(h, rate, window, fired, simultaneity_tol) -> Classes:
    """Sort the events at a stop (all arrays in the events' local orientation).

    Parameters
    ----------
    h, rate, window : ndarray, shape (n,)
        Event values, rates and windows (:func:`windows`) at the stop.
    fired : sequence of int
    simultaneity_tol : float

    Returns
    -------
    Classes
        An event within its window of the surface is at it, and crosses with the group
        if the flow carries it across (an event just switched back sits there): the
        integrator cannot order it after the stop. It is undecided when its time is known
        only to more than ``simultaneity_tol``.

    Examples
    --------
    >>> c = classify(np.array([0.0, -1e-12, -1e-8]), np.ones(3), np.full(3, 1e-9), [0], 1e-7)
    >>> c.group, c.near, c.undecided
    ([0, 1], [2], [])
    >>> classify(np.array([0.0, -1e-12]), np.ones(2), np.full(2, 1e-9), [0], 1e-10).undecided
    [1]
    """
    codes = np.empty(h.size, dtype=np.int64)
    rules.classify(frozen(h), frozen(rate), frozen(window), flags_of(fired, h.size),
                   float(simultaneity_tol), codes)
    return Classes.of(codes)


class Stop(NamedTuple):
    """What the rules read at a stop ``x`` of region ``mask`` (:func:`examine`): made once,
    read by :func:`settle` and :func:`bderiv.models.events.crossings.switch`.

    Attributes
    ----------
    sign, h, Dh, F, rate
        :func:`local_view` at ``x``.
    window : ndarray, shape (n,)
        :func:`windows`.
    classes : Classes
        :func:`classify`.
    """

    sign: np.ndarray
    h: np.ndarray
    Dh: np.ndarray
    F: np.ndarray
    rate: np.ndarray
    window: np.ndarray
    classes: Classes


def examine(system, mask, x, err, fired, simultaneity_tol) -> Stop:
    """The :class:`Stop` at ``x`` in region ``mask``: the local view, the windows from the
    state's error bound ``err`` (d,) and the located events ``fired``, and the classes."""
    sign, h, Dh, F, rate = local_view(system, mask, x)
    window, _ = windows(Dh, rate, err, fired)
    return Stop(sign, h, Dh, F, rate, window,
                classify(h, rate, window, fired, simultaneity_tol))


class StopCalls:
    """A model's checked evaluations at the stops of one run, each kept for the last state
    it was asked at (and mask, for the field).

    At a stop the excursion screen, :func:`settle`, :func:`.crossings.switch` and the
    final time look at the same state: the event Jacobian (numerical where not given: tens
    of calls of ``events``), the events and the region's field are evaluated there once.
    With a compiled model (``system.compiled``) the events and the fields are its compiled
    functions called and checked in compiled code (the same values), the events and the
    region's field of :meth:`local_view` in one call. The arrays given out are shared, so
    they are read-only. Everything else is the model's own (``calls.dim``,
    ``calls.eval_reset``, ...).

    Parameters
    ----------
    system : HybridSystem
        The model (any object with the checked evaluations).

    Examples
    --------
    >>> from bderiv.analysis.system import HybridSystem
    >>> seen = []
    >>> s = HybridSystem(lambda x, mask: -x, lambda x: seen.append(1) or x[:1], n_events=1,
    ...                  dim=2)
    >>> calls = StopCalls(s)
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


def local_view(system, mask, x):
    """Event values, gradients, field and rates at ``x`` in the local orientation of
    region ``mask`` (an event whose bit is set has its function negated); through
    ``system``'s own ``local_view`` when it keeps them (:class:`StopCalls`).

    Returns
    -------
    sign : ndarray, shape (n,)
    h : ndarray, shape (n,)
    Dh : ndarray, shape (n, d)
    F : ndarray, shape (d,)
        The field of region ``mask``.
    rate : ndarray, shape (n,)
        ``Dh @ F``.
    """
    if isinstance(system, StopCalls):
        return system.local_view(mask, x)
    return _local_view(system, mask, x)


def _local_view(system, mask, x):
    sign = orientation(int(mask), system.n_events)
    F = system.eval_field(x, mask)
    Dh, rate = local_rates(sign, system.eval_event_jacobian(x), F)
    return sign, sign * system.eval_events(x), Dh, F, rate


def local_rates(sign, J, F):
    """The gradients ``Dh = sign J`` (n, d) in the local orientation ``sign`` (n,) and the
    rates ``Dh . F`` (n,) of the event Jacobian ``J`` (n, d) in the field ``F`` (d,)."""
    J = frozen(J)
    Dh, rate = np.empty(J.shape), np.empty(J.shape[0])
    rules.local_rates(frozen(sign), J, frozen(F), Dh, rate)
    return Dh, rate


def tightened(options):
    """``options`` with rtol and atol divided by ``REFINE_FACTOR`` (rtol no lower than
    ``MIN_RTOL``), or None when rtol is already at that floor."""
    if options.rtol <= MIN_RTOL:
        return None
    return options.with_overrides(rtol=max(options.rtol / REFINE_FACTOR, MIN_RTOL),
                                  atol=options.atol / REFINE_FACTOR)


class Settled(NamedTuple):
    """What :func:`settle` returns.

    Attributes
    ----------
    sol : OdeResult
        The stretch (integrated again more tightly where that decided its events).
    err : ndarray, shape (d,)
        The state's error bound at its end (:func:`state_error`).
    scale : ndarray, shape (d,)
        The largest ``|x_i|`` of the run up to its end.
    fired : list of int
        The events located at its stop (none at the final time or the section).
    stop : Stop or None
        :func:`examine` at its stop, None when no event was located there.
    """

    sol: object
    err: np.ndarray
    scale: np.ndarray
    fired: list
    stop: Stop | None


def settle(system, mask, sol, simultaneity_tol, options, scale, carried,
           integrate=None) -> Settled:
    """The stretch ``sol``, or the same stretch integrated more tightly when events at its
    stop are undecided; with the state's error bound and the :class:`Stop` at its end.

    The state alone is integrated again, rtol and atol divided by ``REFINE_FACTOR`` each
    time, until no event at the stop is undecided or rtol reaches ``MIN_RTOL`` (events
    still undecided there are grouped: the integrator cannot order them). When that
    decides the same group as ``sol`` (the common case: simultaneous events), ``sol`` is
    kept; otherwise the stretch is integrated once more at the deciding tolerances, with
    the variational equations, and returned.

    Parameters
    ----------
    system : HybridSystem
    mask : int
        The stretch's region.
    sol : OdeResult
        The stretch from solve_ivp (one terminal event function per event, in order).
    simultaneity_tol : float
    options : SolverOptions
        The tolerances ``sol`` was integrated with.
    scale : ndarray, shape (d,)
        Largest ``|x_i|`` of the run before the stretch.
    carried : ndarray, shape (d,)
        The error bound at the stretch's start (:func:`state_error`).
    integrate : callable ``integrate(options, variational=...) -> OdeResult``, optional
        Integrates the same stretch with other options (the state alone with
        ``variational=False``); without it (a run that needs no derivative: the state does
        not depend on how near events are grouped) ``sol`` is returned as it is.

    Returns
    -------
    Settled
    """
    d, n = system.dim, system.n_events

    def decide(sol, options):
        grown = np.maximum(scale, np.abs(sol.y[:d]).max(axis=1))
        err = state_error(options.atol, options.rtol, grown, carried)
        fired = [k for k in range(n) if sol.t_events[k].size]
        if sol.status != 1 or not fired:
            return Settled(sol, err, grown, fired, None)
        stop = examine(system, mask, sol.y[:d, -1], err, fired, simultaneity_tol)
        return Settled(sol, err, grown, fired, stop)

    first = decide(sol, options)
    if integrate is None or first.stop is None or not first.stop.classes.undecided:
        return first
    classes, finer = first.stop.classes, options
    while classes is not None and classes.undecided and tightened(finer) is not None:
        finer = tightened(finer)
        stop = decide(integrate(finer, variational=False), finer).stop
        classes = None if stop is None else stop.classes
    decided = first.stop.classes
    if classes is not None and (classes.group, classes.near) == (decided.group, decided.near):
        return first
    return decide(integrate(finer), finer)


def on_side_at_start(funcs, t0, mask, n):
    """solve_ivp event functions for a stretch from ``t0`` that read an event exactly on
    its surface at ``t0`` on the side its bit of ``mask`` says.

    solve_ivp takes a value 0 at a step's start as the end of a crossing, and places the
    root there: a stretch that starts exactly on a surface (a located stop can land with
    ``h_k == 0.0``) would otherwise stop at once, crossing nothing.

    Parameters
    ----------
    funcs : list of callables ``f(t, y)``
        The terminal event functions, the first ``n`` for the events in order (further
        ones, a section, are kept as they are).
    t0 : float
    mask : int
    n : int

    Returns
    -------
    list of callables
        With the ``terminal`` and ``direction`` attributes of ``funcs``.

    Examples
    --------
    >>> def f(t, y):
    ...     return y[0]
    >>> g, = on_side_at_start([f], 1.0, 0b0, 1)
    >>> float(g(1.0, [0.0])) < 0.0, float(g(1.5, [0.0]))
    (True, 0.0)
    """
    tiny = np.finfo(np.float64).tiny

    def on_side(func, side):
        def ev(t, y):
            value = func(t, y)
            return side * tiny if t == t0 and value == 0.0 else value

        ev.terminal = getattr(func, "terminal", False)
        ev.direction = getattr(func, "direction", 0)
        return ev

    return ([on_side(f, 1.0 if mask >> k & 1 else -1.0) for k, f in enumerate(funcs[:n])]
            + list(funcs[n:]))


def check_sides(h, mask, window, t):
    """Refuse a region ``mask`` that disagrees with the event values ``h`` (n,) after the
    stop at ``t`` (its group switched, its resets applied): every event must be on the
    side its bit says (set: ``h_k > 0``), or within its ``window`` (n,) of the surface (a
    located event a rounding across it, an event switched with it on its way there: the
    excursion screen looks for a return inside the steps from such a start,
    :mod:`bderiv.models.events.excursions`).

    Raises
    ------
    ValueError
        Naming the time, the event, its value, its window and the mask.

    Examples
    --------
    >>> check_sides(np.array([-1.0, 1e-19]), 0b00, np.array([1e-9, 1e-9]), 0.5)
    >>> check_sides(np.array([-1.0, 1e-3]), 0b00, np.array([1e-9, 1e-9]), 0.5)
    Traceback (most recent call last):
    ...
    ValueError: after the stop at t=0.5 event 1 is on the wrong side of its surface:
    h_1 = 0.001, beyond its window 1e-09 (the accuracy of the stop), where region mask 0b00
    (bit k set: h_k > 0) says h_1 < 0; the run lost track of a crossing (an internal error:
    please report it with the model)
    """
    h = scratch(h)
    k = rules.wrong_side(h, int(mask), scratch(window))
    if k < 0:
        return
    says = ">" if mask >> k & 1 else "<"
    raise ValueError(
        f"after the stop at t={t:.10g} event {k} is on the wrong side of its surface: "
        f"h_{k} = {h[k]:.3g}, beyond its window {window[k]:.3g} (the accuracy of the stop), "
        f"where region mask {format_mask(int(mask), h.size)} (bit k set: h_k > 0) says "
        f"h_{k} {says} 0; the run lost track of a crossing (an internal error: please "
        f"report it with the model)"
    )


def check_carried(system, h, mask, window, group, x, t):
    """Refuse an event that reads a rounding across its surface after the stop at ``t``
    (``h`` (n,) at the state ``x`` after the group ``group``, within its ``window``: what
    :func:`check_sides` lets pass) and that the field of region ``mask`` carries further
    across (:func:`bderiv.models.compiled.rules.carried_across`; both paths).

    Its crossing is at once, at the stop's point, and the integrator reads the event across
    at both ends of every step: it would be lost, the run going on in a region the state
    has left. It comes where events cross in turn at one point: the end of a trajectory
    that spirals into the intersection of their surfaces faster than the crossings can be
    counted (:mod:`bderiv.models.events.zeno`), or a corner met within the accuracy.

    Raises
    ------
    ValueError
        Naming the time, the event, its value, its window, its rate and the region.
    """
    h = np.ascontiguousarray(h, dtype=np.float64)
    window = np.ascontiguousarray(window, dtype=np.float64)
    skip = sum(1 << k for k in group)
    if not rules.reads_across(h, int(mask), window, skip):
        return
    J = np.ascontiguousarray(system.eval_event_jacobian(x), dtype=np.float64)
    F = np.ascontiguousarray(system.eval_field(x, mask), dtype=np.float64)
    k = rules.carried_across(h, int(mask), window, skip, J, F)
    if k < 0:
        return
    says = ">" if mask >> k & 1 else "<"
    raise ValueError(
        f"after the events {list(group)} at t={t:.10g} event {k} is a rounding across its "
        f"surface (h_{k} = {h[k]:.3g}, within its window {window[k]:.3g}, where region mask "
        f"{format_mask(int(mask), h.size)} says h_{k} {says} 0) and the field of that "
        f"region carries it further across (dh_{k}/dt = {float(J[k] @ F):.3g}): it crosses "
        f"at once, at the same point, and the integrator cannot locate that crossing "
        f"(events crossing in turn at one point: a trajectory that spirals into the "
        f"intersection of their surfaces, a Zeno accumulation, or a corner met within the "
        f"integration accuracy); end the run before t={t:.10g}, or tighten rtol and atol"
    )
