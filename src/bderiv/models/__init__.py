"""The model side: what a run needs, its integration and its events.

- :mod:`~bderiv.models.calls`: :class:`~bderiv.models.calls.ModelCalls`, checked calls of
  the user's functions (field, events, Jacobians, resets), numerical Jacobians, corner
  sampling; :mod:`~bderiv.models.user_functions` wraps each function and checks its
  outputs; :mod:`~bderiv.models.section`: the Poincare section's checked calls;
- :mod:`~bderiv.models.integrate`: the run from region to region (``run``) over one
  interface with two integrators, :func:`scipy.integrate.solve_ivp` for Python callables
  (``scipy_path``) and the compiled DOP853 for numba functions (``compiled_path``);
- :mod:`~bderiv.models.events`: what happens at a stop, the same code for both
  integrators: location (``locate``), grouping and switching with resets (``crossings``),
  crossings inside a step (``excursions``) and a group at the final time (``finaltime``);
- :mod:`~bderiv.models.compiled`: the compiled integrator and the compiled model calls.

The user's class, :class:`~bderiv.analysis.system.HybridSystem`, is
:class:`~bderiv.models.calls.ModelCalls` with the analyses as its methods; it lives in the
analysis layer above (:mod:`bderiv.analysis`), so that imports point one way. See
``docs/design.md``, "Layers, top to bottom".
"""

from .._support import _compiling  # noqa: F401 - a first compilation is announced
