"""Checks of the user's compiled functions, and the errors the driver's status codes mean.

Before the driver runs, each function must be a numba dispatcher that compiles for the
types the integrator passes and returns the array type the driver expects (numba would
otherwise raise a typing traceback from inside the driver). After a failed run, the state
the driver left is evaluated again here, in Python, to say what came back.
"""

from __future__ import annotations

import re
from functools import lru_cache

import numpy as np
from numba.core.dispatcher import Dispatcher
from numba.core.errors import NumbaError

from .._format import MASK_MEANING, format_mask
from ._rhs import (
    EVENTS_NONFINITE,
    EVENTS_SHAPE,
    EVENTS_SIGNATURE,
    FIELD_NONFINITE,
    FIELD_SHAPE,
    FIELD_SIGNATURE,
    JACOBIAN_NONFINITE,
    JACOBIAN_SHAPE,
    JACOBIAN_SIGNATURE,
)

#: each user function: its signature, how its call is written, the shape it must return
#: (from d, n), and the driver's codes of its two failed checks (shape, finite)
_FUNCTIONS = {
    "field": (FIELD_SIGNATURE, "field(x, mask)", lambda d, n: (d,), FIELD_SHAPE,
              FIELD_NONFINITE),
    "field_jacobian": (JACOBIAN_SIGNATURE, "field_jacobian(x, mask)", lambda d, n: (d, d),
                       JACOBIAN_SHAPE, JACOBIAN_NONFINITE),
    "events": (EVENTS_SIGNATURE, "events(x)", lambda d, n: (n,), EVENTS_SHAPE,
               EVENTS_NONFINITE),
}
_ANSI = re.compile(r"\x1b\[[0-9;]*m")


def _typing_summary(exc: Exception) -> str:
    """The first informative line of a numba typing error, without terminal colours."""
    lines = [ln.strip() for ln in _ANSI.sub("", str(exc)).splitlines() if ln.strip()]
    useful = [ln for ln in lines if not ln.startswith(("Failed in", "File", "During"))]
    return (useful or lines or ["(no message)"])[0]


def check_compiled(fn, name: str) -> None:
    """Make sure ``fn`` is a numba dispatcher compiled for the integrator's types.

    Raises
    ------
    TypeError
        If ``fn`` is not a dispatcher, does not compile for the argument types, or returns
        another array type; the message names ``name`` and both types.
    """
    if not isinstance(fn, Dispatcher):
        raise TypeError(
            f"{name} must be a numba.njit-compiled function for the compiled integrator, got "
            f"{type(fn).__name__} {fn!r}"
        )
    _check_types(fn, name)


@lru_cache(maxsize=256)
def _check_types(fn, name: str) -> None:
    """The compilation and return type of :func:`check_compiled` (a passed check is
    remembered: a dispatcher keeps what it compiled)."""
    signature, call, *_ = _FUNCTIONS[name]
    expected = f"{call} with x float64[::1]" + (", mask int64" if "mask" in call else "")
    args = signature.args
    if args not in fn.overloads:
        try:
            fn.compile(args)
        except NumbaError as exc:
            raise TypeError(
                f"{name} does not compile as {expected}: {_typing_summary(exc)}"
            ) from None
        except RuntimeError as exc:  # "compilation disabled": explicit other signatures
            raise TypeError(
                f"{name} was compiled for {[str(s) for s in fn.signatures]} only ({exc}); "
                f"the integrator calls {expected}: give that signature, or none"
            ) from None
    returned = fn.overloads[args].signature.return_type
    if returned != signature.return_type:
        raise TypeError(
            f"{name} must return {signature.return_type} (a C-contiguous float64 array) "
            f"when called as {expected}, but returns {returned}; return a new array (e.g. "
            f"np.ascontiguousarray(...))"
        )


def format_state(x) -> str:
    """A state in a message, every digit kept: ``[0.5, -1.25]``."""
    return "[" + ", ".join(repr(float(v)) for v in x) + "]"


def raise_failed_check(status, fn, name, x, mask, d, n) -> None:
    """Raise the ValueError of a failed output check of ``fn`` (``name``) at ``x``."""
    _, call, shape_of, shape_code, _ = _FUNCTIONS[name]
    region = f"region mask {format_mask(mask, max(n, 1))} ({MASK_MEANING})"
    value = np.asarray(fn(x.copy(), mask) if "mask" in call else fn(x.copy()))
    where = f"in {region} at x = {format_state(x)}"
    if status == shape_code:
        raise ValueError(
            f"{call} must return an array of shape {shape_of(d, n)}, got shape "
            f"{value.shape} {where}"
        )
    bad = np.argwhere(~np.isfinite(value))
    entry = f", entry {bad[0].tolist()} = {value[tuple(bad[0])]}" if bad.size else ""
    raise ValueError(f"{call} returned a non-finite value{entry} {where}")
