"""Event-detecting integration of a hybrid model: the loop over stretches and stops.

:func:`run` integrates a model through its checked calls (a
:class:`~bderiv.models.calls.ModelCalls`, ``HybridSystem.calls``: ``eval_field``, ``eval_events``,
``eval_event_jacobian``, ``eval_field_jacobian``, ``start_mask``, ``n_events``, ``dim``)
from region to region with :func:`scipy.integrate.solve_ivp`. Each stretch stops at the
first event crossing, upward or downward (a surface may be crossed any number of times);
the events that crossed, and those within the options' ``simultaneity_tol`` (in time) of
crossing,
switch together as one :class:`~bderiv.models.events.crossings.EventGroup`
(:func:`bderiv.models.events.crossings.switch`
checks each crossing and that every event of a group is at the stop). With ``section``
the run ends at the first upward crossing of a Poincare section after the start.
:class:`~bderiv.models.integrate.options.SolverOptions` holds the run's settings (the
integrator's and ``simultaneity_tol``), one value passed down to the stops; a run's result
is a
:class:`~bderiv.models.integrate.trajectory.Trajectory`.

What a run records is asked for (``record``): every accepted step (``STEPS``, what
``simulate`` gives by default), its start and end only (``ENDS``: what the flow map, the
return map and the finite differences read; bounded, whatever the span), or the states at
given times (``t_eval``, on each stretch's dense output). The event log, the groups and
(with ``variational``) one (d, d) matrix per stretch are always kept. A record that grows
with the steps is held to the memory the process may still take before it grows
(:func:`bderiv._support._validate.check_record`): a ValueError that names it, not a MemoryError.
"""

from __future__ import annotations

import logging
import weakref
from dataclasses import dataclass
from functools import lru_cache, partial

import numpy as np

from ..._limits import MAX_FORCED_STEPS, MAX_GROUPS
from ..._numerics import GLOBAL_ERROR_FACTOR
from ..._support._format import format_mask, noted_at
from ..._support._progress import SimulationProgress
from ..._support._validate import check_number, check_positive_int
from ..compiled import ENDED, EVENT_JAC_NONE, cancel_point
from ..events.crossings import EventGroup, EventRecord, group_tolerance, switch
from ..events.finaltime import pending_at_final_time
from ..events.locate import settle
from ..events.sides import check_carried, check_sides
from ..events.stopcalls import StopCalls, local_view
from ..events.zeno import ImpactWatch
from ..readiness import PythonTierEnded, integrator_ready
from .compiled_path import CompiledStretches
from .options import check_options
from .record import ENDS, STEPS, RunLog, check_t_eval
from .scipy_path import ScipyStretches
from .trajectory import NoReturn, TooManyGroups, Trajectory

_log = logging.getLogger("bderiv")

__all__ = [
    "GLOBAL_ERROR_FACTOR",
    "EventGroup",
    "EventRecord",
    "ENDS",
    "STEPS",
    "check_t_eval",
    "group_tolerance",
    "run",
    "stretches_for",
]

#: the models whose first run's start region was logged
_TOLD = weakref.WeakSet()


def _tell_start(system, x0):
    """Log once per model, at INFO (logger ``bderiv``), the region its first run starts
    in and the events counted as happened there: events written with the other sign (a
    height where the model wants a penetration) start it in another region than meant."""
    if system in _TOLD or not _log.isEnabledFor(logging.INFO):
        return
    _TOLD.add(system)
    h, n = system.eval_events(x0), system.n_events
    happened = [k for k in range(n) if h[k] > 0]
    _log.info("the run starts in region %s: events %s counted as happened (h_k(x0) > 0); "
              "events written with the other sign start it elsewhere than meant",
              format_mask(sum(1 << k for k in happened), n), happened)


def stretches_for(system, options, section=None, watch=None, stops=None):
    """The integrator of a run's stretches: compiled when the model's functions are numba
    dispatchers (``system.compiled``; the section must then be one too), else solve_ivp
    (``watch``: a :class:`~bderiv._support._progress.SimulationProgress`, or None, told
    each evaluation's time on scipy's path, the time reached after each slice of steps on
    the compiled one; ``stops``: the run's :class:`~bderiv.models.events.stopcalls.StopCalls`).

    Raises
    ------
    TypeError
        A compiled model with a Python section (named).
    ValueError
        A compiled model with another method than DOP853 (the compiled integrator's).
    """
    if not getattr(system, "on_compiled_path", False):
        return ScipyStretches(system, section, watch, stops)
    if options.method != "DOP853":
        raise ValueError(
            f"the model's functions are numba-compiled: they are integrated by the compiled "
            f"DOP853, so method must be 'DOP853', got {options.method!r}"
        )
    compiled_section = None if section is None else section.compiled()
    if system.compiled is None:  # the integrator compiles in the background: scipy's DOP853
        return ScipyStretches(system, section, watch, stops)
    return CompiledStretches(system, compiled_section, stops, watch)


def run(system, x0, t_final, *, options, variational=False, section=None,
        max_groups=MAX_GROUPS, record=STEPS, bar=True):
    """Integrate ``system`` from ``x0`` at time 0 to ``t_final`` with event detection.

    Parameters
    ----------
    system : ModelCalls (``HybridSystem.calls``)
        The model (its checked evaluations are used).
    x0 : ndarray, shape (d,)
        Checked start point, not on an event surface.
    t_final : float
        Final time, > 0 (with ``section``: the longest time to wait for the return).
    options : SolverOptions
        The run's settings, ``simultaneity_tol`` set (the public functions set their
        default): events within this time (first order) of crossing at a stop switch
        with it.
    variational : bool
        Also integrate the variational equations (fills ``Trajectory.linear``).
    section : Section, optional
        Stop at the first upward crossing of ``section(x) = 0`` after time 0 (x0 is on
        the section, or below it); the trajectory ends there
        (:class:`bderiv.models.section.Section`: checked calls; numba-compiled with a compiled
        model).
    max_groups : int
        Largest number of event groups (a Zeno or chattering trajectory is refused).
    record : ``STEPS``, ``ENDS`` or ndarray, shape (k,)
        The samples kept in ``Trajectory.t, x, masks``: every accepted step (held to
        the memory the process may take: ValueError before it grows past it), the start
        and the end only (the time and state at 0 and at the run's end), or the states at
        these times (checked by :func:`check_t_eval`; those after a return to the
        section are not sampled).
    bar : bool
        Draw the bar of the simulated time once the run has lasted a few seconds (on a
        terminal: :class:`~bderiv._support._progress.SimulationProgress`); False in a
        batch, which draws its own.

    Returns
    -------
    Trajectory

    Raises
    ------
    ValueError
        From :func:`bderiv.models.events.crossings.switch`; bounces of an event that
        accumulate at or before ``t_final`` (a Zeno trajectory:
        :class:`bderiv.models.events.zeno.ImpactWatch`); with ``section``, when the
        trajectory does not return to it before ``t_final`` or an event crosses at the
        return.
    RuntimeError
        When the integrator fails or the run has more than ``max_groups`` event groups.
    """
    if getattr(system, "python_first", False):  # a new model of numba functions
        try:
            with system.python_run():
                return _run(system, x0, t_final, options, variational, section, max_groups,
                            record, bar)
        except PythonTierEnded as ended:  # its time spent, or its Python code raised
            system.compile_from_now(ended.__cause__)
    return _run(system, x0, t_final, options, variational, section, max_groups, record, bar)


def _run(system, x0, t_final, options, variational, section, max_groups, record, bar):
    """:func:`run`'s work, on the integrator the model takes now."""
    _tell_start(system, x0)
    if getattr(system, "on_compiled_path", False):
        integrator_ready()  # the compiled integrator, or scipy while it compiles
        system.check_compiled_types()  # on either, the types the compiled path takes
    t_final = check_number(t_final, "t_final")
    max_groups = check_positive_int(max_groups, "max_groups")
    check_options(options)
    if t_final / options.max_step > MAX_FORCED_STEPS:
        raise ValueError(f"max_step={options.max_step:g} would take at least "
                         f"{t_final / options.max_step:.3g} steps to t_final={t_final:g} "
                         f"(more than {MAX_FORCED_STEPS:.0e}): take a larger max_step")
    d = system.dim
    # the Python loop's own state is made for its first stretch
    log, loop = RunLog(record, system.n_events), None
    # the start's region (mask -1) from the signs of its events: by the compiled run, or
    # by start_mask before the first stretch in Python (which refuses a start on a surface)
    now = _Now(0.0, x0, -1, np.abs(x0), np.zeros(d))
    settings = (t_final, options, variational, section, max_groups)
    impacts = ImpactWatch(system, t_final)  # bounces that accumulate: refused
    watch = SimulationProgress(t_final) if bar else None
    try:
        while not now.ended:
            cancel_point()  # a run of a batch on threads stops with its batch
            if compiled_stops(system, section):  # the plain stops at once
                _compiled_stretches(system, log, now, *settings)  # a slice of steps at most
                impacts.see(log.groups)
                if watch is not None:
                    watch(now.t)
            if not now.ended:
                if loop is None:
                    loop = _PythonLoop(system, options, section, watch)
                _python_stretch(system, loop, log, now, *settings)
                impacts.see(log.groups)
    except ValueError as exc:
        said = impacts.explained(exc)
        if said is not exc:
            raise said from exc
        raise
    finally:
        if watch is not None:
            watch.close()
    if section is not None and not now.returned:
        raise NoReturn(
            f"the trajectory did not return to the section (upward) before t={t_final:g}; "
            f"pass a longer time to wait"
        )
    if variational and len(log.linear) == len(log.groups):  # an event stopped it at t_final
        log.linear.append(np.eye(d))
    final, times = None, ()
    if variational and section is None:
        stops = StopCalls(system) if loop is None else loop.stops
        final, times = _final_group(stops, log.groups, now.mask, now.x, t_final, options)
    t, x, masks = log.finish(x0, now)
    return Trajectory(t=t, x=x, masks=masks, events=tuple(log.records),
                      groups=tuple(log.groups), x_final=now.x, mask_final=now.mask,
                      linear=tuple(log.linear), final_group=final,
                      final_pending=bool(times), final_times=times,
                      simultaneity_tol=options.simultaneity_tol)


#: the regions of a run without sensitivity (no field Jacobian to check)
_NO_MASKS = np.empty(0, dtype=np.int64)


class _PythonLoop:
    """What the Python loop's stretches share in a run: the checked calls at a stop (made
    once for all its rules) and the stretches' integrator, which tells ``watch`` (the run's
    bar, or None) each evaluation's time."""

    def __init__(self, system, options, section, watch):
        self.stops = StopCalls(system)
        self.stretches = stretches_for(system, options, section, watch, self.stops)


@lru_cache(maxsize=1024)
def _events_of(bits):
    """The events (ascending) whose bits are set in ``bits``."""
    return tuple(k for k in range(bits.bit_length()) if bits >> k & 1)


@dataclass
class _Now:
    """Where a run is: time, state, region, the largest ``|x_i|`` so far, the state's error
    bound, and whether it ended (at the section: ``returned``)."""

    t: float
    x: np.ndarray
    mask: int
    scale: np.ndarray
    err: np.ndarray
    ended: bool = False
    returned: bool = False


def stops_compile(system) -> bool:
    """Whether ``system``'s stops can be decided in compiled code: a compiled model whose
    event Jacobian is had in compiled code (given compiled, or by complex step) and whose
    resets, if any, are compiled
    (:meth:`bderiv.models.compiled.CompiledModel.run_stretches`)."""
    model = getattr(system, "compiled", None)
    return model is not None and model.event_jac_mode != EVENT_JAC_NONE and \
        not model.has_python_reset


def compiled_stops(system, section) -> bool:
    """Whether a run's plain stops are decided in compiled code now: :func:`stops_compile`,
    and the event Jacobian checked once already where it is checked (a section is compiled
    with a compiled model)."""
    return stops_compile(system) and system.event_jacobian_checked()


def _compiled_stretches(system, log, now, t_final, options, variational, section,
                        max_groups):
    """The stretches from ``now`` that the compiled run decides, recorded in ``log``;
    ``now`` moved to their end."""
    model = system.compiled
    all_checked, checked = (system.checked_compiled_jacobians() if variational
                            else (True, _NO_MASKS))
    out = model.run_stretches(
        now.t, now.x, now.mask, now.scale, now.err, t_final, rtol=options.rtol,
        atol=options.atol, max_step=options.max_step, simultaneity_tol=options.simultaneity_tol,
        variational=variational, all_checked=all_checked, checked=checked,
        groups_left=max_groups - len(log.groups),
        section=None if section is None else section.compiled(), **log.sampling())
    if out is None:  # a user function raised: the Python loop says where
        return
    if out.T.size:
        log.add_steps(out.T, out.X, out.M)
        if variational:
            log.linear.extend(out.L)
    log.add_samples(out.S, out.SM)
    records, groups, states = log.records, log.groups, out.group_x
    for i, (time, (b, m0, m1)) in enumerate(zip(out.group_t.tolist(),
                                                out.group_masks.tolist(), strict=True)):
        group = _events_of(b)
        for k in group:
            records.append(EventRecord(time, k, m1, -1 if m0 >> k & 1 else 1))
        jac = None
        if variational:
            jac = out.group_J[i]
            jac.flags.writeable = False
        # rows of the arrays the compiled run made for this call: no one else's
        groups.append(EventGroup(time, group, m0, m1, states[i, 0], states[i, 1], jac))
    now.t, now.mask, (now.x, now.scale, now.err) = out.t, out.mask, out.state
    now.ended, now.returned = out.code == ENDED, out.returned


def _python_stretch(system, loop, log, now, t_final, options, variational, section,
                    max_groups):
    """One stretch from ``now`` and its stop, in Python (``loop``: a :class:`_PythonLoop`),
    recorded in ``log``; ``now`` moved to its end (after the group's switch)."""
    d, n = system.dim, system.n_events
    stops, stretches = loop.stops, loop.stretches
    if now.mask < 0:  # the run's start
        now.mask = system.start_mask(now.x)
    sol = stretches(now.x, now.t, t_final, now.mask, options, variational)
    again = partial(stretches, now.x, now.t, t_final, now.mask, variational=variational)
    settled = settle(stops, now.mask, sol, options, now.scale, now.err,
                     again if variational else None)
    sol, now.err, now.scale, fired = settled.sol, settled.err, settled.scale, settled.fired
    returned = section is not None and sol.t_events[n].size
    log.add_stretch(sol, now.mask, d, variational, last=returned or sol.status == 0)
    now.t, now.x = float(sol.t[-1]), np.array(sol.y[:d, -1])
    t, x, mask = now.t, now.x, now.mask
    if returned:
        _refuse_event_at_return(fired, t)
        now.ended = now.returned = True
        return
    if sol.status == 0:
        now.ended = True
        return
    with noted_at(t):  # a model's function raised at the stop (a reset): at its time
        group, new, x_after = switch(stops, fired, mask, x, t, options, now.err, settled.stop)
        # every event on the side its bit says, or within its window of the surface
        h_after = stops.eval_events(x_after)
        check_sides(h_after, new, settled.stop.window, t)
        # and none a rounding across that the region's flow carries further across, unseen
        check_carried(stops, h_after, new, settled.stop.window, group, x_after, t)
        log.records.extend(EventRecord(t, k, new, -1 if mask >> k & 1 else 1) for k in group)
        # the stop's event Jacobian at x (kept by ``stops``), for the group's B-derivative
        jac = stops.eval_event_jacobian(x) if variational else None
    log.groups.append(EventGroup(t, tuple(group), mask, new, x.copy(), x_after.copy(), jac))
    now.mask, now.x = new, x_after
    if len(log.groups) > max_groups:
        raise TooManyGroups(max_groups, t)
    now.ended = t >= t_final


def _final_group(system, groups, mask, x, t_final, options):
    """The event group within ``options.simultaneity_tol`` of ``t_final`` and, when it is pending
    (events about to cross after ``t_final``), the times at which its events cross (first
    order); ``(None, ())`` when there is none. Pending events come before the last switched
    group within the tolerance: the flow map merges the two
    (:func:`bderiv.analysis.assembly.flow_map_along`)."""
    view = local_view(system, int(mask), x)
    h, rate = view.h, view.rate
    tol = options.simultaneity_tol
    pending = pending_at_final_time(h, rate, tol)
    if pending:
        bits = sum(1 << k for k in pending)
        group = EventGroup(t_final, tuple(pending), mask, mask ^ bits, x.copy(), x.copy(),
                           system.eval_event_jacobian(x))
        return group, tuple(t_final - float(h[k] / rate[k]) for k in pending)
    if groups and t_final - groups[-1].time <= tol:
        return groups[-1], ()
    return None, ()


def _refuse_event_at_return(fired, t):
    """Refuse a return to the section at which events cross too."""
    if fired:
        raise ValueError(
            f"event(s) {fired} cross at the return to the section (t={t:.10g}): the return "
            f"map is not piecewise differentiable there; choose a section away from events"
        )
