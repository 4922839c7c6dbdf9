"""The "chair": a planar rigid body whose two legs touch compliant ground at one instant.

State ``(x, z, theta, vx, vz, omega)`` (d = 6): centre of mass, pitch angle and their
velocities; unit mass, inertia ``inertia``. Leg k ends at the body-frame point
``(a_k, b_k)``; its height is ``z + a_k sin(theta) + b_k cos(theta)`` and event k is
``h_k = -height_k`` (the foot going down through the ground). In contact the ground pushes
the foot with a Kelvin-Voigt force: vertical ``-stiffness * height - c_k(B) * v_foot_z``,
horizontal ``-friction * v_foot_x``. Gravity acts always.

At touchdown the spring force is 0 but the damping force is not, so the field jumps
across each surface. If the two contact forces simply add (``mode_damping = 0``) the two
event orders give the same linear piece (the saltation matrices commute in effect); with
``mode_damping > 0`` each leg's damping grows to ``damping * (1 + mode_damping)`` while both
legs touch, the table is not additive and the two orders give different pieces.

The event point ``rho`` has the body tilted (``theta = 0.1``) with legs of unequal length so
that both feet are exactly on the ground, falling and rotating; ``x0`` is the analytic
free-flight state ``t_event`` earlier (both feet descend all the way).
"""

from __future__ import annotations

import numpy as np

from ._common import Example, complex_step_jacobian

__all__ = ["chair"]

_G = 9.81


class _Chair:
    def __init__(self, stiffness, damping, mode_damping, friction, inertia, legs):
        self.K = stiffness
        self.C = damping
        self.kappa = mode_damping
        self.Ct = friction
        self.inertia = inertia
        self.legs = np.asarray(legs, dtype=np.float64)  # (2, 2): rows (a_k, b_k)

    def _feet(self, x):
        th = x[2]
        a, b = self.legs[:, 0], self.legs[:, 1]
        c, s = np.cos(th), np.sin(th)
        rx = a * c - b * s  # foot offset from the centre of mass, world frame
        rz = a * s + b * c
        height = x[1] + rz
        vfx = x[3] - x[5] * rz
        vfz = x[4] + x[5] * rx
        return rx, rz, height, vfx, vfz

    def field(self, x, mask):
        rx, rz, height, vfx, vfz = self._feet(x)
        both = (int(mask) & 3) == 3
        c_leg = self.C * (1.0 + self.kappa) if both else self.C
        ax = 0.0 * x[0]
        az = -_G + 0.0 * x[0]
        alpha = 0.0 * x[0]
        for k in range(2):
            if int(mask) >> k & 1:
                fz = -self.K * height[k] - c_leg * vfz[k]
                fx = -self.Ct * vfx[k]
                ax = ax + fx
                az = az + fz
                alpha = alpha + (rx[k] * fz - rz[k] * fx) / self.inertia
        return np.array([x[3], x[4], x[5], ax, az, alpha])

    def field_jacobian(self, x, mask):
        return complex_step_jacobian(lambda y: self.field(y, mask), x, 6)

    def events(self, x):
        return -self._feet(x)[2]

    def event_jacobian(self, x):
        rx = self._feet(x)[0]
        D = np.zeros((2, 6))
        D[:, 1] = -1.0
        D[:, 2] = -rx
        return D


def chair(
    *,
    mode_damping=1.0,
    stiffness=400.0,
    damping=4.0,
    friction=1.0,
    inertia=0.1,
    t_event=0.1,
    t_after=0.05,
):
    """The planar two-legged body landing on both legs at once (d = 6, n = 2).

    Parameters
    ----------
    mode_damping : float
        Extra relative damping of each leg while both legs touch; 0 makes the contact
        forces additive (both event orders then give the same piece).
    stiffness, damping, friction : float
        Ground spring, leg damping and horizontal ground friction (per unit mass).
    inertia : float
        Moment of inertia per unit mass.
    t_event, t_after : float
        Flight time from ``x0`` to the touchdown; ``t_final = t_event + t_after`` (the
        legs are still in contact then).

    Returns
    -------
    Example
    """
    theta = 0.1
    a0, b0, a1 = -0.5, -0.4, 0.6
    b1 = b0 + (a0 - a1) * np.tan(theta)  # both feet on the ground at theta
    model = _Chair(stiffness, damping, mode_damping, friction, inertia, [[a0, b0], [a1, b1]])
    z = -(a0 * np.sin(theta) + b0 * np.cos(theta))
    vx, vz, om = 0.5, -2.0, 0.3
    rho = np.array([0.0, z, theta, vx, vz, om])
    T = float(t_event)
    vz0 = vz + _G * T
    x0 = np.array([-vx * T, z - vz0 * T + 0.5 * _G * T**2, theta - om * T, vx, vz0, om])
    return Example.from_model(
        model,
        n_events=2,
        dim=6,
        rho=rho,
        x0=x0,
        t_event=T,
        t_after=t_after,
        name="chair",
        description=(
            "planar rigid body, two legs touch compliant ground at the same instant "
            f"(d = 6, n = 2, mode_damping = {mode_damping})"
        ),
    )
