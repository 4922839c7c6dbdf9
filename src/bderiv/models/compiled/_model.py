"""The user's compiled functions bound once into one struct the driver takes.

The driver is compiled once for first-class function types (:mod:`._rhs`), so a new model
does not recompile it. Passing dispatchers from Python as first-class functions costs
numba a compile-result lookup per function per call, most of a short stretch's time; a
struct holding the functions passes at a small fraction of that (docs/benchmarks.md,
"Kernel design choices, measured").
:func:`bound_model` builds that struct once per set of functions and keeps it. The struct
also holds the model's parameter values (an empty array for a model without: :mod:`._rhs`)
and its event Jacobian, which the compiled run (:mod:`._run`) reads at the stops.

It holds the driver's address too (:func:`drive_at`): the compiled run calls the driver
through it, so that the run's compilation does not link the driver's code in. Numba links
a called function's machine-code module into its caller's and optimizes and generates the
whole again there; the driver's would be generated three times (its own, the stretch's
examination, the run), about a third of the integrator's compile time.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
from numba import types
from numba.core import cgutils, errors
from numba.experimental import structref
from numba.extending import intrinsic

from ..._kernels._pointer import call_at
from ._cached import compile_eager, eager
from ._integrate import drive_stretch
from ._rhs import (
    COMPLEX_FIELD_TYPE,
    EVENTS_TYPE,
    FIELD_TYPE,
    JACOBIAN_TYPE,
    SECTION_TYPE,
    no_complex_field,
    no_section,
)


@structref.register
class _ModelType(types.StructRef):
    def preprocess_fields(self, fields):
        return tuple((name, types.unliteral(typ)) for name, typ in fields)


class _Model(structref.StructRefProxy):
    """A model's ``field``, ``jacobian``, ``events``, complex field and section as
    first-class functions, and its parameter values."""


#: ``event_jacobian(x) -> (n, d)``, and ``events`` on complex input (for complex step), as
#: the compiled run calls them
EVENT_JACOBIAN_SIGNATURE = types.float64[:, ::1](types.float64[::1])
EVENT_JACOBIAN_TYPE = types.FunctionType(EVENT_JACOBIAN_SIGNATURE)
COMPLEX_EVENTS_SIGNATURE = types.complex128[::1](types.complex128[::1])
COMPLEX_EVENTS_TYPE = types.FunctionType(COMPLEX_EVENTS_SIGNATURE)
#: ``reset(x, mask, k) -> (d,)``, as the compiled run calls it
RESET_SIGNATURE = types.float64[::1](types.float64[::1], types.int64, types.int64)
RESET_TYPE = types.FunctionType(RESET_SIGNATURE)


@eager(EVENT_JACOBIAN_SIGNATURE)
def no_event_jacobian(x):  # pragma: no cover - passed, never called
    """Stands for ``event_jacobian`` when the stops are not compiled (never called)."""
    return np.empty((0, 0))


@eager(COMPLEX_EVENTS_SIGNATURE)
def no_complex_events(x):  # pragma: no cover - passed, never called
    """Stands for the complex events when complex step is not used (never called)."""
    return np.empty(0, dtype=np.complex128)


@eager(RESET_SIGNATURE)
def no_reset(x, mask, k):  # pragma: no cover - passed, never called
    """Stands for ``reset`` when the stops are not compiled or there is none (never
    called)."""
    return np.empty(0)


_MEMBERS = ("field", "jacobian", "events", "cfield", "section", "params", "event_jacobian",
            "cevents", "reset", "driver")
structref.define_proxy(_Model, _ModelType, list(_MEMBERS))
_TYPES = (FIELD_TYPE, JACOBIAN_TYPE, EVENTS_TYPE, COMPLEX_FIELD_TYPE, SECTION_TYPE,
          types.float64[::1], EVENT_JACOBIAN_TYPE, COMPLEX_EVENTS_TYPE, RESET_TYPE, types.int64)
MODEL_TYPE = _ModelType(list(zip(_MEMBERS, _TYPES, strict=True)))
#: the parameters of a model without
NO_PARAMS = np.empty(0)
#: the argument types the driver is compiled for, once: as Python calls it
#: (:mod:`._slices`) and as the compiled run does (:func:`drive_at`)
_VECTOR = types.float64[::1]
DRIVER_ARGS = (MODEL_TYPE, types.int64, types.boolean, types.boolean, types.int64,
               types.int64, types.int64, types.float64, _VECTOR, types.float64, types.float64,
               _VECTOR, types.float64, types.float64, types.int64, types.boolean, types.int64,
               types.boolean)
_driver = {}


def _driver_address():
    """The address of the driver compiled for ``DRIVER_ARGS`` (compiled, or loaded from the
    cache, at the first call)."""
    if not _driver:
        drive_stretch.compile(DRIVER_ARGS)
        compiled = drive_stretch.overloads[DRIVER_ARGS]
        _driver["address"] = compiled.library.get_pointer_to_function(
            compiled.fndesc.llvm_func_name)
    return _driver["address"]


@intrinsic
def drive_at(typingctx, address, args):
    """``drive_stretch(*args)`` called at ``address`` (the struct's ``driver``), ``args``
    of the types ``DRIVER_ARGS`` (else a TypingError): numba's call of a compiled function
    (its exceptions propagate), through a pointer."""
    if not isinstance(args, types.BaseTuple) or tuple(args.types) != DRIVER_ARGS:
        raise errors.TypingError(f"drive_at: the driver takes {DRIVER_ARGS}, got {args}")
    drive_stretch.compile(DRIVER_ARGS)  # for its return type
    signature = drive_stretch.overloads[DRIVER_ARGS].signature

    def codegen(context, builder, sig, llargs):
        values = cgutils.unpack_tuple(builder, llargs[1], len(DRIVER_ARGS))
        return call_at(context, builder, llargs[0], signature.return_type, DRIVER_ARGS,
                       values)

    return signature.return_type(address, args), codegen


@eager(MODEL_TYPE(*_TYPES))
def _bind(field, jacobian, events, cfield, section, params, event_jacobian, cevents, reset,
          driver):
    model = structref.new(MODEL_TYPE)
    model.driver = driver
    model.event_jacobian = event_jacobian
    model.cevents = cevents
    model.reset = reset
    model.field = field
    model.jacobian = jacobian
    model.events = events
    model.cfield = cfield
    model.section = section
    model.params = params
    return model


@lru_cache(maxsize=64)
def _bound(field, jacobian, events, cfield, section, event_jacobian, cevents, reset):
    return _bind(field, jacobian, events, cfield, section, NO_PARAMS, event_jacobian, cevents,
                 reset, _driver_address())


def bound_model(field, jacobian, events, cfield=no_complex_field, section=no_section,
                params=None, event_jacobian=no_event_jacobian, cevents=no_complex_events,
                reset=no_reset):
    """The struct of checked dispatchers and parameter values ``params`` (C-contiguous
    float64; None: none). Without parameters it is kept for the 64 latest sets."""
    compile_eager()  # the placeholders and the binder, at the first struct
    if params is None:
        return _bound(field, jacobian, events, cfield, section, event_jacobian, cevents, reset)
    return _bind(field, jacobian, events, cfield, section, params, event_jacobian, cevents,
                 reset, _driver_address())
