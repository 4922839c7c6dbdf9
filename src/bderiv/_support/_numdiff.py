"""Derivatives of a user's function by central differences, with an error estimate.

Ridders' method (Numerical Recipes, ``dfridr``): central differences at steps ``H, H/2,
H/4, ...`` extrapolated to step 0 (Neville's tableau in ``h**2``), each entry's estimate
the tableau value whose two neighbours agree best, its error estimate that disagreement.
One run covers steps over a factor ``2**(LEVELS - 1)``; runs start at steps spaced by
``START_SPACING`` around the variable's own scale, nearest first, until every entry's
error estimate is small enough. Values equal at every step of a run bound the entry by
their rounding over the largest step, not by 0. A function with a feature near ``x`` (a kink of
``max(h, 0)**1.5`` at ``h = 1e-5``) needs small steps, one of large size and rounding
(``x2 + 1e10 (1 + x0)``) large ones: the ladder finds either, and the error estimate says
when neither exists.

The step of coordinate ``j`` is the exact difference ``(x_j + h) - (x_j - h)`` of the
points evaluated, so rounding of ``x_j +- h`` does not bias the quotient.
"""

from __future__ import annotations

import warnings
from typing import NamedTuple

import numpy as np

from .._limits import (
    ACCEPT_RTOL,
    BASE_STEP,
    CHECK_ERROR_FACTOR,
    CHECK_ROUND_FLOOR,
    CHECK_RTOL,
    ROUND_FLOOR,
    ROW_FLOOR,
    TARGET_RTOL,
)
from .._numerics import SCALE_FLOOR
from ._errors import DamagedCacheError
from ._validate import all_finite

#: levels of one run (steps H .. H / 2**(LEVELS - 1)), each two calls of the function.
LEVELS = 8
#: ratio of the first steps of successive runs (a run covers 2**7: the ranges overlap).
START_SPACING = 2.0**6
#: runs in the order tried: powers of START_SPACING of the first run's step (smaller ones
#: first: a feature near x is the common reason for a failure).
STARTS = (0, -1, 1, -2, 2, -3, 3, -4, 4, -5, 5, -6, 6)
#: a run stops once the next level's estimate is off by SAFE times the best error.
SAFE = 2.0
EPS = float(np.finfo(float).eps)


class Derivative(NamedTuple):
    """Estimates (m, k) of derivatives along k directions, their error estimates (m, k),
    the accuracy each entry needs (m, k) and the number of calls of the function."""

    value: np.ndarray
    error: np.ndarray
    needed: np.ndarray
    calls: int


def variable_scales(x: np.ndarray) -> np.ndarray:
    """The scale of each variable (d,): ``|x_j|``, at least ``SCALE_FLOOR``; a variable
    exactly 0 has no magnitude of its own: 1 (the unit). Never from the other variables:
    ``x = (1, 1, 9e199)`` keeps steps near 1 for the first two."""
    s = np.abs(x)
    return np.where(s > 0, np.maximum(s, SCALE_FLOOR), 1.0)


def _run(fun, x, f0, v, first, needed_of):
    """One Ridders run along ``v`` from step ``first``: (value (m,), error (m,), calls).

    ``needed_of(value)`` gives the accuracy the entries need; the run stops when all
    have it (from the third level on, so that the estimate rests on two extrapolations)
    or when the tableau's diagonal drifts (rounding or a feature inside the steps).
    """
    h, calls = first, 0
    prev = None
    best = err = None
    equal_at = np.zeros(f0.shape)  # the largest step at which the two values were equal
    vv = float(v @ v)
    for level in range(LEVELS):
        xp, xm = x + h * v, x - h * v
        step = float((xp - xm) @ v) / vv  # the exact displacement along v
        try:
            with np.errstate(all="ignore"):  # a probe's overflow shows as non-finite
                fp, fm = fun(xp), fun(xm)
        except (ValueError, ArithmeticError):  # no value there: steps too large here
            break
        calls += 2
        equal_at = np.where((fp == fm) & (equal_at == 0.0), h, equal_at)
        row = [(fp - fm) / step]
        fac = 4.0
        for j in range(1, level + 1):
            row.append((row[j - 1] * fac - prev[j - 1]) / (fac - 1.0))
            fac *= 4.0
            e = np.maximum(np.abs(row[j] - row[j - 1]), np.abs(row[j] - prev[j - 1]))
            if best is None:
                best, err = row[j].copy(), e
            else:
                better = e <= err
                best[better], err[better] = row[j][better], e[better]
        if level and best is not None:
            if level >= 2 and (err <= needed_of(best) * (TARGET_RTOL / ACCEPT_RTOL)).all():
                break
            if (np.abs(row[level] - prev[level - 1]) >= SAFE * err).all():
                break
        prev = row
        h /= 2.0
    if best is None:
        return None, None, calls
    # values equal at a step h: the estimates from there on are their rounding over h, so
    # the derivative is known only to within that rounding, not to be 0 (``x2 + 1e16`` at
    # small steps; ``0.4 (1 + 0.1 y**2)`` at y = 2e-8, equal below the first step)
    floor = np.divide(np.spacing(np.abs(f0)), equal_at, out=np.zeros(f0.shape),
                      where=equal_at > 0.0)
    err = np.maximum(err, floor)
    return best, err, calls


def _needed(value, row_max, f0, scale):
    """The accuracy (m,) entries ``value`` (m,) of a column need: ``ACCEPT_RTOL``
    relative, or ``ROW_FLOOR`` times the row's largest entry ``row_max`` (m,), or the
    rounding of the values ``f0`` (m,) over the variable's ``scale``."""
    return (ACCEPT_RTOL * np.abs(value) + ROW_FLOOR * row_max
            + ROUND_FLOOR * EPS * np.abs(f0) / scale)


def jacobian(fun, x) -> Derivative:
    """The Jacobian (m, d) of ``fun`` at ``x`` (d,), column by column.

    Parameters
    ----------
    fun : callable
        ``fun(y) -> (m,)`` float array; a ``ValueError`` at a probe point (a non-finite
        value) ends the run of steps that reached it.
    x : ndarray, shape (d,)

    Returns
    -------
    Derivative
        ``value`` (m, d); ``needed`` is ``ACCEPT_RTOL`` relative to the entry, or
        ``ROW_FLOOR`` times the row's largest entry.
    """
    d = x.shape[0]
    s = variable_scales(x)
    f0 = fun(x)  # unguarded: a wrong output raises here, not as "no finite value"
    columns, calls, row_max = [], 1, None
    for j in range(d):
        v = np.zeros(d)
        v[j] = 1.0
        col = _column(fun, x, f0, v, s[j], lambda val, known=row_max, s_j=s[j]: _needed(
            val, np.abs(val) if known is None else np.maximum(known, np.abs(val)), f0, s_j))
        calls += col.calls
        row_max = np.abs(col.value) if row_max is None else np.maximum(row_max,
                                                                       np.abs(col.value))
        columns.append(col)
    value = np.stack([c.value for c in columns], axis=1)
    error = np.stack([c.error for c in columns], axis=1)
    needed = _needed(value, np.abs(value).max(axis=1, keepdims=True), f0[:, None], s)
    return Derivative(value, error, needed, calls)


#: the complex step of coordinate j: ``COMPLEX_STEP * |x_j|``, at least ``COMPLEX_FLOOR``
#: (no difference is taken, so a step far below rounding costs nothing; the floor keeps it
#: a normal number whose quotient is exact)
COMPLEX_STEP, COMPLEX_FLOOR = 1e-20, 1e-200


def complex_step(fun, x, m, strict=True):
    """The Jacobian (m, d) of ``fun`` at ``x`` (d,) by the complex step, or None.

    Column j is ``Im fun(x + i h_j e_j) / h_j``: exact to rounding for a complex-analytic
    function (no difference of two values is taken), in d calls. A function that does not
    take complex input (it raises, returns another shape or a non-finite value, or, with
    ``strict``, NumPy discards an imaginary part: ``float(y[0])``, a float array filled
    with complex values) gives None. One that takes it but is not complex-analytic
    (``abs``, ``y.real``) gives a wrong answer silently: hold the result to a central
    difference once (:func:`compare`) before trusting it. ``strict`` costs a warnings
    context per call: a caller that has checked the function once may leave it off.

    Examples
    --------
    >>> complex_step(lambda y: np.array([y[0] * np.sin(y[1])]), np.array([2.0, 0.0]), 1)
    array([[0., 2.]])
    >>> import math
    >>> complex_step(lambda y: np.array([math.sin(y[0])]), np.array([2.0]), 1) is None
    True
    """
    h = np.maximum(COMPLEX_STEP * np.abs(x), COMPLEX_FLOOR)
    if not strict:
        return _complex_columns(fun, x, h, m)
    with warnings.catch_warnings():  # an imaginary part discarded: not usable
        warnings.simplefilter("ignore")
        warnings.simplefilter("error", np.exceptions.ComplexWarning)
        return _complex_columns(fun, x, h, m)


def _complex_columns(fun, x, h, m):
    """The columns of :func:`complex_step` (None where ``fun`` fails on complex input).

    Each call gets a fresh copy of ``x`` (signed zeros kept) with ``i h_j`` added to entry
    j, and its output's imaginary part is copied into column j at once (a function that
    returns one buffer it reuses gives the right columns); the columns are divided by the
    steps once at the end (the integrator of a model without ``field_jacobian`` calls
    this at every stage)."""
    base = x.astype(np.complex128)
    J = np.empty((m, x.shape[0]))
    try:
        for j in range(x.shape[0]):
            y = base.copy()
            y[j] = complex(x[j], h[j])
            out = fun(y)
            if getattr(out, "shape", None) != (m,) and np.shape(out) != (m,):
                return None
            J[:, j] = np.imag(out)
    except DamagedCacheError:  # not the function's refusal: the user must see it
        raise
    except Exception:  # noqa: BLE001 - any refusal of complex input: not usable
        return None
    J /= h
    return J if all_finite(J) else None


def directional(fun, x, v, scale=1.0) -> Derivative:
    """The derivative (m, 1) of ``fun`` at ``x`` along ``v`` (d,), steps from
    ``BASE_STEP * scale``; ``needed`` is ``ACCEPT_RTOL`` (or ``ROW_FLOOR``) relative to
    each entry."""
    f0 = fun(x)
    col = _column(fun, x, f0, v, scale, lambda val: _needed(val, np.abs(val), f0, scale))
    return Derivative(col.value[:, None], col.error[:, None], col.needed[:, None],
                      col.calls + 1)


def _column(fun, x, f0, v, scale, needed_of) -> Derivative:
    """Runs from the ladder of first steps until one gives every entry the accuracy it
    needs; per entry the estimate of smallest error over the runs made, an entry keeping
    the first estimate that is accurate enough (steps far from a variable's scale can
    agree by accident, on a piecewise linear stretch). Steps larger than the first run's
    (for rounding) count only where they agree with its estimate within both errors: at
    large steps ``x + 1e-3 tanh(x / 1e-20)`` looks like ``x``. ``f0 = fun(x)``."""
    best = err = anchor = None
    calls = 0
    for k in STARTS:
        value, e, c = _run(fun, x, f0, v, BASE_STEP * scale * START_SPACING**k, needed_of)
        calls += c
        if value is None:
            continue
        if best is None:
            best, err = value, e
        else:
            better = ~(err <= needed_of(best)) & (e < err)
            if k > 0 and anchor is not None:  # larger steps must agree with the first run
                better &= ~(np.abs(value - anchor[0]) > anchor[1] + e)
            best[better], err[better] = value[better], e[better]
        if k == 0:
            anchor = (value.copy(), e.copy())
        if (err <= needed_of(best)).all():
            break
    if best is None:  # every step of every run met a non-finite value
        return Derivative(np.zeros_like(f0), np.full_like(f0, np.inf), needed_of(f0), calls)
    return Derivative(best, err, needed_of(best), calls)


class Comparison(NamedTuple):
    """A given Jacobian against a central difference along a random direction ``v``.

    ``mismatch`` (m,) is ``|J v - D_v f|``, ``tolerance`` (m,) what it may be (infinite
    for an output whose plain differences approach ``J v``: :func:`_converging`),
    ``relative`` the largest ``mismatch / (|J| |v| + |D_v f|)``, ``component`` where it is
    (the worst ``mismatch / tolerance``), ``error`` (m,) the difference's error estimate.
    """

    mismatch: np.ndarray
    tolerance: np.ndarray
    relative: float
    component: int
    error: np.ndarray
    calls: int

    @property
    def passed(self) -> bool:
        return bool((self.mismatch <= self.tolerance).all())


def compare(fun, x, J, seed=0, scales=None) -> Comparison:
    """Compare ``J`` (m, d), the claimed Jacobian of ``fun`` at ``x``, with the derivative
    along a random direction (normal entries times the variables' scales, seeded;
    ``scales`` (d,) instead of those of ``x``: a point beside another, where a variable
    that is 0 at the other is tiny here, keeps the other's unit step)."""
    scales = variable_scales(x) if scales is None else scales
    v = np.random.default_rng(seed).standard_normal(x.size) * scales
    D = directional(fun, x, v)
    dv, err = D.value[:, 0], D.error[:, 0]
    Jv, size = J @ v, np.abs(J) @ np.abs(v) + np.abs(dv)
    mismatch = np.abs(Jv - dv)
    tolerance = (CHECK_RTOL * size + CHECK_ERROR_FACTOR * err
                 + CHECK_ROUND_FLOOR * EPS * size.max(initial=0.0))
    calls = D.calls
    if not (mismatch <= tolerance).all():
        converging, c = _converging(fun, x, v, Jv)
        calls += c
        tolerance = np.where(converging, np.inf, tolerance)
    with np.errstate(divide="ignore", invalid="ignore"):
        relative = np.where(mismatch > 0, mismatch / size, 0.0)
        worst = np.where(mismatch > 0, mismatch / tolerance, 0.0)
    return Comparison(mismatch, tolerance, float(relative.max(initial=0.0)),
                      int(np.argmax(worst)) if worst.size else 0, err, calls)


#: plain central differences at BASE_STEP / TREND_RATIO**k, k < TREND_STEPS, ...
TREND_RATIO, TREND_STEPS = 4.0, 7


def _converging(fun, x, v, Jv):
    """Outputs (m,) whose central differences along ``v`` approach ``Jv`` as the step
    shrinks (their distance halves at least over the last two of TREND_STEPS steps):
    a function that is not smooth at ``x`` (``max(h, 0)**1.5`` at ``h = 1e-19``), whose
    differences converge slowly, not a wrong Jacobian, whose distance stays. And the
    calls made."""
    gaps = []
    for k in range(TREND_STEPS):
        t = BASE_STEP / TREND_RATIO**k
        xp, xm = x + t * v, x - t * v
        try:
            with np.errstate(all="ignore"):
                diff = (fun(xp) - fun(xm)) / (float((xp - xm) @ v) / (v @ v))
        except (ValueError, ArithmeticError):  # no value there: no trend to see
            return np.zeros(Jv.shape, dtype=bool), 2 * k + 2
        gaps.append(np.abs(Jv - diff))
    return gaps[-1] < 0.5 * gaps[-3], 2 * TREND_STEPS
