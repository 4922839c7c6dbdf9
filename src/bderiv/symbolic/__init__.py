"""Models from equations: a :class:`~bderiv.analysis.system.HybridSystem` from sympy expressions.

:func:`from_sympy` takes the state, one flag per event, the vector field, the events, the
resets and the parameters as sympy expressions, derives every Jacobian symbolically,
shares common subexpressions (:func:`sympy.cse`) and generates numba kernels, cached on
disk so that a second process neither re-derives nor recompiles. Needs the optional
extra ``symbolic`` (sympy).

Layout
------
- ``_inputs``: the argument checks and the canonical symbols (the cache key);
- ``_codegen``: derivation, cse and the generated source; it lists the kernels'
  signatures (``field(x, mask) -> (d,)``, ...: the njit functions the compiled
  integrator calls directly, ``x`` the state followed by the parameter values);
- ``_cache``: the cache folder (``$BDERIV_CACHE_DIR``), keys, storing and importing;
- ``_model``: :func:`from_sympy`, the :class:`Kernels` record, the Python-facing
  :class:`ModelFunctions` (the state alone, the parameters appended) and
  :class:`SymbolicSystem` (a ``HybridSystem`` on the compiled path, with
  ``with_params``);
- ``contacts``: :func:`contact_system`, bodies with point contacts (mass matrix, forces,
  gaps, stance law, impacts) and :class:`ContactSystem`, which checks simultaneous impacts;
- ``_mechanics``: their kernels, the mass matrix solved in compiled code with exact
  Jacobians.
"""

from ._model import BuildInfo, Kernels, ModelFunctions, SymbolicSystem, from_sympy
from .contacts import ContactSystem, contact_system

__all__ = ["BuildInfo", "ContactSystem", "Kernels", "ModelFunctions", "SymbolicSystem",
           "contact_system", "from_sympy"]
