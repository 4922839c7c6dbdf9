"""Integration of a model from region to region: :func:`~bderiv.models.integrate.run.run`,
with one stretch interface served by two integrators (``scipy_path``: solve_ivp over Python
callables; ``compiled_path``: the compiled DOP853 over numba functions)."""
