"""The compass gait (the package's docstring gives the model, the scuffing and the published
numbers compared in the tests)."""

from __future__ import annotations

import numpy as np

from ..._support._numdiff import complex_step
from ..._support._validate import check_number
from ...analysis.system import HybridSystem
from .._common import Example, check_start
from ._shared import _orbit, _positive

__all__ = [
    "GARCIA_EIGENVALUES",
    "GARCIA_FIXED_POINT",
    "STABLE_SLOPE",
    "compass_gait",
    "compass_gait_orbit",
    "compass_section",
    "compass_section_gradient",
    "long_gait_start",
]

#: Garcia et al. (1998), slope 0.009, leg_mass = 0: (theta, theta') just after heel strike
GARCIA_FIXED_POINT = (0.20031090049483, -0.19983247291764)
#: ... and the nonzero eigenvalues of its stride map
GARCIA_EIGENVALUES = (complex(-0.19120868949940, 0.55633363687106),
                      complex(-0.19120868949940, -0.55633363687106))
#: the slope (rad) beyond which the long-period gait of Garcia et al.'s walker (leg_mass 0)
#: is unstable: a multiplier leaves the unit circle through -1 (a period doubling; their
#: 0.0151; its modulus is 0.999904 at 0.015088 and 1.000123 at 0.015089); the stable gait
#: beyond has period two, then longer periods
STABLE_SLOPE = 0.015088
#: the long-period gait's ``(theta, theta')`` just after heel strike against the slope s,
#: ``GARCIA_FIXED_POINT`` times ``f(s) / f(0.009)``, ``f(s) = s^(1/3) - b s`` with b for
#: theta and theta' (a least-squares fit of the fixed points of Garcia et al.'s stride map
#: for s from 1e-4 to 0.04, within 6e-5 of them; their leading term, ``theta* ~ 0.97
#: s^(1/3)``, is the asymptote of small slopes)
_GAIT_FIT = (0.1843, 1.2206)
#: the size ``|x0|`` of a gait's mid-stance state below which the orbit's default
#: perturbation shrinks with it (slopes below about 0.006: the gait's size goes as
#: ``slope^(1/3)``, and a perturbation of 0.01 at slope 1e-3 leads Newton's method to
#: another, unstable, orbit)
_GAIT_SIZE = 0.3


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
        Default: the long-period gait of Garcia et al.'s walker (``leg_mass = 0``) at
        ``slope`` (:func:`long_gait_start`; their published fixed point at 0.009),
        ``theta'`` scaled by ``sqrt(g / leg)``: a start for light legs at any slope. That
        gait is stable up to slope :data:`STABLE_SLOPE` (0.015088) and unstable beyond
        (a period doubling): there :func:`compass_gait_orbit` finds it, unstable (its
        stability says so), not the stable gait of period two. Heavy legs need a start
        of their own.

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
        theta, rate = long_gait_start(slope)
        rate *= np.sqrt(g / leg)
        # the gait of light legs on gentle slopes: heavier legs walk another gait
        remedy = (f"the default start, (theta, theta') = ({theta:.6g}, {rate:.6g}), is the "
                  f"long-period gait of Garcia et al.'s walker (leg_mass 0) at slope "
                  f"{slope:g} (fitted for slopes up to 0.04) and suits light legs only: pass "
                  f"start=(theta, theta'), a state just after a heel strike of the gait with "
                  f"these parameters")
    else:
        given = np.asarray(start, dtype=np.float64)
        if given.shape != (2,) or not np.isfinite(given).all():
            raise ValueError(f"start must be two finite numbers (theta, theta'), got {start!r}")
        theta, rate = given
        remedy = "pass another start, or choose other parameters"
    start = np.array([theta, 2 * theta, rate, rate * (1.0 - np.cos(2.0 * theta))])
    x0, rho, t_event = _step_from(model, start, remedy)
    ex = Example(system=system, rho=rho, x0=x0, t_event=t_event,
                 t_final=float(f"{t_event + 0.1 * t_event:.15g}"), name="compass-gait",
                 description=f"compass-gait walker, slope {slope:g} rad, leg/hip mass "
                 f"{leg_mass / hip_mass:g}: a scuff and a heel strike every step (d = 4, "
                 f"n = 1)")
    return check_start(ex, {"slope": slope, "theta": float(theta), "theta'": float(rate)},
                       remedy=remedy)


def long_gait_start(slope):
    """``(theta, theta')`` just after heel strike of the long-period gait of Garcia et
    al.'s walker (``leg_mass = 0``, ``g = leg = 1``) at ``slope``, to about 6e-5 (exact
    at 0.009: :data:`GARCIA_FIXED_POINT`), for slopes up to 0.04: a start for Newton's
    method (``GARCIA_FIXED_POINT`` times ``f(slope) / f(0.009)``, ``f(s) = s^(1/3) - b s``,
    b fitted to the gait's fixed points, 0.1843 for theta and 1.2206 for theta').

    Raises
    ------
    TypeError, ValueError
        If ``slope`` is not a real number in (0, pi/2) radians (the slopes a walker goes
        down; the fit holds up to 0.04).
    """
    slope = check_number(slope, "slope")
    if not slope < np.pi / 2:
        raise ValueError(f"slope must be in (0, pi/2) radians, got {slope}")

    def f(b):
        return slope ** (1.0 / 3.0) - b * slope

    def f_ref(b):
        return 0.009 ** (1.0 / 3.0) - b * 0.009

    (bt, br), (theta, rate) = _GAIT_FIT, GARCIA_FIXED_POINT
    return theta * f(bt) / f_ref(bt), rate * f(br) / f_ref(br)


def _step_from(model, start, remedy):
    """From a state just after heel strike: the state at mid-stance, the next heel strike
    and the time between them (integrated with scipy, events located by it)."""

    def mid(_t, x):
        return x[0]

    def strike(_t, x):  # continuous: a hit while the swing leg is not yet past (phi >= 0)
        return x[1] - 2.0 * x[0]  # is the scuff the model ignores, stepped over below

    from scipy.integrate import solve_ivp  # here: bderiv.examples imports no scipy.integrate

    mid.terminal, mid.direction = True, -1
    strike.terminal, strike.direction = True, 1
    options = dict(method="DOP853", rtol=1e-12, atol=1e-13)
    field = lambda _t, x: model.field(x, 0)  # noqa: E731
    a = solve_ivp(field, (0.0, 50.0), start, events=mid, **options)
    b, t0 = a, 0.0
    if a.status == 1:  # (a hit's own point is no crossing for the next run: it goes on)
        b = solve_ivp(field, (0.0, 50.0), a.y_events[0][0], events=strike, **options)
        while b.status == 1 and b.y_events[0][0][1] >= 0.0 and t0 < 50.0:
            t0 += float(b.t_events[0][0])
            b = solve_ivp(field, (0.0, 50.0 - t0), b.y_events[0][0], events=strike,
                          **options)
    if not (a.status == 1 and b.status == 1):
        raise ValueError(f"the compass gait with these parameters does not complete a step "
                         f"from (theta, theta') = {start[[0, 2]].tolist()} just after heel "
                         f"strike (no mid-stance and heel strike within 50 time units): "
                         f"{remedy}")
    return a.y_events[0][0], b.y_events[0][0], t0 + float(b.t_events[0][0])


def compass_gait_orbit(example=None, *, perturbation=None, **kwargs):
    """The compass gait by Newton's method from a perturbed mid-stance state.

    Parameters
    ----------
    example : Example, optional
        Default :func:`compass_gait`.
    perturbation : array_like, shape (4,), optional
        Added to ``example.x0`` for the guess. Default ``(0, 0.01, -0.01, 0.005)``, scaled
        by ``|x0| / 0.3`` where ``|x0| < 0.3`` (the small gaits of slopes below about
        0.006, which a perturbation of 0.01 sends to another, unstable, orbit).
    **kwargs
        Passed to :meth:`~bderiv.analysis.system.HybridSystem.periodic_orbit`.

    Returns
    -------
    PeriodicOrbit
    """
    ex = compass_gait() if example is None else example
    if perturbation is None:
        scale = min(1.0, float(np.linalg.norm(ex.x0)) / _GAIT_SIZE)
        perturbation = scale * np.array([0.0, 0.01, -0.01, 0.005])
    return _orbit(ex, perturbation, compass_section, compass_section_gradient, kwargs)
