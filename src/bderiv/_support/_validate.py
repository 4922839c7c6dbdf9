"""Argument checks shared by every public entry point: real numbers and their arrays
(states, matrices, query vectors), flags, memory; the integer checks are
:mod:`bderiv._support._validate_ints`'s.

Each ``check_*`` helper either returns a clean float64 array or value or raises a
``TypeError``/``ValueError`` saying what was expected and what arrived. Nothing here
knows about the mathematics beyond shapes and finiteness.
"""

from __future__ import annotations

import math
import numbers
import reprlib

import numpy as np

from .._limits import SMALL_NEED_BYTES
from ._errors import QUERY, QueryError
from ._format import format_state
from ._tables import human_bytes, memory_headroom
from ._validate_ints import (  # noqa: F401 (re-exported: bderiv.models imports them here)
    check_mask,
    check_masks,
    check_positive_int,
)

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


def as_array(a, name: str) -> np.ndarray:
    """``np.asarray(a)``, a ragged nest of lists refused by ``name`` (NumPy's own words
    named no argument)."""
    try:
        return np.asarray(a)
    except ValueError as exc:
        raise ValueError(f"{name} must be an array, or a nest of lists of equal lengths, "
                         f"got a ragged nest ({exc})") from exc


def check_real_array(a, name: str) -> np.ndarray:
    """Return ``a`` as an ndarray of a real numeric dtype (not yet converted).

    Raises
    ------
    TypeError
        If ``a`` has a bool, complex, object, string or other non-real dtype.
    """
    arr = a if isinstance(a, np.ndarray) else as_array(a, name)
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


#: the words of a size refusal (:func:`check_memory`) that counts a batch's copy
#: (:func:`batch_size`), and what to do instead
AS_ROWS = " and the vectors' float64 copy"
FEWER_ROWS = "pass fewer vectors at a time (the batch's rows in chunks, one call each)"


def batch_size(V, dim: int, name: str = "V") -> tuple[object, int, int]:
    """``(V, m, copy)``: the number of vectors ``m`` of a batch ``V`` of shape (..., dim)
    and the bytes :func:`check_points` takes to copy them (0 for a C-contiguous float64
    array), read from the shape alone, so that a batch is sized before it is converted:
    ``V`` itself when it has a shape (an ndarray, a broadcast view, a memmap or a dask
    array: not converted), else as an array (a nest of lists, held already: converted
    once, as :func:`check_points` would). ``m = copy = 0`` for another shape, which
    :func:`check_points` refuses by name (``name``, as a ragged nest)."""
    if not isinstance(getattr(V, "shape", None), tuple):
        V = as_array(V, name)
    shape = V.shape
    if not shape or shape[-1] != dim or not all(isinstance(s, numbers.Integral)
                                                for s in shape):
        return V, 0, 0
    m = math.prod(int(s) for s in shape[:-1])
    held = isinstance(V, np.ndarray) and V.dtype == np.float64 and V.flags.c_contiguous
    return V, m, 0 if held else 8 * m * dim


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


def check_state(x, dim: int, name: str = "x", *,
                meaning: str = "a state of this system") -> np.ndarray:
    """``x`` as a vector of dimension ``dim``, a state of a system unless ``meaning`` says
    what else: a finite float64 C-contiguous copy, shape (dim,).

    Raises
    ------
    TypeError
        If ``x`` does not hold real numbers (:func:`check_real_array`).
    ValueError
        If its shape is another (a scalar, a ragged nest) or an entry is not finite; the
        message names ``name``, the shape expected and ``meaning``, and what came.
    """
    if type(x) is np.ndarray and x.dtype == np.float64 and x.shape == (dim,):
        arr = x.copy()  # the common case, checked in a third of the time
    else:
        try:
            arr = check_real_array(x, name)
        except ValueError:  # a ragged nest of sequences
            arr = None
        if arr is None or arr.shape != (dim,):
            got = (f"a ragged nest {reprlib.repr(x)}" if arr is None else "a scalar"
                   if arr.ndim == 0 else f"shape {arr.shape}")
            raise ValueError(f"{name} must have shape ({dim},) ({meaning}), got {got}")
        arr = np.array(arr, dtype=np.float64)
    if not all_finite(arr):
        i = int(np.flatnonzero(~np.isfinite(arr))[0])
        raise ValueError(f"{name} must be finite, but {name}[{i}] = {arr[i]}; got "
                         f"{format_state(arr)}")
    return arr


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
    """A parameter value: a finite real number, also as a 0-d real numpy array or an exact
    sympy real number (``sympy.pi``, ``sympy.sqrt(2)``: ``is_number`` and ``is_real``),
    converted by ``float()``."""
    if isinstance(value, np.ndarray) and value.ndim == 0 and value.dtype.kind in "iuf":
        value = value.item()
    elif getattr(value, "is_number", None) is True and \
            getattr(value, "is_extended_real", None) is True:  # sympy's oo too: not finite
        value = float(value)
    if isinstance(value, bool | np.bool_) or not isinstance(value, numbers.Real):
        raise TypeError(f"{name} must be a real number, got {type(value).__name__} {value!r}")
    value = float(value)
    if not math.isfinite(value):
        raise ValueError(f"{name} must be finite, got {value!r}")
    return value
