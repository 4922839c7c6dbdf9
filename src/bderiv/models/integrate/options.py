"""The integrator settings of a run (:class:`SolverOptions`): tolerances, method and step
limit as one frozen value, checked once, with their one set of defaults."""

from __future__ import annotations

from dataclasses import dataclass, replace
from functools import lru_cache

import numpy as np
from scipy.integrate import OdeSolver

from ..._limits import DEFAULT_ATOL, DEFAULT_RTOL
from ..._numerics import MIN_RTOL
from ..._support._validate import check_number

__all__ = ["SOLVE_IVP_METHODS", "SolverOptions"]

#: the methods of :func:`scipy.integrate.solve_ivp` by name.
SOLVE_IVP_METHODS = ("RK45", "RK23", "DOP853", "Radau", "BDF", "LSODA")

@dataclass(frozen=True)
class SolverOptions:
    """Settings of :func:`scipy.integrate.solve_ivp`, validated, with one set of defaults.

    Parameters
    ----------
    rtol : float
        Relative tolerance, in ``[MIN_RTOL, 1)`` (about 2.2e-14: solve_ivp's floor).
    atol : float
        Absolute tolerance, finite, > 0.
    method : str or OdeSolver subclass
        A solve_ivp method name (``SOLVE_IVP_METHODS``) or an ``OdeSolver`` subclass.
    max_step : float
        Largest step, > 0 (``inf``: no limit).

    Examples
    --------
    >>> SolverOptions().with_overrides(rtol=1e-12).rtol
    1e-12
    >>> SolverOptions(atol=float("nan"))
    Traceback (most recent call last):
    ...
    ValueError: atol must be a finite number > 0, got nan
    """

    rtol: float = DEFAULT_RTOL
    atol: float = DEFAULT_ATOL
    method: object = "DOP853"
    max_step: float = np.inf

    def __post_init__(self):
        rtol = check_number(self.rtol, "rtol")
        if not rtol < 1.0 or rtol < MIN_RTOL:
            raise ValueError(
                f"rtol must be in [{MIN_RTOL:.3g}, 1) (solve_ivp cannot honour a smaller "
                f"relative tolerance), got {rtol!r}"
            )
        object.__setattr__(self, "rtol", rtol)
        object.__setattr__(self, "atol", check_number(self.atol, "atol"))
        object.__setattr__(
            self, "max_step", check_number(self.max_step, "max_step", allow_inf=True)
        )
        method = self.method
        known = isinstance(method, str) and method in SOLVE_IVP_METHODS
        if not known and not (isinstance(method, type) and issubclass(method, OdeSolver)):
            raise ValueError(
                f"method must be one of {', '.join(SOLVE_IVP_METHODS)} or an OdeSolver "
                f"subclass, got {method!r}"
            )

    def with_overrides(self, **settings) -> SolverOptions:
        """A copy with the settings that are not None replaced (checked again)."""
        given = {key: value for key, value in settings.items() if value is not None}
        return replace(self, **given) if given else self

    @classmethod
    def resolve(cls, options=None, default=None, **settings) -> SolverOptions:
        """``options`` (or ``default``, or the defaults) with keyword ``settings`` applied.

        The public methods take both an ``options`` object and the keywords ``rtol``,
        ``atol``, ``method``, ``max_step``; a keyword that is not None wins.
        """
        if options is not None and not isinstance(options, cls):
            raise TypeError(f"options must be a SolverOptions, got {type(options).__name__}")
        base = options if options is not None else (default or _defaults(cls))
        for value in settings.values():
            if value is not None:
                return base.with_overrides(**settings)
        return base

    def solve_ivp_kwargs(self) -> dict:
        """Keyword arguments for :func:`scipy.integrate.solve_ivp`."""
        return {"rtol": self.rtol, "atol": self.atol, "method": self.method,
                "max_step": self.max_step}


@lru_cache(maxsize=8)
def _defaults(cls) -> SolverOptions:
    """``cls()``, made once (frozen: shared by every run that passes no options)."""
    return cls()
