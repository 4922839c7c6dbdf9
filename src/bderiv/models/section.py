"""A model's Poincare section ``section(x) = 0`` as checked calls (the gait methods' and
the return map's): its value, its gradient (given and checked once, or numerical), and its
compiled form for the compiled integrator."""

from __future__ import annotations

import numpy as np

from .compiled import check_compiled, is_compiled
from .user_functions import (
    _contiguous_args,
    _noted,
    check_callable,
    check_given_jacobian,
    check_output,
    numerical_jacobian,
)


class Section:
    """A checked Poincare section ``section(x) = 0``, crossed upward (from < 0 to > 0).

    Parameters
    ----------
    func : callable
        ``func(x) -> float``: the section's function, for a state x of shape (d,).
    dim : int
        State dimension d.
    gradient : callable, optional
        ``gradient(x) -> (d,)``. Default: :func:`numerical_jacobian`.
    check : bool
        Compare a given gradient with a central difference of ``func`` the first time
        it is used (:func:`check_given_jacobian`).
    """

    def __init__(self, func, dim: int, gradient=None, check=True):
        if isinstance(func, Section):
            func, gradient = func.func, gradient or func.grad
        if func is None:
            raise TypeError("section must be a callable section(x) -> float, got None")
        check_callable(func, "section")
        check_callable(gradient, "section_gradient")
        self.func, self.dim = func, dim
        self.grad = _contiguous_args(_noted(gradient, "section_gradient(x)"))
        self._call = _contiguous_args(_noted(func, "section(x)"))
        self.check = check  # compare a given gradient with a central difference, once

    def compiled(self):
        """The section as a checked numba dispatcher, for the compiled integrator.

        Raises
        ------
        TypeError
            A Python function (the integrator evaluates the section at every step), or a
            dispatcher that does not compile as ``section(x: float64[::1]) -> float64``.
        """
        if not is_compiled(self.func):
            raise TypeError(
                f"the model's functions are numba-compiled, so section must be too (the "
                f"compiled integrator evaluates it at every step), got the Python function "
                f"{self.func!r}; compile it with numba.njit (or integrate the model by "
                f"solve_ivp: a bderiv.symbolic model's scipy_path())"
            )
        check_compiled(self.func, "section")
        return self.func

    def __call__(self, x) -> float:
        """The checked value ``section(x)`` (the function gets a copy of ``x``)."""
        value = self._call(np.array(x))
        if np.ndim(value) != 0 and np.size(value) != 1:
            raise ValueError(f"section(x) must return one real number, got shape "
                             f"{np.shape(value)}")
        return float(check_output(np.reshape(value, 1), (1,), "section(x)")[0])

    def gradient(self, x) -> np.ndarray:
        """The gradient of the section at ``x``: shape (d,)."""
        if self.grad is not None:
            g = check_output(self.grad(np.array(x)), (self.dim,), "section_gradient(x)")
            if self.check:
                check_given_jacobian(lambda y: np.array([self(y)]), np.asarray(x, float),
                                     g[None], "section(x)", "section_gradient")
                self.check = False
            return g
        return numerical_jacobian(lambda y: np.array([self(y)]), x, "section(x)",
                                  "section_gradient").value[0]
