"""Checks of a B-derivative against finite differences of the event-detecting simulation.

One routine for the CLI, the tests and the benchmarks: :func:`forward_differences` (also
:meth:`HybridSystem.flow_fd <bderiv.analysis.system.HybridSystem.flow_fd>`) and :func:`fd_check`,
which differences the flow with several steps at once (one unperturbed run, one batch
of the perturbed ones) and measures the errors. The differences are one-sided on
purpose: the flow is only piecewise differentiable, so a central quotient converges to
``(D(v) - D(-v)) / 2``, not to ``D(v)``. With a Poincare section they difference the
return map instead. :func:`decay_check` follows perturbations of a periodic orbit through
many strides, the simulated counterpart of a predicted growth rate.
"""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass

import numpy as np

from .._limits import FD_EPS, FD_SIMULTANEITY_TOL, LINEAR_STATE, MIN_FIT_STRIDES
from .._support._progress import resolve_progress
from .._support._validate import (
    check_matrix,
    check_number,
    check_points,
    check_state,
)
from .._support._validate_ints import check_int
from ..models.integrate.options import SolverOptions
from ..models.section import Section
from ._arguments import (
    check_directions,
    check_settings,
    check_steps,
    check_system,
)
from ._cyclic import check_cyclic, kept

__all__ = [
    "FD_OPTIONS",
    "FD_SIMULTANEITY_TOL",
    "DecayCheck",
    "FDCheck",
    "decay_check",
    "fd_check",
    "forward_differences",
]

#: Integrator settings of the finite differences. Tighter than ``SolverOptions()``: the
#: integration error is divided by eps. With the defaults (rtol = 1e-10) the relative
#: error on ``examples.network(3)`` stalls at 1e-6 for eps = 1e-6 instead of falling to
#: 1e-7 (tests/test_checks.py shows it); with these it keeps falling in proportion to eps.
FD_OPTIONS = SolverOptions(rtol=1e-12, atol=1e-13, simultaneity_tol=FD_SIMULTANEITY_TOL)

#: the keywords of the settings (:class:`SolverOptions`'s fields) and the default of
#: :func:`decay_check` when other tolerances are given
_SETTINGS = ("rtol", "atol", "method", "max_step", "simultaneity_tol")
_FD_TOL_ONLY = SolverOptions(simultaneity_tol=FD_SIMULTANEITY_TOL)


def forward_differences(system, x0, t_final, V, eps, *, simultaneity_tol=None,
                        options=None, rtol=None, atol=None, method=None, max_step=None,
                        section=None, progress=None):
    """``(Phi(t_final, x0 + eps v) - Phi(t_final, x0)) / eps`` for every vector v.

    The error is O(eps) (the flow's B-derivative is its first-order term) plus the
    integration error divided by eps. With ``section`` the differences are those of the
    Poincare map: ``(P(x0 + eps v) - P(x0)) / eps`` (the state at the next upward
    crossing of the section; ``t_final`` is the longest wait), the oracle of
    :meth:`HybridSystem.return_map <bderiv.analysis.system.HybridSystem.return_map>`.

    Parameters
    ----------
    system : HybridSystem
    x0 : array_like, shape (d,)
    t_final : float
    V : array_like, shape (..., d)
        Tangent vectors, finite.
    eps : float
        Step, finite, > 0.
    simultaneity_tol : float, optional
        As for ``system.simulate``; default :data:`FD_SIMULTANEITY_TOL`.
    options : SolverOptions, optional
        The settings as one value, default :data:`FD_OPTIONS`.
    rtol, atol, method, max_step : optional
        The settings as keywords (one given with ``options`` must agree with it).
    section : callable ``section(x) -> float``, optional
        Difference the Poincare map of this section instead of the flow.
    progress : callable ``progress(done, total)``, or bool, optional
        Called after each perturbed simulation; ``True`` draws a tqdm bar.

    Returns
    -------
    ndarray, shape (..., d)
    """
    check_system(system)
    options = _settings(simultaneity_tol=simultaneity_tol, options=options, rtol=rtol,
                        atol=atol, method=method, max_step=max_step)
    eps = check_number(eps, "eps")
    flat, lead = check_points(V, system.dim, "V")
    progress = resolve_progress(progress, desc="finite differences")
    FD = _differences(system, x0, t_final, flat, (eps,), options, section, progress)
    return FD[0].reshape(*lead, system.dim)


def _settings(*, simultaneity_tol=None, options=None, rtol=None, atol=None, method=None,
              max_step=None) -> SolverOptions:
    """The settings of the differences: :data:`FD_OPTIONS` where none are given."""
    return SolverOptions.resolve(options, FD_OPTIONS, rtol=rtol, atol=atol, method=method,
                                 max_step=max_step, simultaneity_tol=simultaneity_tol)


def _differences(system, x0, t_final, flat, steps, options, section, progress):
    """(len(steps), m, d): the forward differences of the rows of ``flat`` (m, d) with
    each of ``steps``, from one unperturbed run and one batch of all the perturbed ones."""
    # the final states only: a bounded record (t_eval=()), whatever the span
    settings = {"options": options, "section": section, "t_eval": ()}
    start = check_state(x0, system.dim, "x0")
    base = system.simulate(start, t_final, **settings)
    # the perturbed runs as one batch (its bar, or the callback after each run), shaped
    # (step, vector, d): a failed run is named by its step and its row of V
    steps = np.asarray(steps, dtype=np.float64)[:, None, None]
    starts = start + steps * flat
    # a step below x0's resolution gives x0 again, and a difference of 0 (no error said)
    still = ~(starts != start).any(axis=-1) & (flat != 0).any(axis=-1)
    if still.any():
        i, j = (int(k) for k in np.argwhere(still)[0])
        raise ValueError(f"eps={float(steps[i, 0, 0])!r} is below the resolution of x0 along "
                         f"V[{j}]: x0 + eps * V[{j}] rounds to x0 in float64 (spacing "
                         f"{float(np.spacing(np.abs(start).max())):.3g} at x0's largest "
                         f"entry); take a larger eps")
    runs = system.simulate_many(starts, t_final, progress=progress, **settings)
    return (runs.x_final - base.x_final) / steps


@dataclass(frozen=True)
class FDCheck:
    """Finite differences of the simulated flow against the B-derivative.

    Attributes
    ----------
    eps : tuple of float
        The steps, in the order given.
    errors : ndarray, shape (m, len(eps))
        ``|FD_eps(v) - D(v)| / |D(v)|`` (Euclidean norms) for every vector v and step.
    max_errors : tuple of float
        ``max |FD - D V| / max |D V|`` over the batch (entries), one per step.
    ratios : tuple of float
        ``max_errors[i + 1] / max_errors[i]``: about the ratio of the steps when the error
        is O(eps), as the B-derivative predicts.
    seconds_per_vector : float
        Wall time of one perturbed simulation (the unperturbed run amortised).
    """

    eps: tuple
    errors: np.ndarray
    max_errors: tuple
    ratios: tuple
    seconds_per_vector: float

    def first_order(self, low: float = 0.03, high: float = 0.3) -> bool:
        """Whether every ratio of successive max errors lies in ``(low, high)``."""
        return all(low < r < high for r in self.ratios)


def fd_check(system, x0, t_final, V, D_V, eps=FD_EPS, *, progress=None,
             **simulate_options) -> FDCheck:
    """Compare ``D_V = D(V)`` with forward differences of ``system``'s simulated flow.

    Parameters
    ----------
    system : HybridSystem
    x0 : array_like, shape (d,)
        Start point of the nominal trajectory.
    t_final : float
    V : array_like, shape (m, d)
        Tangent vectors.
    D_V : array_like, shape (m, d)
        The B-derivative applied to ``V`` (for example ``system.flow_bderivative(x0,
        t_final)(V)``), no row zero (the errors are relative).
    eps : sequence of float
        Steps, each finite and > 0.
    progress : callable ``progress(done, total)``, or bool, optional
        Called after each simulation (``total``: one per vector and step); ``True``
        draws a tqdm bar.
    **simulate_options
        The settings, as for :func:`forward_differences` (``simultaneity_tol``,
        ``options``, ``rtol``, ``atol``, ``method``, ``max_step``, ``section``: with a
        section, ``t_final`` is the longest wait and ``D_V`` the return map's
        B-derivative). The runs of every step are one batch: their final states are kept,
        ``len(eps) * m`` of them.

    Returns
    -------
    FDCheck

    Raises
    ------
    TypeError, ValueError
        Before any simulation, for an argument of the wrong type, shape or range (named),
        or a setting not named above.
    """
    check_system(system)
    check_state(x0, system.dim, "x0")
    V = check_directions(V, system.dim, "vector")
    D_V = check_matrix(D_V, "D_V", V.shape)
    zero = np.flatnonzero(~np.any(D_V, axis=1))
    if zero.size:
        raise ValueError(f"D_V must have no zero row (errors are relative to |D(v)|), but "
                         f"row {int(zero[0])} is zero")
    eps = check_steps(eps)
    check_settings("fd_check", simulate_options, (*_SETTINGS, "options", "section"))
    section = simulate_options.pop("section", None)
    options = _settings(**simulate_options)
    progress = resolve_progress(progress, desc="finite differences")
    t0 = time.perf_counter()
    # every step's runs in one batch, one unperturbed run for all
    FD = _differences(system, x0, t_final, V, eps, options, section, progress)
    per_vector = (time.perf_counter() - t0) / (len(eps) * V.shape[0] + 1)
    errors = np.linalg.norm(FD - D_V, axis=2) / np.linalg.norm(D_V, axis=1)
    worst = tuple(float(w) for w in np.abs(FD - D_V).max(axis=(1, 2)) / np.abs(D_V).max())
    ratios = tuple(b / a if a else float("nan") for a, b in zip(worst, worst[1:], strict=False))
    return FDCheck(eps, errors.T, worst, ratios, per_vector)


@dataclass(frozen=True)
class DecayCheck:
    """Perturbations of a periodic orbit followed by simulation, stride by stride.

    Attributes
    ----------
    deviations : ndarray, shape (m, strides + 1)
        ``|P^k(x0 + eps v) - x0|`` (Euclidean, cyclic coordinates left out) for every vector
        v and stride k = 0..strides.
    rates : ndarray, shape (m,)
        Per-stride growth factor of each vector: ``exp`` of the least-squares slope of
        ``log deviations`` over its ``fitted`` strides; NaN for a vector with fewer than
        :data:`MIN_FIT_STRIDES` of them (a warning said why).
    rate : float
        The largest of ``rates`` (NaN if any is NaN): the simulated counterpart of a
        predicted growth rate.
    window : tuple of int
        First and last stride fitted over all vectors (the first strides are a transient).
    fitted : ndarray of bool, shape (m, strides + 1)
        The strides fitted for each vector: after the transient, above ``floor``, and in
        the linear regime (before the deviation first exceeds ``ceiling``).
    ceiling : float
        The largest deviation counted as linear.
    """

    deviations: np.ndarray
    rates: np.ndarray
    rate: float
    window: tuple
    fitted: np.ndarray
    ceiling: float


def decay_check(system, x0, section, V, *, eps=1e-4, strides=40, floor=1e-9, ceiling=None,
                cyclic=(), t_max=10.0, **simulate_options) -> DecayCheck:
    """Measure how perturbations of a periodic orbit decay in long simulations.

    An independent check of a predicted growth rate
    (:meth:`PeriodicOrbit.stability <bderiv.analysis.orbit.PeriodicOrbit.stability>`): the
    nonlinear system is simulated from ``x0 + eps v`` through ``strides`` returns to the
    section, and the per-stride factor by which the deviation from ``x0`` shrinks is
    fitted, for each vector over the strides where the deviation is in the **linear
    regime**: after the transient (the first quarter), above ``floor`` and before it first
    exceeds ``ceiling``. A deviation that grows beyond the ceiling has left the regime the
    linearisation describes (an unstable orbit's perturbations saturate), and later strides
    say nothing about the rate; a vector with fewer than :data:`MIN_FIT_STRIDES` strides in
    the regime gets the rate NaN and a ``RuntimeWarning`` with the reason, so a saturated
    run never reports decay.

    Parameters
    ----------
    system : HybridSystem
    x0 : array_like, shape (d,)
        The fixed point on the section.
    section : callable
        ``section(x) -> float``.
    V : array_like, shape (m, d)
        Perturbation directions, m >= 1, no row zero (unit size is sensible).
    eps : float
        Size of the perturbations.
    strides : int
        Returns simulated per vector (>= 4).
    floor : float
        Deviations below this (the integration error) are not fitted; finite, >= 0.
    ceiling : float, optional
        The largest deviation counted as linear (default ``LINEAR_STATE * |x0|``, or
        ``LINEAR_STATE`` when x0 is 0).
    cyclic : sequence of int
        Coordinates that advance every stride (the orbit's ``cyclic``): left out of the
        deviations and of ``|x0|``.
    t_max : float
        Longest wait for each return.
    **simulate_options
        ``simultaneity_tol``, ``options``, ``rtol``, ``atol``, ``method``, ``max_step``,
        ``max_groups`` for ``system.simulate`` (default the tight :data:`FD_OPTIONS` and
        :data:`FD_SIMULTANEITY_TOL`).

    Returns
    -------
    DecayCheck

    Raises
    ------
    TypeError, ValueError
        Before any simulation, for an argument of the wrong type, shape or range (named),
        or a setting not named above.

    Warns
    -----
    RuntimeWarning
        When a vector's deviation leaves the linear regime before
        :data:`MIN_FIT_STRIDES` strides after the transient (pass a smaller eps).
    """
    check_system(system)
    x0 = check_state(x0, system.dim, "x0")
    Section(section, system.dim)  # checked: callable
    V = check_directions(V, system.dim, "direction of perturbation", nonzero=True)
    eps = check_number(eps, "eps")
    t_max = check_number(t_max, "t_max")
    floor = check_number(floor, "floor", strict=False)
    strides = check_int(strides, "strides", low=4)
    check_settings("decay_check", simulate_options, (*_SETTINGS, "options", "max_groups"))
    keep = kept(check_cyclic(cyclic, system.dim), system.dim)
    size = float(np.linalg.norm(x0[keep]))
    if ceiling is None:
        ceiling = LINEAR_STATE * (size if size > 0 else 1.0)
    ceiling = check_number(ceiling, "ceiling")
    # the tight FD_OPTIONS unless other tolerances are given; FD_SIMULTANEITY_TOL always
    given = {key: simulate_options.pop(key, None) for key in _SETTINGS}
    options = simulate_options.pop("options", None)
    loose = options is not None or given["rtol"] is not None or given["atol"] is not None
    simulate_options["options"] = SolverOptions.resolve(
        options, _FD_TOL_ONLY if loose else FD_OPTIONS, **given)
    dev = np.empty((V.shape[0], strides + 1))
    X = x0 + eps * V
    for k in range(strides + 1):  # stride by stride, every vector's run in one batch
        if k:
            X = system.simulate_many(X, t_max, section=section, t_eval=(),
                                     **simulate_options).x_final
        for i, x in enumerate(X):
            dev[i, k] = np.linalg.norm((x - x0)[keep])
    return _fit_decay(dev, floor, ceiling, eps)


def _fit_decay(dev, floor, ceiling, eps) -> DecayCheck:
    """Fit each row of ``dev`` (m, strides + 1) over its strides in the linear regime."""
    strides = dev.shape[1] - 1
    first = strides // 4
    k = np.arange(strides + 1)
    # the regime ends at the first deviation above the ceiling, for good
    linear = np.cumsum(dev > ceiling, axis=1) == 0
    fitted = (k >= first) & linear & (dev > floor)
    rates = np.full(dev.shape[0], np.nan)
    left = []
    for i, (row, keep) in enumerate(zip(dev, fitted, strict=True)):
        if keep.sum() >= MIN_FIT_STRIDES:
            rates[i] = np.exp(np.polyfit(k[keep], np.log(row[keep]), 1)[0])
        elif not linear[i, -1]:
            left.append(f"vector {i} left the linear regime at stride "
                        f"{int(np.argmin(linear[i]))} (deviation "
                        f"{row[np.argmin(linear[i])]:.3g} > ceiling {ceiling:.3g})")
        else:
            raise ValueError(f"the deviation of vector {i} falls below floor={floor:g} "
                             f"before stride {first + MIN_FIT_STRIDES}: pass a larger eps "
                             f"or fewer strides")
    if left:
        warnings.warn(
            f"decay_check: {'; '.join(left)}, before {MIN_FIT_STRIDES} strides after the "
            f"transient (stride {first}); the perturbations grow out of the regime the "
            f"linearisation describes, so no rate is fitted for them (NaN). Pass a smaller "
            f"eps (now {eps:g}) to measure the growth",
            RuntimeWarning, stacklevel=3)
    used = np.flatnonzero(fitted.any(axis=0))
    window = (int(used[0]), int(used[-1])) if used.size else (first, first)
    return DecayCheck(dev, rates, float(np.max(rates)), window, fitted, float(ceiling))
