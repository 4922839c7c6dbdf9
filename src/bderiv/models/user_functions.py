"""A user's model functions as the model side calls them: wrapped, outputs checked.

The functions a model is made of (field, events, Jacobians, resets, a section) are the
user's: :func:`check_callable` and :func:`compiled_or_refused` take them in,
:func:`_noted`, :func:`_contiguous_args` and :func:`_appending` wrap them (what an
exception they raise says, the compiled path's argument types, the parameter values),
:func:`check_output` validates what they return, and
:func:`numerical_jacobian` / :func:`check_given_jacobian` stand in for a Jacobian not given
or hold a given one to its function. :mod:`.calls` and :mod:`.section` are built on them.
"""

from __future__ import annotations

import inspect

import numba
import numpy as np

from .._limits import ACCEPT_RTOL
from .._support import _format
from .._support import _numdiff as numdiff
from .._support._tables import INT64_EVENTS
from .._support._validate import all_finite, check_finite, check_real_array
from .compiled import Cancelled, is_compiled, note_refused, refuse_damaged_cache, refused_types

#: how a model's functions are called, in the order :class:`~.calls.ModelCalls` holds them
MODEL_CALLS = ("field(x, mask)", "events(x)", "event_jacobian(x)", "field_jacobian(x, mask)",
               "corner_field(x)", "reset(x, mask, k)", "reset_jacobian(x, mask, k)",
               "reset_guard(x, mask, k)")


def check_callable(f, name: str, call: str | None = None) -> None:
    """Refuse a parameter that should be a function (None passes: optional), or one whose
    signature cannot take the arguments of ``call`` (``"field(x, mask)"``: it raised
    Python's own TypeError, naming no role, at the first call)."""
    if f is None:
        return
    if not callable(f):
        raise TypeError(f"{name} must be callable, got {type(f).__name__}")
    if call is None:
        return
    args = call[call.index("(") + 1:-1].split(", ")
    try:
        signature = inspect.signature(getattr(f, "py_func", f))
    except (TypeError, ValueError):  # a builtin or a ufunc: not inspectable, called as is
        return
    try:
        signature.bind(*args)
    except TypeError:
        raise TypeError(f"{name} is called as {call}, but it takes {signature}") from None


def _noted(fn, call: str, n_events: int = 1):
    """``fn`` (a Python function of the model, called as ``call``: ``"field(x, mask)"``),
    an exception it raises noted with the call, its state and mask
    (:func:`bderiv._support._format.note_call`; the integrator adds the time), the
    exception itself kept. None, a numba dispatcher (its exceptions are the compiled
    path's to word) and every function on Python 3.10 (no notes) as they are."""
    if fn is None or is_compiled(fn) or not _format.NOTES:
        return fn

    def note(exc, x, ints):
        if not isinstance(exc, Cancelled):  # the batch's, not the function's
            _format.note_call(exc, call, x, ints, n_events)

    # one wrapper per arity: no tuple of arguments packed at every call
    def noted_x(x):
        try:
            return fn(x)
        except Exception as exc:  # the function's own (KeyboardInterrupt passes)
            note(exc, x, ())
            raise

    def noted_mask(x, mask):
        try:
            return fn(x, mask)
        except Exception as exc:
            note(exc, x, (mask,))
            raise

    def noted_k(x, mask, k):
        try:
            return fn(x, mask, k)
        except Exception as exc:
            note(exc, x, (mask, k))
            raise

    noted = (noted_x, noted_mask, noted_k)[call.count(",")]
    noted.__wrapped__ = fn
    return noted


def noted_functions(model) -> tuple:
    """A model's eight functions (``field``, ``events``, ...: :data:`MODEL_CALLS`' order),
    each Python one :func:`_noted`."""
    return tuple(_noted(getattr(model, call[:call.index("(")]), call, model.n_events)
                 for call in MODEL_CALLS)


def _contiguous_args(fn):
    """``fn`` itself, or for a numba dispatcher a function that passes it the types the
    compiled path compiled it for (a C-contiguous float64 state, int masks and events): a
    strided view or an int array would make numba compile another version of it. A complex
    state (a complex step's) goes as C-contiguous complex128, the version the compiled path
    compiles for the complex step of a field and of events; where a version does not
    compile, later calls for it raise a TypeError at once, in every model of ``fn``
    (numba would try to compile it again at each: :func:`~.compiled.refused_types`). A
    compilation that fails on a damaged numba disk cache of ``fn`` raises the
    :class:`~bderiv._support._errors.DamagedCacheError` naming its files
    (:func:`bderiv.models.compiled.refuse_damaged_cache`)."""
    if not is_compiled(fn):
        return fn

    def call(x, *ints):
        complex_state = type(x) is np.ndarray and x.dtype.kind == "c"
        args = (np.ascontiguousarray(x, dtype=np.complex128 if complex_state else np.float64),
                *(int(i) for i in ints))
        refused = refused_types(fn) if complex_state else ()
        if refused and tuple(map(numba.typeof, args)) in refused:
            raise TypeError(f"{fn.__name__} does not compile for complex input")
        try:
            return fn(*args)
        except Exception:
            types = tuple(map(numba.typeof, args))
            if types not in fn.overloads:  # its compilation failed: a damaged disk cache?
                refuse_damaged_cache(fn, fn.__name__, types)
                if complex_state:
                    note_refused(fn, types)
            raise

    call.__wrapped__ = fn
    return call


def _appending(fn, params):
    """``fn`` itself without parameters, else a function of the state that calls ``fn``
    on the state followed by ``params`` (the model's functions take both)."""
    if fn is None or params is None:
        return fn

    def call(x, *rest):
        return fn(np.concatenate((np.asarray(x), params)), *rest)

    call.__wrapped__ = fn
    return call


def check_params(params):
    """``params`` as a read-only float64 array, shape (m,), or None.

    Raises
    ------
    TypeError
        If it is not real (bool, complex, ...).
    ValueError
        If it is not 1-d or not finite.
    """
    if params is None:
        return None
    arr = check_real_array(params, "params")
    if arr.ndim != 1:
        raise ValueError(f"params must be a 1-d array of parameter values, got shape "
                         f"{arr.shape}")
    arr = np.array(arr, dtype=np.float64)
    check_finite(arr, "params")
    arr.flags.writeable = False
    return arr


def compiled_or_refused(field, events, field_jacobian):
    """The compiled path's functions when ``field`` is a numba dispatcher, else None.

    A compiled ``field`` takes a compiled ``events`` and ``field_jacobian`` (or none):
    the integrator calls all three at every step. The functions called only at the stops
    (event and reset Jacobians, resets, corner fields) may be either.

    Raises
    ------
    TypeError
        Naming the function that is not compiled.
    """
    if not is_compiled(field):
        return None
    for fn, name in ((events, "events"), (field_jacobian, "field_jacobian")):
        if fn is not None and not is_compiled(fn):
            raise TypeError(
                f"field is numba-compiled, so {name} must be too (the compiled integrator "
                f"calls it at every step), got the Python function {fn!r}; compile it with "
                f"numba.njit, or pass field as a Python function"
            )
    return field, events, field_jacobian


def check_mask_width(n_events, **functions) -> None:
    """Refuse a model of more than 63 events whose functions that take the region's mask
    (``functions``: by name) include a numba one: numba passes it as an int64, which
    holds 63 events (a larger mask raised numba's OverflowError in the first run that
    crossed event 63, or the compiled integrator refused the model after its first
    second on Python)."""
    compiled = [name for name, fn in functions.items() if fn is not None and is_compiled(fn)]
    if compiled and n_events > INT64_EVENTS:
        one = len(compiled) == 1
        raise ValueError(
            f"n_events={n_events}, but {', '.join(compiled)} {'is' if one else 'are'} "
            f"numba-compiled, and numba takes the region's mask as an int64, which holds "
            f"{INT64_EVENTS} events; write {'it' if one else 'them'} as Python (masks are "
            f"then Python ints), or model at most {INT64_EVENTS} events")


def check_rows(table, masks, field, mask_name) -> None:
    """Rows of ``corner_field(x)`` against ``field(mask)`` for the first, the last and the
    middle of ``masks``: a table that is not the field's is refused, naming the mask (it
    was used as it came: a silent wrong map)."""
    for m in {int(masks[0]), int(masks[-1]), int(masks[masks.size // 2])}:
        row, want = table[m], field(m)
        if not np.allclose(row, want, rtol=ACCEPT_RTOL, atol=ACCEPT_RTOL * max(
                1.0, float(np.abs(want).max()))):
            raise ValueError(f"corner_field(x) row {m} = {row} is not field(x, mask="
                             f"{mask_name(m)}) = {want}: corner_field must give every "
                             f"region's field, row mask")


def check_output(value, shape, what) -> np.ndarray:
    """Validate the output of a user function: real, of ``shape``, finite; float64 array.

    ``what`` names the call in an error: a string, or a function of no arguments that
    returns it (formatted only when the output is refused: the check runs at every stage
    of an integration, the message almost never)."""
    if type(value) is np.ndarray and value.dtype == np.float64 and value.shape == shape \
            and all_finite(value):
        return value  # the common case, as the checks below would return it
    if callable(what):
        what = what()
    try:
        arr = check_real_array(value, what)
    except TypeError as exc:
        raise TypeError(f"{what} must return real numbers: {exc}") from None
    if arr.shape != shape:
        raise ValueError(f"{what} must return an array of shape {shape}, got shape {arr.shape}")
    arr = np.asarray(arr, dtype=np.float64)
    if np.count_nonzero(np.isfinite(arr)) != arr.size:
        idx = tuple(int(i) for i in np.argwhere(~np.isfinite(arr))[0])
        raise ValueError(f"{what} returned a non-finite value: entry {list(idx)} = {arr[idx]}")
    return arr


def numerical_jacobian(fun, x, what: str, jac_name: str) -> numdiff.Derivative:
    """Jacobian of ``fun`` at ``x`` by :func:`bderiv._support._numdiff.jacobian`, refused where its
    error estimate exceeds the accuracy the entry needs.

    ``what`` names the function and its mask (and event) in the error, ``jac_name`` the
    parameter that gives the Jacobian instead.
    """
    D = numdiff.jacobian(fun, x)
    bad = np.argwhere(~(D.error <= D.needed))
    if bad.size:
        with np.errstate(divide="ignore", invalid="ignore"):  # an entry may need 0
            worst = np.nan_to_num(D.error / D.needed, nan=np.inf)[tuple(bad.T)]
        i, j = (int(k) for k in bad[np.argmax(worst)])
        raise ValueError(
            f"the numerical Jacobian of {what} at x = {x} is not accurate enough: entry "
            f"[{i}, {j}] (output {i} by x_{j}) = {D.value[i, j]:.6g} has an estimated error "
            f"{D.error[i, j]:.3g}, more than the {D.needed[i, j]:.3g} it needs "
            f"({ACCEPT_RTOL:g} relative, or the rounding of its row); no "
            f"finite-difference step resolves the function there (a kink or steep feature "
            f"near x, or noise): pass {jac_name}"
        )
    return D


def check_given_jacobian(fun, x, J, what: str, jac_name: str) -> None:
    """Refuse a given Jacobian ``J`` of ``fun`` at ``x`` that does not match its
    derivative along a random direction (:func:`bderiv._support._numdiff.compare`)."""
    c = numdiff.compare(fun, x, J)
    if c.passed:
        return
    i = c.component
    raise ValueError(
        f"{jac_name} does not match {what} at x = {x}: along a random direction v, "
        f"component {i} of J v differs from the central difference of {what} by "
        f"{c.mismatch[i]:.3g} (tolerance {c.tolerance[i]:.3g}; {c.relative:.3g} relative "
        f"to |J| |v|). Correct {jac_name} (bderiv.check_jacobians lists every function and "
        f"mask), or pass check_jacobians=False to skip this check (for a system built "
        f"for you, dataclasses.replace(system, check_jacobians=False))"
    )
