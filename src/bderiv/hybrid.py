"""HybridSystem: a nonlinear event-selected model and the B-derivative at its event points.

A model is a family of smooth vector fields ``field(x, mask)`` (one per region, bit k of
``mask`` set iff event k has happened, MATH.md section 1) and the event functions
``events(x)`` (event k happens when its value crosses 0 upward). :class:`HybridSystem`
checks every call of the user functions, gives their Jacobians (analytic when given, else
numerical), samples the corner table and builds the
:class:`~bderiv.bderivative.BDerivative` at an event point. Its other methods are thin:

- :meth:`HybridSystem.simulate`: event-detecting integration (:mod:`bderiv.simulate`);
- :meth:`HybridSystem.flow_bderivative`: the flow map's B-derivative, assembled here from a
  trajectory integrated with its variational equations and one ``BDerivative`` per event
  group (here rather than in :mod:`bderiv.flowmap`, which only composes given stages: the
  assembly needs the model, and the map should not import the model side);
- :meth:`HybridSystem.flow_fd`: forward differences of the simulated flow
  (:mod:`bderiv.checks`).

Missing Jacobians are computed with :func:`scipy.differentiate.jacobian` (adaptive step,
error estimate); the user functions need not be vectorised, they are wrapped.
"""

from __future__ import annotations

import numpy as np

from . import checks
from ._format import format_mask, transversality_message
from ._usercalls import check_callable, check_output, numerical_jacobian
from ._validate import check_number, check_positive_int, check_real_array
from .bderivative import BDerivative
from .flowmap import FlowBDerivative
from .simulate import EventGroup, EventRecord, SolverOptions, Trajectory, run

# EventGroup, EventRecord, Trajectory live in bderiv.simulate; re-exported for old imports
__all__ = ["EventGroup", "EventRecord", "HybridSystem", "SolverOptions", "Trajectory"]


def _spread_masks(events, mask_before):
    """Global masks of all 2**g local masks of a group (bit j of local = event events[j])."""
    g = len(events)
    local = np.arange(1 << g, dtype=np.int64)
    glob = np.full(1 << g, int(mask_before), dtype=np.int64)
    for j, k in enumerate(events):
        glob |= ((local >> j) & 1) << int(k)
    return glob


class HybridSystem:
    """A nonlinear event-selected system: region vector fields and event functions.

    Parameters
    ----------
    field : callable
        ``field(x, mask) -> (d,)``: the smooth vector field of region ``mask`` at ``x``
        (shape ``(d,)``), defined on a neighbourhood of the surfaces, across them. Bit k of
        ``mask`` is set iff event k has happened.
    events : callable
        ``events(x) -> (n,)``: the event values; event k happens when value k crosses 0
        upward.
    n_events : int
        Number of events n.
    dim : int
        State dimension d.
    event_jacobian : callable, optional
        ``event_jacobian(x) -> (n, d)``. Default: :func:`scipy.differentiate.jacobian`.
    field_jacobian : callable, optional
        ``field_jacobian(x, mask) -> (d, d)``. Default: :func:`scipy.differentiate.jacobian`
        (slow inside the variational equations; give it when you can).
    corner_field : callable, optional
        ``corner_field(x) -> (2**n, d)``: all region fields at ``x`` at once, row ``mask``
        equal to ``field(x, mask)``. Used to sample the corner table without a Python loop
        over the 2**n masks (needed for n around 16 to 20).

    Notes
    -----
    Every output of the user functions is checked (shape and finiteness); errors say which
    function, which mask, the expected and the received shape. Numerical Jacobians use
    :func:`scipy.differentiate.jacobian` (order 8, initial step 0.05, tolerances
    ``atol=1e-11, rtol=1e-10``) on a wrapper that loops over the points scipy asks for;
    inside the variational equations that costs one adaptive Jacobian per right-hand side
    evaluation, so pass ``field_jacobian`` for speed.

    Examples
    --------
    Two events of a constant field that both happen at t = 1 from the origin:

    >>> import numpy as np
    >>> from bderiv.hybrid import HybridSystem
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

    def __init__(self, field, events, *, n_events, dim, event_jacobian=None,
                 field_jacobian=None, corner_field=None):
        for f, name in ((field, "field"), (events, "events"),
                        (event_jacobian, "event_jacobian"),
                        (field_jacobian, "field_jacobian"), (corner_field, "corner_field")):
            check_callable(f, name)
        if field is None or events is None:
            raise TypeError("field and events are required callables")
        self.n_events = check_positive_int(n_events, "n_events")
        self.dim = check_positive_int(dim, "dim")
        self._field = field
        self._events = events
        self._event_jac = event_jacobian
        self._field_jac = field_jacobian
        self._corner_field = corner_field

    def __repr__(self):
        return f"HybridSystem(n_events={self.n_events}, dim={self.dim})"

    # ------------------------------------------------------------------------------
    # checked evaluations
    # ------------------------------------------------------------------------------
    def _check_state(self, x, name="x"):
        arr = check_real_array(x, name)
        if arr.shape != (self.dim,):
            raise ValueError(
                f"{name} must have shape ({self.dim},) (a state of this system), got shape "
                f"{arr.shape}"
            )
        arr = np.array(arr, dtype=np.float64)
        if not np.isfinite(arr).all():
            raise ValueError(f"{name} must be finite, got {arr}")
        return arr

    def _check_mask(self, mask):
        if isinstance(mask, bool) or not isinstance(mask, int | np.integer):
            raise TypeError(f"mask must be an integer, got {type(mask).__name__}")
        if not 0 <= mask < (1 << self.n_events):
            raise ValueError(f"mask must be in [0, 2**{self.n_events}), got {mask}")
        return int(mask)

    def eval_field(self, x, mask):
        """The checked vector field of region ``mask`` at ``x``: shape (d,)."""
        return check_output(self._field(x, mask), (self.dim,), f"field(x, mask={mask})")

    def eval_events(self, x):
        """The checked event values at ``x``: shape (n,)."""
        return check_output(self._events(x), (self.n_events,), "events(x)")

    def eval_event_jacobian(self, x):
        """Jacobian of the events at ``x``, shape (n, d) (analytic if given, else numerical)."""
        x = self._check_state(x)
        n, d = self.n_events, self.dim
        if self._event_jac is not None:
            return check_output(self._event_jac(x), (n, d), "event_jacobian(x)")
        return numerical_jacobian(self.eval_events, x, n, "events")

    def eval_field_jacobian(self, x, mask):
        """Jacobian of ``field(., mask)`` at ``x``, shape (d, d)."""
        x = self._check_state(x)
        mask = self._check_mask(mask)
        d = self.dim
        if self._field_jac is not None:
            return check_output(
                self._field_jac(x, mask), (d, d), f"field_jacobian(x, mask={mask})"
            )
        return numerical_jacobian(lambda y: self.eval_field(y, mask), x, d, "field")

    def sample_corners(self, x, masks=None):
        """Region fields at ``x`` for the given masks (default all 2**n).

        Parameters
        ----------
        x : array_like, shape (d,)
        masks : array_like of int, shape (m,), optional

        Returns
        -------
        F : ndarray, shape (m, d) (``(2**n, d)`` by default)
            ``F[i] = field(x, masks[i])``; taken from ``corner_field`` when given.
        """
        x = self._check_state(x)
        n, d = self.n_events, self.dim
        masks = (
            np.arange(1 << n, dtype=np.int64)
            if masks is None
            else np.asarray(masks, dtype=np.int64).reshape(-1)
        )
        if self._corner_field is not None and (masks.size > 16 or masks.size == 1 << n):
            table = check_output(self._corner_field(x), (1 << n, d), "corner_field(x)")
            return np.ascontiguousarray(table[masks])
        out = np.empty((masks.size, d))
        for i, m in enumerate(masks.tolist()):
            out[i] = self.eval_field(x, m)
        return out

    # ------------------------------------------------------------------------------
    # B-derivative at an event point
    # ------------------------------------------------------------------------------
    def _bderivative_at(self, x, events, mask_before, *, where="at rho"):
        """BDerivative of the group ``events`` at ``x`` entered from region ``mask_before``."""
        events = tuple(int(k) for k in events)
        Dh = self.eval_event_jacobian(x)[list(events)]
        glob = _spread_masks(events, mask_before)
        F = self.sample_corners(x, glob)
        G = F @ Dh.T
        bad = np.argwhere(~(G > 0))
        if bad.size:
            i, j = (int(v) for v in bad[0])
            region = format_mask(int(glob[i]), self.n_events)
            raise ValueError(transversality_message(events[j], region, G[i, j], where))
        return BDerivative(Dh, F)

    def bderivative(self, rho, *, tol=1e-9):
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
            With ``Dh = event_jacobian(rho)`` (n, d) and ``F[mask] = field(rho, mask)``.

        Raises
        ------
        TypeError
            If ``tol`` is not a real number.
        ValueError
            If ``tol`` is NaN, infinite or negative, if some event value exceeds ``tol``
            (the residuals are named), or when transversality fails (the mask and the
            event are named).
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
        return self._bderivative_at(rho, range(self.n_events), 0)

    # ------------------------------------------------------------------------------
    # the flow: simulation, its B-derivative, its finite differences
    # ------------------------------------------------------------------------------
    def start_mask(self, x0):
        """Region mask of a start point from the signs of its event values.

        Raises ``ValueError`` when ``x0`` lies exactly on an event surface.
        """
        x0 = self._check_state(x0, "x0")
        h = self.eval_events(x0)
        on = np.flatnonzero(h == 0)
        if on.size:
            raise ValueError(
                f"x0 lies on the surface of event(s) {on.tolist()} (events(x0) = {h}); the "
                f"region is ambiguous there: start slightly before or after the event"
            )
        return int(np.sum((h > 0).astype(np.int64) << np.arange(self.n_events)))

    def simulate(self, x0, t_final, *, simultaneity_tol=1e-12, options=None, rtol=None,
                 atol=None, method=None, max_step=None):
        """Integrate from ``x0`` at time 0 to ``t_final`` with event detection.

        Parameters
        ----------
        x0 : array_like, shape (d,)
            Start point, not on an event surface; its region comes from the event signs.
        t_final : float
            Final time, > 0.
        simultaneity_tol : float
            Events whose (first-order) time to crossing, counted from the integrator's stop
            at an event, is at most this are switched together at the stop (one group),
            provided they are at the stop to within the integration accuracy
            (:func:`bderiv.simulate.group_tolerance`). Events that already crossed inside
            the step are always switched, so none is lost when two surfaces are crossed
            inside one solver step.
        options : SolverOptions, optional
            Integrator settings (default ``SolverOptions()``: DOP853, rtol 1e-10, atol
            1e-12, no step limit).
        rtol, atol, method, max_step : optional
            Override the settings of ``options`` (see :class:`SolverOptions`).

        Returns
        -------
        Trajectory

        Raises
        ------
        TypeError, ValueError
            On a bad argument (named). ValueError also if ``x0`` lies on a surface, if an
            event that happened crosses back downward, if a switched event does not cross
            upward in its new region (transversality broken), or if an event grouped by
            ``simultaneity_tol`` is not at the stop (a smaller tolerance is suggested),
            naming the event, the mask and the time.
        """
        options = SolverOptions.resolve(options, rtol=rtol, atol=atol, method=method,
                                        max_step=max_step)
        x0 = self._check_state(x0, "x0")
        return run(self, x0, t_final, simultaneity_tol=simultaneity_tol, options=options)

    def flow_bderivative(self, x0, t_final, *, simultaneity_tol=1e-7, options=None,
                         rtol=None, atol=None, method=None, max_step=None):
        """The B-derivative of ``x -> Phi(t_final, x)`` at ``x0``.

        The nominal trajectory and its variational equations are integrated once. Events
        switched within ``simultaneity_tol`` (time) of each other form one group; each
        group gives a :class:`BDerivative` built at the group's state from the model
        (event Jacobian rows of the group, region fields around the entering mask), and
        the stage is ``D+ . M . D-`` (MATH.md section 2).

        Parameters
        ----------
        x0 : array_like, shape (d,)
        t_final : float
        simultaneity_tol : float
            Time window within which events of the nominal trajectory count as
            simultaneous (default 1e-7, well above the event-location accuracy; events in
            the window must also be at the group's point to within the integration
            accuracy, see :meth:`simulate`).
        options, rtol, atol, method, max_step
            Integrator settings, as for :meth:`simulate`.

        Returns
        -------
        FlowBDerivative
            Evaluates tangent vectors ``(..., d)``; ``final_field`` is the field at the
            final point (the derivative in the final time).
        """
        options = SolverOptions.resolve(options, rtol=rtol, atol=atol, method=method,
                                        max_step=max_step)
        x0 = self._check_state(x0, "x0")
        traj = run(self, x0, t_final, simultaneity_tol=simultaneity_tol, options=options,
                   variational=True)
        jumps = [
            self._bderivative_at(g.state, g.events, g.mask_before,
                                 where=f"at the event point at t={g.time:.10g}")
            for g in traj.groups
        ]
        return FlowBDerivative(
            traj.linear, jumps, final_field=self.eval_field(traj.x_final, traj.mask_final),
            group_times=[g.time for g in traj.groups],
            group_events=[g.events for g in traj.groups],
            x0=traj.x[0], x_final=traj.x_final, t_final=float(t_final),
        )

    def flow_fd(self, x0, t_final, V, eps, *, simultaneity_tol=checks.FD_SIMULTANEITY_TOL,
                options=None, rtol=None, atol=None, method=None, max_step=None):
        """Forward (one-sided) finite differences of the simulated flow.

        ``(Phi(t_final, x0 + eps v) - Phi(t_final, x0)) / eps`` for every vector v; see
        :func:`bderiv.checks.forward_differences` (which this calls) for why one-sided and
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
