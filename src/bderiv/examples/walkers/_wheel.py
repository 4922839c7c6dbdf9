"""The rimless wheel (the package's docstring gives the model and its closed forms)."""

from __future__ import annotations

import numpy as np

from ...analysis.system import HybridSystem
from .._common import Example, check_start
from ._shared import _orbit, _positive

__all__ = ["rimless_wheel", "rimless_wheel_orbit", "wheel_section", "wheel_section_gradient"]


class _Wheel:
    def __init__(self, alpha, slope, g, leg):
        self.alpha, self.slope, self.rate = alpha, slope, g / leg
        self.c = np.cos(2.0 * alpha)

    def field(self, x, mask):
        return np.array([x[1], self.rate * np.sin(x[0] + self.slope)])

    def field_jacobian(self, x, mask):
        return np.array([[0.0, 1.0], [self.rate * np.cos(x[0] + self.slope), 0.0]])

    def events(self, x):
        return np.array([x[0] - self.alpha])

    def event_jacobian(self, x):
        return np.array([[1.0, 0.0]])

    def reset(self, x, mask, k):
        return np.array([x[0] - 2.0 * self.alpha, self.c * x[1]])

    def reset_jacobian(self, x, mask, k):
        return np.diag([1.0, self.c])


def wheel_section(x):
    """The rimless wheel's section: mid-stance ``theta = 0``, crossed as theta grows."""
    return x[0]


def wheel_section_gradient(x):
    """Gradient of :func:`wheel_section`: ``(1, 0)``."""
    return np.array([1.0, 0.0])


def rimless_wheel(*, alpha=np.pi / 8, slope=0.08, g=1.0, leg=1.0) -> Example:
    """The rimless wheel on its periodic gait (module docstring).

    Parameters
    ----------
    alpha : float
        Half the angle between spokes, in (0, pi/4) radians (``pi / alpha`` spokes when
        that is an integer; default 8 spokes).
    slope : float
        Slope in radians, in (0, pi/2).
    g, leg : float
        Gravity and spoke length, > 0.

    Returns
    -------
    Example
        d = 2, n = 1. ``x0 = (0, omega_0)`` the gait's state at mid-stance and ``rho =
        (alpha, omega_-)`` the impact that ends the step, at ``t_event`` (both in closed
        form from the energy balance; the time by quadrature). :func:`rimless_wheel_orbit`
        finds the gait with :meth:`~bderiv.analysis.system.HybridSystem.periodic_orbit`.

    Examples
    --------
    >>> ex = rimless_wheel()
    >>> M = ex.system.bderivative(ex.rho)  # the saltation matrix of the leg swap
    >>> M.n_events, M.dim
    (1, 2)
    """
    alpha, slope, g, leg = float(alpha), float(slope), float(g), float(leg)
    if not 0.0 < alpha < np.pi / 4:
        raise ValueError(f"alpha must be in (0, pi/4) radians, got {alpha}")
    if not 0.0 < slope < np.pi / 2:
        raise ValueError(f"slope must be in (0, pi/2) radians, got {slope}")
    _positive(g=g, leg=leg)
    model = _Wheel(alpha, slope, g, leg)
    rate, c = model.rate, model.c
    u = c**2 * 4.0 * rate * np.sin(alpha) * np.sin(slope) / (1.0 - c**2)

    def speed(theta):  # omega at theta on the gait (energy from -alpha)
        return np.sqrt(u + 2.0 * rate * (np.cos(slope - alpha) - np.cos(theta + slope)))

    top = -slope  # the hub above the contact point: the slowest point of the step
    if top > -alpha and not u + 2.0 * rate * (np.cos(slope - alpha) - 1.0) > 0:
        raise ValueError(f"the wheel with alpha={alpha:g}, slope={slope:g} has no gait: it "
                         f"stops before rolling over its spoke (steeper slope or smaller "
                         f"alpha)")
    from scipy.integrate import quad  # here: bderiv.examples imports no scipy.integrate

    t_event = quad(lambda th: 1.0 / speed(th), 0.0, alpha, epsabs=1e-14, epsrel=1e-13)[0]
    system = HybridSystem(model.field, model.events, n_events=1, dim=2,
                          event_jacobian=model.event_jacobian,
                          field_jacobian=model.field_jacobian, reset=model.reset,
                          reset_jacobian=model.reset_jacobian)
    ex = Example(system=system, rho=np.array([alpha, speed(alpha)]),
                 x0=np.array([0.0, speed(0.0)]), t_event=t_event,
                 t_final=float(f"{t_event + 0.1 * t_event:.15g}"), name="rimless-wheel",
                 description=f"rimless wheel, spokes {2 * alpha:.4g} rad apart, slope "
                 f"{slope:g} rad: a leg swap every step (d = 2, n = 1)")
    return check_start(ex, {"alpha": alpha, "slope": slope, "g": g, "leg": leg})


def rimless_wheel_orbit(example=None, *, perturbation=(0.0, 0.05), **kwargs):
    """The wheel's gait by Newton's method from a perturbed mid-stance state.

    Parameters
    ----------
    example : Example, optional
        Default :func:`rimless_wheel`.
    perturbation : array_like, shape (2,)
        Added to ``example.x0`` for the guess.
    **kwargs
        Passed to :meth:`~bderiv.analysis.system.HybridSystem.periodic_orbit`.

    Returns
    -------
    PeriodicOrbit
    """
    return _orbit(rimless_wheel() if example is None else example, perturbation,
                  wheel_section, wheel_section_gradient, kwargs)
