"""The model side: a hybrid system, its integration, its events and its flow map's assembly.

- :mod:`~bderiv.models.system`: :class:`~bderiv.models.system.HybridSystem`, the model
  (field, events, Jacobians, resets) and its methods;
- :mod:`~bderiv.models.calls`: checked calls of the user's functions, numerical Jacobians;
- :mod:`~bderiv.models.assembly`: the B-derivatives the model gives, at a group of events,
  at a point and along a trajectory;
- :mod:`~bderiv.models.integrate`: the run from region to region (``run``) over one
  interface with two integrators, :func:`scipy.integrate.solve_ivp` for Python callables
  (``scipy_path``) and the compiled DOP853 for numba functions (``compiled_path``);
- :mod:`~bderiv.models.events`: what happens at a stop, the same code for both
  integrators: location (``locate``), grouping and switching with resets (``crossings``),
  crossings inside a step (``excursions``) and a group at the final time (``finaltime``);
- :mod:`~bderiv.models.compiled`: the compiled integrator and the compiled model calls.

See ``docs/design.md``, "The model side".
"""
