"""Integer arguments: counts, indices, region masks, event orders.

Each ``check_*`` helper returns the checked value (an int, or an int64 array) or raises a
``TypeError`` (not integers: a bool or a float such as 3.0 is refused, but by
:func:`check_order`, which takes whole floats) or a ``ValueError`` (out of range) naming
the argument, what was expected and what came. The checks of real numbers and their
arrays are :mod:`bderiv._support._validate`'s.
"""

from __future__ import annotations

import math

import numpy as np

from ._tables import INT64_EVENTS, mask_dtype


def is_integer(value) -> bool:
    """Whether ``value`` is an integer, a NumPy one too, but not a bool (nor a float such
    as 3.0: ``int(2.5)`` would be 2, silently)."""
    return isinstance(value, int | np.integer) and not isinstance(value, bool)


def check_int(value, name: str, *, low: int | None = None, high: int | None = None,
              span: str = "", meaning: str = "") -> int:
    """An integer parameter (:func:`is_integer`, else ``TypeError``) in ``[low, high]``
    (None: no bound; else ``ValueError``), as an int.

    Both messages name ``name``, the range (``span``: in words of its own; else ``>= low``,
    ``<= high`` or ``in [low, high]``), ``meaning`` (what the integer is), and what came.

    Examples
    --------
    >>> check_int(2.0, "iterations", low=2)
    Traceback (most recent call last):
    ...
    TypeError: iterations must be an integer >= 2, got float 2.0
    """
    integer = is_integer(value)
    if integer and (low is None or value >= low) and (high is None or value <= high):
        return int(value)
    if not span and low is not None:
        span = f">= {low}" if high is None else f"in [{low}, {high}]"
    elif not span and high is not None:
        span = f"<= {high}"
    expected = f"{name} must be an integer" + (f" {span}" if span else "") + (
        f" ({meaning})" if meaning else "")
    if not integer:
        raise TypeError(f"{expected}, got {type(value).__name__} {value!r}")
    raise ValueError(f"{expected}, got {value}")


def check_positive_int(value, name: str) -> int:
    """A positive integer parameter: :func:`check_int` ``>= 1``."""
    return check_int(value, name, low=1)


def check_mask(mask, n_events: int, name: str = "mask") -> int:
    """A region mask of a system of ``n_events`` events: an integer in [0, 2**n)."""
    if not is_integer(mask):
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


def check_distinct(indices: list, n: int, name: str, noun: str, hint: str = "") -> list:
    """``indices`` (a list of ints) each in ``[0, n)`` and each once, returned; else a
    ValueError naming ``name``, the indices out of range or repeated (``noun``: what an
    index names, "foot", "event"; ``hint`` follows "once")."""
    out = [i for i in indices if not 0 <= i < n]
    if out:
        raise ValueError(f"{name} must hold {noun} indices in [0, {n}), got {out} in "
                         f"{indices}")
    twice = sorted({i for i in indices if indices.count(i) > 1})
    if twice:
        raise ValueError(f"{name} must name each {noun} once{hint}, got {twice} more than "
                         f"once in {indices}")
    return indices


def check_indices(idx, size: int, name: str) -> np.ndarray:
    """Distinct indices in ``[0, size)``, a 1-D sequence of integers, as int64 (``()``:
    none); a TypeError for another type, a ValueError for one out of range or repeated."""
    if isinstance(idx, str | bytes) or np.ndim(idx) != 1:
        raise TypeError(f"{name} must be a 1-D sequence of integers (indices in [0, {size})), "
                        f"got {type(idx).__name__} {idx!r}")
    arr = np.asarray(idx) if len(idx) else np.zeros(0, np.int64)
    if arr.ndim != 1 or arr.dtype.kind not in "iu":
        raise TypeError(f"{name} must be a 1-D sequence of integers, got {arr!r}")
    if arr.size and (arr.min() < 0 or arr.max() >= size or len(set(arr.tolist())) < arr.size):
        raise ValueError(f"{name} must be distinct indices in [0, {size}), got {arr.tolist()}")
    return arr.astype(np.int64)


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


def check_pieces(n: int, max_pieces) -> None:
    """Refuse n! pieces above ``max_pieces``."""
    check_positive_int(max_pieces, "max_pieces")
    count = math.factorial(n)
    if count > max_pieces:
        raise ValueError(
            f"{n} events have {n}! = {count} pieces, more than max_pieces={max_pieces}; pass "
            f"a larger max_pieces, or use piece(order) for the orders you need"
        )
