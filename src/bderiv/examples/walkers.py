"""Passive walkers down a slope: the rimless wheel and the compass gait (leg swaps as resets).

Both walk down a slope of angle ``slope`` under gravity alone; each step ends with an
impact at which the legs exchange their roles. The impact is a reset that relabels the
legs (and changes the velocities by the conservation of angular momentum), so the state
lands back on the side of the event surface it came from or on the surface with the flow
leaving it: a leg swap (mathematics.md section 9, "Where a reset lands"). Units are the
walkers' own: lengths in leg lengths and time in ``sqrt(leg / g)`` when ``g = leg = 1``
(the defaults, as in the publications).

**Rimless wheel** (McGeer 1990; Coleman, Chatterjee & Ruina 1997): spokes of length
``leg`` at angles ``2 alpha`` apart around a point mass at the hub. State ``(theta,
omega)``: the stance spoke's angle from the slope's normal, positive downhill (the walking
direction), and its rate; in stance the hub is an inverted pendulum,
``theta'' = (g / leg) sin(theta + slope)``. The next spoke hits the ground when
``theta = alpha``: event ``h = theta - alpha``. The impact conserves the angular momentum
about the new contact point: ``omega -> cos(2 alpha) omega``, and the new stance spoke is
the one at ``theta - 2 alpha`` (``-alpha`` on the surface): the reset
``(theta, omega) -> (theta - 2 alpha, cos(2 alpha) omega)`` lands at ``h = -2 alpha``,
back where the step began, so the event's bit stays clear and every step ends with an
upward crossing of the same surface. The section of the gait is mid-stance,
``theta = 0`` (:func:`wheel_section`). Closed forms (energy balance from ``-alpha`` to
``alpha``): the map on ``u = omega^2`` after the impact is ``u -> c^2 (u + K)``, ``c =
cos(2 alpha)``, ``K = 4 (g / leg) sin(alpha) sin(slope)``; its fixed point is
``u* = c^2 K / (1 - c^2)`` and the multiplier of the gait is ``c^2 = cos(2 alpha)^2``.
The model does not describe a wheel too slow to roll over the top of a spoke (``omega``
reaching 0 before the vertical; the trailing spoke is no event).

**Compass gait** (McGeer 1990; Goswami, Thuilot & Espiau 1998; Garcia, Chatterjee, Ruina &
Coleman 1998): two straight legs of length ``leg`` with point feet, a point mass
``hip_mass`` at the hip and ``leg_mass`` on each leg at ``leg_com`` (as a fraction of the
leg, from the hip: 1 puts it at the foot, as in Garcia et al.; 0.5 in the middle, as in
Goswami et al.). The coordinates are Garcia et al.'s: state ``(theta, phi, theta', phi')``,
``theta`` the stance leg's angle from the slope's normal (positive uphill: a step runs from
``theta > 0`` to ``theta < 0``), ``phi`` the angle from the stance leg to the swing leg
(the swing leg's angle from the normal is ``theta - phi``). The swing foot is on the
ground when ``phi = 0`` or ``phi = 2 theta``; event ``h = phi - 2 theta``. The heel strike
is its upward crossing with the swing leg ahead (``phi < 0``); the reset swaps the legs,
``theta -> theta - phi`` and ``phi -> -phi`` (``-theta`` and ``-2 theta`` on the surface),
and gives the velocities from the conservation of the angular momentum of the whole walker
about the new stance foot and of the new swing leg about the hip. Just after the heel
strike the state is on the surface again, moving into ``h > 0``: the bit is set (flipped).
**Scuffing**: with point feet on a straight slope the swing foot dips under the ground near
mid-stance, where the legs pass each other. As in the literature (Garcia et al., McGeer),
that contact is ignored: the surface ``h = 0`` is crossed downward there (the bit is
cleared, no reset: the fields of the two regions are the same), and only the next upward
crossing, once the swing leg is past the stance leg, is the heel strike (the reset refuses
an upward crossing with ``phi >= 0``). Each step thus has two events of the same index:
the scuff (downward, no jump) and the heel strike (upward, leg swap). The section of the
gait is mid-stance, ``theta = 0`` crossed downward (:func:`compass_section`).

**Published numbers** compared in the tests: Garcia, Chatterjee, Ruina & Coleman, "The
simplest walking model: stability, complexity, and scaling", ASME J. Biomech. Eng. 120(2),
281-288 (1998), the limit ``leg_mass / hip_mass -> 0`` (``leg_mass = 0`` here), slope
0.009, ``g = leg = 1``: the stable (long-period) gait just after heel strike has
``theta* = 0.20031090049483``, ``theta'* = -0.19983247291764``, and its stride map's
nonzero eigenvalues are ``-0.19120868949940 +- 0.55633363687106 i`` (the digits of the
simulation code published with the paper, M. Garcia 1998, integrated to 1e-10:
:data:`GARCIA_FIXED_POINT`, :data:`GARCIA_EIGENVALUES`). The fixed point agrees to 1e-10;
the eigenvalues to 1.7e-3 only: the return map's B-derivative gives ``-0.1900998 +-
0.5575988 i`` (modulus 0.58911, Garcia's 0.58827), and so do central differences of the
stride map of Garcia's equations integrated by scipy at rtol 1e-13 (tests/test_bounces.py),
to 1e-8. The two computations here agree with each other, not with the code's comment
beyond the second decimal (whose integration and differencing steps the code does not say).
"""

from __future__ import annotations

import numpy as np
from scipy.integrate import quad, solve_ivp

from .._support._numdiff import complex_step
from ..analysis.system import HybridSystem
from ._common import Example, check_start

__all__ = [
    "GARCIA_EIGENVALUES",
    "GARCIA_FIXED_POINT",
    "compass_gait",
    "compass_gait_orbit",
    "compass_section",
    "compass_section_gradient",
    "rimless_wheel",
    "rimless_wheel_orbit",
    "wheel_section",
    "wheel_section_gradient",
]

#: Garcia et al. (1998), slope 0.009, leg_mass = 0: (theta, theta') just after heel strike
GARCIA_FIXED_POINT = (0.20031090049483, -0.19983247291764)
#: ... and the nonzero eigenvalues of its stride map
GARCIA_EIGENVALUES = (complex(-0.19120868949940, 0.55633363687106),
                      complex(-0.19120868949940, -0.55633363687106))


def _positive(**values):
    for name, v in values.items():
        if not (np.isfinite(v) and v > 0):
            raise ValueError(f"{name} must be a finite number > 0, got {v}")


# ----------------------------------------------------------------------------------
# rimless wheel
# ----------------------------------------------------------------------------------
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


def _orbit(ex, perturbation, section, gradient, kwargs):
    """``periodic_orbit`` of a walker from ``ex.x0 + perturbation``, awaiting the return
    for two steps' time by default."""
    kwargs.setdefault("section_gradient", gradient)
    kwargs.setdefault("period_guess", 2.0 * ex.t_event)
    return ex.system.periodic_orbit(ex.x0 + np.asarray(perturbation, dtype=np.float64),
                                    section, **kwargs)


# ----------------------------------------------------------------------------------
# compass gait
# ----------------------------------------------------------------------------------
def _along(angle):
    """Unit vector from a foot to the hip for a leg at ``angle`` from the slope normal
    (slope frame: x downhill, y along the normal), and its derivative in the angle."""
    s, c = np.sin(angle), np.cos(angle)
    return np.array([-s, c]), np.array([-c, -s])


def _cross(a, b):
    return a[0] * b[1] - a[1] * b[0]


class _Compass:
    """The compass gait's functions; the heel strike's Jacobian by the complex step."""

    def __init__(self, hip_mass, leg_mass, leg, leg_com, slope, g):
        self.M, self.m, self.leg, self.slope = hip_mass, leg_mass, leg, slope
        self.b = leg_com * leg  # leg mass from the hip
        self.a = leg - self.b   # ... from the foot
        self.g = g

    def _masses(self, q):
        """Positions (from the stance foot) and Jacobians d/d(theta, phi) of the hip, the
        stance leg's mass and the swing leg's mass: three ((2,), (2, 2)) pairs."""
        theta, psi = q[0], q[0] - q[1]  # psi: the swing leg's angle from the normal
        u, du = _along(theta)
        w, dw = _along(psi)
        hip, J_hip = self.leg * u, np.stack([self.leg * du, 0.0 * du], axis=1)
        stance, J_stance = self.a * u, np.stack([self.a * du, 0.0 * du], axis=1)
        swing = hip - self.b * w
        J_swing = np.stack([self.leg * du - self.b * dw, self.b * dw], axis=1)
        return (hip, J_hip), (stance, J_stance), (swing, J_swing)

    def _system(self, x):
        """Lagrange's equations ``A(phi) q'' = r(x)``: the theta row is the whole walker's,
        the phi row the swing leg's torque balance about the (free) hip divided by its
        mass, so that ``leg_mass = 0`` is Garcia et al.'s limit. With ``psi = theta - phi``
        (the swing leg's angle from the normal), ``l, a, b`` the leg and the leg mass's
        distances from the foot and the hip:

        A = [[M l^2 + m a^2 + m (l^2 - 2 l b cos phi + b^2), m (l b cos phi - b^2)],
             [l b cos phi - b^2, b^2]]
        r = [(M l + m a + m l) g sin(theta - slope) - m b g sin(psi - slope)
               - m l b sin(phi) (theta'^2 - psi'^2),
             b g sin(psi - slope) + l b theta'^2 sin(phi)]
        """
        theta, phi, thd, phd = x
        psi, psd = theta - phi, thd - phd
        M, m, ell, a, b, g, s = self.M, self.m, self.leg, self.a, self.b, self.g, self.slope
        cphi, sphi = np.cos(phi), np.sin(phi)
        A = np.array([[M * ell**2 + m * a**2 + m * (ell**2 - 2 * ell * b * cphi + b**2),
                       m * (ell * b * cphi - b**2)],
                      [ell * b * cphi - b**2, b**2]])
        r = np.array([(M * ell + m * a + m * ell) * g * np.sin(theta - s)
                      - m * b * g * np.sin(psi - s) - m * ell * b * sphi * (thd**2 - psd**2),
                      b * g * np.sin(psi - s) + ell * b * thd**2 * sphi])
        return A, r

    def field(self, x, mask):
        A, r = self._system(x)
        return np.concatenate([x[2:], np.linalg.solve(A, r)])

    def field_jacobian(self, x, mask):
        """``d q'' = A^-1 (dr - dA q'')`` (A depends on phi alone)."""
        theta, phi, thd, phd = x
        psi, psd = theta - phi, thd - phd
        m, ell, b, g, s = self.m, self.leg, self.b, self.g, self.slope
        A, r = self._system(x)
        qdd = np.linalg.solve(A, r)
        cphi, sphi = np.cos(phi), np.sin(phi)
        cpsi, K0 = np.cos(psi - s), (self.M * ell + m * self.a + m * ell) * g
        dr = np.array([
            [K0 * np.cos(theta - s) - m * b * g * cpsi,
             m * b * g * cpsi - m * ell * b * cphi * (thd**2 - psd**2),
             -2 * m * ell * b * sphi * phd, -2 * m * ell * b * sphi * psd],
            [b * g * cpsi, -b * g * cpsi + ell * b * thd**2 * cphi, 2 * ell * b * thd * sphi, 0.0],
        ])
        dA_dphi = ell * b * sphi * np.array([[2 * m, -m], [-1.0, 0.0]])
        dr[:, 1] -= dA_dphi @ qdd
        J = np.zeros((4, 4))
        J[0, 2] = J[1, 3] = 1.0
        J[2:] = np.linalg.solve(A, dr)
        return J

    def events(self, x):
        return np.array([x[1] - 2.0 * x[0]])

    def event_jacobian(self, x):
        return np.array([[-2.0, 1.0, 0.0, 0.0]])

    def heel_strike(self, x):
        """The leg swap: new angles, and the velocities conserving the angular momentum of
        the walker about the new stance foot and of the new swing leg about the hip."""
        q, qd = x[:2], x[2:]
        q_new = np.array([q[0] - q[1], -q[1]])
        (hip, J_hip), (stance, J_stance), (swing, J_swing) = self._masses(q)
        foot = hip - self.leg * _along(q[0] - q[1])[0]  # the swing foot: the new pivot
        H_walker = (self.M * _cross(hip - foot, J_hip @ qd)
                    + self.m * _cross(stance - foot, J_stance @ qd)
                    + self.m * _cross(swing - foot, J_swing @ qd))
        H_leg = _cross(stance - hip, J_stance @ qd)  # per unit leg mass
        # after: positions from the new foot; the old swing leg's mass is the new stance's
        (hip2, J_hip2), (stance2, J_stance2), (swing2, J_swing2) = self._masses(q_new)
        A = np.zeros((2, 2), dtype=x.dtype)
        for j in range(2):
            A[0, j] = (self.M * _cross(hip2, J_hip2[:, j])
                       + self.m * _cross(stance2, J_stance2[:, j])
                       + self.m * _cross(swing2, J_swing2[:, j]))
            A[1, j] = _cross(swing2 - hip2, J_swing2[:, j])
        return np.concatenate([q_new, np.linalg.solve(A, np.array([H_walker, H_leg]))])

    def reset(self, x, mask, k):
        if mask & 1:  # downward: the scuff at mid-stance, ignored
            return np.array(x, dtype=np.float64)
        if not x[1] < 0:
            raise ValueError(f"the compass gait's swing foot reaches the ground (h = 0, "
                             f"upward) with the swing leg behind the stance leg (phi = "
                             f"{x[1]:.6g} >= 0): a scuff the model does not resolve")
        return self.heel_strike(x)

    def reset_jacobian(self, x, mask, k):
        if mask & 1:
            return np.eye(4)
        return complex_step(self.heel_strike, x, 4, strict=False)


def compass_section(x):
    """The compass gait's section: mid-stance ``theta = 0``, crossed as theta decreases."""
    return -x[0]


def compass_section_gradient(x):
    """Gradient of :func:`compass_section`: ``(-1, 0, 0, 0)``."""
    return np.array([-1.0, 0.0, 0.0, 0.0])


def compass_gait(*, slope=0.009, hip_mass=1.0, leg_mass=0.0, leg_com=1.0, leg=1.0,
                 g=1.0, start=None) -> Example:
    """The compass-gait walker on its periodic gait (module docstring).

    Parameters
    ----------
    slope : float
        Slope in radians, in (0, pi/2).
    hip_mass : float
        Point mass at the hip, > 0.
    leg_mass : float
        Point mass on each leg, >= 0 (0: Garcia et al.'s simplest walking model).
    leg_com : float
        Where the leg mass sits, as a fraction of the leg from the hip, in (0, 1].
    leg, g : float
        Leg length and gravity, > 0.
    start : (float, float), optional
        ``(theta, theta')`` just after a heel strike to start the step from (with ``phi =
        2 theta``, ``phi' = theta' (1 - cos 2 theta)``, exact for ``leg_mass = 0``).
        Default: Garcia et al.'s published fixed point, ``theta'`` scaled by
        ``sqrt(g / leg)`` (a good start for slopes near 0.009 and light legs).

    Returns
    -------
    Example
        d = 4, n = 1: ``x0`` the step's state at mid-stance (after the scuff), ``rho`` the
        heel strike, ``t_event`` the time between them, by integration (scipy).
        :func:`compass_gait_orbit` finds the gait of the parameters given from there.

    Raises
    ------
    ValueError
        On a parameter out of range (named), or when the step from ``start`` does not
        reach mid-stance and the heel strike.

    Examples
    --------
    >>> ex = compass_gait()
    >>> ex.system.n_events, ex.system.dim
    (1, 4)
    """
    slope, hip_mass, leg_mass = float(slope), float(hip_mass), float(leg_mass)
    leg_com, leg, g = float(leg_com), float(leg), float(g)
    if not 0.0 < slope < np.pi / 2:
        raise ValueError(f"slope must be in (0, pi/2) radians, got {slope}")
    if not (np.isfinite(leg_mass) and leg_mass >= 0):
        raise ValueError(f"leg_mass must be a finite number >= 0, got {leg_mass}")
    if not 0.0 < leg_com <= 1.0:
        raise ValueError(f"leg_com must be in (0, 1], got {leg_com}")
    _positive(hip_mass=hip_mass, leg=leg, g=g)
    model = _Compass(hip_mass, leg_mass, leg, leg_com, slope, g)
    system = HybridSystem(model.field, model.events, n_events=1, dim=4,
                          event_jacobian=model.event_jacobian,
                          field_jacobian=model.field_jacobian, reset=model.reset,
                          reset_jacobian=model.reset_jacobian)
    if start is None:
        theta, rate = GARCIA_FIXED_POINT[0], GARCIA_FIXED_POINT[1] * np.sqrt(g / leg)
    else:
        given = np.asarray(start, dtype=np.float64)
        if given.shape != (2,) or not np.isfinite(given).all():
            raise ValueError(f"start must be two finite numbers (theta, theta'), got {start!r}")
        theta, rate = given
    start = np.array([theta, 2 * theta, rate, rate * (1.0 - np.cos(2.0 * theta))])
    x0, rho, t_event = _step_from(model, start)
    ex = Example(system=system, rho=rho, x0=x0, t_event=t_event,
                 t_final=float(f"{t_event + 0.1 * t_event:.15g}"), name="compass-gait",
                 description=f"compass-gait walker, slope {slope:g} rad, leg/hip mass "
                 f"{leg_mass / hip_mass:g}: a scuff and a heel strike every step (d = 4, "
                 f"n = 1)")
    return check_start(ex, {"slope": slope, "theta": float(theta), "theta'": float(rate)})


def _step_from(model, start):
    """From a state just after heel strike: the state at mid-stance, the next heel strike
    and the time between them (integrated with scipy, events located by it)."""

    def mid(_t, x):
        return x[0]

    def strike(_t, x):  # only once the swing leg is past the stance leg
        return x[1] - 2.0 * x[0] if x[1] < 0 else -1.0

    mid.terminal, mid.direction = True, -1
    strike.terminal, strike.direction = True, 1
    options = dict(method="DOP853", rtol=1e-12, atol=1e-13)
    field = lambda _t, x: model.field(x, 0)  # noqa: E731
    a = solve_ivp(field, (0.0, 50.0), start, events=mid, **options)
    b = (solve_ivp(field, (0.0, 50.0), a.y_events[0][0], events=strike, **options)
         if a.status == 1 else a)
    if not (a.status == 1 and b.status == 1):
        raise ValueError(f"the compass gait with these parameters does not complete a step "
                         f"from (theta, theta') = {start[[0, 2]].tolist()} just after heel "
                         f"strike (no mid-stance and heel strike within 50 time units): "
                         f"pass another start")
    return a.y_events[0][0], b.y_events[0][0], float(b.t_events[0][0])


def compass_gait_orbit(example=None, *, perturbation=(0.0, 0.01, -0.01, 0.005), **kwargs):
    """The compass gait by Newton's method from a perturbed mid-stance state.

    Parameters
    ----------
    example : Example, optional
        Default :func:`compass_gait`.
    perturbation : array_like, shape (4,)
        Added to ``example.x0`` for the guess.
    **kwargs
        Passed to :meth:`~bderiv.analysis.system.HybridSystem.periodic_orbit`.

    Returns
    -------
    PeriodicOrbit
    """
    return _orbit(compass_gait() if example is None else example, perturbation,
                  compass_section, compass_section_gradient, kwargs)


# ----------------------------------------------------------------------------------
# the demo: orbit, stability, and the reference numbers
# ----------------------------------------------------------------------------------
