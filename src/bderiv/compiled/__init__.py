"""Compiled integration of a region's flow: the model's functions as numba dispatchers.

:func:`integrate_stretch` integrates one region from a start state to a final time or the
first event crossing with scipy's DOP853 (the same tableau, error norm, step-size control,
first step and dense output) in one compiled driver, the user's ``field``, ``events`` and
``field_jacobian`` called as compiled functions (no Python call per step), optionally with
the variational equations. The foundation of the compiled path of issue 19; see
``docs/design.md``, "The compiled integrator".
"""

from __future__ import annotations

from ._cached import key_all_kernels
from .stretch import Stretch, integrate_stretch

key_all_kernels()

__all__ = ["Stretch", "integrate_stretch"]
