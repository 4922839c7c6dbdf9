"""Single shooting by Levenberg-Marquardt steps, Jacobians from the flow's B-derivative.

The problem (hybrid-tools' ``ShootingMethodOptimizer``): choose some coordinates of the
start state and/or some parameters ``w`` (the decision, shape (q,)) so that chosen
coordinates of the final state ``Phi_p(T, x0)`` match a target: the residual
``r(w) = Phi(T, x0(w))[out] - target`` (shape (o,)). Each iteration

1. stops when ``|r| < error_tol`` at the current ``w`` (simulated once: its residual
   comes from the trial that accepted it);
2. takes the Jacobian ``J = dr / dw`` (o, q): the rows ``out`` and the decision columns
   of the piece of the flow's B-derivative ``D`` (dimension d + m, parameters included:
   :mod:`.parametric`) that the nominal trajectory selects (its event order in each
   group); one flow map per iteration, exact (no time-step approximation of the event);
3. solves ``(J^T J + lambda diag(J^T J)) s = J^T r`` and tries ``w - s``: accepted when
   ``|r|`` decreases (lambda divided by 10), else lambda multiplied by 10 and the step
   halved, up to ``line_search_max_iters`` times (else ``w`` kept); a trial point whose
   simulation is refused (a Zeno trajectory, say) is a failed trial;
4. stops when the accepted change of ``w`` is below ``input_state_tol`` (after the first
   iteration).

Steps 1, 3 and 4 are hybrid-tools' rules and constants (:class:`ShootingConfig` has its
defaults), so a comparison differs in the Jacobian alone.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .._support._validate import check_number, check_state
from .._support._validate_ints import check_indices, check_int, check_positive_int
from .parametric import ParametricFlow

__all__ = ["ShootingConfig", "ShootingResult", "shoot"]


@dataclass(frozen=True)
class ShootingConfig:
    """Stopping rule and Levenberg-Marquardt constants (hybrid-tools' defaults).

    Checked when built: ``max_iters >= 1`` and ``line_search_max_iters >= 0`` integers;
    ``error_tol > 0``, ``input_state_tol >= 0`` (0: never stop for a small step);
    ``0 < min_lambda <= initial_lambda <= max_lambda``; ``lambda_increase >= 1``,
    ``0 < lambda_decrease <= 1``, ``0 < line_search_backoff < 1``; all finite. Anything
    else is a ``TypeError``/``ValueError`` naming the field.
    """

    max_iters: int = 50
    error_tol: float = 0.05
    input_state_tol: float = 1e-3
    initial_lambda: float = 1e-4
    lambda_increase: float = 10.0
    lambda_decrease: float = 0.1
    min_lambda: float = 1e-10
    max_lambda: float = 1e6
    line_search_max_iters: int = 15
    line_search_backoff: float = 0.5

    def __post_init__(self):
        checked = {  # in the fields' order
            "max_iters": check_positive_int(self.max_iters, "max_iters"),
            "error_tol": check_number(self.error_tol, "error_tol"),
            "input_state_tol": check_number(self.input_state_tol, "input_state_tol",
                                            strict=False),
            "initial_lambda": check_number(self.initial_lambda, "initial_lambda"),
            "lambda_increase": check_number(self.lambda_increase, "lambda_increase", low=1.0,
                                            strict=False),
            "lambda_decrease": _check_fraction(self.lambda_decrease, "lambda_decrease",
                                               closed=True),
            "min_lambda": check_number(self.min_lambda, "min_lambda"),
            "max_lambda": check_number(self.max_lambda, "max_lambda"),
            "line_search_max_iters": check_int(self.line_search_max_iters,
                                               "line_search_max_iters", low=0),
            "line_search_backoff": _check_fraction(self.line_search_backoff,
                                                   "line_search_backoff"),
        }
        low, high = checked["min_lambda"], checked["max_lambda"]
        if low > high:
            raise ValueError(f"min_lambda must be <= max_lambda, got min_lambda={low!r} > "
                             f"max_lambda={high!r}")
        if not low <= checked["initial_lambda"] <= high:
            raise ValueError(f"initial_lambda must lie in [min_lambda, max_lambda] = "
                             f"[{low!r}, {high!r}], got {checked['initial_lambda']!r}")
        for name, value in checked.items():  # plain int and float (not a NumPy scalar)
            object.__setattr__(self, name, value)


def _check_fraction(value, name, closed=False):
    """A factor in (0, 1) (``closed``: in (0, 1])."""
    value = check_number(value, name)
    if value > 1.0 or (value == 1.0 and not closed):
        raise ValueError(f"{name} must be a finite number in (0, 1{']' if closed else ')'}, "
                         f"got {value!r}")
    return value


@dataclass
class ShootingResult:
    """What :func:`shoot` found.

    Attributes
    ----------
    decision : ndarray, shape (q,)
        The final decision (start-state coordinates, then parameters, as asked).
    x_final : ndarray, shape (o,)
        The output coordinates of the final state reached from ``decision``.
    converged : bool
        ``|r| < error_tol`` at ``decision``.
    iterations : int
        Levenberg-Marquardt steps taken (hybrid-tools' count: the index of the iteration
        that stopped).
    errors : list of float
        ``|r|`` at each iteration's nominal.
    simulations : int
        Simulations run (nominal and trial points).
    refusals : list of str
        Trial points whose simulation was refused (counted as failed trials), with why.
    """

    decision: np.ndarray
    x_final: np.ndarray
    converged: bool
    iterations: int
    errors: list = field(default_factory=list)
    simulations: int = 0
    refusals: list = field(default_factory=list)


def shoot(flow, x0, p, t_final, target, *, output_indices, state_indices=(),
          param_indices=(), initial_guess=None, config=None):
    """Levenberg-Marquardt shooting on a :class:`ParametricFlow`.

    Parameters
    ----------
    flow : ParametricFlow
    x0 : array_like, shape (d,)
        The start state (its ``state_indices`` entries replaced by the decision).
    p : array_like, shape (m,)
        The parameters (their ``param_indices`` entries replaced by the decision).
    t_final : float
    target : array_like, shape (o,)
        Wanted values of the final state at ``output_indices``.
    output_indices : sequence of int, length o
    state_indices, param_indices : sequence of int
        The decision: these coordinates of x0, then these parameters (q in all, >= 1).
    initial_guess : array_like, shape (q,), optional
        Default: the values in ``x0`` and ``p``.
    config : ShootingConfig, optional

    Returns
    -------
    ShootingResult
    """
    if not isinstance(flow, ParametricFlow):
        raise TypeError(f"flow must be a ParametricFlow, got {type(flow).__name__}")
    config = ShootingConfig() if config is None else config
    if not isinstance(config, ShootingConfig):
        raise TypeError(f"config must be a ShootingConfig, got {type(config).__name__}")
    d, m = flow.dim, flow.n_params
    z0 = flow._z(x0, p)
    t_final = check_number(t_final, "t_final")
    out = check_indices(output_indices, d, "output_indices")
    cols = np.concatenate((check_indices(state_indices, d, "state_indices"),
                           d + check_indices(param_indices, m, "param_indices")))
    if not cols.size or not out.size:
        raise ValueError("give at least one decision index (state_indices, param_indices) "
                         "and one output index")
    target = check_state(target, out.size, "target", meaning="one value per output index")
    w = z0[cols].copy() if initial_guess is None else check_state(
        initial_guess, cols.size, "initial_guess",
        meaning="one value per decision index: state_indices, then param_indices")
    sims = 0

    def residual(wv):
        nonlocal sims
        z = z0.copy()
        z[cols] = wv
        sims += 1
        return flow.final(z[:d], z[d:], t_final)[out] - target, z

    lam, errors, refusals = config.initial_lambda, [], []
    r, z = residual(w)
    for i in range(config.max_iters):
        err = float(np.linalg.norm(r))
        errors.append(err)
        if err < config.error_tol:
            return ShootingResult(w, r + target, True, i, errors, sims, refusals)
        step = flow.step(z[:d], z[d:], t_final)
        P = step.D.piece(step.orders) if step.D.n_groups else step.D.piece()
        J = P[np.ix_(out, cols)]
        JtJ = J.T @ J
        Dm = np.diag(np.maximum(np.diag(JtJ), 1e-10))
        try:
            s = np.linalg.solve(JtJ + lam * Dm, J.T @ r)
        except np.linalg.LinAlgError:
            s = np.linalg.pinv(JtJ + lam * Dm) @ (J.T @ r)
        w_new, r_new, lam = _adaptive(residual, w, s, r, lam, config, refusals)
        if np.linalg.norm(w_new - w) < config.input_state_tol and i > 0:
            # the decision returned is the accepted one, with its own final state
            return ShootingResult(w_new, r_new + target,
                                  float(np.linalg.norm(r_new)) < config.error_tol, i, errors,
                                  sims, refusals)
        w, r = w_new, r_new  # the accepted trial's residual: not simulated again
        z[cols] = w
    return ShootingResult(w, r + target, float(np.linalg.norm(r)) < config.error_tol,
                          config.max_iters, errors, sims, refusals)


def _adaptive(residual, w, s, r, lam, config, refusals):
    """hybrid-tools' step rule: the full step if it lowers ``|r|``, else halved steps
    with lambda growing; ``w`` (and its residual ``r``) kept when none does. A trial point
    whose simulation bderiv refuses (a ValueError: a Zeno trajectory, a grazing contact)
    is a failed trial, its message appended to ``refusals``. Returns ``(w, r, lambda)``
    of the point kept."""
    err = float(np.linalg.norm(r))

    def trial(wv):
        try:
            return residual(wv)[0]
        except ValueError as exc:
            refusals.append(f"at {wv.tolist()}: {exc}")
            return None

    r_try = trial(w - s)
    if r_try is not None and np.linalg.norm(r_try) < err:
        return w - s, r_try, max(lam * config.lambda_decrease, config.min_lambda)
    for _ in range(config.line_search_max_iters):
        lam = min(lam * config.lambda_increase, config.max_lambda)
        s = s * config.line_search_backoff
        r_try = trial(w - s)
        if r_try is not None and np.linalg.norm(r_try) < err:
            return w - s, r_try, lam
    return w, r, lam
