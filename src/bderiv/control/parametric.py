"""Flows in the state and the parameters: a parameter is a state that does not move.

A model written with ``params`` (:class:`~bderiv.analysis.system.HybridSystem`: every
function takes ``z = (x, p)``, the state followed by the m parameter values) has, over the
augmented state ``z`` with ``p' = 0``, the flow ``(x, p) -> (Phi_p(t, x), p)``. Its
B-derivative at ``(x0, p)`` is the B-derivative of ``Phi`` in the state *and* the
parameter directions: the last m columns of each piece are ``d Phi / d p`` through the
same event groups, with the event-time changes that the parameters cause (the saltation
terms see the parameter components of the event Jacobian). So the derivative in the
parameter directions is no new mathematics: :func:`augment` builds the augmented model
from the same functions, and :class:`ParametricFlow` reads off, per step,

- the next state, simulated;
- the step's :class:`~bderiv.FlowBDerivative` ``D`` of dimension d + m;
- the order in which the nominal trajectory met the events of each of ``D``'s groups
  (:func:`nominal_orders`), whose piece ``P`` (d + m, d + m) gives ``A = P[:d, :d]``
  (d, d) and ``B = P[:d, d:]`` (d, m).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .._limits import SIMULATION_SIMULTANEITY_TOL
from .._support._validate import check_number, check_state
from .._support._validate_ints import check_positive_int
from ..analysis.system import HybridSystem
from ..models.integrate.options import DERIVATIVE_OPTIONS, SolverOptions

__all__ = ["ParametricFlow", "Step", "StepEndsAtImpact", "augment", "nominal_orders"]


class StepEndsAtImpact(ValueError):
    """A step whose end ``dt`` lies within the B-derivatives' ``simultaneity_tol`` of an
    event with a reset: the step's flow map jumps there and has no B-derivative
    (:meth:`ParametricFlow.step`). ``event`` and ``time`` (from the step's start) name
    the impact."""

    def __init__(self, message, event, time):
        super().__init__(message)
        self.event, self.time = event, time


def _augmented_functions(field, events, reset, d, m):
    """Python functions of the augmented model from functions of ``z = (x, p)``."""

    def sized(value, name):
        value = np.asarray(value)
        if value.shape != (d,):
            raise ValueError(f"{name} must return shape ({d},) (the state, dim = {d}), got "
                             f"shape {value.shape}")
        return value

    def aug_field(z, mask):
        out = np.zeros(d + m, dtype=np.result_type(z, np.float64))
        out[:d] = sized(field(z, mask), "field(z, mask)")
        return out

    aug_reset = None
    if reset is not None:
        def aug_reset(z, mask, k):
            out = np.array(z, dtype=np.float64)
            out[:d] = sized(reset(z, mask, k), "reset(z, mask, k)")
            return out

    return aug_field, events, aug_reset


def _compiled_augmented(field, events, reset, d, m):
    """The same as numba functions (compiled at their first call, in each process: a
    closure over another dispatcher is not kept in numba's disk cache)."""
    import numba

    @numba.njit
    def aug_field(z, mask):
        value = field(z, mask)
        if value.shape[0] != d:
            raise ValueError("field(z, mask) must return the state's dim entries")
        out = np.zeros_like(z)
        out[:d] = value
        return out

    aug_reset = None
    if reset is not None:
        @numba.njit
        def aug_reset(z, mask, k):
            value = reset(z, mask, k)
            if value.shape[0] != d:
                raise ValueError("reset(z, mask, k) must return the state's dim entries")
            out = z.copy()
            out[:d] = value
            return out

    return aug_field, events, aug_reset


def augment(field, events, *, n_events, dim, n_params, reset=None) -> HybridSystem:
    """The model over ``z = (x, p)`` (dimension ``dim + n_params``, ``p' = 0``) from the
    functions of a ``params`` model.

    Parameters
    ----------
    field : callable
        ``field(z, mask) -> (dim,)``, ``z`` of shape (dim + n_params,): the functions one
        passes to ``HybridSystem(..., params=p)``.
    events : callable
        ``events(z) -> (n_events,)``.
    n_events, dim, n_params : int
    reset : callable, optional
        ``reset(z, mask, k) -> (dim,)``.

    Returns
    -------
    HybridSystem
        Of dimension ``dim + n_params``; Jacobians numerical (complex step in compiled
        code for numba functions). Numba dispatchers give a compiled model whose wrappers
        close over them: numba cannot keep such closures in its disk cache, so they
        compile again in every process (seconds, at the first run). For a compiled model
        used in many processes, write the augmented functions directly, the field's last
        ``n_params`` entries 0, with ``numba.njit(cache=True)``, and pass them to
        :class:`~bderiv.analysis.system.HybridSystem` (as :mod:`.models` does).
    """
    d, m = check_positive_int(dim, "dim"), check_positive_int(n_params, "n_params")
    compiled = all(hasattr(f, "py_func") for f in (field, events))
    make = _compiled_augmented if compiled else _augmented_functions
    aug_field, aug_events, aug_reset = make(field, events, reset, d, m)
    return HybridSystem(aug_field, aug_events, n_events=n_events, dim=d + m, reset=aug_reset)


@dataclass(frozen=True)
class Step:
    """One step of a parametric flow from ``(x, p)`` over ``dt``.

    Attributes
    ----------
    x_next : ndarray, shape (d,)
        The state at the end of the step (the flow map's run: each event switched at its
        own time).
    D : FlowBDerivative or None
        The B-derivative of ``(x, p) -> (x_next, p)``, dimension d + m.
    orders : list of list of int
        The local event order of each of ``D``'s groups along the nominal trajectory
        (:func:`nominal_orders`).
    ties : tuple of int
        The groups whose events the nominal trajectory crossed at one integrator stop (no
        order measurable: ``orders`` lists them ascending, a piece of the B-derivative all
        the same).
    A : ndarray, shape (d, d)
        ``P[:d, :d]`` of the piece ``P = D.piece(orders)``.
    B : ndarray, shape (d, m)
        ``P[:d, d:]``: the derivative in the parameter directions.
    groups : tuple of tuple of int
        ``D.group_events``: the global events of each group.
    """

    x_next: np.ndarray
    D: object
    orders: list
    ties: tuple
    A: np.ndarray
    B: np.ndarray
    groups: tuple


def nominal_orders(D, events, t_final):
    """The order in which a trajectory met the events of each group of ``D``.

    Parameters
    ----------
    D : FlowBDerivative
        Built along the trajectory (its groups possibly merged over a window).
    events : sequence of EventRecord
        The trajectory's event log, from a run with a small ``simultaneity_tol`` (each
        event switched at its own time).
    t_final : float
        The end of the run: a group at the final time (``D.stops_at_group``) has the final
        time as its last local event, placed after the events crossed before it.

    Returns
    -------
    orders : list of list of int
        Local indices of each group, by crossing time (ascending index among equal times).
    ties : tuple of int
        The groups with two events crossed at the same time.
    """
    orders, ties = [], []
    for i, (glob, t0) in enumerate(zip(D.group_events, D.group_times, strict=True)):
        span = D.group_spreads[i] + max(1e-9, 1e-9 * abs(t0))
        times = []
        for e in glob:
            hits = [r.time for r in events if r.event == e and -span <= r.time - t0 <= span]
            times.append(min(hits, key=lambda t, t0=t0: abs(t - t0)) if hits else np.inf)
        final = D.stops_at_group and i == D.n_groups - 1
        if final:  # the final time is local event len(glob); events not yet crossed after
            times.append(float(t_final))
        order = sorted(range(len(times)), key=lambda k: (times[k], k))
        if final:
            n_g = len(glob)
            order = [k for k in order if times[k] <= t_final and k != n_g] + [n_g] + \
                [k for k in order if times[k] > t_final]
        crossed = sorted(t for t in times if np.isfinite(t))
        if any(b - a <= 0.0 for a, b in zip(crossed, crossed[1:], strict=False)):
            ties.append(i)
        orders.append(order)
    return orders, tuple(ties)


class ParametricFlow:
    """The flow of a model in its state and its parameters, step by step.

    Parameters
    ----------
    system : HybridSystem
        The augmented model over ``z = (x, p)`` (:func:`augment`, or a model written so:
        its field's last ``n_params`` entries zero).
    n_params : int
        m: the last m coordinates of ``z`` are the parameters.
    simultaneity_tol : float, optional
        Window of the steps' B-derivatives (``flow_bderivative``), > 0 (default
        ``DERIVATIVE_SIMULTANEITY_TOL``, 1e-7): events crossed within it form one group,
        whose piece is chosen by the order the nominal trajectory took.
    options : SolverOptions, optional
        Settings of every run (its ``simultaneity_tol`` that of the B-derivatives; one
        given as a keyword too must agree with it); the simulations keep
        ``simulate``'s own ``simultaneity_tol``.

    Attributes
    ----------
    dim, n_params : int
        d and m.
    options : SolverOptions
        The settings of the B-derivatives (``simultaneity_tol`` set, also as the attribute
        ``simultaneity_tol``).
    defaults : ndarray, shape (m,), or None
        Parameter values a model builder suggests (:mod:`.models`).
    x0 : ndarray, shape (d,), or None
        A start state a model builder suggests.
    """

    def __init__(self, system, n_params, *, simultaneity_tol=None, options=None):
        if not isinstance(system, HybridSystem):
            raise TypeError(f"system must be a HybridSystem (the augmented model), got "
                            f"{type(system).__name__}")
        m = check_positive_int(n_params, "n_params")
        if m >= system.dim:
            raise ValueError(f"n_params must be below the system's dimension {system.dim} "
                             f"(state first, then the parameters), got {m}")
        self.system, self.n_params, self.dim = system, m, system.dim - m
        self.options = SolverOptions.resolve(options, DERIVATIVE_OPTIONS,
                                             simultaneity_tol=simultaneity_tol)
        self.simultaneity_tol = check_number(self.options.simultaneity_tol, "simultaneity_tol")
        self._simulation = self.options.with_overrides(
            simultaneity_tol=SIMULATION_SIMULTANEITY_TOL)
        self.defaults = self.x0 = None

    def _z(self, x, p):
        x = check_state(x, self.dim, "x", meaning=f"a state of the model, d = {self.dim}")
        p = check_state(p, self.n_params, "p",
                        meaning=f"the parameters' values, n_params = {self.n_params}")
        return np.concatenate((x, p))

    def rate_check(self, x, p):
        """Refuse a model whose parameters move: the field's last m entries at ``(x, p)``
        (in the region of the start) must be 0 (ValueError naming them); returns the
        checked ``z = (x, p)``."""
        z = self._z(x, p)
        mask = self.system.calls.start_mask(z)
        rate = np.asarray(self.system.calls.eval_field(z, mask))[self.dim:]
        if np.any(rate != 0):
            raise ValueError(f"the parameters must not move: the augmented model's "
                             f"field(z, mask)[{self.dim}:] must be 0 (the last n_params = "
                             f"{self.n_params} coordinates of z are the parameters), got "
                             f"{rate} at z = {z}, mask {mask}")
        return z

    def final(self, x, p, dt):
        """The state at ``dt`` from ``x`` under parameters ``p``: shape (d,)."""
        z = self.rate_check(x, p)
        traj = self.system.simulate(z, check_number(dt, "dt"), options=self._simulation,
                                    t_eval=())
        return traj.x_final[:self.dim].copy()

    def step(self, x, p, dt, *, orders=None):
        """Simulate one step and linearise it along the nominal trajectory.

        Parameters
        ----------
        x : array_like, shape (d,)
        p : array_like, shape (m,)
        dt : float
        orders : callable, optional
            How each group's piece is chosen: None for the nominal trajectory's order
            (default), or ``orders(group_events, at_final_time) -> local order`` (a fixed
            order, for comparisons; ``Step.orders`` still reports the nominal's).

        Returns
        -------
        Step

        Raises
        ------
        StepEndsAtImpact
            A ValueError: an event with a reset within ``simultaneity_tol`` of the step's
            end ``dt`` (either side).
        """
        z, dt = self.rate_check(x, p), check_number(dt, "dt")
        try:
            D = self.system.flow_bderivative(z, dt, options=self.options)
        except ValueError:
            impact = self._impact_near(z, dt) if self.system.reset is not None else None
            if impact is None:
                raise
            raise StepEndsAtImpact(
                f"the step over dt = {dt!r} ends at an impact: event {impact.event} (with a "
                f"reset) crosses at t = {impact.time!r} from the step's start, within "
                f"simultaneity_tol = {self.simultaneity_tol!r} of its end, so the step's "
                f"flow map jumps there and has no B-derivative; choose a step length dt "
                f"whose end avoids the impact", impact.event, impact.time) from None
        if any(s > 0 for s in D.group_spreads) or D.stops_at_group:
            # the crossing times within a merged group: the run's own event log
            events = self.system.simulate(z, dt, options=self._simulation, t_eval=()).events
            nominal, ties = nominal_orders(D, events, dt)
        else:  # every group crossed at one stop: no order measurable, ascending
            nominal = [list(range(J.n_events)) for J in D.jumps]
            ties = tuple(i for i, J in enumerate(D.jumps) if J.n_events > 1)
        chosen = nominal if orders is None else [list(orders(g, D.stops_at_group and
                                                             i == D.n_groups - 1))
                                                 for i, g in enumerate(D.group_events)]
        P = D.piece(chosen) if D.n_groups else D.piece()
        d = self.dim
        return Step(x_next=D.x_final[:d].copy(), D=D, orders=nominal, ties=ties,
                    A=P[:d, :d], B=P[:d, d:], groups=D.group_events)

    def _impact_near(self, z, dt):
        """The event record within twice ``simultaneity_tol`` of ``dt`` (either side) on a
        run a little past it, or None (the run refused too: None)."""
        tol = 2.0 * self.simultaneity_tol
        try:
            events = self.system.simulate(z, dt + tol, options=self._simulation,
                                          t_eval=()).events
        except ValueError:
            return None
        near = [r for r in events if abs(r.time - dt) <= tol]
        return min(near, key=lambda r: abs(r.time - dt)) if near else None
