"""Compiled integration of a region's flow: the model's functions as numba dispatchers.

:func:`integrate_stretch` integrates one region from a start state to a final time or the
first event crossing with scipy's DOP853 (the same tableau, error norm, step-size control,
first step and dense output) in one compiled driver, the user's ``field``, ``events`` and
``field_jacobian`` called as compiled functions (no Python call per step), optionally with
the variational equations. :class:`CompiledModel` holds a model's checked dispatchers for
the model side (:mod:`bderiv.models.integrate.compiled_path`), with the Jacobian computed in
compiled code
where none is given. See ``docs/design.md``, "The compiled integrator" and "The compiled
path".
"""

from __future__ import annotations

from ._cached import key_all_kernels
from ._checks import (
    check_compiled,
    check_compiled_functions,
    is_compiled,
    machine_has,
    note_refused,
    refuse_damaged_cache,
    refused_types,
)
from ._integrate import EVENT
from ._notice import tell_python_stops
from ._run import ENDED, HANDOFF
from ._slices import Cancelled, cancel_point, stopped_by
from ._stops import EVENT_JAC_COMPLEX_STEP, EVENT_JAC_GIVEN, EVENT_JAC_NONE
from .model import JACOBIAN_MODES, CompiledModel, dense_at
from .stretch import Stretch, integrate_stretch

key_all_kernels()

__all__ = ["ENDED", "EVENT", "EVENT_JAC_COMPLEX_STEP", "EVENT_JAC_GIVEN", "EVENT_JAC_NONE",
           "HANDOFF", "JACOBIAN_MODES", "Cancelled", "CompiledModel", "Stretch",
           "cancel_point", "check_compiled", "check_compiled_functions", "dense_at",
           "integrate_stretch", "is_compiled", "machine_has", "note_refused",
           "refuse_damaged_cache", "refused_types", "stopped_by", "tell_python_stops"]
