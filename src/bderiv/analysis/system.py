"""HybridSystem: a nonlinear event-selected model and the B-derivative at its event points.

A model is a family of smooth vector fields ``field(x, mask)`` (one per region, bit k of
``mask`` set iff ``h_k(x) > 0``, mathematics.md section 1) and the event functions
``events(x)``. Along a trajectory a surface may be crossed upward (the bit is set) or
downward (cleared), any number of times; a group crossed downward is handled in its local
orientation (:mod:`bderiv.models.events.crossings`). :class:`HybridSystem`
checks every call of the user functions and gives their Jacobians (analytic when given,
else numerical). Its methods are thin:

- :meth:`HybridSystem.bderivative`: the :class:`~bderiv.engine.bderivative.BDerivative` at an
  event point, its corner table sampled from the model (:mod:`bderiv.analysis.assembly`);
- :meth:`HybridSystem.simulate`: event-detecting integration (:mod:`bderiv.models.integrate.run`);
- :meth:`HybridSystem.flow_bderivative`: the flow map's B-derivative, assembled from a
  trajectory integrated with its variational equations and one ``BDerivative`` per event
  group (:mod:`bderiv.analysis.assembly`);
- :meth:`HybridSystem.flow_fd`: forward differences of the simulated flow
  (:mod:`bderiv.analysis.checks`);
- :meth:`HybridSystem.return_map`: the B-derivative of a Poincare map
  (:mod:`bderiv.analysis.returnmap`), and :meth:`HybridSystem.periodic_orbit`: a gait found by
  Newton's method with it, with its stability (:mod:`bderiv.analysis.orbit`).

The checked evaluations of the user functions live in :class:`bderiv.models.calls.ModelCalls`.
Missing Jacobians are computed by central differences with Richardson extrapolation
(:mod:`bderiv._support._numdiff`: adaptive step, error estimate), on a compiled model in compiled
code; the user functions need not be vectorised, they are wrapped.
"""

from __future__ import annotations

import numpy as np

from .._limits import (
    DEFAULT_T_MAX,
    DERIVATIVE_SIMULTANEITY_TOL,
    FD_SIMULTANEITY_TOL,
    MAX_GROUPS,
    ON_SURFACE_TOL,
    ORBIT_MAX_ITER,
    ORBIT_TOL,
    SIMULATION_SIMULTANEITY_TOL,
)
from .._support._validate import check_number
from ..models.calls import ModelCalls
from ..models.integrate.many import Trajectories, check_states, run_many
from ..models.integrate.options import SolverOptions
from ..models.integrate.run import (
    ENDS,
    STEPS,
    EventGroup,
    EventRecord,
    check_t_eval,
    run,
)
from ..models.integrate.trajectory import Trajectory
from ..models.section import Section
from . import checks
from .assembly import flow_map_along, point_bderivative
from .orbit import ORBIT_OPTIONS, periodic_orbit
from .returnmap import return_map

# EventGroup, EventRecord, Trajectory live in models.integrate.run: the types the methods
# return, re-exported beside the model
__all__ = ["EventGroup", "EventRecord", "HybridSystem", "SolverOptions", "Trajectories",
           "Trajectory"]


class HybridSystem(ModelCalls):
    """A nonlinear event-selected system: region vector fields and event functions.

    Parameters
    ----------
    field : callable
        ``field(x, mask) -> (d,)``: the smooth vector field of region ``mask`` at ``x``
        (shape ``(d,)``), defined on a neighbourhood of the surfaces, across them. Bit k of
        ``mask`` is set iff event k has happened.
    events : callable
        ``events(x) -> (n,)``: the event values h(x); the region's bit k is set iff
        ``h_k(x) > 0``, and a crossing of ``h_k = 0`` in either direction is an event.
    n_events : int
        Number of events n.
    dim : int
        State dimension d.
    event_jacobian : callable, optional
        ``event_jacobian(x) -> (n, d)``. Default: numerical (see Notes); on a compiled
        model the complex step of ``events`` where they compile for complex input.
    field_jacobian : callable, optional
        ``field_jacobian(x, mask) -> (d, d)``. Default: numerical (slow inside the
        variational equations of a Python model; give it when you can); on a compiled
        model computed in compiled code (complex step, else central differences).
    corner_field : callable, optional
        ``corner_field(x) -> (2**n, d)``: all region fields at ``x`` at once, row ``mask``
        equal to ``field(x, mask)``. Used to sample the corner table without a Python loop
        over the 2**n masks (needed for n around 16 to 20).
    reset : callable, optional
        ``reset(x, mask, k) -> (d,)``: the state right after event k is crossed at ``x``
        from region ``mask`` (an impact; mathematics.md section 9; bit k of ``mask`` set: a
        downward crossing, return ``x`` for no jump). The state may land on the far side
        (its bit flips) or back on the side it came from: a bounce (``[q, -e v]`` for a
        ball) or a leg swap keeps the bit, and the next crossing of that surface is a new
        event (:func:`bderiv.models.events.crossings.landing` decides; ``EventGroup.bounced``).
        Simultaneous events are reset one after the other, in ascending order, each with
        the mask before the group with the bits of the events already reset flipped;
        their resets must commute (checked, :func:`bderiv.models.events.crossings.apply_resets`)
        and
        must not move the surfaces still pending. Default: no jump.
    reset_jacobian : callable, optional
        ``reset_jacobian(x, mask, k) -> (d, d)``. Default: numerical.
    check_jacobians : bool
        Compare each given Jacobian (and a ``section_gradient``) with a central difference
        of its function along a random direction the first time it is used for each mask
        (and event), and refuse a mismatch (default True; the cost is one numerical
        directional derivative per mask). :func:`bderiv.check_jacobians` reports them
        all at a point.
    params : array_like, shape (m,), optional
        Parameter values: every function above then takes ``x`` of shape (d + m,), the
        state followed by ``params`` (Jacobians are still by the state: (n, d), (d, d));
        the methods and a Poincare section take the state alone. With compiled functions
        a model with other values is another ``HybridSystem`` over the same dispatchers,
        not another compilation (a stability map builds one per grid point).

    Notes
    -----
    Every output of the user functions is checked (shape and finiteness); errors say which
    function, which mask, the expected and the received shape.

    Compiled models: when ``field`` is a ``numba.njit`` dispatcher, every run is
    integrated by the compiled DOP853 (``method`` must be ``"DOP853"``); ``events`` and a
    given ``field_jacobian`` must then be compiled too, and so must a Poincare section
    (:meth:`return_map`, :meth:`periodic_orbit`). With ``event_jacobian`` compiled (or
    none, and ``events`` compiling for complex input) and ``reset`` compiled if given, the
    stops are decided in compiled code as well: a run is one compiled call. ``repr()``
    says how a model runs after its first run; the tutorial (section 12) says how to write
    one.

    A Jacobian not given is computed by the complex step where the function takes complex
    input (:func:`bderiv.complex_step_jacobian`: d calls, exact to rounding), held to a
    central difference at its first use for each mask (and event): a function that is
    not complex-analytic (``abs``, ``x.real``) fails that. Otherwise by central
    differences with Richardson extrapolation (:mod:`bderiv._support._numdiff`: steps from an
    eighth of each variable's magnitude, smaller and larger ones tried until each entry's
    error estimate is below 1e-7 of the entry), refused, naming the function, mask, entry
    and estimated error, where no step reaches that. These cost 10 to 100 calls of the
    function per variable; inside the variational equations of :meth:`flow_bderivative`
    that is one Jacobian per right-hand side evaluation, typically 90 % of the time: pass
    ``field_jacobian``. :attr:`numerical_jacobian_cost` says what they cost so far, the
    first one of each kind is logged (logger ``"bderiv"``, level INFO) with how it is
    computed, and a build (flow map, return map, orbit) of over 2 s spent mostly in them
    is reported at WARNING with their count, calls and time, once per model.

    Examples
    --------
    Two events of a constant field that both happen at t = 1 from the origin:

    >>> import numpy as np
    >>> from bderiv.analysis.system import HybridSystem
    >>> F = np.array([[1.0, 1.0], [1.0, 2.0], [2.0, 1.0], [1.5, 1.5]])
    >>> sys = HybridSystem(lambda x, mask: F[mask], lambda x: x - 1.0, n_events=2, dim=2)
    >>> sys.bderivative(np.ones(2))(np.array([-1.0, -2.0]))
    array([-1.75, -2.25])
    >>> traj = sys.simulate(np.zeros(2), 2.0, simultaneity_tol=1e-9)
    >>> [(round(g.time, 9), g.events) for g in traj.groups]
    [(1.0, (0, 1))]
    >>> D = sys.flow_bderivative(np.zeros(2), 2.0)
    >>> D(np.array([-1.0, -2.0])).round(9)
    array([-1.75, -2.25])
    """

    def __repr__(self):
        head = f"HybridSystem(n_events={self.n_events}, dim={self.dim}"
        reset_jac = [] if self._reset_jac is not None or not self.has_resets else \
            ["reset_jacobian"]
        if self._compiled_functions is not None:  # the compiled path says how it runs
            how = ("functions checked at the first use" if self._compiled is None
                   else self._compiled.describe())
            numerical = f", numerical: {reset_jac[0]}" if reset_jac else ""
            return f"{head}, compiled: {how}{numerical})"
        missing = [name for name, f in (("event_jacobian", self._event_jac),
                                        ("field_jacobian", self._field_jac)) if f is None]
        missing += reset_jac
        numerical = f", numerical: {', '.join(missing)}" if missing else ""
        return f"{head}{numerical})"

    # ------------------------------------------------------------------------------
    # B-derivative at an event point
    # ------------------------------------------------------------------------------
    def bderivative(self, rho, *, tol=ON_SURFACE_TOL):
        """The B-derivative (PL saltation map) at a point where all n events are 0.

        Parameters
        ----------
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
            decides as :meth:`simulate` does), and the reset Jacobians there
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
            accurate to ``reset_tol``), as :meth:`simulate` refuses them.
        """
        tol = check_number(tol, "tol", strict=False)
        rho = self._check_state(rho, "rho")
        h = self.eval_events(rho)
        off = np.flatnonzero(np.abs(h) > tol)
        if off.size:
            raise ValueError(
                f"rho is not a point where all {self.n_events} events happen: events(rho) = "
                f"{h}; residuals above tol={tol:g} for events {off.tolist()} "
                f"(values {h[off].tolist()})"
            )
        return point_bderivative(self, rho, tol)

    # ------------------------------------------------------------------------------
    # the flow: simulation, its B-derivative, its finite differences
    # ------------------------------------------------------------------------------
    def simulate(self, x0, t_final, *, simultaneity_tol=SIMULATION_SIMULTANEITY_TOL,
                 options=None, rtol=None, atol=None, method=None, max_step=None,
                 max_groups=MAX_GROUPS, section=None, t_eval=None):
        """Integrate from ``x0`` at time 0 to ``t_final`` with event detection.

        Parameters
        ----------
        x0 : array_like, shape (d,)
            Start point, not on an event surface; its region comes from the event signs.
        t_final : float
            Final time, > 0.
        simultaneity_tol : float
            Events at the integrator's stop to within the integration accuracy that are
            crossing are switched together at the stop (one group: nothing orders them;
            :mod:`bderiv.models.events.locate`), and so are events that already crossed
            inside the step, so none is lost when two surfaces are crossed inside one
            solver step. Those whose time is known only to more than this are integrated
            again more tightly where a derivative is computed. Events within this time of
            crossing but measurably later are switched at their own time: the trajectory
            is the true one (a flow map merges such groups: :meth:`flow_bderivative`).
        options : SolverOptions, optional
            Integrator settings (default ``SolverOptions()``: DOP853, rtol 1e-10, atol
            1e-12, no step limit).
        rtol, atol, method, max_step : optional
            Override the settings of ``options`` (see :class:`SolverOptions`); a compiled
            model takes ``method="DOP853"`` only (its compiled integrator).
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
        options = SolverOptions.resolve(options, rtol=rtol, atol=atol, method=method,
                                        max_step=max_step)
        x0 = self._check_state(x0, "x0")
        if section is not None:
            section = Section(section, self.dim)
        return run(self, x0, t_final, simultaneity_tol=simultaneity_tol, options=options,
                   max_groups=max_groups, section=section,
                   record=self._record(t_eval, t_final))

    def _record(self, t_eval, t_final):
        """``run``'s ``record`` for ``t_eval``: every step (None) or the checked times."""
        if t_eval is None:
            return STEPS
        return check_t_eval(t_eval, check_number(t_final, "t_final"), self.dim)

    def simulate_many(self, X0, t_final, *, simultaneity_tol=SIMULATION_SIMULTANEITY_TOL,
                      options=None, rtol=None, atol=None, method=None, max_step=None,
                      max_groups=MAX_GROUPS, section=None, progress=None, t_eval=None):
        """:meth:`simulate` from every start state of a batch.

        Each run is the one :meth:`simulate` makes from that state (the same trajectory,
        to the bit). On a compiled model whose stops are decided in compiled code (its
        event Jacobian given compiled or had by complex step, its resets compiled) the runs go on
        ``numba.config.NUMBA_NUM_THREADS`` threads, whose compiled stretches run at once
        (the compiled run releases the GIL; the Python parts of the runs take turns);
        otherwise one after the other in this thread, where threads would only take turns
        at the GIL (:mod:`bderiv.models.integrate.many`). Ctrl-C stops the batch within a
        second.

        Parameters
        ----------
        X0 : array_like, shape (m, d) or (..., d)
            Start states, one per row; each not on an event surface.
        t_final : float
            Final time, > 0 (with ``section``: the longest time to wait).
        simultaneity_tol, options, rtol, atol, method, max_step, max_groups, section
            As for :meth:`simulate`, the same for every run.
        progress : None, bool or callable ``progress(done, total)``, optional
            None: a bar of the runs done, drawn once the batch has lasted a few seconds
            (on a terminal); False: none; True: a tqdm bar from the start; a callable:
            called after each run (in the calling thread, as runs finish).
        t_eval : array_like, shape (k,), optional
            As for :meth:`simulate`: the times at which each run keeps its state
            (``()``: none, the final states and the events only).

        Returns
        -------
        Trajectories
            ``trajectories`` (one :class:`Trajectory` per start state, also by ``len``,
            iteration and ``runs[i]``), ``x_final`` of shape (..., d) and ``mask_final``
            of shape (...).

        Raises
        ------
        TypeError, ValueError
            On a bad argument (named; ``X0`` of another shape than (..., d), or not
            finite: the row is named); a run's ValueError or RuntimeError with the index
            and value of its start state before the message (the first failing run in
            the order of ``X0``, as a loop would raise it).

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
        options = SolverOptions.resolve(options, rtol=rtol, atol=atol, method=method,
                                        max_step=max_step)
        X0, lead = check_states(X0, self.dim)
        if section is not None:
            section = Section(section, self.dim)
        return run_many(self, X0, lead, t_final, simultaneity_tol=simultaneity_tol,
                        options=options, max_groups=max_groups, section=section,
                        progress=progress, record=self._record(t_eval, t_final))

    def flow_bderivative(self, x0, t_final, *, simultaneity_tol=DERIVATIVE_SIMULTANEITY_TOL,
                         options=None, rtol=None, atol=None, method=None, max_step=None):
        """The B-derivative of ``x -> Phi(t_final, x)`` at ``x0``.

        The nominal trajectory and its variational equations are integrated once. Events
        switched within ``simultaneity_tol`` (time) of each other form one group; each
        group gives a :class:`BDerivative` built at the group's state from the model
        (event Jacobian rows of the group, region fields around the entering mask, in the
        group's local orientation: rows negated for events crossed downward), and the
        stage is ``D+ . M . D-`` (mathematics.md section 2).

        Parameters
        ----------
        x0 : array_like, shape (d,)
        t_final : float
        simultaneity_tol : float
            Time window within which events of the nominal trajectory count as
            simultaneous (default 1e-7, well above the event-location accuracy). The run
            switches each event at its own time (:meth:`simulate`); groups whose events
            cross within this time of the first of them are merged into one, the group's
            map at the nearby point where they are simultaneous, and
            ``FlowBDerivative.group_spreads`` says how far apart they were (a smaller
            tolerance gives the separated events' map: docs/mathematics.md, section 7,
            "Events close together"). A stretch whose events' times are known less well
            than this is integrated again more tightly until they are decided (section
            11).
        options, rtol, atol, method, max_step
            Integrator settings, as for :meth:`simulate`.

        Returns
        -------
        FlowBDerivative
            Evaluates tangent vectors ``(..., d)``; ``final_field`` is the field at the
            final point (the derivative in the final time). An event group within
            ``simultaneity_tol`` of ``t_final`` (either side) has the final time as one
            more event: its jumps apply only to the directions for which they come before
            it (``stops_at_group``; mathematics.md section 7). Refused there with resets.
        """
        options = SolverOptions.resolve(options, rtol=rtol, atol=atol, method=method,
                                        max_step=max_step)
        x0 = self._check_state(x0, "x0")
        with self.numerical_jacobian_watch("flow_bderivative"):
            traj = run(self, x0, t_final, simultaneity_tol=simultaneity_tol, options=options,
                       variational=True, record=ENDS)
            return self.flow_map_along(traj)

    def flow_map_along(self, traj):
        """The :class:`FlowBDerivative` along a trajectory integrated with its variational
        equations (``run(..., variational=True)``):
        :func:`bderiv.analysis.assembly.flow_map_along`."""
        return flow_map_along(self, traj)

    # ------------------------------------------------------------------------------
    # gaits: return maps and periodic orbits
    # ------------------------------------------------------------------------------
    def return_map(self, x0, section, *, section_gradient=None, t_max=DEFAULT_T_MAX,
                   tol=ON_SURFACE_TOL, simultaneity_tol=DERIVATIVE_SIMULTANEITY_TOL, options=None,
                   rtol=None, atol=None, method=None, max_step=None):
        """The B-derivative of the Poincare map of ``section(x) = 0`` at x0 on it.

        Parameters
        ----------
        x0 : array_like, shape (d,)
            A point of the section: ``|section(x0)| <= tol``.
        section : callable
            ``section(x) -> float``; the flow must cross ``section = 0`` upward (from < 0
            to > 0), transversally, at x0 and at the return. A ``numba.njit`` dispatcher
            on a compiled model (required there).
        section_gradient : callable, optional
            ``section_gradient(x) -> (d,)``; numerical by default.
        t_max : float
            Longest time to wait for the return.
        tol : float
            Largest accepted ``|section(x0)|``.
        simultaneity_tol, options, rtol, atol, method, max_step
            As for :meth:`flow_bderivative`.

        Returns
        -------
        ReturnMap
            A :class:`FlowBDerivative` (``__call__``, ``event_times``, ``orders``,
            ``piece``) mapping tangent vectors ``(..., d)`` at x0 to tangent vectors at
            ``P(x0)``, with the correction for the change in return time
            (:mod:`bderiv.analysis.returnmap`); ``period`` is the return time.
        """
        options = SolverOptions.resolve(options, rtol=rtol, atol=atol, method=method,
                                        max_step=max_step)
        x0 = self._check_state(x0, "x0")
        section = Section(section, self.dim, section_gradient, self.check_jacobians)
        with self.numerical_jacobian_watch("return_map"):
            return return_map(self, x0, section,
                              t_max=check_number(t_max, "t_max"),
                              tol=check_number(tol, "tol", strict=False),
                              simultaneity_tol=simultaneity_tol, options=options)[0]

    def periodic_orbit(self, x_guess, section, period_guess=None, *, section_gradient=None,
                       tol=ORBIT_TOL, max_iter=ORBIT_MAX_ITER,
                       simultaneity_tol=DERIVATIVE_SIMULTANEITY_TOL, options=None, cyclic=()):
        """A periodic orbit through the section ``section(x) = 0``: ``P(x) = x``.

        Newton's method with the return map's B-derivative, the piecewise-linear Newton
        equation solved exactly (:mod:`bderiv.analysis.orbit` says how and why).

        Parameters
        ----------
        x_guess : array_like, shape (d,)
            A guess near the section (it is moved onto it first).
        section, section_gradient
            As for :meth:`return_map`.
        period_guess : float, optional
            Expected period: the return is awaited for 3 times it (default 100).
        tol : float
            Stop when ``max |P(x) - x| <= tol * max(1, max |x|)``.
        max_iter : int
            Largest number of Newton iterations.
        simultaneity_tol : float
            For the orbit's return map, as for :meth:`flow_bderivative`.
        options : SolverOptions, optional
            Default ``SolverOptions(rtol=1e-12, atol=1e-13)``.
        cyclic : sequence of int
            Coordinates the model and the section do not depend on (a forward position,
            a heading): left out of ``P(x) = x`` and of the stability, their advance per
            period in ``PeriodicOrbit.advance`` (checked:
            :func:`bderiv.analysis.orbit.periodic_orbit`).

        Returns
        -------
        PeriodicOrbit
            With ``x0``, ``period``, ``trajectory``, ``return_map``, ``residual``,
            ``history``, ``advance`` and ``stability()``.
        """
        x_guess = self._check_state(x_guess, "x_guess")
        options = SolverOptions.resolve(options, ORBIT_OPTIONS)
        section = Section(section, self.dim, section_gradient, self.check_jacobians)
        with self.numerical_jacobian_watch("periodic_orbit"):
            return periodic_orbit(self, x_guess, section,
                                  period_guess=period_guess, tol=tol, max_iter=max_iter,
                                  simultaneity_tol=simultaneity_tol, options=options,
                                  cyclic=cyclic)

    def flow_fd(self, x0, t_final, V, eps, *, simultaneity_tol=FD_SIMULTANEITY_TOL,
                options=None, rtol=None, atol=None, method=None, max_step=None):
        """Forward (one-sided) finite differences of the simulated flow.

        ``(Phi(t_final, x0 + eps v) - Phi(t_final, x0)) / eps`` for every vector v; see
        :func:`bderiv.analysis.checks.forward_differences` (which this calls) for why one-sided and
        why the integrator settings default to the tight ``checks.FD_OPTIONS``.

        Parameters
        ----------
        x0 : array_like, shape (d,)
        t_final : float
        V : array_like, shape (..., d)
            Tangent vectors.
        eps : float
            Step, > 0.
        simultaneity_tol, options, rtol, atol, method, max_step
            As for :meth:`simulate`; defaults ``checks.FD_SIMULTANEITY_TOL`` and
            ``checks.FD_OPTIONS``.

        Returns
        -------
        ndarray, shape (..., d)
        """
        options = SolverOptions.resolve(options, checks.FD_OPTIONS, rtol=rtol, atol=atol,
                                        method=method, max_step=max_step)
        return checks.forward_differences(self, x0, t_final, V, eps,
                                          simultaneity_tol=simultaneity_tol, options=options)
