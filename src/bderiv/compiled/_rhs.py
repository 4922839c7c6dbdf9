"""The right-hand side the integrator sees: the user's field, and the variational equations.

The integrated vector is ``y = x`` (length d), or with the variational equations
``y = (x, Phi)`` (length d + d * d, the sensitivity Phi row-major) with
``Phi' = J(x) Phi``, ``J = field_jacobian(x, mask)``: the layout of the Python path
(:func:`bderiv.simulate.run`), so that both control the error of the same vector.

Every output of a user function is checked here (shape, finite); a failure returns a status
code and leaves the state in ``bad``, and the driver stops: the Python side turns the code
into an error that names the function, the region and the state.
"""

from __future__ import annotations

import numpy as np
from numba import njit, types

OK = 0
FIELD_SHAPE = 1
FIELD_NONFINITE = 2
JACOBIAN_SHAPE = 3
JACOBIAN_NONFINITE = 4
EVENTS_SHAPE = 5
EVENTS_NONFINITE = 6

_VECTOR = types.float64[::1]
#: the types the integrator calls the user's functions with: field(x, mask) -> (d,),
#: field_jacobian(x, mask) -> (d, d), events(x) -> (n,); C-contiguous float64 arrays.
FIELD_SIGNATURE = _VECTOR(_VECTOR, types.int64)
JACOBIAN_SIGNATURE = types.float64[:, ::1](_VECTOR, types.int64)
EVENTS_SIGNATURE = _VECTOR(_VECTOR)
FIELD_TYPE = types.FunctionType(FIELD_SIGNATURE)
JACOBIAN_TYPE = types.FunctionType(JACOBIAN_SIGNATURE)
EVENTS_TYPE = types.FunctionType(EVENTS_SIGNATURE)


@njit(cache=True)
def all_finite(a):
    """True when every entry of the 1-D or 2-D array ``a`` is finite."""
    for v in a.ravel():
        if not np.isfinite(v):
            return False
    return True


@njit(cache=True)
def rhs(field, jac, variational, mask, d, y, out, bad):
    """``out = f(y)``: the field at ``x = y[:d]``, and ``J(x) Phi`` when ``variational``.

    The user's functions get a fresh copy of ``x`` (they may keep or change it). Returns
    ``OK`` or the code of the failed check, the state copied into ``bad``.
    """
    x = y[:d].copy()
    f = field(x, mask)
    status = OK
    if f.size != d:
        status = FIELD_SHAPE
    elif not all_finite(f):
        status = FIELD_NONFINITE
    elif variational:
        J = jac(x, mask)
        if J.shape[0] != d or J.shape[1] != d:
            status = JACOBIAN_SHAPE
        elif not all_finite(J):
            status = JACOBIAN_NONFINITE
        else:  # Phi row-major in y[d:]; BLAS for the product (d^3 of the stage's work)
            out[d:] = np.dot(J, y[d:].reshape((d, d))).ravel()
    if status != OK:
        bad[:] = y[:d]
        return status
    out[:d] = f
    return OK


@njit(cache=True)
def call_events(events, x, n, g, bad):
    """``g = events(x)`` checked (shape (n,), finite); a status as :func:`rhs`."""
    value = events(x.copy())
    if value.size != n:
        bad[:] = x
        return EVENTS_SHAPE
    if not all_finite(value):
        bad[:] = x
        return EVENTS_NONFINITE
    g[:] = value
    return OK


@njit(JACOBIAN_SIGNATURE, cache=True)
def no_jacobian(x, mask):  # pragma: no cover - passed, never called
    """Stands for ``field_jacobian`` when the sensitivity is not carried (never called)."""
    return np.empty((0, 0))


@njit(EVENTS_SIGNATURE, cache=True)
def no_events(x):
    """``events`` of a model without events: no values."""
    return np.empty(0)
