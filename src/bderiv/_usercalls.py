"""Checked calls of a user's model functions: outputs validated, numerical Jacobians."""

from __future__ import annotations

import numpy as np
from scipy.differentiate import jacobian as _scipy_jacobian

from ._validate import check_real_array

#: Tolerances of :func:`scipy.differentiate.jacobian` for missing Jacobians.
_JAC_TOLERANCES = {"atol": 1e-11, "rtol": 1e-10}
_JAC_INITIAL_STEP = 0.05


def check_callable(f, name: str) -> None:
    """Refuse a parameter that should be a function (None passes: optional)."""
    if f is not None and not callable(f):
        raise TypeError(f"{name} must be callable, got {type(f).__name__}")


def check_output(value, shape, what: str) -> np.ndarray:
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


def numerical_jacobian(fun, x, n_out: int, what: str) -> np.ndarray:
    """Jacobian (n_out, d) of ``fun`` at ``x`` by :func:`scipy.differentiate.jacobian`
    (adaptive step, error estimate) on a wrapper that loops over the points scipy asks for;
    ``what`` names the function in the error raised for a non-finite result."""
    d = x.shape[0]

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
