"""The user's compiled functions bound once into one struct the driver takes.

The driver is compiled once for first-class function types (:mod:`._rhs`), so a new model
does not recompile it. Passing three dispatchers from Python as first-class functions costs
numba a compile-result lookup each, about 50 us per function per call (measured: 150 us of
a 220 us stretch at d = 8); a struct holding the three functions is passed for about 1 us.
:func:`bound_model` builds that struct once per triple of functions and keeps it.
"""

from __future__ import annotations

from functools import lru_cache

from numba import njit, types
from numba.experimental import structref

from ._rhs import EVENTS_TYPE, FIELD_TYPE, JACOBIAN_TYPE


@structref.register
class _ModelType(types.StructRef):
    def preprocess_fields(self, fields):
        return tuple((name, types.unliteral(typ)) for name, typ in fields)


class _Model(structref.StructRefProxy):
    """A model's ``field``, ``jacobian`` and ``events`` as first-class functions."""


structref.define_proxy(_Model, _ModelType, ["field", "jacobian", "events"])
MODEL_TYPE = _ModelType([("field", FIELD_TYPE), ("jacobian", JACOBIAN_TYPE),
                         ("events", EVENTS_TYPE)])


@njit(MODEL_TYPE(FIELD_TYPE, JACOBIAN_TYPE, EVENTS_TYPE), cache=True)
def _bind(field, jacobian, events):
    model = structref.new(MODEL_TYPE)
    model.field = field
    model.jacobian = jacobian
    model.events = events
    return model


@lru_cache(maxsize=64)
def bound_model(field, jacobian, events):
    """The struct of three checked dispatchers (kept for the 64 latest triples)."""
    return _bind(field, jacobian, events)
