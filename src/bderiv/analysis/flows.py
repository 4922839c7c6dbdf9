"""The flow of a model: its simulation, its B-derivative, its finite differences.

Functions over a model (:class:`~bderiv.analysis.system.HybridSystem`, whose methods of the
same names call them): :func:`bderivative` at an event point (:mod:`.assembly`),
:func:`simulate` and :func:`simulate_many`, event-detecting integration
(:mod:`bderiv.models.integrate.run`), :func:`flow_bderivative`, the flow map's B-derivative
from a trajectory integrated with its variational equations, and :func:`flow_fd`, forward
differences of the simulated flow (:mod:`.checks`). Each checks its arguments, resolves the
settings (the keywords, or ``options=``, and the function's default ``simultaneity_tol``)
into one :class:`~bderiv.models.integrate.options.SolverOptions` and hands it, with the
model's checked calls (``model.calls``), to the model side.
"""

from __future__ import annotations

import numpy as np

from .._limits import MAX_GROUPS, ON_SURFACE_TOL
from .._support._validate import check_number, check_state
from ..models.integrate.many import check_states, run_many
from ..models.integrate.options import DERIVATIVE_OPTIONS, SIMULATION_OPTIONS, SolverOptions
from ..models.integrate.run import ENDS, STEPS, check_t_eval, run
from ..models.section import Section
from . import checks
from .assembly import flow_map_along, point_bderivative

__all__ = ["bderivative", "flow_bderivative", "flow_fd", "simulate", "simulate_many"]


def bderivative(model, rho, *, tol=ON_SURFACE_TOL):
    """The B-derivative (PL saltation map) at a point where all n events are 0.

    Parameters
    ----------
    model : HybridSystem
        The model (:class:`~bderiv.analysis.system.HybridSystem`).
    rho : array_like, shape (d,)
        The event point: ``events(rho)`` must vanish.
    tol : float
        Largest accepted ``|events(rho)[k]|``, a finite number >= 0.

    Returns
    -------
    BDerivative
        With ``Dh = event_jacobian(rho)`` (n, d) and ``F[mask] = field(rho, mask)``;
        with resets, ``F[mask]`` at rho moved by the resets of the events in ``mask``,
        the field of the region the state lands in (an event whose reset sends the
        state back, a bounce or a leg swap, keeps its bit:
        :func:`bderiv.models.events.crossings.landing`
        decides as :func:`simulate` does), and the reset Jacobians there
        (mathematics.md section 9).

    Raises
    ------
    TypeError
        If ``tol`` is not a real number.
    ValueError
        If ``tol`` is NaN, infinite or negative, if some event value exceeds ``tol``
        (the residuals are named), when transversality fails (the mask and the
        event are named), or when the resets of the events applied in different
        orders give different states (:func:`bderiv.models.events.crossings.apply_resets`:
        further
        apart than ``RESET_MISMATCH * reset_tol * max(1, max |rho|)``, rho taken as
        accurate to ``reset_tol``), as :func:`simulate` refuses them.
    """
    tol = check_number(tol, "tol", strict=False)
    rho = check_state(rho, model.dim, "rho")
    h = model.calls.eval_events(rho)
    off = np.flatnonzero(np.abs(h) > tol)
    if off.size:
        raise ValueError(
            f"rho is not a point where all {model.n_events} events happen: events(rho) = "
            f"{h}; residuals above tol={tol:g} for events {off.tolist()} "
            f"(values {h[off].tolist()})"
        )
    return point_bderivative(model, rho, tol)


def simulate(model, x0, t_final, *, simultaneity_tol=None,
             options=None, rtol=None, atol=None, method=None, max_step=None,
             max_groups=MAX_GROUPS, section=None, t_eval=None):
    """Integrate from ``x0`` at time 0 to ``t_final`` with event detection.

    Parameters
    ----------
    model : HybridSystem
        The model (:class:`~bderiv.analysis.system.HybridSystem`).
    x0 : array_like, shape (d,)
        Start point, not on an event surface; its region comes from the event signs.
    t_final : float
        Final time, > 0.
    simultaneity_tol : float, optional
        Default ``SIMULATION_SIMULTANEITY_TOL`` (1e-12, ``bderiv._limits``). Events at the
        integrator's stop to within the integration accuracy that are
        crossing are switched together at the stop (one group: nothing orders them;
        :mod:`bderiv.models.events.locate`), and so are events that already crossed
        inside the step, so none is lost when two surfaces are crossed inside one
        solver step. Those whose time is known only to more than this are integrated
        again more tightly where a derivative is computed. Events within this time of
        crossing but measurably later are switched at their own time: the trajectory
        is the true one (a flow map merges such groups: :func:`flow_bderivative`).
    options : SolverOptions, optional
        The settings as one value (default ``SolverOptions()``: DOP853, rtol 1e-10, atol
        1e-12, no step limit; its ``simultaneity_tol`` left None takes this function's).
    rtol, atol, method, max_step : optional
        The settings as keywords (see
        :class:`~bderiv.models.integrate.options.SolverOptions`); one given with
        ``options`` must agree with it (ValueError naming both). A compiled model takes
        ``method="DOP853"`` only (its compiled integrator).
    max_groups : int
        Largest number of event groups (default 10,000): a Zeno or chattering
        trajectory is refused with a RuntimeError.
    section : callable ``section(x) -> float``, optional
        Stop at the first upward crossing of ``section(x) = 0`` after time 0 (the
        Poincare map: ``x_final`` is ``P(x0)``, ``t[-1]`` the return time);
        ``t_final`` is then the longest time to wait (ValueError if it passes).
    t_eval : array_like, shape (k,), optional
        Times at which to keep the state, ascending, in ``[0, t_final]`` (as
        :func:`scipy.integrate.solve_ivp`'s): ``Trajectory.t, x, masks`` hold these
        samples only (with a section, those up to the return), each on the dense output
        of the stretch that holds it (at an event time, the state after the group).
        ``t_eval=()`` keeps none: the final state and the events only. What the run
        stores is then bounded by ``k`` and the number of events, whatever the span.
        Default None: every accepted step, a record that grows with the span; before
        it outgrows the memory the process may take (the memory available and
        ``RLIMIT_AS``) the run is refused with a ValueError that names it.

    Returns
    -------
    Trajectory
        Its event log records every crossing, upward (bit set) or downward (bit
        cleared), with its direction (``EventRecord.direction``,
        ``EventGroup.directions``).

    Raises
    ------
    TypeError, ValueError
        On a bad argument (named). ValueError also if ``x0`` lies on a surface, if a
        crossing is grazing (not transversal in the region before or after it: the
        time, event and direction are named), or if a record of the run (every
        step's samples; a stretch's steps, kept to search for crossings inside them)
        would outgrow the memory the process may take (the record, its size and what to
        pass instead are named).

    Examples
    --------
    >>> import numpy as np
    >>> from bderiv.analysis.system import HybridSystem
    >>> s = HybridSystem(lambda x, mask: np.array([x[1], -x[0]]), lambda x: x[:1] - 2.0,
    ...                  n_events=1, dim=2)
    >>> traj = s.simulate([1.0, 0.0], 100.0, t_eval=np.linspace(0.0, 100.0, 5))
    >>> traj.t.shape, traj.x.shape, bool(abs(traj.x_final[0] - np.cos(100.0)) < 1e-7)
    ((5,), (5, 2), True)
    """
    options = SolverOptions.resolve(options, SIMULATION_OPTIONS, rtol=rtol, atol=atol,
                                    method=method, max_step=max_step,
                                    simultaneity_tol=simultaneity_tol)
    x0 = check_state(x0, model.dim, "x0")
    if section is not None:
        section = Section(section, model.dim)
    return run(model.calls, x0, t_final, options=options, max_groups=max_groups,
               section=section,
               record=_record(t_eval, t_final, model.dim))


def _record(t_eval, t_final, dim):
    """``run``'s ``record`` for ``t_eval``: every step (None) or the checked times."""
    if t_eval is None:
        return STEPS
    return check_t_eval(t_eval, check_number(t_final, "t_final"), dim)


def simulate_many(model, X0, t_final, *, simultaneity_tol=None,
                  options=None, rtol=None, atol=None, method=None, max_step=None,
                  max_groups=MAX_GROUPS, section=None, progress=None, t_eval=None):
    """:func:`simulate` from every start state of a batch.

    Each run is the one :func:`simulate` makes from that state (the same trajectory,
    to the bit). On a compiled model whose stops are decided in compiled code (its
    event Jacobian given compiled or had by complex step, its resets compiled) the runs go on
    ``numba.config.NUMBA_NUM_THREADS`` threads, whose compiled stretches run at once
    (the compiled run releases the GIL; the Python parts of the runs take turns);
    otherwise one after the other in this thread, where threads would only take turns
    at the GIL (:mod:`bderiv.models.integrate.many`). Ctrl-C stops the batch within a
    second.

    Parameters
    ----------
    model : HybridSystem
        The model (:class:`~bderiv.analysis.system.HybridSystem`).
    X0 : array_like, shape (m, d) or (..., d)
        Start states, one per row; each not on an event surface.
    t_final : float
        Final time, > 0 (with ``section``: the longest time to wait).
    simultaneity_tol, options, rtol, atol, method, max_step, max_groups, section
        As for :func:`simulate`, the same for every run.
    progress : None, bool or callable ``progress(done, total)``, optional
        None: a bar of the runs done, drawn once the batch has lasted a few seconds
        (on a terminal); False: none; True: a tqdm bar from the start; a callable:
        called after each run (in the calling thread, as runs finish).
    t_eval : array_like, shape (k,), optional
        As for :func:`simulate`: the times at which each run keeps its state
        (``()``: none, the final states and the events only).

    Returns
    -------
    Trajectories
        ``trajectories`` (one :class:`~bderiv.models.integrate.trajectory.Trajectory` per start
        state, also by ``len``, iteration and ``runs[i]``), ``x_final`` of shape (..., d) and
        ``mask_final`` of shape (...).

    Raises
    ------
    TypeError, ValueError
        On a bad argument (named; ``X0`` of another shape than (..., d), or not
        finite: the row is named); a batch whose runs would take more memory than the
        process may (a ValueError before any run, from ``X0``'s shape, or as the runs
        finish, from what they hold: pass fewer start states, or ``t_eval=()``); a
        run's ValueError or RuntimeError with the index and value of its start state
        before the message (the first failing run in the order of ``X0``, as a loop
        would raise it).

    Examples
    --------
    >>> import numpy as np
    >>> from bderiv.analysis.system import HybridSystem
    >>> s = HybridSystem(lambda x, mask: np.array([1.0, -x[0]]), lambda x: x[:1] - 1.0,
    ...                  n_events=1, dim=2)
    >>> runs = s.simulate_many(np.array([[0.0, 0.0], [0.5, 0.0]]), 2.0)
    >>> runs.x_final.shape, [round(r.events[0].time, 9) for r in runs]
    ((2, 2), [1.0, 0.5])
    """
    options = SolverOptions.resolve(options, SIMULATION_OPTIONS, rtol=rtol, atol=atol,
                                    method=method, max_step=max_step,
                                    simultaneity_tol=simultaneity_tol)
    record = _record(t_eval, t_final, model.dim)
    X0, lead = check_states(X0, model.dim, record)  # sized before it is copied
    if section is not None:
        section = Section(section, model.dim)
    return run_many(model.calls, X0, lead, t_final, options=options, max_groups=max_groups,
                    section=section, progress=progress, record=record)


def flow_bderivative(model, x0, t_final, *, simultaneity_tol=None,
                     options=None, rtol=None, atol=None, method=None, max_step=None):
    """The B-derivative of ``x -> Phi(t_final, x)`` at ``x0``.

    The nominal trajectory and its variational equations are integrated once. Events switched
    within ``simultaneity_tol`` (time) of each other form one group; each group gives a
    :class:`~bderiv.engine.bderivative.BDerivative` built at the group's state from the model
    (event Jacobian rows of the group, region fields around the entering mask, in the group's local
    orientation: rows negated for events crossed downward), and the stage is ``D+ . M . D-``
    (mathematics.md section 2).

    Parameters
    ----------
    model : HybridSystem
        The model (:class:`~bderiv.analysis.system.HybridSystem`).
    x0 : array_like, shape (d,)
    t_final : float
    simultaneity_tol : float, optional
        Time window within which events of the nominal trajectory count as
        simultaneous (default ``DERIVATIVE_SIMULTANEITY_TOL``, 1e-7, well above the
        event-location accuracy). The run
        switches each event at its own time (:func:`simulate`); groups whose events
        cross within this time of the first of them are merged into one, the group's
        map at the nearby point where they are simultaneous, and
        ``FlowBDerivative.group_spreads`` says how far apart they were (a smaller
        tolerance gives the separated events' map: docs/mathematics.md, section 7,
        "Events close together"). A stretch whose events' times are known less well
        than this is integrated again more tightly until they are decided (section
        11).
    options, rtol, atol, method, max_step
        Integrator settings, as for :func:`simulate`.

    Returns
    -------
    FlowBDerivative
        Evaluates tangent vectors ``(..., d)``; ``final_field`` is the field at the
        final point (the derivative in the final time). An event group within
        ``simultaneity_tol`` of ``t_final`` (either side) has the final time as one
        more event: its jumps apply only to the directions for which they come before
        it (``stops_at_group``; mathematics.md section 7). Refused there with resets.
    """
    options = SolverOptions.resolve(options, DERIVATIVE_OPTIONS, rtol=rtol, atol=atol,
                                    method=method, max_step=max_step,
                                    simultaneity_tol=simultaneity_tol)
    x0 = check_state(x0, model.dim, "x0")
    with model.calls.numerical_jacobian_watch("flow_bderivative"):
        traj = run(model.calls, x0, t_final, options=options, variational=True, record=ENDS)
        return flow_map_along(model, traj)


def flow_fd(model, x0, t_final, V, eps, *, simultaneity_tol=None,
            options=None, rtol=None, atol=None, method=None, max_step=None):
    """Forward (one-sided) finite differences of the simulated flow.

    ``(Phi(t_final, x0 + eps v) - Phi(t_final, x0)) / eps`` for every vector v; see
    :func:`bderiv.analysis.checks.forward_differences` (which this calls) for why one-sided and
    why the integrator settings default to the tight ``checks.FD_OPTIONS``.

    Parameters
    ----------
    model : HybridSystem
        The model (:class:`~bderiv.analysis.system.HybridSystem`).
    x0 : array_like, shape (d,)
    t_final : float
    V : array_like, shape (..., d)
        Tangent vectors.
    eps : float
        Step, > 0.
    simultaneity_tol, options, rtol, atol, method, max_step
        As for :func:`simulate`; defaults ``checks.FD_SIMULTANEITY_TOL`` and
        ``checks.FD_OPTIONS``.

    Returns
    -------
    ndarray, shape (..., d)
    """
    return checks.forward_differences(model, x0, t_final, V, eps,
                                      simultaneity_tol=simultaneity_tol, options=options,
                                      rtol=rtol, atol=atol, method=method,
                                      max_step=max_step)
