"""The right-hand side the integrator sees: the user's field, and the variational equations.

The integrated vector is ``y = x`` (length d), or with the variational equations
``y = (x, Phi)`` (length d + d * d, the sensitivity Phi row-major) with
``Phi' = J(x) Phi``, ``J = field_jacobian(x, mask)``: the layout of the Python path
(:func:`bderiv.models.integrate.run.run`), so that both control the error of the same vector.

Without a ``field_jacobian``, ``J`` is computed here (:func:`jacobian`): by complex step
when the field compiles for complex input (exact to rounding: no difference is taken), else
by central differences, each coordinate with a step from its magnitude, at least 1.

A model with parameters (:class:`~bderiv.models.compiled.CompiledModel`'s ``params``, m values)
has functions that take ``x`` of length d + m, the state followed by the parameter values
(:func:`argument`): a parameter change is another array in the model's struct, not
another compilation. The section takes the state alone.

Every output of a user function is checked here (shape, finite); a failure returns a status
code and leaves the state in ``bad``, and the driver stops: the Python side turns the code
into an error that names the function, the region and the state.
"""

from __future__ import annotations

import numpy as np
from numba import njit, types

from ..._numerics import CENTRAL_STEP, COMPLEX_STEP, SCALE_FLOOR
from ._cached import eager

OK = 0
FIELD_SHAPE = 1
FIELD_NONFINITE = 2
JACOBIAN_SHAPE = 3
JACOBIAN_NONFINITE = 4
EVENTS_SHAPE = 5
EVENTS_NONFINITE = 6
SECTION_NONFINITE = 7
#: a user function raised (caught in compiled code: the state is kept, and the Python side
#: calls the function again there to say what it raised)
FIELD_RAISED = 8
EVENTS_RAISED = 9
JACOBIAN_RAISED = 10
SECTION_RAISED = 11

#: how J is had: the given ``field_jacobian``, complex step, central differences
JAC_GIVEN = 0
JAC_COMPLEX_STEP = 1
JAC_CENTRAL = 2

_VECTOR = types.float64[::1]
_CVECTOR = types.complex128[::1]
#: the types the integrator calls the user's functions with: field(x, mask) -> (d,),
#: field_jacobian(x, mask) -> (d, d), events(x) -> (n,), section(x) -> float;
#: C-contiguous float64 arrays (the field for complex step: complex128 in and out).
FIELD_SIGNATURE = _VECTOR(_VECTOR, types.int64)
COMPLEX_FIELD_SIGNATURE = _CVECTOR(_CVECTOR, types.int64)
JACOBIAN_SIGNATURE = types.float64[:, ::1](_VECTOR, types.int64)
EVENTS_SIGNATURE = _VECTOR(_VECTOR)
SECTION_SIGNATURE = types.float64(_VECTOR)
FIELD_TYPE = types.FunctionType(FIELD_SIGNATURE)
COMPLEX_FIELD_TYPE = types.FunctionType(COMPLEX_FIELD_SIGNATURE)
JACOBIAN_TYPE = types.FunctionType(JACOBIAN_SIGNATURE)
EVENTS_TYPE = types.FunctionType(EVENTS_SIGNATURE)
SECTION_TYPE = types.FunctionType(SECTION_SIGNATURE)


@njit(cache=True, inline="always")
def finite_vector(v):
    """True when every entry of the 1-D array ``v`` is finite (no view made: the hot path).

    ``v[j] * 0`` is zero for a finite entry and NaN otherwise; their sum, in four partial
    sums, is zero exactly when all are finite (faster than a loop that stops at the first
    bad entry, which cannot overlap its iterations: docs/benchmarks.md, "Kernel design
    choices, measured")."""
    n = v.size
    s0 = s1 = s2 = s3 = 0.0
    for j in range(0, n - 3, 4):
        s0 += v[j] * 0.0
        s1 += v[j + 1] * 0.0
        s2 += v[j + 2] * 0.0
        s3 += v[j + 3] * 0.0
    for j in range(n - n % 4, n):
        s0 += v[j] * 0.0
    return s0 + s1 + s2 + s3 == 0.0


@njit(cache=True)
def all_finite(a):
    """True when every entry of the 2-D array ``a`` is finite."""
    for i in range(a.shape[0]):
        if not finite_vector(a[i]):
            return False
    return True


@njit(cache=True)
def coordinate_scale(v):
    """A coordinate's own scale: ``|v|``, at least ``SCALE_FLOOR``; 1 for ``v = 0``."""
    s = abs(v)
    return max(s, SCALE_FLOOR) if s > 0.0 else 1.0


@njit(cache=True, inline="always")
def fill_argument(a, y, params, d):
    """``a`` = the state ``y[:d]`` followed by ``params``: element loops, no slice of ``y``
    (a view costs two atomic reference counts)."""
    for j in range(d):
        a[j] = y[j]
    for j in range(params.size):
        a[d + j] = params[j]


@njit(cache=True, inline="always")
def state_argument(model, y, d):
    """:func:`argument` at the state ``x = y[:d]`` (``y`` may be the integrated vector)."""
    p = model.params
    a = np.empty(d + p.size)
    fill_argument(a, y, p, d)
    return a


@njit(cache=True)
def argument(model, x):
    """What the model's functions take at the state ``x`` (d,): a fresh copy of it,
    followed by the model's parameter values (none for a model without)."""
    return state_argument(model, x, x.size)


@njit(cache=True)
def jacobian(model, mode, x, mask, d, J):
    """``J = d field(x, mask) / dx`` (d, d) by ``mode``; a status (checked: shape, finite).

    The state is ``x[:d]`` (``x`` may be the integrated vector, the state first). Complex
    step: column j is ``Im field(x + i h e_j) / h``; central differences: ``(f(x + h e_j)
    - f(x - h e_j)) / (2 h)`` with the step as represented (``(x_j + h) - x_j``), h =
    ``CENTRAL_STEP * max(|x_j|, 1)``.
    """
    if mode == JAC_GIVEN:
        try:
            given = model.jacobian(state_argument(model, x, d), mask)
        except Exception:  # noqa: BLE001 - whatever it raised: named from Python
            return JACOBIAN_RAISED
        if given.shape[0] != d or given.shape[1] != d:
            return JACOBIAN_SHAPE
        for i in range(d):
            for j in range(d):
                J[i, j] = given[i, j]
    elif mode == JAC_COMPLEX_STEP:
        base = state_argument(model, x, d)
        z = np.empty(base.size, dtype=np.complex128)
        for j in range(d):
            h = COMPLEX_STEP * coordinate_scale(x[j])
            for i in range(base.size):
                z[i] = base[i]
            z[j] = complex(x[j], h)
            try:
                f = model.cfield(z, mask)
            except Exception:  # noqa: BLE001
                return FIELD_RAISED
            if f.size != d:
                return FIELD_SHAPE
            for i in range(d):
                J[i, j] = f[i].imag / h
    else:
        xs = state_argument(model, x, d)
        for j in range(d):
            # the step from max(|x_j|, 1), not from |x_j|: a coordinate near 0 (a pitch at
            # 1e-31 on a symmetric gait) does not vary the field on a scale of its size, and
            # a step of 2^-17 |x_j| there is all rounding (J off by 1e-2: the variational
            # equations' error estimate sees it, and their steps shrank to 1e-9)
            step = CENTRAL_STEP * max(abs(x[j]), 1.0)
            for i in range(d):
                xs[i] = x[i]
            xs[j] = x[j] + step
            up_step = xs[j] - x[j]
            try:
                up = model.field(xs.copy(), mask)
                xs[j] = x[j] - step
                down_step = x[j] - xs[j]
                down = model.field(xs.copy(), mask)
            except Exception:  # noqa: BLE001
                return FIELD_RAISED
            if up.size != d or down.size != d:
                return FIELD_SHAPE
            for i in range(d):
                J[i, j] = (up[i] - down[i]) / (up_step + down_step)
    return OK if all_finite(J) else JACOBIAN_NONFINITE


@njit(cache=True, inline="always")
def field_value(model, a, mask, d):
    """``(status, field(a, mask))`` at the argument ``a`` (fresh: :func:`state_argument`),
    checked: ``OK`` or the failed check (shape, finite, raised)."""
    try:
        f = model.field(a, mask)
    except Exception:  # noqa: BLE001 - whatever it raised: named from Python
        return FIELD_RAISED, np.empty(0)
    if f.size != d:
        return FIELD_SHAPE, f
    # finite_vector written out: inlined, it takes f as a new reference, whose count
    # numba does not prune here (two atomic operations per field call)
    n = f.size
    s0 = s1 = s2 = s3 = 0.0
    for j in range(0, n - 3, 4):
        s0 += f[j] * 0.0
        s1 += f[j + 1] * 0.0
        s2 += f[j + 2] * 0.0
        s3 += f[j + 3] * 0.0
    for j in range(n - n % 4, n):
        s0 += f[j] * 0.0
    if s0 + s1 + s2 + s3 != 0.0:
        return FIELD_NONFINITE, f
    return OK, f


@njit(cache=True)
def sensitivity_rate(model, mode, mask, d, y, out):
    """``out[d:] = J(x) Phi`` at ``y = (x, Phi)`` (Phi row-major, J by ``mode``): the
    variational part of :func:`rhs`; a status (the checks of :func:`jacobian`)."""
    J = np.empty((d, d))
    status = jacobian(model, mode, y, mask, d, J)
    if status == OK:  # BLAS for the product (d^3 of the work)
        np.dot(J, y[d:].reshape((d, d)), out[d:].reshape((d, d)))
    return status


@njit(cache=True)
def rhs(model, mode, variational, mask, d, y, out, bad):
    """``out = f(y)``: the field at ``x = y[:d]``, and ``J(x) Phi`` when ``variational``
    (``out`` may be shorter than ``y``: the state's part only, for ``d`` entries).

    The user's functions get a fresh copy of ``x`` (they may keep or change it;
    :func:`argument`). Returns ``OK`` or the code of the failed check, the state copied
    into ``bad``. (The integrator's stages write this out in their loop:
    :func:`._dop853.stages`; the driver calls this once per stretch, not inlined.)
    """
    status, f = field_value(model, state_argument(model, y, d), mask, d)
    if status == OK and variational:
        status = sensitivity_rate(model, mode, mask, d, y, out)
    if status != OK:
        for j in range(d):
            bad[j] = y[j]
        return status
    for j in range(d):
        out[j] = f[j]
    return OK


@njit(cache=True, inline="always")
def state_events(model, with_section, y, d, n, g, bad):
    """:func:`call_events` at the state ``x = y[:d]`` (``y`` may be the integrated vector;
    no view of it: the driver's call at every step)."""
    m = n - 1 if with_section else n
    status = OK
    try:
        value = model.events(state_argument(model, y, d))
    except Exception:  # noqa: BLE001 - whatever it raised: named from Python
        value, status = np.empty(0), EVENTS_RAISED
    if status != OK:
        pass
    elif value.size != m:
        status = EVENTS_SHAPE
    elif not finite_vector(value):
        status = EVENTS_NONFINITE
    else:
        for k in range(m):
            g[k] = value[k]
        if with_section:
            x = np.empty(d)
            for j in range(d):
                x[j] = y[j]
            try:
                s = model.section(x)
            except Exception:  # noqa: BLE001
                s, status = 0.0, SECTION_RAISED
            if status != OK:
                pass
            elif np.isfinite(s):
                g[m] = s
            else:
                status = SECTION_NONFINITE
    if status != OK:
        for j in range(d):
            bad[j] = y[j]
    return status


@njit(cache=True)
def call_events(model, with_section, x, n, g, bad):
    """``g = events(x)`` checked (shape, finite), and ``g[n - 1] = section(x)`` when
    ``with_section``; a status as :func:`rhs`."""
    return state_events(model, with_section, x, x.size, n, g, bad)


@njit(cache=True)
def checked_field(model, x, mask, d):
    """``(status, field(x, mask))`` at the state ``x`` (d,): ``OK`` or the failed check
    (shape, finite)."""
    return field_value(model, state_argument(model, x, d), mask, d)


@njit(cache=True)
def events_rows(model, X, n, G, bad):
    """``G[i] = events(X[i])`` for every row of ``X`` (m, d), checked; a status (the
    failed row in ``bad``)."""
    for i in range(X.shape[0]):
        status = call_events(model, np.bool_(False), X[i], n, G[i], bad)  # argument() copies X[i]
        if status != OK:
            return status
    return OK


@njit(cache=True)
def field_rows(model, x, masks, d, out):
    """``out[i] = field(x, masks[i])`` for every mask, checked: ``(status, i)`` (i: the
    failed mask's index)."""
    for i in range(masks.size):
        status, f = checked_field(model, x, masks[i], d)
        if status != OK:
            return status, i
        for j in range(d):
            out[i, j] = f[j]
    return OK, 0


@njit(cache=True)
def events_and_field(model, x, mask, n, d, h, F):
    """``h = events(x)`` and ``F = field(x, mask)``, checked (what a stop reads first, in
    one call); a status as :func:`rhs`."""
    status = call_events(model, np.bool_(False), x, n, h, np.empty(d))
    if status != OK:
        return status
    status, f = checked_field(model, x, mask, d)
    if status == OK:
        for i in range(d):
            F[i] = f[i]
    return status


@eager(JACOBIAN_SIGNATURE)
def no_jacobian(x, mask):  # pragma: no cover - passed, never called
    """Stands for ``field_jacobian`` when the sensitivity is not carried (never called)."""
    return np.empty((0, 0))


@eager(COMPLEX_FIELD_SIGNATURE)
def no_complex_field(x, mask):  # pragma: no cover - passed, never called
    """Stands for the complex field when complex step is not used (never called)."""
    return np.empty(0, dtype=np.complex128)


@eager(EVENTS_SIGNATURE)
def no_events(x):
    """``events`` of a model without events: no values."""
    return np.empty(0)


@eager(SECTION_SIGNATURE)
def no_section(x):  # pragma: no cover - passed, never called
    """Stands for the section of a run without one (never called)."""
    return 0.0
