"""iLQR through contact: the backward pass on the pieces of each step's B-derivative.

Problem. Piecewise-constant inputs ``u_0 .. u_{N-1}`` (each (m,): the parameters of a
:class:`~bderiv.control.parametric.ParametricFlow`, held over one step of length ``dt``),
``x_{k+1} = Phi(dt, x_k; u_k)`` (the simulated hybrid flow, events and resets included),
and the cost ::

    J(U) = sum_k 1/2 u_k^T R u_k + 1/2 (x_N - x*)^T Qf (x_N - x*).

Linearisation. At each iteration the nominal ``(X, U)`` is simulated step by step and each
step's flow map is linearised by its B-derivative ``D_k`` over ``z = (x, u)``
(dimension d + m). Where ``D_k`` has event groups with several events (simultaneous, or
within the window ``flow.simultaneity_tol``), ``D_k`` is piecewise linear: the backward
pass takes the piece ``P_k`` of the order in which the nominal trajectory crossed those
events (:func:`~bderiv.control.parametric.nominal_orders`), ``A_k = P_k[:d, :d]``,
``B_k = P_k[:d, d:]``: the derivative on the side of the kink where the nominal is, exact
where the group's events cross at one point and first order in their gap where the
window merged events apart (the group's map is built at the nearby simultaneous point).
No average of pieces is ever formed.

Backward pass (Gauss-Newton iLQR, regularised by ``mu`` on ``Q_uu``)::

    V_x = Qf (x_N - x*),  V_xx = Qf
    Q_u = R u_k + B^T V_x,  Q_uu = R + B^T V_xx B + mu I,  Q_ux = B^T V_xx A
    k_k = -Q_uu^-1 Q_u,  K_k = -Q_uu^-1 Q_ux
    V_x = A^T V_x + K^T Q_uu k + K^T Q_u + Q_ux^T k,  V_xx = A^T V_xx A + K^T Q_uu K + ...

Forward pass: ``u_k = u_k + alpha k_k + K_k (x_k' - x_k)`` simulated, ``alpha`` halved
from 1 until the cost falls by at least 1e-4 of the predicted decrease (else ``mu`` grows
tenfold and the backward pass is redone). A trial whose rollout or linearisation bderiv
refuses is a failed trial, as in :func:`~bderiv.control.shooting.shoot` (recorded in
:attr:`ILQRResult.refusals`): above all one where a step ends at an impact (an event with
a reset within the window of the step's end, where the step's flow map jumps:
:class:`~bderiv.control.parametric.StepEndsAtImpact`), which smaller steps (a larger
``mu``, a smaller ``alpha``) may avoid.

A switch of order. A new nominal may cross a group's events in another order than the
last one (it moved across the kink). That is detected (each step's orders compared,
by global event index, with the previous nominal's), reported in
:attr:`Iteration.switches`, and handled by re-linearising: the next backward pass uses the
new order's piece. Events that leave or join a step or a group are reported as
``"regrouped"``.

Assumptions: the cost's Hessian is Gauss-Newton's (no second derivative of the flow: the
pieces are linear); each step's flow is piecewise smooth with transversal events (bderiv
refuses grazing and names it); the nominal order picks the piece valid on the nominal's
side, so a step that crosses the kink is only first-order right until re-linearised.

The comparison (``linearisation=(e_0, e_1, ...)``): every group's piece taken in that fixed
priority order of the events, whatever the nominal did: a single-order linearisation,
what a method that processes one guard at a time in a fixed sequence computes at a
simultaneous touchdown.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from .._support._progress import search_bar
from .._support._validate import check_matrix, check_number, check_real_array, check_state
from .._support._validate_ints import check_indices, check_positive_int
from . import _passes as passes
from ._passes import ROUNDED, ROUNDING
from .parametric import ParametricFlow, StepEndsAtImpact

__all__ = ["ROUNDING", "ILQRResult", "Iteration", "cost_gradient", "ilqr", "rollout"]


@dataclass
class Iteration:
    """One iteration: the nominal's cost, what was accepted, what changed.

    ``orders[k]``: per group of step k, its events (global indices) in the order the
    nominal crossed them. ``switches``: ``(step, events, old order, new order)`` where the
    order changed from the previous nominal; ``regrouped``: steps whose groups changed.
    """

    cost: float
    alpha: float
    mu: float
    orders: tuple
    switches: list = field(default_factory=list)
    regrouped: list = field(default_factory=list)
    seconds: float = 0.0


@dataclass
class ILQRResult:
    """``U`` (N, m) and ``X`` (N + 1, d) of the last nominal (the best: every accepted
    step lowers the cost), its ``cost``; ``history``: one :class:`Iteration` per
    linearisation (``history[0]`` the start); ``converged`` when the relative decrease
    fell below ``tol``, the cost to ``cost_tol`` or the predicted decrease to rounding
    (at the start too: a nominal that reaches the target, or a converged solution given
    again, is returned as it is); ``stalled`` when no step decreased the cost at the
    largest ``mu``; ``reason``: why the iterations stopped, in words; ``refusals``: the
    trial iterates whose rollout or linearisation bderiv refused (failed trials), with
    why."""

    U: np.ndarray
    X: np.ndarray
    cost: float
    converged: bool
    stalled: bool
    history: list
    reason: str = ""
    refusals: list = field(default_factory=list)

    @property
    def costs(self):
        """The nominal cost at each iteration: list of float."""
        return [it.cost for it in self.history]


def rollout(flow, x0, U, dt):
    """The states ``X`` (N + 1, d) from ``x0`` under the inputs ``U`` (N, m)."""
    X = np.empty((len(U) + 1, flow.dim))
    X[0] = x0
    for k, u in enumerate(U):
        X[k + 1] = flow.final(X[k], u, dt)
    return X


def _order_fn(linearisation, n_events):
    """None (the nominal's orders) or a callable choosing a fixed priority order."""
    if isinstance(linearisation, str):
        if linearisation != "nominal":
            raise ValueError(f"linearisation must be 'nominal' or a sequence of event "
                             f"indices (a fixed order), got {linearisation!r}")
        return None
    try:
        prio = [int(e) for e in linearisation]
    except TypeError:
        raise TypeError(f"linearisation must be 'nominal' or a sequence of event indices "
                        f"(a fixed order), got {linearisation!r}") from None
    if len(set(prio)) != len(prio) or any(not 0 <= e < n_events for e in prio):
        raise ValueError(f"linearisation, a fixed order, lists events of the model "
                         f"(0 .. {n_events - 1}) each once, got {prio}")

    def fixed(glob, final):
        missing = [e for e in glob if e not in prio]
        if missing:
            raise ValueError(f"the fixed order {prio} does not place events {missing}")
        order = sorted(range(len(glob)), key=lambda k: prio.index(glob[k]))
        return order + [len(glob)] if final else order

    return fixed


def _changes(old, new):
    switches, regrouped = [], []
    for k, (a, b) in enumerate(zip(old, new, strict=True)):
        if [sorted(g) for g in a] != [sorted(g) for g in b]:
            regrouped.append(k)
            continue
        switches += [(k, tuple(sorted(g)), g, h) for g, h in zip(a, b, strict=True) if g != h]
    return switches, regrouped


def cost_gradient(flow, x0, U, dt, target, Qf, R, *, linearisation="nominal"):
    """``dJ / dU`` (N, m) by the adjoint on the pieces the nominal selects.

    ``lambda_N = Qf (x_N - x*)``, ``lambda_k = A_k^T lambda_{k+1}``,
    ``dJ/du_k = R u_k + B_k^T lambda_{k+1}`` (the transposed pieces: the vjp of each step).
    The one-sided derivative on the nominal's side where each group's events cross at
    one point (a window below their gaps); where ``flow.simultaneity_tol`` merges events
    apart, an approximation, first order in their gap (the group's map is built at the
    nearby simultaneous point: 1e-4 relative on the chair's touchdowns 5 ms apart).
    """
    x0, U, target, Qf, R = _checked(flow, x0, U, dt, target, Qf, R)
    X = rollout(flow, x0, U, dt)
    steps, _ = _start(flow, X, U, dt, _order_fn(linearisation, flow.system.n_events))
    lam, G = Qf @ (X[-1] - target), np.empty_like(U)
    for k in range(len(U) - 1, -1, -1):
        G[k] = R @ U[k] + steps[k].B.T @ lam
        lam = steps[k].A.T @ lam
    return G


def _checked(flow, x0, U, dt, target, Qf, R):
    if not isinstance(flow, ParametricFlow):
        raise TypeError(f"flow must be a ParametricFlow, got {type(flow).__name__}")
    d, m = flow.dim, flow.n_params
    check_number(dt, "dt")
    x0 = check_state(x0, d, "x0", meaning=f"the start, a state of the model, d = {d}")
    U = check_real_array(U, "U").astype(np.float64)
    target = check_state(target, d, "target", meaning=f"a state of the model, d = {d}")
    Qf = check_matrix(Qf, "Qf", (d, d))
    R = check_matrix(R, "R", (m, m))
    if U.ndim != 2 or U.shape[1] != m or not len(U):
        raise ValueError(f"U must have shape (N, {m}), N >= 1, got shape {U.shape}")
    if not np.isfinite(U).all():
        bad = np.argwhere(~np.isfinite(U))[0]
        raise ValueError(f"U must be finite, got U[{bad[0]}, {bad[1]}] = "
                         f"{U[tuple(bad)]}")
    for a, name in ((Qf, "Qf"), (R, "R")):
        if not np.allclose(a, a.T) or np.linalg.eigvalsh(a).min() < 0:
            raise ValueError(f"{name} must be symmetric positive semi-definite")
    return x0, U, target, Qf, R


def _checked_settings(max_iters, tol, cost_tol, mu0, mu_max, line_search):
    """The numeric keywords of :func:`ilqr`, checked before any simulation."""
    max_iters = check_positive_int(max_iters, "max_iters")
    tol = check_number(tol, "tol", strict=False)
    if tol >= 1.0:
        raise ValueError(f"tol must be a finite number in [0, 1) (a relative decrease of the "
                         f"cost; max_iters bounds the iterations), got {tol!r}")
    cost_tol = check_number(cost_tol, "cost_tol", strict=False)
    mu0, mu_max = check_number(mu0, "mu0"), check_number(mu_max, "mu_max")
    if mu_max < mu0:
        raise ValueError(f"mu_max must be >= mu0 (the regularisation grows from mu0 up to "
                         f"mu_max), got mu_max={mu_max!r} < mu0={mu0!r}")
    line_search = check_positive_int(line_search, "line_search")
    return max_iters, tol, cost_tol, mu0, mu_max, line_search


def _start(flow, X, U, dt, fixed):
    """``_passes.linearise`` of the first nominal, its refusal advising what to change."""
    try:
        return passes.linearise(flow, X, U, dt, fixed)
    except StepEndsAtImpact as exc:
        raise StepEndsAtImpact(f"the first nominal (from U0) cannot be linearised: {exc}. "
                               f"Change dt or N (the steps end at k dt) so that no step "
                               f"ends at the impact, or start from other inputs U0",
                               exc.event, exc.time) from None


def ilqr(flow, x0, U0, dt, target, *, Qf, R, linearisation="nominal", max_iters=30,
         tol=1e-10, cost_tol=0.0, mu0=1e-6, mu_max=1e8, line_search=12, inputs=None):
    """iLQR with piecewise-constant inputs on a :class:`ParametricFlow` (module docstring).

    Parameters
    ----------
    flow : ParametricFlow
        Its m parameters are the inputs.
    x0 : array_like, shape (d,)
    U0 : array_like, shape (N, m)
        The first nominal inputs, one row per step.
    dt : float
        Step length (the horizon is ``N dt``).
    target : array_like, shape (d,)
    Qf : array_like, shape (d, d)
    R : array_like, shape (m, m)
        Positive semi-definite weights (symmetric).
    linearisation : "nominal" or sequence of int
        ``"nominal"``: each group's piece by the nominal's order; a sequence of event
        indices: the fixed-order piece (a single-order linearisation, for comparison).
    max_iters : int
        Iterations (linearisations after the start), >= 1.
    tol : float
        Stop when an accepted step lowers the cost by less than ``tol`` times it; in
        [0, 1) (0: never stop for a small decrease).
    cost_tol : float
        Stop when the cost is below it, >= 0.

        Whatever ``tol`` and ``cost_tol``, a nominal (the start included) is converged
        where the decrease the Gauss-Newton model predicts, ``-(d1 + d2)`` of a backward
        pass at ``mu = min(mu, mu0)``, is at most :data:`ROUNDING` (16) eps times the
        cost: a decrease below the rounding of the cost itself, which no line search can
        tell from 0 (at a minimum the gradient is at rounding level and its square, the
        predicted decrease, far below). So ``ilqr`` restarted at its own solution returns
        it, converged, without raising ``mu`` to ``mu_max``.
    mu0, mu_max : float
        First and largest regularisation of ``Q_uu``: ``0 < mu0 <= mu_max``, finite.
    line_search : int
        Forward passes (``alpha`` = 1, 1/2, ...) tried before ``mu`` grows, >= 1.
    inputs : sequence of int, optional
        The parameters that are inputs (indices in [0, m), each once; default all): the
        others are held at their values in ``U0`` (a model's restitution or gravity, as
        ``shoot``'s ``param_indices`` holds them), their rows and columns of ``R`` unused
        but for the constant they add to the cost.

    Returns
    -------
    ILQRResult
        Its ``reason`` says why it stopped. A trial iterate whose rollout or
        linearisation bderiv refuses (a step that ends at an impact, within the window of
        an event with a reset: the step's flow map jumps and has no B-derivative) is a
        failed trial, ``mu`` grows; where no trial gets past, the best iterate is returned
        with ``stalled`` and a ``reason`` that names the impact.

    Raises
    ------
    StepEndsAtImpact
        A ValueError: a step of the first nominal (from ``U0``) ends at an impact, named
        with its index k, its time span and what to change (dt, N or U0).
    """
    x0, U, target, Qf, R = _checked(flow, x0, U0, dt, target, Qf, R)
    fixed = _order_fn(linearisation, flow.system.n_events)
    free = np.arange(U.shape[1]) if inputs is None else check_indices(
        inputs, U.shape[1], "inputs")
    if not free.size:
        raise ValueError("inputs must name at least one of the flow's parameters, got none")
    max_iters, tol, cost_tol, mu0, mu_max, line_search = _checked_settings(
        max_iters, tol, cost_tol, mu0, mu_max, line_search)
    mu, history, refusals = mu0, [], []
    X = rollout(flow, x0, U, dt)
    cost = passes.total_cost(X, U, target, Qf, R)
    start = time.perf_counter()
    steps, orders = _start(flow, X, U, dt, fixed)
    history.append(Iteration(cost, 0.0, mu, orders, seconds=time.perf_counter() - start))
    converged, stalled = cost <= cost_tol, False  # (a start at the target: done)
    reason = f"the cost {cost!r} is at most cost_tol = {cost_tol!r}" if converged else ""
    with search_bar(max_iters, "ilqr", "iteration") as bar:  # long searches
        while len(history) <= max_iters and not converged:
            if passes.converged_to_rounding(steps, U, X, target, Qf, R, min(mu, mu0), cost,
                                            free):
                converged, reason = True, ROUNDED
                break
            start, accepted, impacts = time.perf_counter(), None, []
            while accepted is None and mu <= mu_max:
                back = passes.backward(steps, U, X, target, Qf, R, mu, free)
                if back is not None:
                    accepted = passes.line_search(flow, X, U, dt, back, cost, line_search, fixed,
                                            (target, Qf, R), refusals, impacts)
                if accepted is None:
                    mu *= 10.0
            if accepted is None:
                stalled, reason = True, passes.stall_reason(mu_max, impacts)
                break
            X, U, new, alpha, steps, new_orders = accepted
            converged = cost - new < tol * cost or new <= cost_tol
            if converged:
                reason = (f"the cost {new!r} is at most cost_tol = {cost_tol!r}"
                          if new <= cost_tol else
                          f"an accepted step lowered the cost by less than tol = {tol!r} "
                          f"times it")
            cost, mu = new, max(mu / 10.0, 1e-12)
            switches, regrouped = _changes(orders, new_orders)
            orders = new_orders
            history.append(Iteration(cost, alpha, mu, orders, switches, regrouped,
                                     time.perf_counter() - start))
            bar(len(history) - 1, f"cost {cost:.4g}")
    if not reason:
        reason = f"max_iters = {max_iters} iterations done"
    return ILQRResult(U, X, cost, converged, stalled, history, reason, refusals)


