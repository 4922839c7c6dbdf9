"""Models from equations: a :class:`~bderiv.analysis.system.HybridSystem` from sympy expressions.

The builders return a plain ``HybridSystem`` (no subclass): its functions are the compiled
kernels, ``params`` their parameter values, and its ``source`` a :class:`SymbolicSource`
(the kernels, how they were built, the parameters' names, the contacts), so
``with_params``, ``param_values`` and ``scipy_path`` of ``HybridSystem`` apply.

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
- ``_model``: :func:`from_sympy`, the :class:`Kernels` and :class:`BuildInfo` records,
  :class:`SymbolicSource` (a model's ``source``: where it came from) and the
  Python-facing :class:`ModelFunctions` (the state alone, the parameters appended);
- ``contacts``: :func:`contact_system`, bodies with point contacts (mass matrix, forces,
  gaps, stance law, impacts), whose ``reset_guard`` checks simultaneous impacts, and
  :func:`coupling`;
- ``_contact_checks``: its own argument checks (mass matrix, stance laws, impact law, one
  role per symbol) and :class:`~._contact_checks.ParamCheck`, the parameter values it
  cannot take (at the build and by ``with_params``);
- ``_mechanics``: their kernels, the mass matrix solved in compiled code with exact
  Jacobians.
"""

from ._model import BuildInfo, Kernels, ModelFunctions, SymbolicSource, from_sympy
from .contacts import contact_system, coupling

__all__ = ["BuildInfo", "Kernels", "ModelFunctions", "SymbolicSource", "contact_system",
           "coupling", "from_sympy"]
