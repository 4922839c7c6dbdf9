"""Argument checks shared by every public entry point.

Each ``check_*`` helper either returns a clean float64/int64 array or raises a
``TypeError``/``ValueError`` saying what was expected and what arrived. Nothing here
knows about the mathematics beyond shapes and finiteness.
"""

from __future__ import annotations

import numpy as np

_KIND_NAMES = {
    "b": "bool",
    "c": "complex",
    "O": "object",
    "U": "string",
    "S": "bytes",
    "V": "structured/void",
    "M": "datetime",
    "m": "timedelta",
}


def check_real_array(a, name: str) -> np.ndarray:
    """Return ``a`` as an ndarray of a real numeric dtype (not yet converted).

    Raises
    ------
    TypeError
        If ``a`` has a bool, complex, object, string or other non-real dtype.
    """
    arr = a if isinstance(a, np.ndarray) else np.asarray(a)
    kind = arr.dtype.kind
    if kind not in "fiu":
        what = _KIND_NAMES.get(kind, str(arr.dtype))
        raise TypeError(
            f"{name} must hold real numbers (float or integer dtype), got dtype {arr.dtype} "
            f"({what})"
        )
    return arr


def check_finite(arr: np.ndarray, name: str) -> None:
    """Raise ``ValueError`` naming the first non-finite entry of ``arr``."""
    if arr.dtype.kind == "f":
        bad = ~np.isfinite(arr)
        if bad.any():
            idx = tuple(int(i) for i in np.argwhere(bad)[0])
            raise ValueError(f"{name} must be finite, but {name}{list(idx)} = {arr[idx]}")


def check_matrix(a, name: str, shape: tuple[int | None, int | None]) -> np.ndarray:
    """Validate a 2-D real finite matrix; ``None`` in ``shape`` means any size.

    Returns a C-contiguous float64 copy that the caller owns.
    """
    arr = check_real_array(a, name)
    if arr.ndim != 2:
        raise ValueError(f"{name} must be a 2-D array, got {arr.ndim}-D with shape {arr.shape}")
    for axis, (want, got) in enumerate(zip(shape, arr.shape, strict=True)):
        if want is not None and want != got:
            expected = ", ".join("any" if s is None else str(s) for s in shape)
            raise ValueError(
                f"{name} must have shape ({expected}), got {arr.shape} (axis {axis}: expected "
                f"{want}, got {got})"
            )
    check_finite(arr, name)
    return np.array(arr, dtype=np.float64, order="C", copy=True)


def check_points(V, dim: int, name: str = "V") -> tuple[np.ndarray, tuple[int, ...]]:
    """Validate query vectors of shape ``(..., dim)``.

    Returns
    -------
    flat : ndarray, shape (m, dim)
        C-contiguous float64 (a view when the input already is one, else a copy).
    lead : tuple
        The leading shape, so that the result can be reshaped to ``lead + (dim,)``.
    """
    arr = check_real_array(V, name)
    if arr.ndim == 0 or arr.shape[-1] != dim:
        got = "a scalar" if arr.ndim == 0 else f"shape {arr.shape}"
        raise ValueError(
            f"{name} must have shape (..., {dim}) (vectors of dimension {dim}, the dimension "
            f"of this map), got {got}"
        )
    lead = arr.shape[:-1]
    flat = np.ascontiguousarray(arr.reshape(-1, dim), dtype=np.float64)
    if not np.isfinite(flat).all():
        row = int(np.flatnonzero(~np.isfinite(flat).all(axis=1))[0])
        if lead:
            where = ", ".join(str(int(i)) for i in np.unravel_index(row, lead))
            what = f"vector {name}[{where}] = {flat[row]} is not"
        else:
            what = f"{name} = {flat[row]} is not"
        raise ValueError(f"{name} must be finite, but {what}")
    return flat, lead


def check_out(out, shape: tuple[int, ...], name: str = "out") -> np.ndarray:
    """Check a user ``out`` array: float64, C-contiguous, writeable, of the given shape."""
    if not isinstance(out, np.ndarray):
        raise TypeError(f"{name} must be a numpy array, got {type(out).__name__}")
    if out.shape != shape:
        raise ValueError(f"{name} must have shape {shape}, got {out.shape}")
    if out.dtype != np.float64 or not out.flags.c_contiguous or not out.flags.writeable:
        raise ValueError(
            f"{name} must be a writeable C-contiguous float64 array, got dtype {out.dtype}, "
            f"contiguous={out.flags.c_contiguous}, writeable={out.flags.writeable}"
        )
    return out


def check_order(order, n: int) -> np.ndarray:
    """Validate an event order: a permutation of ``0..n-1``; returns int64 array."""
    arr = np.asarray(order)
    if arr.dtype.kind not in "iu":
        if arr.dtype.kind == "f" and arr.ndim == 1 and np.all(arr == np.round(arr)):
            arr = arr.astype(np.int64)
        else:
            raise TypeError(f"order must be a sequence of integers, got dtype {arr.dtype}")
    if arr.shape != (n,) or not np.array_equal(np.sort(arr), np.arange(n)):
        raise ValueError(
            f"order must be a permutation of 0..{n - 1} (each of the {n} events once), "
            f"got {arr.tolist()}"
        )
    return arr.astype(np.int64)


def check_positive_int(value, name: str) -> int:
    """Validate a positive integer parameter."""
    if isinstance(value, bool) or not isinstance(value, int | np.integer):
        raise TypeError(f"{name} must be an integer, got {type(value).__name__}")
    if value < 1:
        raise ValueError(f"{name} must be >= 1, got {value}")
    return int(value)
