"""DOP853 (Dormand-Prince 8(5,3)) kernels: stages, error norm, step control, dense output.

The tableau is scipy's own (``scipy.integrate._ivp.dop853_coefficients``), read once
here: the same digits as ``solve_ivp(method="DOP853")``, so that both take the same steps
and the tests can hold this integrator to scipy's on the same problems. The module is
private to scipy; if it moves, importing :mod:`bderiv.models.compiled` fails with an ImportError
that says so (writing the tableau in would silently drift from the solver it is compared
with). Where scipy.integrate is not imported yet, the file is run on its own (it needs only
NumPy): importing the package would import its quadrature, BVP and special functions, about
0.35 s of every process that runs the compiled path, which never calls them. The arrays
become compile-time constants of the kernels.

The kernels mirror ``scipy.integrate._ivp.rk`` (``rk_step``, ``DOP853._estimate_error_norm``,
``RungeKutta._step_impl``'s factors, ``Dop853DenseOutput``) and ``common.select_initial_step``.
They work on the integrated vector ``y`` of length ``m`` (the state, or the state and its
sensitivity, see :mod:`._rhs`) and do no validation.
"""

from __future__ import annotations

import importlib.util
import pathlib
import sys

import numpy as np
import scipy
from numba import njit

from ._rhs import OK, field_value, fill_argument, rhs, sensitivity_rate

_TABLEAU = "scipy.integrate._ivp.dop853_coefficients"


def _scipys_tableau():
    """scipy's module of the DOP853 tableau: its file run on its own where scipy.integrate
    is not imported and the file is there (an install without sources imports it)."""
    path = pathlib.Path(scipy.__file__).parent / "integrate" / "_ivp" / "dop853_coefficients.py"
    if "scipy.integrate" not in sys.modules and path.is_file():
        spec = importlib.util.spec_from_file_location(_TABLEAU, path)
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
        return module
    try:
        return importlib.import_module(_TABLEAU)
    except ImportError as exc:  # pragma: no cover - depends on scipy's private layout
        raise ImportError(
            f"bderiv.models.compiled reads the DOP853 tableau from scipy's private module "
            f"{_TABLEAU}, which this scipy does not have; install a scipy that has it "
            f"(1.15 to 1.17 do)") from exc


_tableau = _scipys_tableau()
#: stages of a step (the 13th row of K holds f at the step's end, the FSAL value)
N_STAGES = _tableau.N_STAGES
#: stages with the three extra ones of the dense output
N_STAGES_EXTENDED = _tableau.N_STAGES_EXTENDED
#: rows of the dense output's coefficient array F
INTERPOLATOR_POWER = _tableau.INTERPOLATOR_POWER
A = np.ascontiguousarray(_tableau.A, dtype=np.float64)
B = np.ascontiguousarray(_tableau.B, dtype=np.float64)
C = np.ascontiguousarray(_tableau.C, dtype=np.float64)
E3 = np.ascontiguousarray(_tableau.E3, dtype=np.float64)
E5 = np.ascontiguousarray(_tableau.E5, dtype=np.float64)
D = np.ascontiguousarray(_tableau.D, dtype=np.float64)
#: step-size control of scipy's RungeKutta: safety factor, bounds of one change, and the
#: exponent -1 / (error estimator order + 1) with the estimator of order 7
SAFETY = 0.9
MIN_FACTOR = 0.2
MAX_FACTOR = 10.0
ERROR_EXPONENT = -1.0 / 8.0


@njit(cache=True)
def rms(v, scale):
    """RMS norm of ``v / scale`` (scipy's ``common.norm``)."""
    s = 0.0
    for j in range(v.size):
        q = v[j] / scale[j]
        s += q * q
    return np.sqrt(s / v.size)


@njit(cache=True)
def initial_step(model, jac_mode, variational, mask, d, t0, y0, f0, t_bound, max_step, rtol,
                 atol, work, bad):
    """scipy's ``select_initial_step`` (order 7): ``(status, h_abs)``; one rhs call.

    ``work`` is an (3, m) scratch array; ``bad`` receives the state of a failed call.
    """
    m = y0.size
    interval = abs(t_bound - t0)
    scale, y1, f1 = work[0], work[1], work[2]
    for j in range(m):
        scale[j] = atol[j] + abs(y0[j]) * rtol
    d0 = rms(y0, scale)
    d1 = rms(f0, scale)
    h0 = 1e-6 if d0 < 1e-5 or d1 < 1e-5 else 0.01 * d0 / d1
    h0 = min(h0, interval)
    for j in range(m):
        y1[j] = y0[j] + h0 * f0[j]
    status = rhs(model, jac_mode, variational, mask, d, y1, f1, bad)
    if status != OK:
        return status, 0.0
    for j in range(m):
        y1[j] = f1[j] - f0[j]  # reuse y1 for the difference
    d2 = rms(y1, scale) / h0
    if d1 <= 1e-15 and d2 <= 1e-15:
        h1 = max(1e-6, h0 * 1e-3)
    else:
        h1 = (0.01 / max(d1, d2)) ** (1.0 / 8.0)
    return OK, min(100.0 * h0, h1, interval, max_step)


@njit(cache=True, inline="always")
def _combination(y, K, s, h, n, out):
    """``out[:n] = y[:n] + h * (K[:s, :n].T @ A[s, :s])``: stage s's point (scipy's
    ``y + dot(K[:s].T, a[:s]) * h``), each component's sum in the order r = 0, 1, ...

    Called with a constant ``s`` (:func:`step_point`, :func:`dense_point`): LLVM unrolls
    the sum over the rows, folds the coefficients in and vectorizes over the components.
    ``out`` must not overlap ``y`` or ``K``."""
    for j in range(n):
        acc = 0.0
        for r in range(s):
            acc += K[r, j] * A[s, r]
        out[j] = y[j] + acc * h


@njit(cache=True, inline="always")
def step_point(y, K, s, h, n, out):
    """:func:`_combination` for stage ``s`` of the step (1 to 12; 12 is the step's
    8th-order solution, ``A[12, :12]`` being ``B``), one branch per stage: a constant
    number of rows in each (faster than a sum over ``s`` rows: docs/benchmarks.md,
    "Kernel design choices, measured")."""
    if s == 1:
        _combination(y, K, 1, h, n, out)
    elif s == 2:
        _combination(y, K, 2, h, n, out)
    elif s == 3:
        _combination(y, K, 3, h, n, out)
    elif s == 4:
        _combination(y, K, 4, h, n, out)
    elif s == 5:
        _combination(y, K, 5, h, n, out)
    elif s == 6:
        _combination(y, K, 6, h, n, out)
    elif s == 7:
        _combination(y, K, 7, h, n, out)
    elif s == 8:
        _combination(y, K, 8, h, n, out)
    elif s == 9:
        _combination(y, K, 9, h, n, out)
    elif s == 10:
        _combination(y, K, 10, h, n, out)
    elif s == 11:
        _combination(y, K, 11, h, n, out)
    else:
        _combination(y, K, 12, h, n, out)


@njit(cache=True, inline="always")
def dense_point(y, K, s, h, n, out):
    """:func:`step_point` for the dense output's extra stages (13 to 15): each use of
    :func:`stages` compiles only the branches it runs."""
    if s == 13:
        _combination(y, K, 13, h, n, out)
    elif s == 14:
        _combination(y, K, 14, h, n, out)
    else:
        _combination(y, K, 15, h, n, out)


@njit(cache=True, inline="always")
def stages(model, jac_mode, variational, mask, d, y, K, first, last, h, n, points, bad,
           point):
    """Stages ``first`` to ``last - 1`` of the step of size ``h`` from ``y``: each one's
    point (its first n components, by ``point``: :func:`step_point` or
    :func:`dense_point`) into ``points``, the right-hand side there into ``K[s]``. Returns
    a status (the failed point's state in ``bad``).

    :func:`._rhs.rhs` written out: called per stage it would take the arrays as new
    references, an atomic increment and decrement each that numba cannot prune around
    the user's call (10 of the 22 reference counts of a field call at d = 8). Inlined
    straight into the driver, for the step and for the dense output's extra stages, each
    with only the stage points it runs (``point``: 12 branches, 3; were it inlined through
    a helper, each inlining of the helper would copy it again): a call of it costs its
    arguments' counts, those around the field's calls too (the driver slower per step),
    and so does a call of :func:`step_point` per stage (docs/design.md, "What the
    integrator compiles, measured")."""
    params = model.params
    for s in range(first, last):
        point(y, K, s, h, n, points)
        a = np.empty(d + params.size)
        fill_argument(a, points, params, d)
        status, f = field_value(model, a, mask, d)
        if status == OK and variational:
            status = sensitivity_rate(model, jac_mode, mask, d, points, K[s])
        if status != OK:
            for j in range(d):
                bad[j] = points[j]
            return status
        for j in range(d):
            K[s, j] = f[j]
    return OK


@njit(cache=True, inline="always")
def error_norm(K, h, y, y_new, rtol, atol, work):
    """scipy's combined 5th / 3rd order error estimate of DOP853, scaled RMS norm.

    The scaled estimates go to ``work[1]`` and ``work[2]`` (``work`` (3, m)) in a loop over
    the components (vectorized), their squares are then summed in the order j = 0, 1, ...:
    the same roundings as one loop."""
    m = y.size
    for j in range(m):
        scale = atol[j] + max(abs(y[j]), abs(y_new[j])) * rtol
        a5 = 0.0
        a3 = 0.0
        for r in range(N_STAGES + 1):
            a5 += K[r, j] * E5[r]
            a3 += K[r, j] * E3[r]
        work[1, j] = a5 / scale
        work[2, j] = a3 / scale
    e5 = 0.0
    e3 = 0.0
    for j in range(m):
        e5 += work[1, j] * work[1, j]
        e3 += work[2, j] * work[2, j]
    if e5 == 0.0 and e3 == 0.0:
        return 0.0
    return abs(h) * e5 / np.sqrt((e5 + 0.01 * e3) * m)


@njit(cache=True)
def step_factor(err, rejected):
    """The factor of the next step size after a step with error norm ``err``."""
    if err < 1.0:
        factor = MAX_FACTOR if err == 0.0 else min(MAX_FACTOR, SAFETY * err ** ERROR_EXPONENT)
        return min(1.0, factor) if rejected else factor
    return max(MIN_FACTOR, SAFETY * err ** ERROR_EXPONENT)


@njit(cache=True, inline="always")
def dense_coefficients(y_old, y_new, h, K, F):
    """The 7th-order dense output of the step ``y_old -> y_new`` of size ``h``, of the
    first n components (``F`` (7, n)), from its stages ``K`` with the three extra ones in
    ``K[13:16, :n]`` (:func:`stages` from 13), as scipy's ``DOP853._dense_output_impl``.
    n is the vector's length, or d when the state's output alone is needed."""
    n = F.shape[1]
    for j in range(n):
        dy = y_new[j] - y_old[j]
        F[0, j] = dy
        F[1, j] = h * K[0, j] - dy
        F[2, j] = 2.0 * dy - h * (K[N_STAGES, j] + K[0, j])
    for i in range(D.shape[0]):  # h * (D[i] @ K), each sum in the order r = 0, 1, ...
        for j in range(n):
            acc = 0.0
            for r in range(N_STAGES_EXTENDED):
                acc += D[i, r] * K[r, j]
            F[3 + i, j] = h * acc


@njit(cache=True)
def dense_eval(F, y_old, t_old, h, t, count, out):
    """The dense output at ``t`` of its first ``count`` components into ``out[:count]``
    (scipy's ``Dop853DenseOutput``: alternating factors x and 1 - x, x = (t - t_old) / h)."""
    x = (t - t_old) / h
    n_rows = F.shape[0]
    # each component's sum and products in scipy's order; the rows outer, so that the
    # inner loop runs over the components (2.5x at d = 44: the same bits)
    for j in range(count):
        out[j] = 0.0
    for i in range(n_rows):
        f = x if i % 2 == 0 else 1.0 - x
        for j in range(count):
            out[j] = (out[j] + F[n_rows - 1 - i, j]) * f
    for j in range(count):
        out[j] += y_old[j]


@njit(cache=True)
def dense_rows(t_old, h, F, y_old, T, out):
    """``out[i]`` = the dense output at ``T[i]`` of the recorded steps (start times
    ``t_old`` (S,), sizes ``h``, coefficients ``F`` (S, 7, d), start states ``y_old``
    (S, d)): each time on the step that holds it (the first or last outside them)."""
    last = t_old.size - 1
    for i in range(T.size):
        j = min(max(np.searchsorted(t_old, T[i], side="right") - 1, 0), last)
        dense_eval(F[j], y_old[j], t_old[j], h[j], T[i], out.shape[1], out[i])


@njit(cache=True)
def step_starts(steps, ys, d):
    """The driver's dense record of a stretch (``steps`` (S, 2), its record ``ys``
    (S + 1, m)) as :func:`dense_rows` takes it: the steps' start times and sizes, and their
    start states (rows of ``ys`` as they are when it holds the state alone, else copied
    out), all C-contiguous."""
    t_old, h = np.ascontiguousarray(steps[:, 0]), np.ascontiguousarray(steps[:, 1])
    y_old = ys[:-1] if ys.shape[1] == d else np.ascontiguousarray(ys[:-1, :d])
    return t_old, h, y_old

