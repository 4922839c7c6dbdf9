"""Event-detecting integration of a hybrid model: trajectory, event log, solver options.

:func:`run` integrates a model (any object with the checked evaluations of
:class:`~bderiv.hybrid.HybridSystem`: ``eval_field``, ``eval_events``,
``eval_event_jacobian``, ``eval_field_jacobian``, ``start_mask``, ``n_events``, ``dim``)
from region to region with :func:`scipy.integrate.solve_ivp`. Each stretch stops at the
first event crossing; the events that crossed, and those within ``simultaneity_tol`` (in
time) of crossing, switch together as one :class:`EventGroup`. A group is checked against
the model: every event of it must be at the stop to within the integration accuracy
(:func:`group_tolerance`), so a large ``simultaneity_tol`` cannot silently switch an
event early and return a wrong state. :class:`SolverOptions` holds the integrator settings
with their one set of defaults.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from dataclasses import field as dc_field
from typing import NamedTuple

import numpy as np
from scipy.integrate import OdeSolver, solve_ivp

from ._format import format_mask, transversality_message
from ._validate import check_number

__all__ = [
    "EventGroup",
    "EventRecord",
    "SolverOptions",
    "Trajectory",
    "group_tolerance",
    "run",
]

#: the methods of :func:`scipy.integrate.solve_ivp` by name.
SOLVE_IVP_METHODS = ("RK45", "RK23", "DOP853", "Radau", "BDF", "LSODA")
#: smallest rtol solve_ivp honours (it raises smaller ones to this, with a warning).
MIN_RTOL = 100 * np.finfo(np.float64).eps
#: refuse trajectories with more event groups than this times (n + 1) (chattering).
MAX_GROUPS_FACTOR = 50
#: global over local error of the integrator in :func:`group_tolerance`: an adaptive
#: Runge-Kutta method keeps each step's error below atol + rtol |x|; the error of the
#: state at a stop, a sum of such step errors, is a modest multiple of it.
GLOBAL_ERROR_FACTOR = 10.0


@dataclass(frozen=True)
class SolverOptions:
    """Settings of :func:`scipy.integrate.solve_ivp`, validated, with one set of defaults.

    Parameters
    ----------
    rtol : float
        Relative tolerance, in ``[MIN_RTOL, 1)`` (about 2.2e-14: solve_ivp's floor).
    atol : float
        Absolute tolerance, finite, > 0.
    method : str or OdeSolver subclass
        A solve_ivp method name (``SOLVE_IVP_METHODS``) or an ``OdeSolver`` subclass.
    max_step : float
        Largest step, > 0 (``inf``: no limit).

    Examples
    --------
    >>> SolverOptions().with_overrides(rtol=1e-12).rtol
    1e-12
    >>> SolverOptions(atol=float("nan"))
    Traceback (most recent call last):
    ...
    ValueError: atol must be a finite number > 0, got nan
    """

    rtol: float = 1e-10
    atol: float = 1e-12
    method: object = "DOP853"
    max_step: float = np.inf

    def __post_init__(self):
        rtol = check_number(self.rtol, "rtol")
        if not rtol < 1.0 or rtol < MIN_RTOL:
            raise ValueError(
                f"rtol must be in [{MIN_RTOL:.3g}, 1) (solve_ivp cannot honour a smaller "
                f"relative tolerance), got {rtol!r}"
            )
        object.__setattr__(self, "rtol", rtol)
        object.__setattr__(self, "atol", check_number(self.atol, "atol"))
        object.__setattr__(
            self, "max_step", check_number(self.max_step, "max_step", allow_inf=True)
        )
        method = self.method
        known = isinstance(method, str) and method in SOLVE_IVP_METHODS
        if not known and not (isinstance(method, type) and issubclass(method, OdeSolver)):
            raise ValueError(
                f"method must be one of {', '.join(SOLVE_IVP_METHODS)} or an OdeSolver "
                f"subclass, got {method!r}"
            )

    def with_overrides(self, **settings) -> SolverOptions:
        """A copy with the settings that are not None replaced (checked again)."""
        given = {key: value for key, value in settings.items() if value is not None}
        return replace(self, **given) if given else self

    @classmethod
    def resolve(cls, options=None, default=None, **settings) -> SolverOptions:
        """``options`` (or ``default``, or the defaults) with keyword ``settings`` applied.

        The public methods take both an ``options`` object and the keywords ``rtol``,
        ``atol``, ``method``, ``max_step``; a keyword that is not None wins.
        """
        if options is not None and not isinstance(options, cls):
            raise TypeError(f"options must be a SolverOptions, got {type(options).__name__}")
        base = options if options is not None else (default or cls())
        return base.with_overrides(**settings)

    def solve_ivp_kwargs(self) -> dict:
        """Keyword arguments for :func:`scipy.integrate.solve_ivp`."""
        return {"rtol": self.rtol, "atol": self.atol, "method": self.method,
                "max_step": self.max_step}


class EventRecord(NamedTuple):
    """One line of the event log: ``event`` switched at ``time``; ``mask`` is the mask after."""

    time: float
    event: int
    mask: int


class EventGroup(NamedTuple):
    """Events switched together at one stop of the integrator.

    Attributes
    ----------
    time : float
        Time of the first event of the group (the integrator's stop).
    events : tuple of int
        Global indices of the events switched, ascending.
    mask_before, mask_after : int
        Region masks before and after the group.
    state : ndarray, shape (d,)
        State at ``time``.
    """

    time: float
    events: tuple
    mask_before: int
    mask_after: int
    state: np.ndarray


@dataclass(frozen=True, eq=False)
class Trajectory:
    """Result of :meth:`HybridSystem.simulate <bderiv.hybrid.HybridSystem.simulate>`.

    Attributes
    ----------
    t : ndarray, shape (N,)
        Output times, ascending, from 0 to ``t_final``; an event time appears twice (end of
        one stretch, start of the next).
    x : ndarray, shape (N, d)
        States at ``t``.
    masks : ndarray, shape (N,), int64
        Region mask in effect on the stretch each sample belongs to.
    events : tuple of EventRecord
        The event log ``(time, event, mask after)`` in order of switching.
    groups : tuple of EventGroup
        The same events grouped by the integrator stop at which they switched.
    x_final : ndarray, shape (d,)
        State at ``t_final``.
    mask_final : int
        Region mask at ``t_final``.
    linear : tuple of ndarray, each (d, d)
        Classical derivatives of the smooth stretches (variational equations); filled only
        when integrated with ``variational=True`` (for the flow's B-derivative).
    """

    t: np.ndarray
    x: np.ndarray
    masks: np.ndarray
    events: tuple
    groups: tuple
    x_final: np.ndarray
    mask_final: int
    linear: tuple = dc_field(default=(), repr=False)


def group_tolerance(Dh: np.ndarray, options: SolverOptions, scale: float) -> np.ndarray:
    """Largest ``|h_k(x)|`` at which event k counts as being at the stop ``x``: shape (n,).

    The integrator keeps each component's step error below ``atol + rtol * |x_i|``; with
    ``scale`` the largest ``|x_i|`` met so far, a state error ``e`` with
    ``|e_i| <= GLOBAL_ERROR_FACTOR * (atol + rtol * scale)`` moves ``h_k`` by at most
    ``|Dh[k]|_1`` times that. Events closer than this to their surface cannot be told
    from simultaneous at the solver's accuracy; events further away are not at the stop.
    """
    step = options.atol + options.rtol * scale
    return GLOBAL_ERROR_FACTOR * step * np.abs(Dh).sum(axis=1)


class _EventValues:
    """``events(x)`` cached on the last state (solve_ivp calls every event function)."""

    def __init__(self, system):
        self.system, self.key, self.value = system, None, None

    def __call__(self, y):
        x = y[: self.system.dim]
        if self.key is None or not np.array_equal(self.key, x):
            self.key, self.value = x.copy(), self.system.eval_events(x)
        return self.value

    def terminal_events(self, mask):
        """One terminal solve_ivp event per event; pending ones cross upward."""
        funcs = []
        for k in range(self.system.n_events):

            def ev(_t, y, k=k):
                return self(y)[k]

            ev.terminal = True
            ev.direction = -1 if mask >> k & 1 else 1
            funcs.append(ev)
        return funcs


def _integrate_stretch(system, x, t, t_final, mask, options, events, variational):
    """Integrate region ``mask`` from ``(t, x)`` until ``t_final`` or an event."""
    d = system.dim
    if variational:  # the state and the (d, d) derivative of the flow, row-major

        def rhs(_t, y):
            J = system.eval_field_jacobian(y[:d], mask)
            return np.concatenate((system.eval_field(y[:d], mask),
                                   (J @ y[d:].reshape(d, d)).ravel()))

        y0 = np.concatenate((x, np.eye(d).ravel()))
    else:

        def rhs(_t, y):
            return system.eval_field(y, mask)

        y0 = x
    sol = solve_ivp(rhs, (t, t_final), y0, events=events.terminal_events(mask),
                    **options.solve_ivp_kwargs())
    if sol.status == -1:
        raise RuntimeError(f"solve_ivp failed at t={sol.t[-1]:.6g}: {sol.message}")
    return sol


def _switch(system, sol, mask, x, simultaneity_tol, options, scale):
    """The events switched at the stop ``x`` of ``sol`` and the mask after them.

    An event grouped by ``simultaneity_tol`` must be at ``x`` to within
    :func:`group_tolerance` (``scale``: the largest ``|x_i|`` so far). Raises
    ``ValueError`` on a downward crossing, on a grouped event not at ``x`` and on a
    switched event that would cross back in its new region.
    """
    n, t = system.n_events, float(sol.t[-1])
    fired = [k for k in range(n) if sol.t_events[k].size]
    for k in fired:
        if mask >> k & 1:
            raise ValueError(
                f"event {k} crossed its surface downward at t={t:.10g} in region mask "
                f"{format_mask(mask, n)}: transversality is broken (an event that happened "
                f"must stay happened)"
            )
    h = system.eval_events(x)
    Dh = system.eval_event_jacobian(x)
    rate_before = Dh @ system.eval_field(x, mask)
    group, near = [], []
    for k in (k for k in range(n) if not mask >> k & 1):
        if k in fired or h[k] >= 0:  # crossed: always switched, none is ever lost
            group.append(k)
        elif rate_before[k] > 0 and -h[k] / rate_before[k] <= simultaneity_tol:
            group.append(k)
            near.append(k)
    _check_near(near, h, rate_before, group_tolerance(Dh, options, scale), group, t,
                simultaneity_tol)
    new = mask | sum(1 << k for k in group)
    rate_after = Dh @ system.eval_field(x, new)
    for k in group:
        if not rate_after[k] > 0:
            raise ValueError(
                transversality_message(k, format_mask(new, n), rate_after[k],
                                       f"at t={t:.10g} after switching events {group}")
                + " (the event would cross back)"
            )
    return group, new


def _check_near(near, h, rate, tol, group, t, simultaneity_tol):
    """Refuse events grouped by ``simultaneity_tol`` that are not at the stop."""
    far = [k for k in near if abs(h[k]) > tol[k]]
    if not far:
        return
    k = far[0]
    gap = -h[k] / rate[k]
    raise ValueError(
        f"events {group} were grouped at t={t:.10g} by simultaneity_tol={simultaneity_tol:g}, "
        f"but event {k} is not at that point: h_{k} = {h[k]:.3g}, beyond the integration "
        f"accuracy {tol[k]:.3g}; it happens about {gap:.3g} later. Switching it early would "
        f"give a wrong state: pass a simultaneity_tol below {gap:.3g} to switch it on its own"
    )


@dataclass
class _Log:
    """What :func:`run` accumulates, stretch by stretch."""

    t: list = dc_field(default_factory=list)
    x: list = dc_field(default_factory=list)
    masks: list = dc_field(default_factory=list)
    records: list = dc_field(default_factory=list)
    groups: list = dc_field(default_factory=list)
    linear: list = dc_field(default_factory=list)

    def add_stretch(self, sol, mask, d, variational):
        self.t.append(sol.t)
        self.x.append(sol.y[:d].T)
        self.masks.append(np.full(sol.t.size, mask, dtype=np.int64))
        if variational:
            self.linear.append(np.array(sol.y[d:, -1].reshape(d, d)))


def run(system, x0, t_final, *, simultaneity_tol, options=None, variational=False):
    """Integrate ``system`` from ``x0`` at time 0 to ``t_final`` with event detection.

    Parameters
    ----------
    system : HybridSystem
        The model (its checked evaluations are used).
    x0 : ndarray, shape (d,)
        Checked start point, not on an event surface.
    t_final : float
        Final time, > 0.
    simultaneity_tol : float
        Events within this time (first order) of crossing at a stop switch with it.
    options : SolverOptions, optional
    variational : bool
        Also integrate the variational equations (fills ``Trajectory.linear``).

    Returns
    -------
    Trajectory
    """
    t_final = check_number(t_final, "t_final")
    simultaneity_tol = check_number(simultaneity_tol, "simultaneity_tol", strict=False)
    options = SolverOptions() if options is None else options
    d, n = system.dim, system.n_events
    mask = system.start_mask(x0)
    events, log = _EventValues(system), _Log()
    t, x, scale = 0.0, x0, float(np.abs(x0).max())
    while True:
        sol = _integrate_stretch(system, x, t, t_final, mask, options, events, variational)
        log.add_stretch(sol, mask, d, variational)
        t, x = float(sol.t[-1]), np.array(sol.y[:d, -1])
        scale = max(scale, float(np.abs(sol.y[:d]).max()))
        if sol.status == 0:
            break
        group, new = _switch(system, sol, mask, x, simultaneity_tol, options, scale)
        log.records.extend(EventRecord(t, k, new) for k in group)
        log.groups.append(EventGroup(t, tuple(group), mask, new, x.copy()))
        mask = new
        if len(log.groups) > MAX_GROUPS_FACTOR * (n + 1):
            raise RuntimeError(
                f"more than {MAX_GROUPS_FACTOR * (n + 1)} event groups before t_final="
                f"{t_final}: the trajectory chatters or the events are not event-selected"
            )
        if t >= t_final:
            break
    if variational and len(log.linear) == len(log.groups):  # an event stopped it at t_final
        log.linear.append(np.eye(d))
    return Trajectory(t=np.concatenate(log.t), x=np.concatenate(log.x),
                      masks=np.concatenate(log.masks), events=tuple(log.records),
                      groups=tuple(log.groups), x_final=x, mask_final=mask,
                      linear=tuple(log.linear))
