"""HybridSystem: from a nonlinear event-selected model to B-derivatives of its flow.

A model is a family of smooth vector fields ``field(x, mask)`` (one per region, bit k of
``mask`` set iff event k has happened, MATH.md section 1) and the event functions
``events(x)`` (event k happens when its value crosses 0 upward). This module

- samples the corner table and the event Jacobian at an event point and builds the
  :class:`~bderiv.bderivative.BDerivative` there (:meth:`HybridSystem.bderivative`);
- integrates the model with event detection (:meth:`HybridSystem.simulate`), grouping
  events that happen within a tolerance and never losing one;
- composes the classical derivatives of the smooth stretches (variational equations,
  integrated once alongside the trajectory) with one ``BDerivative`` per event group into
  a :class:`~bderiv.flowmap.FlowBDerivative` (:meth:`HybridSystem.flow_bderivative`);
- gives one-sided finite differences of the simulated flow for checks
  (:meth:`HybridSystem.flow_fd`).

Missing Jacobians are computed with :func:`scipy.differentiate.jacobian` (adaptive step,
error estimate); the user functions need not be vectorised, they are wrapped.
"""

from __future__ import annotations

from dataclasses import dataclass
from dataclasses import field as dc_field
from typing import NamedTuple

import numpy as np
from scipy.differentiate import jacobian as _scipy_jacobian
from scipy.integrate import solve_ivp

from ._validate import check_positive_int, check_real_array
from .bderivative import BDerivative
from .flowmap import FlowBDerivative

__all__ = ["EventGroup", "EventRecord", "HybridSystem", "Trajectory"]

#: Tolerances of :func:`scipy.differentiate.jacobian` for missing Jacobians.
_JAC_TOLERANCES = {"atol": 1e-11, "rtol": 1e-10}
_JAC_INITIAL_STEP = 0.05
#: Refuse trajectories with more event groups than this (chattering or a broken model).
_MAX_GROUPS_FACTOR = 50


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
    """Result of :meth:`HybridSystem.simulate`.

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
        by :meth:`HybridSystem.flow_bderivative`, empty for :meth:`HybridSystem.simulate`.
    """

    t: np.ndarray
    x: np.ndarray
    masks: np.ndarray
    events: tuple
    groups: tuple
    x_final: np.ndarray
    mask_final: int
    linear: tuple = dc_field(default=(), repr=False)


def _check_callable(f, name):
    if f is not None and not callable(f):
        raise TypeError(f"{name} must be callable, got {type(f).__name__}")


def _check_output(value, shape, what):
    """Validate the output of a user function: real, of ``shape``, finite; float64 array."""
    try:
        arr = check_real_array(value, what)
    except TypeError as exc:
        raise TypeError(f"{what} must return real numbers: {exc}") from None
    if arr.shape != shape:
        raise ValueError(f"{what} must return an array of shape {shape}, got shape {arr.shape}")
    arr = np.asarray(arr, dtype=np.float64)
    if not np.isfinite(arr).all():
        idx = tuple(int(i) for i in np.argwhere(~np.isfinite(arr))[0])
        raise ValueError(f"{what} returned a non-finite value: entry {list(idx)} = {arr[idx]}")
    return arr


def _spread_masks(events, mask_before):
    """Global masks of all 2**g local masks of a group (bit j of local = event events[j])."""
    g = len(events)
    local = np.arange(1 << g, dtype=np.int64)
    glob = np.full(1 << g, int(mask_before), dtype=np.int64)
    for j, k in enumerate(events):
        glob |= ((local >> j) & 1) << int(k)
    return glob


def _fmt_mask(mask, n):
    return f"{mask} (binary {mask:0{n}b})"


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

    def __init__(
        self,
        field,
        events,
        *,
        n_events,
        dim,
        event_jacobian=None,
        field_jacobian=None,
        corner_field=None,
    ):
        for f, name in (
            (field, "field"),
            (events, "events"),
            (event_jacobian, "event_jacobian"),
            (field_jacobian, "field_jacobian"),
            (corner_field, "corner_field"),
        ):
            _check_callable(f, name)
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
        return _check_output(self._field(x, mask), (self.dim,), f"field(x, mask={mask})")

    def eval_events(self, x):
        """The checked event values at ``x``: shape (n,)."""
        return _check_output(self._events(x), (self.n_events,), "events(x)")

    def eval_event_jacobian(self, x):
        """Jacobian of the events at ``x``, shape (n, d) (analytic if given, else numerical)."""
        x = self._check_state(x)
        n, d = self.n_events, self.dim
        if self._event_jac is not None:
            return _check_output(self._event_jac(x), (n, d), "event_jacobian(x)")
        return self._numerical_jacobian(self.eval_events, x, n, "events")

    def eval_field_jacobian(self, x, mask):
        """Jacobian of ``field(., mask)`` at ``x``, shape (d, d)."""
        x = self._check_state(x)
        mask = self._check_mask(mask)
        d = self.dim
        if self._field_jac is not None:
            return _check_output(
                self._field_jac(x, mask), (d, d), f"field_jacobian(x, mask={mask})"
            )
        return self._numerical_jacobian(lambda y: self.eval_field(y, mask), x, d, "field")

    def _numerical_jacobian(self, fun, x, n_out, what):
        d = self.dim

        def vectorised(X):  # scipy passes (d, ...) and wants (n_out, ...)
            batch = X.shape[1:]
            flat = X.reshape(d, -1)
            out = np.empty((n_out, flat.shape[1]))
            for i in range(flat.shape[1]):
                out[:, i] = fun(flat[:, i])
            return out.reshape((n_out, *batch))

        res = _scipy_jacobian(
            vectorised, x, tolerances=_JAC_TOLERANCES, initial_step=_JAC_INITIAL_STEP
        )
        jac = np.asarray(res.df, dtype=np.float64).reshape(n_out, d)
        if not np.isfinite(jac).all():
            raise ValueError(f"the numerical Jacobian of {what} at x = {x} is not finite")
        return jac

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
            table = _check_output(self._corner_field(x), (1 << n, d), "corner_field(x)")
            return np.ascontiguousarray(table[masks])
        out = np.empty((masks.size, d))
        for i, m in enumerate(masks.tolist()):
            out[i] = self.eval_field(x, m)
        return out

    # ------------------------------------------------------------------------------
    # B-derivative at an event point
    # ------------------------------------------------------------------------------
    def _bderivative_at(self, x, events, mask_before, *, where="rho"):
        """BDerivative of the group ``events`` at ``x`` entered from region ``mask_before``."""
        events = tuple(int(k) for k in events)
        Dh = self.eval_event_jacobian(x)[list(events)]
        glob = _spread_masks(events, mask_before)
        F = self.sample_corners(x, glob)
        G = F @ Dh.T
        bad = np.argwhere(~(G > 0))
        if bad.size:
            i, j = (int(v) for v in bad[0])
            n = self.n_events
            raise ValueError(
                f"transversality fails at {where}: event {events[j]} has rate "
                f"{G[i, j]:.6g} <= 0 in region mask {_fmt_mask(int(glob[i]), n)}; every "
                f"event must cross its surface upward (Dh[k] . field(x, mask) > 0) in every "
                f"region around the event point"
            )
        return BDerivative(Dh, F)

    def bderivative(self, rho, *, tol=1e-9):
        """The B-derivative (PL saltation map) at a point where all n events are 0.

        Parameters
        ----------
        rho : array_like, shape (d,)
            The event point: ``events(rho)`` must vanish.
        tol : float
            Largest accepted ``|events(rho)[k]|``.

        Returns
        -------
        BDerivative
            With ``Dh = event_jacobian(rho)`` (n, d) and ``F[mask] = field(rho, mask)``.

        Raises
        ------
        ValueError
            If some event value exceeds ``tol`` (the residuals are named), or when
            transversality fails (the mask and the event are named).
        """
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
    # simulation
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

    def simulate(
        self,
        x0,
        t_final,
        *,
        rtol=1e-10,
        atol=1e-12,
        simultaneity_tol=1e-12,
        method="DOP853",
        max_step=np.inf,
    ):
        """Integrate from ``x0`` at time 0 to ``t_final`` with event detection.

        Parameters
        ----------
        x0 : array_like, shape (d,)
            Start point, not on an event surface; its region comes from the event signs.
        t_final : float
            Final time, > 0.
        rtol, atol : float
            Tolerances of :func:`scipy.integrate.solve_ivp`.
        simultaneity_tol : float
            Events whose (first-order) time to crossing, counted from the integrator's stop
            at an event, is at most this are switched together at the stop (one group).
            Events that already crossed inside the step are always switched, so none is
            lost when two surfaces are crossed inside one solver step.
        method : str
            Integrator of ``solve_ivp`` (default ``"DOP853"``).
        max_step : float
            Largest step of the integrator.

        Returns
        -------
        Trajectory

        Raises
        ------
        ValueError
            If ``x0`` lies on a surface, if an event that happened crosses back downward
            or if a switched event does not cross upward in its new region (transversality
            broken), naming the event, the mask and the time.
        """
        return self._run(
            x0,
            t_final,
            rtol=rtol,
            atol=atol,
            simultaneity_tol=simultaneity_tol,
            method=method,
            max_step=max_step,
            variational=False,
        )

    def _run(self, x0, t_final, *, rtol, atol, simultaneity_tol, method, max_step, variational):
        x0 = self._check_state(x0, "x0")
        t_final = float(t_final)
        if not np.isfinite(t_final) or t_final <= 0:
            raise ValueError(f"t_final must be a finite positive time, got {t_final}")
        if not simultaneity_tol >= 0:
            raise ValueError(f"simultaneity_tol must be >= 0, got {simultaneity_tol}")
        n, d = self.n_events, self.dim
        mask = self.start_mask(x0)

        cache = {"key": None, "val": None}

        def event_values(y):
            x = y[:d]
            if cache["key"] is not None and np.array_equal(cache["key"], x):
                return cache["val"]
            val = self.eval_events(x)
            cache["key"], cache["val"] = x.copy(), val
            return val

        def make_event(k, direction):
            def ev(t, y):
                return event_values(y)[k]

            ev.terminal = True
            ev.direction = direction
            return ev

        ts, xs, ms, log, groups, linear = [], [], [], [], [], []
        t, x = 0.0, x0
        max_groups = _MAX_GROUPS_FACTOR * (n + 1)
        while True:
            cur = mask

            if variational:

                def rhs(_t, y, cur=cur):
                    xx = y[:d]
                    f = self.eval_field(xx, cur)
                    J = self.eval_field_jacobian(xx, cur)
                    return np.concatenate((f, (J @ y[d:].reshape(d, d)).ravel()))

                y0 = np.concatenate((x, np.eye(d).ravel()))
            else:

                def rhs(_t, y, cur=cur):
                    return self.eval_field(y, cur)

                y0 = x
            evs = [make_event(k, -1 if cur >> k & 1 else 1) for k in range(n)]
            sol = solve_ivp(
                rhs,
                (t, t_final),
                y0,
                method=method,
                rtol=rtol,
                atol=atol,
                events=evs,
                max_step=max_step,
            )
            if sol.status == -1:
                raise RuntimeError(f"solve_ivp failed at t={sol.t[-1]:.6g}: {sol.message}")
            ts.append(sol.t)
            xs.append(sol.y[:d].T)
            ms.append(np.full(sol.t.size, cur, dtype=np.int64))
            t, y = float(sol.t[-1]), sol.y[:, -1]
            x = np.array(y[:d])
            if variational:
                linear.append(np.array(y[d:].reshape(d, d)))
            if sol.status == 0:
                break
            # a terminal event stopped the integration at t
            fired = [k for k in range(n) if sol.t_events[k].size]
            for k in fired:
                if cur >> k & 1:
                    raise ValueError(
                        f"event {k} crossed its surface downward at t={t:.10g} in region "
                        f"mask {_fmt_mask(cur, n)}: transversality is broken (an event that "
                        f"happened must stay happened)"
                    )
            h = self.eval_events(x)
            pending = [k for k in range(n) if not cur >> k & 1]
            Dh = self.eval_event_jacobian(x)
            rate_before = Dh @ self.eval_field(x, cur)
            group = []
            for k in pending:
                if k in fired or h[k] >= 0:
                    group.append(k)
                elif rate_before[k] > 0 and -h[k] / rate_before[k] <= simultaneity_tol:
                    group.append(k)
            new = cur
            for k in group:
                new |= 1 << k
            rate_after = Dh @ self.eval_field(x, new)
            for k in group:
                if not rate_after[k] > 0:
                    raise ValueError(
                        f"transversality broken at t={t:.10g}: event {k} switched but its "
                        f"rate in the new region mask {_fmt_mask(new, n)} is "
                        f"{rate_after[k]:.6g} <= 0 (it would cross back)"
                    )
            for k in group:
                log.append(EventRecord(t, k, new))
            groups.append(EventGroup(t, tuple(group), cur, new, x.copy()))
            mask = new
            if len(groups) > max_groups:
                raise RuntimeError(
                    f"more than {max_groups} event groups before t_final={t_final}: the "
                    f"trajectory chatters or the events are not event-selected"
                )
            if t >= t_final:
                break
        if variational and len(linear) == len(groups):  # stopped by an event at t_final
            linear.append(np.eye(d))
        return Trajectory(
            t=np.concatenate(ts),
            x=np.concatenate(xs),
            masks=np.concatenate(ms),
            events=tuple(log),
            groups=tuple(groups),
            x_final=x,
            mask_final=mask,
            linear=tuple(linear),
        )

    # ------------------------------------------------------------------------------
    # derivatives of the flow
    # ------------------------------------------------------------------------------
    def flow_bderivative(
        self,
        x0,
        t_final,
        *,
        simultaneity_tol=1e-7,
        rtol=1e-11,
        atol=1e-12,
        method="DOP853",
    ):
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
            simultaneous (default 1e-7, well above the event-location accuracy).
        rtol, atol, method
            Integrator settings.

        Returns
        -------
        FlowBDerivative
            Evaluates tangent vectors ``(..., d)``; ``final_field`` is the field at the
            final point (the derivative in the final time).
        """
        traj = self._run(
            x0,
            t_final,
            rtol=rtol,
            atol=atol,
            simultaneity_tol=simultaneity_tol,
            method=method,
            max_step=np.inf,
            variational=True,
        )
        jumps = []
        for g in traj.groups:
            jumps.append(
                self._bderivative_at(
                    g.state, g.events, g.mask_before, where=f"the event point at t={g.time:.10g}"
                )
            )
        return FlowBDerivative(
            traj.linear,
            jumps,
            final_field=self.eval_field(traj.x_final, traj.mask_final),
            group_times=[g.time for g in traj.groups],
            group_events=[g.events for g in traj.groups],
            x0=traj.x[0],
            x_final=traj.x_final,
            t_final=float(t_final),
        )

    def flow_fd(
        self,
        x0,
        t_final,
        V,
        eps,
        *,
        rtol=1e-12,
        atol=1e-13,
        simultaneity_tol=1e-13,
        method="DOP853",
    ):
        """Forward (one-sided) finite differences of the simulated flow.

        ``(Phi(t_final, x0 + eps v) - Phi(t_final, x0)) / eps`` for every vector v.
        One-sided on purpose: the flow is only piecewise differentiable, so the central
        quotient converges to ``(D(v) - D(-v)) / 2``, not to the B-derivative ``D(v)``.
        The error is O(eps) plus the integration error divided by eps.

        Parameters
        ----------
        x0 : array_like, shape (d,)
        t_final : float
        V : array_like, shape (..., d)
            Tangent vectors.
        eps : float
            Step, > 0.
        rtol, atol, simultaneity_tol, method
            Passed to :meth:`simulate` (tight defaults; a group tolerance far below the
            event-time spread ``eps * |v|`` keeps true event orders).

        Returns
        -------
        ndarray, shape (..., d)
        """
        x0 = self._check_state(x0, "x0")
        arr = check_real_array(V, "V")
        if arr.ndim == 0 or arr.shape[-1] != self.dim:
            raise ValueError(f"V must have shape (..., {self.dim}), got shape {arr.shape}")
        if not eps > 0:
            raise ValueError(f"eps must be > 0, got {eps}")
        flat = np.asarray(arr, dtype=np.float64).reshape(-1, self.dim)
        kw = dict(rtol=rtol, atol=atol, simultaneity_tol=simultaneity_tol, method=method)
        base = self.simulate(x0, t_final, **kw).x_final
        out = np.empty_like(flat)
        for i, v in enumerate(flat):
            out[i] = (self.simulate(x0 + eps * v, t_final, **kw).x_final - base) / eps
        return out.reshape(arr.shape)
