"""Gaits of a model: the B-derivative of its Poincare map, its periodic orbits.

Functions over a model (:class:`~bderiv.analysis.system.HybridSystem`, whose methods of the
same names call them): :func:`return_map` (:mod:`.returnmap` builds it) and
:func:`periodic_orbit` (Newton's method with it, :mod:`.orbit`), each with the section
checked (:class:`~bderiv.models.section.Section`) and the integrator settings resolved.
"""

from __future__ import annotations

from .._limits import DEFAULT_T_MAX, ON_SURFACE_TOL, ORBIT_MAX_ITER, ORBIT_TOL
from .._support._validate import check_number, check_state
from ..models.integrate.options import DERIVATIVE_OPTIONS, SolverOptions
from ..models.section import Section
from . import orbit, returnmap
from .orbit import ORBIT_OPTIONS

__all__ = ["periodic_orbit", "return_map"]


def return_map(model, x0, section, *, section_gradient=None, t_max=DEFAULT_T_MAX,
               tol=ON_SURFACE_TOL, simultaneity_tol=None, options=None, rtol=None, atol=None,
               method=None, max_step=None):
    """The B-derivative of the Poincare map of ``section(x) = 0`` at x0 on it.

    Parameters
    ----------
    model : HybridSystem
        The model (:class:`~bderiv.analysis.system.HybridSystem`).
    x0 : array_like, shape (d,)
        A point of the section: ``|section(x0)| <= tol``.
    section : callable
        ``section(x) -> float``; the flow must cross ``section = 0`` upward (from < 0
        to > 0), transversally, at x0 and at the return. A ``numba.njit`` dispatcher
        on a compiled model (required there).
    section_gradient : callable, optional
        ``section_gradient(x) -> (d,)``; numerical by default.
    t_max : float
        Longest time to wait for the return.
    tol : float
        Largest accepted ``|section(x0)|``.
    simultaneity_tol, options, rtol, atol, method, max_step
        As for :func:`~bderiv.analysis.flows.flow_bderivative`.

    Returns
    -------
    ReturnMap
        A :class:`~bderiv.analysis.flowmap.FlowBDerivative` (``__call__``, ``event_times``,
        ``orders``, ``piece``) mapping tangent vectors ``(..., d)`` at x0 to tangent vectors at
        ``P(x0)``, with the correction for the change in return time
        (:mod:`bderiv.analysis.returnmap`); ``period`` is the return time.
    """
    options = SolverOptions.resolve(options, DERIVATIVE_OPTIONS, rtol=rtol, atol=atol,
                                    method=method, max_step=max_step,
                                    simultaneity_tol=simultaneity_tol)
    x0 = check_state(x0, model.dim, "x0")
    section = Section(section, model.dim, section_gradient, model.check_jacobians)
    with model.calls.numerical_jacobian_watch("return_map"):
        return returnmap.return_map(model, x0, section, t_max=check_number(t_max, "t_max"),
                                    tol=check_number(tol, "tol", strict=False),
                                    options=options).map


def periodic_orbit(model, x_guess, section, period_guess=None, *, section_gradient=None,
                   tol=ORBIT_TOL, max_iter=ORBIT_MAX_ITER,
                   simultaneity_tol=None, options=None, cyclic=()):
    """A periodic orbit through the section ``section(x) = 0``: ``P(x) = x``.

    Newton's method with the return map's B-derivative, the piecewise-linear Newton
    equation solved exactly (:mod:`bderiv.analysis.orbit` says how and why).

    Parameters
    ----------
    model : HybridSystem
        The model (:class:`~bderiv.analysis.system.HybridSystem`).
    x_guess : array_like, shape (d,)
        A guess near the section (it is moved onto it first).
    section, section_gradient
        As for :func:`~bderiv.analysis.poincare.return_map`.
    period_guess : float, optional
        Expected period: the return is awaited for 3 times it (default 100).
    tol : float
        Stop when ``max |P(x) - x| <= tol * max(1, max |x|)``.
    max_iter : int
        Largest number of Newton iterations.
    simultaneity_tol : float, optional
        For the orbit's return map, as for :func:`~bderiv.analysis.flows.flow_bderivative`
        (default ``DERIVATIVE_SIMULTANEITY_TOL``, 1e-7).
    options : SolverOptions, optional
        Default ``SolverOptions(rtol=1e-12, atol=1e-13)`` (``orbit.ORBIT_OPTIONS``); a
        ``simultaneity_tol`` given must agree with it (ValueError naming both).
    cyclic : sequence of int
        Coordinates the model and the section do not depend on (a forward position,
        a heading): left out of ``P(x) = x`` and of the stability, their advance per
        period in ``PeriodicOrbit.advance`` (checked:
        :func:`bderiv.analysis.orbit.periodic_orbit`).

    Returns
    -------
    PeriodicOrbit
        With ``x0``, ``period``, ``trajectory``, ``return_map``, ``residual``,
        ``history``, ``advance`` and ``stability()``.
    """
    x_guess = check_state(x_guess, model.dim, "x_guess")
    options = SolverOptions.resolve(options, ORBIT_OPTIONS, simultaneity_tol=simultaneity_tol)
    section = Section(section, model.dim, section_gradient, model.check_jacobians)
    with model.calls.numerical_jacobian_watch("periodic_orbit"):
        return orbit.periodic_orbit(model, x_guess, section, period_guess=period_guess,
                                    tol=tol, max_iter=max_iter, options=options,
                                    cyclic=cyclic)
