"""Argument checks shared by every public entry point.

Each ``check_*`` helper either returns a clean float64/int64 array or raises a
``TypeError``/``ValueError`` saying what was expected and what arrived. Nothing here
knows about the mathematics beyond shapes and finiteness.
"""

from __future__ import annotations

import math
import numbers

import numpy as np

from .._limits import SMALL_NEED_BYTES
from ._errors import QUERY, QueryError
from ._tables import INT64_EVENTS, human_bytes, mask_dtype, memory_headroom

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


def all_finite(arr: np.ndarray) -> bool:
    """Whether every entry of a real (float, integer or bool) array is finite; one pass
    (a sum) where it can.

    A sum is finite only if every term is (an infinity stays, a NaN spreads, and two
    infinities of opposite signs give NaN); a finite array whose sum overflows is caught
    by the element-wise test that follows. The smallest arrays (a model's state, its
    field: checked at every stage of an integration) are summed as Python numbers, about
    half the cost of NumPy's element-wise test; the middle sizes take that test alone,
    counted by ``np.count_nonzero`` (a third of the cost of ``ndarray.all``, as in
    :func:`check_finite`); the large ones are summed by NumPy first.
    """
    if arr.size <= 32 and arr.dtype.kind in "fiub" and math.isfinite(
            sum(arr.ravel().tolist())):
        return True
    if arr.size < 4096:
        return np.count_nonzero(np.isfinite(arr)) == arr.size
    with np.errstate(over="ignore", invalid="ignore"):
        total = arr.sum()
    return math.isfinite(total) or bool(np.isfinite(arr).all())


def check_finite(arr: np.ndarray, name: str) -> None:
    """Raise ``ValueError`` naming the first non-finite entry of ``arr``."""
    if arr.dtype.kind == "f" and np.count_nonzero(np.isfinite(arr)) != arr.size:
        idx = tuple(int(i) for i in np.argwhere(~np.isfinite(arr))[0])
        raise ValueError(f"{name} must be finite, but {name}{list(idx)} = {arr[idx]}")


def singular_condition(mat: np.ndarray) -> float | None:
    """The condition number of a square matrix singular to working precision
    (``cond * eps >= 1``, or not finite), else None."""
    cond = np.linalg.cond(mat)
    return None if cond * np.finfo(np.float64).eps < 1.0 else float(cond)


def check_matrix(a, name: str, shape: tuple[int | None, int | None], *,
                 copy: bool = True) -> np.ndarray:
    """Validate a 2-D real finite matrix; ``None`` in ``shape`` means any size.

    Returns a C-contiguous float64 copy that the caller owns (``copy=False``: the checked
    array itself, any real dtype and layout, for a caller that copies it anyway).
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
    return np.array(arr, dtype=np.float64, order="C", copy=True) if copy else arr


def check_points(V, dim: int, name: str = "V", *, index_shape=None, offset: int = 0,
                 meaning: str = "vectors of dimension {dim}, the dimension of this map"
                 ) -> tuple[np.ndarray, tuple[int, ...]]:
    """Validate query vectors of shape ``(..., dim)``.

    ``index_shape`` and ``offset`` say where the rows sit in a larger batch (a chunk of
    rows ``offset:`` of a batch of leading shape ``index_shape``), so that a non-finite
    vector is named by its index in the whole batch. ``meaning`` says what the rows are in
    the shape's message (``{dim}`` filled in).

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
            f"{name} must have shape (..., {dim}) ({meaning.format(dim=dim)}), got {got}"
        )
    lead = arr.shape[:-1]
    flat = np.ascontiguousarray(arr.reshape(-1, dim), dtype=np.float64)
    if not all_finite(flat):
        row = int(np.flatnonzero(~np.isfinite(flat).all(axis=1))[0])
        shape = lead if index_shape is None else tuple(index_shape)
        if not shape:  # one vector: no index to name
            raise ValueError(f"{name} must be finite, but {name} = {flat[row]} is not")
        raise QueryError(f"{name} must be finite, but vector {QUERY} = {flat[row]} is not",
                         row + offset, name, shape)  # renumbered by callers: QueryError.at
    return flat, lead


def frozen(a, dtype=np.float64) -> np.ndarray:
    """``a`` in the one form a compiled kernel takes an array it only reads: C-contiguous,
    of ``dtype``, read-only (a view; a copy only to change the dtype or the layout).

    A read-only and a writeable array are two numba types, so a kernel given both compiles
    twice (one to two seconds on a cold cache, issue 36); read-only, not writeable, because
    many arrays of the package are read-only by design and a view is free where a
    writeable copy is not.
    """
    arr = np.ascontiguousarray(a, dtype=dtype)
    if arr.flags.writeable:
        arr = arr.view()
        arr.flags.writeable = False
    return arr


def scratch(a, dtype=np.float64) -> np.ndarray:
    """``a`` in the form the compiled run passes its own arrays to the stop rules it shares
    with the Python loop (every function of :mod:`bderiv.models.compiled.rules`):
    C-contiguous, of ``dtype``, writeable (``a`` itself when it is; a copy otherwise).

    The compiled run can only pass writeable arrays, so the Python loop passes the rules
    the same type, and each compiles once for both (in a process that runs both, and in
    the disk cache: the compiled integrator, compiling in the background, loads the rules
    that the Python loop compiled). :func:`frozen` is the form of the other kernels. As
    there, a scalar becomes shape (1,) and a subclass a plain array.
    """
    arr = np.ascontiguousarray(a, dtype=dtype)
    return arr if arr.flags.writeable else arr.copy()


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


def check_state(x, dim: int, name: str = "x") -> np.ndarray:
    """A state of a system of dimension ``dim``: a finite float64 copy, shape (dim,)."""
    if type(x) is np.ndarray and x.dtype == np.float64 and x.shape == (dim,):
        arr = x.copy()  # the common case, checked in a third of the time
    else:
        arr = check_real_array(x, name)
        if arr.shape != (dim,):
            raise ValueError(
                f"{name} must have shape ({dim},) (a state of this system), got "
                f"shape {arr.shape}"
            )
        arr = np.array(arr, dtype=np.float64)
    if not all_finite(arr):
        raise ValueError(f"{name} must be finite, got {arr}")
    return arr


def check_mask(mask, n_events: int, name: str = "mask") -> int:
    """A region mask of a system of ``n_events`` events: an integer in [0, 2**n)."""
    if isinstance(mask, bool) or not isinstance(mask, int | np.integer):
        raise TypeError(f"{name} must be an integer, got {type(mask).__name__}")
    if not 0 <= mask < (1 << n_events):
        raise ValueError(f"{name} must be in [0, 2**{n_events}), got {mask}")
    return int(mask)


def check_masks(masks, n_events: int, name: str = "masks") -> np.ndarray:
    """Region masks of a system of ``n_events`` events (each as :func:`check_mask`), as a
    1-D array: int64, or Python ints (dtype object) beyond 63 events, which an int64 does
    not hold (an unsigned or object array is never cast: a uint64 mask with bit 63 set
    would read as negative)."""
    values = np.asarray(masks)
    if values.dtype.kind not in "iu":  # Python ints beyond int64, int64 and uint64 mixed
        values = np.asarray(masks, dtype=object)
    flat = values.reshape(-1)
    if values.dtype.kind in "iu" and n_events <= INT64_EVENTS:
        if flat.size:
            low, high = int(flat.min()), int(flat.max())
            if low < 0 or high >= 1 << n_events:
                bad = low if low < 0 else high
                raise ValueError(f"{name} must be in [0, 2**{n_events}), got {bad}")
        return flat.astype(np.int64)
    return np.array([check_mask(m, n_events, f"{name}[{i}]")
                     for i, m in enumerate(flat.tolist())], dtype=mask_dtype(n_events))


def check_positive_int(value, name: str) -> int:
    """Validate a positive integer parameter."""
    if isinstance(value, bool) or not isinstance(value, int | np.integer):
        raise TypeError(f"{name} must be an integer, got {type(value).__name__}")
    if value < 1:
        raise ValueError(f"{name} must be >= 1, got {value}")
    return int(value)


def check_bool(value, name: str) -> bool:
    """Validate a flag: ``True`` or ``False`` (a NumPy bool too), returned as a bool.

    Anything else is refused, above all the truthy values that would silently mean True
    (``"no"``, ``"False"``, ``1``, a list).

    Examples
    --------
    >>> check_bool(False, "fast_paths")
    False
    >>> check_bool("no", "fast_paths")
    Traceback (most recent call last):
    ...
    TypeError: fast_paths must be True or False, got str 'no'
    """
    if not isinstance(value, bool | np.bool_):
        raise TypeError(f"{name} must be True or False, got {type(value).__name__} {value!r}")
    return bool(value)


def check_finite_result(res, name: str, offset: int, what: str = "result") -> None:
    """Refuse a result that overflowed (finite inputs near the float64 range): a
    :class:`~bderiv._support._errors.QueryError` naming the row, ``offset`` its batch's first."""
    if not all_finite(res):
        q = int(np.flatnonzero(~np.isfinite(res).all(axis=1))[0])
        raise QueryError(
            f"the {what} for {QUERY} overflowed (not finite) although the input "
            f"is finite: its entries are too large for float64. The map is positively "
            f"homogeneous, M(s v) = s M(v) for s > 0: scale the vectors down and the result up",
            q + offset, name)


def check_memory(need: int, memory_limit, what: str, instead: str = "") -> None:
    """Refuse ``need`` bytes above ``memory_limit`` (default: what the process may still
    take, :func:`bderiv._support._tables.memory_headroom`: the memory available, and under
    ``ulimit -v`` what the address-space limit leaves); ``instead``: what to do, if said."""
    limit = memory_limit_for(need, memory_limit)
    if need > limit:
        raise ValueError(f"{what} take {human_bytes(need)}, more than the memory limit of "
                         f"{human_bytes(limit)}" + (f": {instead}" if instead else ""))


class RecordTooLarge(ValueError):
    """A record of a run (its samples, a stretch's steps) would grow past the memory the
    process may still take: refused before it grows (:func:`check_record`)."""


def check_record(held: int, more: int, what: str, instead: str) -> None:
    """Refuse a record that holds ``held`` bytes and is about to take ``more``, when the
    process may not take them (:func:`bderiv._support._tables.memory_headroom`): a
    :class:`RecordTooLarge` naming the record (``what``), the sizes and what to pass
    ``instead``. A need up to ``SMALL_NEED_BYTES`` is not checked."""
    if more <= SMALL_NEED_BYTES:
        return
    room = memory_headroom()
    if more > room:
        raise RecordTooLarge(
            f"{what} holds {human_bytes(held)} and going on needs about {human_bytes(more)} "
            f"more, but the process may take only {human_bytes(room)} (the memory available "
            f"and the address-space limit RLIMIT_AS): {instead}"
        )


def memory_limit_for(need: int, memory_limit) -> int:
    """The limit, in bytes, that ``need`` bytes are held to: ``memory_limit`` checked
    (:func:`memory_limit_bytes`), or by default what the process may still take (the memory
    available and the address-space limit ``RLIMIT_AS``:
    :func:`~bderiv._support._tables.memory_headroom`), read only for a need above
    ``SMALL_NEED_BYTES`` (a smaller one is its own limit: never refused by default)."""
    if memory_limit is not None:
        return memory_limit_bytes(memory_limit)
    return memory_headroom() if need > SMALL_NEED_BYTES else need


def memory_limit_bytes(value) -> int:
    """A ``memory_limit`` argument as bytes: a positive integer (or integral float)."""
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise TypeError(
            f"memory_limit must be a number of bytes (an integer), got {type(value).__name__} "
            f"{value!r}"
        )
    if not (math.isfinite(value) and value > 0 and value == int(value)):
        raise ValueError(f"memory_limit must be a positive whole number of bytes, got {value!r}")
    return int(value)


def check_pieces(n: int, max_pieces) -> None:
    """Refuse n! pieces above ``max_pieces``."""
    check_positive_int(max_pieces, "max_pieces")
    count = math.factorial(n)
    if count > max_pieces:
        raise ValueError(
            f"{n} events have {n}! = {count} pieces, more than max_pieces={max_pieces}; pass "
            f"a larger max_pieces, or use piece(order) for the orders you need"
        )


def check_number(value, name: str, *, low: float = 0.0, strict: bool = True,
                 allow_inf: bool = False) -> float:
    """Validate a real scalar parameter: ``> low`` (``>= low`` if not ``strict``), finite.

    Raises
    ------
    TypeError
        If ``value`` is not a real number (bool, str, complex, array ... are refused).
    ValueError
        If it is NaN, infinite (unless ``allow_inf``) or out of range; the message names
        ``name``, the expected range and the value received.
    """
    if type(value) is not float and (isinstance(value, bool | np.bool_)
                                     or not isinstance(value, numbers.Real)):
        raise TypeError(f"{name} must be a real number, got {type(value).__name__} {value!r}")
    value = float(value)
    ok = value > low if strict else value >= low
    if not ok or math.isnan(value) or (math.isinf(value) and not allow_inf):
        bound = "" if low == -math.inf else f" > {low:g}" if strict else f" >= {low:g}"
        kind = "a number" if allow_inf else "a finite number"
        raise ValueError(f"{name} must be {kind}{bound}, got {value!r}")
    return value


def check_numbers(*, low: float = 0.0, strict: bool = True, **values) -> tuple:
    """:func:`check_number` of each keyword's value, named by its keyword: the floats in
    the keywords' order (a builder's parameters; ``low=-inf``: any finite number)."""
    return tuple(check_number(v, name, low=low, strict=strict) for name, v in values.items())


def check_value(value, name: str) -> float:
    """A parameter value: a finite real number."""
    if isinstance(value, bool | np.bool_) or not isinstance(value, numbers.Real):
        raise TypeError(f"{name} must be a real number, got {type(value).__name__} {value!r}")
    value = float(value)
    if not math.isfinite(value):
        raise ValueError(f"{name} must be finite, got {value!r}")
    return value
