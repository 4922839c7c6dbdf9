"""Checks of the user's compiled functions, and the errors the driver's status codes mean.

Before the driver runs, each function must be a numba dispatcher that compiles for the
types the integrator passes and returns the array type the driver expects (numba would
otherwise raise a typing traceback from inside the driver). After a failed run, the state
the driver left is evaluated again here, in Python, to say what came back.
"""

from __future__ import annotations

import re
import weakref
from functools import lru_cache

import numpy as np
from numba.core.dispatcher import Dispatcher
from numba.core.errors import NumbaError

from ..._kernels._cache import damaged_entry
from ..._support._errors import DamagedCacheError
from ..._support._format import (
    ANSI,
    BLOW_UP_HINT,
    blown_up,
    format_region,
    format_state,
    step_underflow,
)
from ._integrate import STEP_UNDERFLOW
from ._rhs import (
    COMPLEX_FIELD_SIGNATURE,
    EVENTS_NONFINITE,
    EVENTS_RAISED,
    EVENTS_SHAPE,
    EVENTS_SIGNATURE,
    FIELD_NONFINITE,
    FIELD_RAISED,
    FIELD_SHAPE,
    FIELD_SIGNATURE,
    JAC_COMPLEX_STEP,
    JAC_GIVEN,
    JACOBIAN_NONFINITE,
    JACOBIAN_RAISED,
    JACOBIAN_SHAPE,
    JACOBIAN_SIGNATURE,
    SECTION_NONFINITE,
    SECTION_RAISED,
    SECTION_SIGNATURE,
)

#: each user function: its signature, how its call is written, the shape it must return
#: (from d, n), and the driver's codes of its failed checks (shape, finite, raised)
_FUNCTIONS = {
    "field": (FIELD_SIGNATURE, "field(x, mask)", lambda d, n: (d,), FIELD_SHAPE,
              FIELD_NONFINITE, FIELD_RAISED),
    "field_jacobian": (JACOBIAN_SIGNATURE, "field_jacobian(x, mask)", lambda d, n: (d, d),
                       JACOBIAN_SHAPE, JACOBIAN_NONFINITE, JACOBIAN_RAISED),
    "events": (EVENTS_SIGNATURE, "events(x)", lambda d, n: (n,), EVENTS_SHAPE,
               EVENTS_NONFINITE, EVENTS_RAISED),
    "section": (SECTION_SIGNATURE, "section(x)", lambda d, n: (), None, SECTION_NONFINITE,
                SECTION_RAISED),
}


#: numba's lowering of a closed-over value: ``freevar(name: value)`` and where
_FREEVAR = re.compile(r'During: lowering ".*freevar\((\w+): (.*)\)" at (.*)$')


def _typing_summary(exc: Exception) -> str:
    """The first informative line of a numba typing error, without terminal colours.

    Where that line is only a repr of numba's internals (``<... object at 0x...>``), the
    step that failed instead: a closed-over value numba cannot compile in is named, with
    what to close over.
    """
    lines = [ln.strip() for ln in ANSI.sub("", str(exc)).splitlines() if ln.strip()]
    useful = [ln for ln in lines if not ln.startswith(("Failed in", "File", "During"))]
    first = (useful or lines or ["(no message)"])[0]
    if " object at 0x" not in first:
        return first
    for line in lines:
        found = _FREEVAR.search(line)
        if found:
            name, value, where = found.groups()
            return (f"it reads the closed-over {name} = {value} ({where}), a value numba "
                    f"cannot compile in: close over a NumPy array, a tuple or a number "
                    f"instead (not a list, dict or other object)")
    steps = [ln for ln in lines if ln.startswith("During:") and "Pass " not in ln]
    return steps[0] if steps else first


def is_compiled(fn) -> bool:
    """Whether ``fn`` is a numba dispatcher (``numba.njit``-compiled function)."""
    return isinstance(fn, Dispatcher)


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


def check_compiled_functions(field, events, field_jacobian=None) -> None:
    """:func:`check_compiled` of the functions the integrator calls at every step (a
    ``field_jacobian`` of None: none given)."""
    for fn, name in ((field, "field"), (events, "events"), (field_jacobian, "field_jacobian")):
        if fn is not None:
            check_compiled(fn, name)


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
        except Exception as exc:
            refuse_damaged_cache(fn, name, args)
            if isinstance(exc, NumbaError):
                raise TypeError(
                    f"{name} does not compile as {expected}: {_typing_summary(exc)}"
                ) from None
            if isinstance(exc, RuntimeError):  # "compilation disabled": other signatures
                raise TypeError(
                    f"{name} was compiled for {[str(s) for s in fn.signatures]} only "
                    f"({exc}); the integrator calls {expected}: give that signature, or "
                    f"none"
                ) from None
            raise
    returned = fn.overloads[args].signature.return_type
    if returned != signature.return_type:
        hint = ("a float" if name == "section" else "a C-contiguous float64 array; return a "
                "new float64 array (e.g. np.ascontiguousarray(..., dtype=np.float64))")
        raise TypeError(
            f"{name} must return {signature.return_type} ({hint}) when called as "
            f"{expected}, but returns {returned}"
        )


#: per dispatcher of the user's, the argument types it failed to compile for: numba would
#: try again at every call (up to a second each), so a failure is kept for the process
_REFUSED = weakref.WeakKeyDictionary()


def refused_types(fn) -> set:
    """The argument types (tuples of numba types) ``fn`` is known not to compile for."""
    return _REFUSED.get(fn, set())


def note_refused(fn, args) -> None:
    """Keep that ``fn`` does not compile for ``args`` (:func:`refused_types`)."""
    _REFUSED.setdefault(fn, set()).add(args)


@lru_cache(maxsize=256)
def compiles_as(fn, signature) -> bool:
    """Whether the dispatcher ``fn`` compiles for ``signature``'s arguments and returns
    its return type (quietly: False where it does not)."""
    args = signature.args
    if args in refused_types(fn):
        return False
    if args not in fn.overloads:
        try:
            fn.compile(args)
        except Exception as exc:
            refuse_damaged_cache(fn, getattr(fn, "__name__", "a function"), args)
            if isinstance(exc, NumbaError | RuntimeError | TypeError | ValueError):
                note_refused(fn, args)
                return False
            raise
    return fn.overloads[args].signature.return_type == signature.return_type


def refuse_damaged_cache(fn, name: str, args) -> None:
    """After a failed compilation of the user's ``fn`` for ``args``: raise the
    :class:`~bderiv._support._errors.DamagedCacheError` (a RuntimeError) naming the
    damaged disk cache when that is why (:func:`damaged_entry`), else return."""
    why = damaged_entry(fn, args)
    if why is not None:
        raise DamagedCacheError(f"{name} ({fn.py_func.__qualname__}): {why}")


def compiles_for_complex(field) -> bool:
    """Whether the dispatcher ``field`` compiles for ``(complex128[::1], int64)`` and
    returns a complex128 array (then its Jacobian is had by complex step)."""
    return compiles_as(field, COMPLEX_FIELD_SIGNATURE)


def raise_failed_check(status, fn, name, x, mask, d, n, params=None) -> None:
    """Raise the ValueError of a failed output check of ``fn`` (``name``) at ``x`` (the
    model's ``params`` after it, but for the section)."""
    _, call, shape_of, shape_code, _, raised_code = _FUNCTIONS[name]
    region = format_region(mask, max(n, 1))
    x = np.ascontiguousarray(x, dtype=np.float64)
    arg = x if params is None or name == "section" else np.concatenate((x, params))
    where = f"in {region} at x = {format_state(x)}"
    try:  # called again from Python, it says what it raised (a deterministic function)
        value = np.asarray(fn(arg.copy(), mask) if "mask" in call else fn(arg.copy()))
    except Exception as exc:
        raise ValueError(f"{call} raised {type(exc).__name__}: {exc}; {where}") from exc
    if status == raised_code:
        how = (" (on complex input, for the complex-step Jacobian, or at a nearby state "
               "for central differences)" if name == "field" else "")
        raise ValueError(f"{call} raised an exception in compiled code{how} {where}; "
                         f"called again there from Python, it did not")
    if status == shape_code:
        raise ValueError(
            f"{call} must return an array of shape {shape_of(d, n)}, got shape "
            f"{value.shape} {where}"
        )
    bad = np.argwhere(~np.isfinite(value))
    entry = f", entry {bad[0].tolist()} = {value[tuple(bad[0])]}" if bad.size else ""
    raise ValueError(f"{call} returned a non-finite value{entry} {where}")


def raise_failed_run(status, named, x, t, mask, d, n, jac_mode=JAC_GIVEN,
                     params=None) -> None:
    """Raise the error of a failed driver run: its status code, the state ``x`` at ``t``
    (None: a call at a given state, outside a run).

    ``named`` maps "field", "events", "field_jacobian", "section" to the functions passed;
    ``params`` are the model's parameter values (None: none). A function that came back
    non-finite at a non-finite state is not blamed: the integration itself left the
    floating-point range, and the error says so.
    """
    region = format_region(mask, max(n, 1))
    if status == STEP_UNDERFLOW:
        raise RuntimeError(step_underflow(region, x, t))
    x = np.asarray(x, dtype=np.float64)
    shapes = (FIELD_SHAPE, EVENTS_SHAPE, JACOBIAN_SHAPE)
    if status not in shapes and not np.isfinite(x).all():  # the integrator's step overflowed
        raise ValueError(blown_up(region, x, t))
    if status in (FIELD_SHAPE, FIELD_NONFINITE, FIELD_RAISED):
        name = "field"
    elif status in (EVENTS_SHAPE, EVENTS_NONFINITE, EVENTS_RAISED):
        name = "events"
    elif status in (SECTION_NONFINITE, SECTION_RAISED):
        name = "section"
    elif jac_mode == JAC_GIVEN:
        name = "field_jacobian"
    else:
        how = "complex step" if jac_mode == JAC_COMPLEX_STEP else "central differences"
        raise ValueError(
            f"the Jacobian of field computed by {how} (no field_jacobian given) is not "
            f"finite in {region} at x = {format_state(x)}"
        )
    raise_failed_check(status, named[name], name, x, mask, d, n, params)


def raise_overflowed_run(exc, x, t, mask, n, field=None) -> None:
    """Raise the ValueError of a stretch whose driver raised ``exc`` (an ArithmeticError)
    in its own arithmetic, the stretch of region ``mask`` from ``(t, x)``.

    The model's functions never raise out of the driver (what they raise is caught in
    compiled code, a status code: :func:`raise_failed_run`), so a division by zero or an
    overflow there is the step-size control's: the state's or the field's size scaled by
    the tolerances overflowed float64 (a zero initial step, an infinite error norm).
    ``field()``, if given, is the field at ``x`` (its size is named; not when it fails).
    """
    x = np.asarray(x, dtype=np.float64)
    sizes = f"|x| up to {np.abs(x).max(initial=0.0):.3g}"
    if field is not None:
        try:
            sizes += f", |field(x, mask)| up to {np.abs(field()).max(initial=0.0):.3g}"
        except Exception:  # noqa: BLE001 - only a detail of the message
            pass
    raise ValueError(
        f"the integration blew up in the stretch of {format_region(mask, max(n, 1))} "
        f"from t = {t!r}, x = {format_state(x)} ({sizes}): the integrator's "
        f"step-size control overflowed ({type(exc).__name__}: {exc}, in its own arithmetic, "
        f"not in a function of the model) as the state or its rate of change, scaled by the "
        f"tolerances, went beyond the floating-point range (float64 ends near 1.8e308); "
        f"{BLOW_UP_HINT}"
    ) from exc


def machine_has(dispatcher) -> bool:
    """Whether ``dispatcher`` is compiled in this process or its disk cache holds an entry
    for this machine (numba's codegen magic tuple: the CPU and its features)."""
    if dispatcher.signatures:
        return True
    try:
        index = dispatcher._cache._cache_file._load_index()
        magic = dispatcher.targetctx.codegen().magic_tuple()
    except Exception:  # noqa: BLE001 - uncached, another numba, a damaged index: not there
        return False
    return any(key[1] == magic for key in index)
