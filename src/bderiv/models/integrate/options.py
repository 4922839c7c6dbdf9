"""The settings of a run (:class:`SolverOptions`): tolerances, method, step limit and
``simultaneity_tol`` as one frozen value, checked once at the public boundary and passed as
one value through every layer below it (the run, its stops, the flow and return maps).

``simultaneity_tol``'s default depends on the use (``bderiv._limits``: simulation,
derivative, finite differences): a value that leaves it None takes the default of the
function it is given to (:meth:`SolverOptions.resolve`); the layers below the public
functions receive it set."""

from __future__ import annotations

from dataclasses import dataclass, replace
from functools import lru_cache

import numpy as np

from ..._limits import (
    DEFAULT_ATOL,
    DEFAULT_RTOL,
    DERIVATIVE_SIMULTANEITY_TOL,
    SIMULATION_SIMULTANEITY_TOL,
)
from ..._numerics import MIN_RTOL
from ..._support._validate import check_number

__all__ = ["DERIVATIVE_OPTIONS", "SIMULATION_OPTIONS", "SOLVE_IVP_METHODS", "SolverOptions",
           "check_options"]

#: the methods of :func:`scipy.integrate.solve_ivp` by name.
SOLVE_IVP_METHODS = ("RK45", "RK23", "DOP853", "Radau", "BDF", "LSODA")

@dataclass(frozen=True)
class SolverOptions:
    """Settings of a run: those of :func:`scipy.integrate.solve_ivp` and
    ``simultaneity_tol``, validated, with one set of defaults.

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
    simultaneity_tol : float or None
        Events within this time (first order) of crossing at a stop switch with it; the
        flow and return maps merge groups this close (finite, >= 0). None: the default of
        the function the value is given to (:meth:`resolve`).

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
    simultaneity_tol: float | None = None

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
        if self.simultaneity_tol is not None:
            object.__setattr__(self, "simultaneity_tol", check_number(
                self.simultaneity_tol, "simultaneity_tol", strict=False))
        method = self.method
        known = isinstance(method, str) and method in SOLVE_IVP_METHODS
        if not known and not (isinstance(method, type) and _is_ode_solver(method)):
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

        The public functions take both an ``options`` value and the keywords ``rtol``,
        ``atol``, ``method``, ``max_step``, ``simultaneity_tol`` (None: not given). A
        keyword given with ``options`` must agree with the value ``options`` holds
        (ValueError naming both); ``simultaneity_tol`` left None takes ``default``'s (the
        function's own).
        """
        if options is not None and not isinstance(options, cls):
            raise TypeError(f"options must be a SolverOptions, got {type(options).__name__}")
        base = options if options is not None else (default or _defaults(cls))
        given = {key: value for key, value in settings.items() if value is not None}
        resolved = base.with_overrides(**given)  # the keywords checked
        for key in given if options is not None else ():
            held = getattr(options, key)
            if held is not None and getattr(resolved, key) != held:
                raise ValueError(
                    f"{key}={given[key]!r} and options.{key}={held!r} disagree: pass the "
                    f"setting once, as a keyword or in options"
                )
        if resolved.simultaneity_tol is None and default is not None:
            resolved = resolved.with_overrides(simultaneity_tol=default.simultaneity_tol)
        return resolved

    def solve_ivp_kwargs(self) -> dict:
        """Keyword arguments for :func:`scipy.integrate.solve_ivp`."""
        return {"rtol": self.rtol, "atol": self.atol, "method": self.method,
                "max_step": self.max_step}


#: the settings of a simulation (``simulate``, ``simulate_many``) and of the
#: B-derivatives along trajectories (flow and return maps): the defaults with each use's
#: own ``simultaneity_tol`` (``bderiv._limits``).
SIMULATION_OPTIONS = SolverOptions(simultaneity_tol=SIMULATION_SIMULTANEITY_TOL)
DERIVATIVE_OPTIONS = SolverOptions(simultaneity_tol=DERIVATIVE_SIMULTANEITY_TOL)


def check_options(options) -> None:
    """Refuse what a layer below the public functions cannot run with: ``options`` not a
    :class:`SolverOptions`, or one whose ``simultaneity_tol`` is not set (the public
    functions set their default: :meth:`SolverOptions.resolve`)."""
    if not isinstance(options, SolverOptions):
        raise TypeError(f"options must be a SolverOptions, got {type(options).__name__}")
    if options.simultaneity_tol is None:
        raise ValueError("options.simultaneity_tol must be set (a number >= 0), got None")


@lru_cache(maxsize=8)
def _defaults(cls) -> SolverOptions:
    """``cls()``, made once (frozen: shared by every run that passes no options)."""
    return cls()


def _is_ode_solver(method: type) -> bool:
    """Whether ``method`` is an ``OdeSolver`` subclass (scipy.integrate imported here: at
    import it costs a process about 0.35 s, which the compiled path never needs)."""
    from scipy.integrate import OdeSolver

    return issubclass(method, OdeSolver)
