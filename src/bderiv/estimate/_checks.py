"""Checked inputs of the hybrid Kalman filter: states, covariances, measurements.

Every refusal is a ``ValueError`` (or ``TypeError`` for a wrong kind of object) naming the
parameter, what was expected and what came.
"""

from __future__ import annotations

import numpy as np

from .._support._format import format_state
from .._support._validate_ints import check_distinct

#: relative asymmetry ``max|P - P^T| / max|P|`` a covariance may have (rounding of sums)
SYMMETRY_RTOL = 1e-9
#: relative negative eigenvalue ``-min(eig) / max(eig)`` a covariance may have (rounding)
PSD_RTOL = 1e-9


def check_vector(x, name: str, size: int | None = None) -> np.ndarray:
    """``x`` as a finite float64 array of shape (size,) (any size when None)."""
    return check_matrix(x, name, (size,))


def check_matrix(a, name: str, shape) -> np.ndarray:
    """``a`` as a finite float64 array of ``shape`` (entries None: any size there), from
    anything that ``numpy.array(a, dtype=float64)`` converts but a string."""
    if isinstance(a, str | bytes) or a is None:
        raise TypeError(f"{name} must be an array of numbers, got {type(a).__name__}")
    try:
        if np.iscomplexobj(a):  # (numpy would drop the imaginary part with a warning)
            raise TypeError
        arr = np.array(a, dtype=np.float64)
    except (TypeError, ValueError):
        raise TypeError(f"{name} must be an array of real numbers, got {a!r}") from None
    if arr.ndim != len(shape) or any(s is not None and s != t for s, t in zip(shape, arr.shape,
                                                                           strict=True)):
        want = ", ".join("k" if s is None else str(s) for s in shape)
        raise ValueError(f"{name} must have shape ({want}{',' * (len(shape) == 1)}), got "
                         f"shape {arr.shape}")
    if not np.isfinite(arr).all():
        at = np.unravel_index(int(np.flatnonzero(~np.isfinite(arr))[0]), arr.shape)
        raise ValueError(f"{name} must be finite, but {name}[{', '.join(map(str, at))}] = "
                         f"{arr[at]}; got {format_state(arr)}")
    return arr


def check_covariance(P, name: str, dim: int, *, definite: bool = False) -> np.ndarray:
    """A covariance (dim, dim): finite, symmetric and positive semi-definite (definite:
    positive definite), each to rounding; returned symmetrised.

    Raises
    ------
    ValueError
        Naming ``name`` and the asymmetry or the smallest eigenvalue found.
    """
    P = check_matrix(P, name, (dim, dim))
    scale = float(np.abs(P).max())
    asym = float(np.abs(P - P.T).max())
    if asym > SYMMETRY_RTOL * scale:
        raise ValueError(f"{name} must be symmetric, got max|{name} - {name}^T| = {asym:.3g} "
                         f"(max|{name}| = {scale:.3g})")
    P = 0.5 * (P + P.T)
    w = np.linalg.eigvalsh(P)
    top = max(float(w[-1]), 0.0)
    if definite and not w[0] > PSD_RTOL * top:
        raise ValueError(f"{name} must be positive definite, got smallest eigenvalue "
                         f"{w[0]:.3g} (largest {w[-1]:.3g})")
    if w[0] < -PSD_RTOL * top:
        raise ValueError(f"{name} must be positive semi-definite, got eigenvalue {w[0]:.3g} "
                         f"(largest {w[-1]:.3g})")
    return P


def check_time(dt, name: str = "dt") -> float:
    """A finite time > 0."""
    if isinstance(dt, bool) or not isinstance(dt, int | float | np.integer | np.floating):
        raise TypeError(f"{name} must be a number, got {type(dt).__name__}")
    dt = float(dt)
    if not (np.isfinite(dt) and dt > 0):
        raise ValueError(f"{name} must be a finite number > 0, got {dt}")
    return dt


def measurement_model(h, H, x, dim: int):
    """The predicted measurement ``h(x)`` (p,) and its Jacobian ``H`` (p, dim) at ``x``.

    ``H`` is a matrix (p, dim) or a callable ``H(x) -> (p, dim)``; ``h`` a callable
    ``h(x) -> (p,)`` or None (the linear measurement ``H x``).
    """
    if callable(H):
        Hx = check_matrix(H(x.copy()), "H(x)", (None, dim))
    elif H is None:
        raise TypeError("H must be given: a (p, d) matrix or a callable H(x) -> (p, d)")
    else:
        Hx = check_matrix(H, "H", (None, dim))
    if not Hx.shape[0]:
        raise ValueError(f"H{'(x)' if callable(H) else ''} must have at least one row (one per "
                         f"measured quantity, shape (p, {dim}), p >= 1), got shape {Hx.shape}")
    if h is None:
        return Hx @ x, Hx
    if not callable(h):
        raise TypeError(f"h must be a callable h(x) -> (p,) or None, got {type(h).__name__}")
    hx = check_vector(h(x.copy()), "h(x)")
    if hx.shape[0] != Hx.shape[0]:
        raise ValueError(f"h(x) has {hx.shape[0]} entries but H has {Hx.shape[0]} rows")
    return hx, Hx


def check_priority(priority, n_events: int) -> tuple | None:
    """``priority`` (None, or global event indices each once, in ``[0, n_events)``) as a
    tuple of int."""
    if priority is None:
        return None
    name = "priority (global event indices, each once, in the order assumed)"
    if isinstance(priority, str | bytes) or np.ndim(priority) != 1:
        raise TypeError(f"{name} must be a 1-D sequence of integers, got "
                        f"{type(priority).__name__} {priority!r}")
    bad = [k for k in priority
           if isinstance(k, bool | np.bool_) or not isinstance(k, int | np.integer)]
    if bad:
        raise TypeError(f"{name} must hold integers, got {bad[0]!r} in {priority!r}")
    return tuple(check_distinct([int(k) for k in priority], n_events, "priority", "event"))
