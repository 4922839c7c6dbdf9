"""Event location at a stop of the integrator: how well each event is known, and when.

The rules here are plain functions of arrays (the state's error bound, the event values,
their gradients ``Dh`` and rates ``Dh . F``), written once for any integrator: their
arithmetic is :mod:`bderiv.models.compiled.rules`, which the compiled run calls too (the
same bits on both paths); only :func:`settle` deals with
:func:`scipy.integrate.solve_ivp` (docs/mathematics.md, section 11). The model's values at
the stop come from :mod:`bderiv.models.events.stopcalls`; the sides of the surfaces after
it are checked by :mod:`bderiv.models.events.sides`.

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

from typing import NamedTuple

import numpy as np

from ..._numerics import GLOBAL_ERROR_FACTOR, MIN_RTOL, REFINE_FACTOR
from ..._support._validate import scratch
from ._python_rules import rules
from .stopcalls import local_view

__all__ = [
    "GLOBAL_ERROR_FACTOR",
    "Classes",
    "Settled",
    "Stop",
    "classify",
    "examine",
    "flags_of",
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
    >>> state_error(1e-12, 1e-10, 500.0)
    array([5.0001e-07])
    """
    scale = scratch(scale)
    carried = scratch(np.broadcast_to(carried, scale.shape))
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
    u = rules.windows(scratch(Dh), scratch(rate), scratch(err), flags_of(fired, rate.size),
                      window)
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
    rules.classify(scratch(h), scratch(rate), scratch(window), flags_of(fired, h.size),
                   float(simultaneity_tol), codes)
    return Classes.of(codes)


class Stop(NamedTuple):
    """What the rules read at a stop ``x`` of region ``mask`` (:func:`examine`): made once,
    read by :func:`settle` and :func:`bderiv.models.events.crossings.switch`.

    Attributes
    ----------
    sign, h, Dh, F, rate
        :func:`~bderiv.models.events.stopcalls.local_view` at ``x``.
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


def examine(system, mask, x, err, fired, options) -> Stop:
    """The :class:`Stop` at ``x`` in region ``mask``: the local view, the windows from the
    state's error bound ``err`` (d,) and the located events ``fired``, and the classes (by
    the ``simultaneity_tol`` of ``options``, the run's
    :class:`~bderiv.models.integrate.options.SolverOptions`)."""
    sign, h, Dh, F, rate = local_view(system, mask, x)
    window, _ = windows(Dh, rate, err, fired)
    return Stop(sign, h, Dh, F, rate, window,
                classify(h, rate, window, fired, options.simultaneity_tol))


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


def settle(system, mask, sol, options, scale, carried, integrate=None) -> Settled:
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
    system : ModelCalls
        The model's checked calls (``HybridSystem.calls``).
    mask : int
        The stretch's region.
    sol : OdeResult
        The stretch from solve_ivp (one terminal event function per event, in order).
    options : SolverOptions
        The tolerances ``sol`` was integrated with, and the run's ``simultaneity_tol``.
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
        stop = examine(system, mask, sol.y[:d, -1], err, fired, options)
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
