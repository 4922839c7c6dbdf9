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
from numba.extending import register_jitable

from .._support._validate import check_numbers
from ._common import Example, check_start

__all__ = ["chair"]

_G = 9.81


@register_jitable
def _offset(a, b, theta):
    """World-frame offset ``(r_x, r_z)`` of the body-frame point ``(a, b)`` at pitch
    ``theta``."""
    c, s = np.cos(theta), np.sin(theta)
    return a * c - b * s, a * s + b * c


def _functions(K, C, kappa, Ct, inertia, legs) -> dict:
    """The chair's field, events and event Jacobian: plain functions over the constants
    (``legs`` (2, 2): rows ``(a_k, b_k)``), for Python as they are and for numba compiled."""

    def field(x, mask):
        c_leg = C * (1.0 + kappa) if (mask & 3) == 3 else C
        out = np.empty_like(x)  # complex for complex x: the complex step
        out[0], out[1], out[2] = x[3], x[4], x[5]
        ax, az, alpha = 0.0 * x[0], -_G + 0.0 * x[0], 0.0 * x[0]
        for k in range(2):
            if mask >> k & 1:
                rx, rz = _offset(legs[k, 0], legs[k, 1], x[2])
                fz = -K * (x[1] + rz) - c_leg * (x[4] + x[5] * rx)  # height, v_foot_z
                fx = -Ct * (x[3] - x[5] * rz)  # v_foot_x
                ax = ax + fx
                az = az + fz
                alpha = alpha + (rx * fz - rz * fx) / inertia
        out[3], out[4], out[5] = ax, az, alpha
        return out

    def events(x):
        out = np.empty(2)
        for k in range(2):
            out[k] = -(x[1] + _offset(legs[k, 0], legs[k, 1], x[2])[1])
        return out

    def event_jacobian(x):
        D = np.zeros((2, 6))
        for k in range(2):
            D[k, 1] = -1.0
            D[k, 2] = -_offset(legs[k, 0], legs[k, 1], x[2])[0]
        return D

    return {"field": field, "events": events, "event_jacobian": event_jacobian}


def chair(
    *,
    mode_damping=1.0,
    stiffness=400.0,
    damping=4.0,
    friction=1.0,
    inertia=0.1,
    t_event=0.1,
    t_after=0.05,
    compiled=False,
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
    compiled : bool
        The model's functions compiled with numba (they run on the compiled integrator),
        else Python functions: the same equations either way.

    Returns
    -------
    Example
    """
    theta = 0.1
    a0, b0, a1 = -0.5, -0.4, 0.6
    b1 = b0 + (a0 - a1) * np.tan(theta)  # both feet on the ground at theta
    legs = np.array([[a0, b0], [a1, b1]])
    # checked by name: a negative inertia or stiffness gave a model all the same
    stiffness, inertia = check_numbers(stiffness=stiffness, inertia=inertia)
    damping, mode_damping, friction = check_numbers(
        strict=False, damping=damping, mode_damping=mode_damping, friction=friction)
    functions = _functions(stiffness, damping, mode_damping, friction, inertia, legs)
    z = -(a0 * np.sin(theta) + b0 * np.cos(theta))
    vx, vz, om = 0.5, -2.0, 0.3
    rho = np.array([0.0, z, theta, vx, vz, om])
    T = float(t_event)
    vz0 = vz + _G * T
    x0 = np.array([-vx * T, z - vz0 * T + 0.5 * _G * T**2, theta - om * T, vx, vz0, om])
    ex = Example.from_functions(
        functions,
        compiled=compiled,
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
    return check_start(ex, {"t_event": T, "t_after": float(t_after)})
