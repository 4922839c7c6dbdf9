"""The passes of :func:`~bderiv.control.ilqr.ilqr`: the cost, the linearisation of a
nominal, the backward pass, forward passes in a line search, and the stopping tests."""

from __future__ import annotations

import numpy as np

from .parametric import StepEndsAtImpact

#: an iterate is converged where the predicted decrease of the cost (the Gauss-Newton
#: model's, at ``mu = min(mu, mu0)``) is at most ROUNDING eps times the cost: no step can
#: show a decrease that small against the rounding of the cost itself
ROUNDING = 16.0
_EPS = float(np.finfo(np.float64).eps)
ROUNDED = ("the predicted decrease of the cost is at rounding level (at most "
           f"{ROUNDING:g} eps times the cost): a minimum to the cost's precision")


def total_cost(X, U, target, Qf, R):
    e = X[-1] - target
    return float(0.5 * np.einsum("ki,ij,kj->", U, R, U) + 0.5 * e @ Qf @ e)


def linearise(flow, X, U, dt, fixed):
    """Each step's :class:`Step`, and the nominal's orders. A step bderiv refuses is a
    ValueError of the same class naming the step k and its time span."""
    steps = []
    for k in range(len(U)):
        try:
            steps.append(flow.step(X[k], U[k], dt, orders=fixed))
        except StepEndsAtImpact as exc:
            raise StepEndsAtImpact(f"step {k} (t = {k * dt:.6g} to {(k + 1) * dt:.6g} from "
                                   f"x0): {exc}", exc.event, k * dt + exc.time) from None
        except ValueError as exc:
            raise ValueError(f"step {k} (t = {k * dt:.6g} to {(k + 1) * dt:.6g} from x0): "
                             f"{exc}") from None
    orders = tuple(tuple(tuple(g[j] for j in o if j < len(g))
                         for g, o in zip(s.groups, s.orders, strict=True)) for s in steps)
    return steps, orders


def backward(steps, U, X, target, Qf, R, mu, free):
    """Gains ``k`` (N, m), ``K`` (N, m, d) and the predicted decrease terms, or None when
    ``Q_uu`` is not positive definite. Only the inputs ``free`` (indices) move: the
    others' gains are 0 (the problem in the free inputs alone, ``B``'s and ``R``'s rows
    and columns of them; the others' values enter ``Q_u`` through ``R u``)."""
    N, m = U.shape
    Vx, Vxx = Qf @ (X[-1] - target), Qf.copy()
    k_ff, K, d1, d2 = np.zeros((N, m)), np.zeros((N, m, X.shape[1])), 0.0, 0.0
    pick = np.ix_(free, free)
    for k in range(N - 1, -1, -1):
        A, B = steps[k].A, steps[k].B
        Qu = (R @ U[k] + B.T @ Vx)[free]
        Quu = (R + B.T @ Vxx @ B)[pick] + mu * np.eye(free.size)
        Qux = (B.T @ Vxx @ A)[free]
        try:
            L = np.linalg.cholesky(0.5 * (Quu + Quu.T))
        except np.linalg.LinAlgError:
            return None
        sol = np.linalg.solve(L.T, np.linalg.solve(L, np.column_stack((Qu, Qux))))
        kf, Kf = -sol[:, 0], -sol[:, 1:]
        k_ff[k, free], K[k, free] = kf, Kf
        d1 += kf @ Qu
        d2 += 0.5 * kf @ Quu @ kf
        Vx = A.T @ Vx + Kf.T @ Quu @ kf + Kf.T @ Qu + Qux.T @ kf
        Vxx = A.T @ Vxx @ A + Kf.T @ Quu @ Kf + Kf.T @ Qux + Qux.T @ Kf
        Vxx = 0.5 * (Vxx + Vxx.T)
    return k_ff, K, d1, d2


def converged_to_rounding(steps, U, X, target, Qf, R, mu, cost, free):
    """The Gauss-Newton model's predicted decrease at ``mu`` is at rounding level of the
    cost: ``-(d1 + d2) <= ROUNDING * eps * cost``."""
    back = backward(steps, U, X, target, Qf, R, mu, free)
    return back is not None and -(back[2] + back[3]) <= ROUNDING * _EPS * abs(cost)


def _trial(flow, X, U, dt, k_ff, K, alpha, refusals):
    """A forward pass ``(X, U)``, or None where bderiv refuses its
    rollout (the refusal appended to ``refusals``)."""
    try:
        return _forward(flow, X, U, dt, k_ff, K, alpha)
    except ValueError as exc:
        refusals.append(f"alpha {alpha:g}: the rollout: {exc}")
        return None


def _forward(flow, X, U, dt, k_ff, K, alpha):
    Xn, Un = np.empty_like(X), np.empty_like(U)
    Xn[0] = X[0]
    for k in range(len(U)):
        Un[k] = U[k] + alpha * k_ff[k] + K[k] @ (Xn[k] - X[k])
        Xn[k + 1] = flow.final(Xn[k], Un[k], dt)
    return Xn, Un


def line_search(flow, X, U, dt, back, cost, line_search, fixed, weights, refusals,
                 impacts):
    """``alpha`` = 1, 1/2, ...: the first trial that lowers the cost enough (Armijo, 1e-4)
    and whose nominal bderiv linearises, as ``(X, U, cost, alpha, steps, orders)``; None
    if none does. A refused trial is a failed one (its refusal appended to ``refusals``,
    and, where a step ends at an impact, to ``impacts``)."""
    k_ff, K, d1, d2 = back
    alpha = 1.0
    for _ in range(line_search):
        trial = _trial(flow, X, U, dt, k_ff, K, alpha, refusals)
        if trial is not None:
            Xn, Un = trial
            new = total_cost(Xn, Un, *weights)
            expected = -(alpha * d1 + alpha**2 * d2)
            if new < cost and cost - new >= 1e-4 * expected:
                try:
                    return (Xn, Un, new, alpha) + linearise(flow, Xn, Un, dt, fixed)
                except ValueError as exc:
                    refusals.append(f"alpha {alpha:g}: the linearisation: {exc}")
                    if isinstance(exc, StepEndsAtImpact):
                        impacts.append(str(exc))
        alpha *= 0.5
    return None


def stall_reason(mu_max, impacts):
    why = (f"no trial step lowered the cost with the regularisation mu up to mu_max = "
           f"{mu_max!r}")
    if not impacts:
        return why + " (a minimum of the cost, or a kink of it the model does not see)"
    return (f"{why}: the iterates reached a step ending at an impact ({len(impacts)} "
            f"trial(s) refused, the last: {impacts[-1]}); the best iterate is returned. "
            f"Steps whose ends avoid the impacts (another dt or N) may go further")
