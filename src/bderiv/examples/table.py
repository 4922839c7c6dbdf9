"""The "table": a rigid body in 3-D landing flat on 4 legs (n = 4 > rank Dh = 3).

State ``(p, euler, v, w)`` (d = 12): position of the centre of mass, Z-Y-X Euler angles
``(roll, pitch, yaw)``, velocity, and body-frame angular velocity; unit mass, diagonal
inertia. Leg k ends at the body point ``P[k] = (+-lx, +-ly, -leg)``; its height is
``p_z + (R P[k])_z`` which does not depend on the yaw, so the 4 event gradients span only
3 directions (height, roll, pitch). Event k is ``h_k = -height_k``. In contact the ground
pushes foot k with ``(-friction v_x, -friction v_y, -stiffness height - c(B) v_z)`` (foot
velocity v); with ``mode_damping > 0`` the damping grows with the number of legs touching,
``c(B) = damping (1 + mode_damping (|B| - 1) / 3)``, so the corner table is not additive.

At ``rho`` the body is level (roll = pitch = 0, yaw = 0.3), all four feet on the ground,
falling and slowly rotating so that the feet descend at different speeds; ``x0`` is
``rho`` flowed back in free flight for ``t_event``.
"""

from __future__ import annotations

import numpy as np

from .._support._numdiff import complex_step
from ._common import Example, check_start, flow_back

__all__ = ["table"]

_G = 9.81


def _rotation(phi, th, psi):
    """R = Rz(psi) Ry(th) Rx(phi) as a nested list (complex-safe)."""
    cf, sf = np.cos(phi), np.sin(phi)
    ct, st = np.cos(th), np.sin(th)
    cp, sp = np.cos(psi), np.sin(psi)
    return np.array(
        [
            [cp * ct, cp * st * sf - sp * cf, cp * st * cf + sp * sf],
            [sp * ct, sp * st * sf + cp * cf, sp * st * cf - cp * sf],
            [-st, ct * sf, ct * cf],
        ]
    )


class _Table:
    def __init__(self, stiffness, damping, mode_damping, friction, inertia, feet):
        self.K = stiffness
        self.C = damping
        self.kappa = mode_damping
        self.Ct = friction
        self.I = np.asarray(inertia, dtype=np.float64)
        self.P = np.asarray(feet, dtype=np.float64)  # (4, 3) body frame

    def _feet(self, x):
        R = _rotation(x[3], x[4], x[5])
        r = self.P @ R.T  # (4, 3) world offsets
        w_world = R @ x[9:12]
        height = x[2] + r[:, 2]
        vel = x[6:9] + np.cross(w_world, r)  # (4, 3)
        return R, r, height, vel

    def field(self, x, mask):
        R, r, height, vel = self._feet(x)
        mask = int(mask)
        count = bin(mask & 15).count("1")
        c_leg = self.C * (1.0 + self.kappa * max(count - 1, 0) / 3.0)
        force = np.zeros(3, dtype=x.dtype)
        torque = np.zeros(3, dtype=x.dtype)
        for k in range(4):
            if mask >> k & 1:
                fk = np.array(
                    [
                        -self.Ct * vel[k, 0],
                        -self.Ct * vel[k, 1],
                        -self.K * height[k] - c_leg * vel[k, 2],
                    ]
                )
                force = force + fk
                torque = torque + np.cross(r[k], fk)
        acc = force + np.array([0.0, 0.0, -_G])
        w = x[9:12]
        tau_body = R.T @ torque
        dw = (tau_body - np.cross(w, self.I * w)) / self.I
        phi, th = x[3], x[4]
        p, q, rr = w[0], w[1], w[2]
        sf, cf = np.sin(phi), np.cos(phi)
        deuler = np.array(
            [
                p + (q * sf + rr * cf) * np.tan(th),
                q * cf - rr * sf,
                (q * sf + rr * cf) / np.cos(th),
            ]
        )
        return np.concatenate((x[6:9], deuler, acc, dw))

    def field_jacobian(self, x, mask):
        return complex_step(lambda y: self.field(y, mask), x, 12, strict=False)

    def events(self, x):
        return -self._feet(x)[2]

    def event_jacobian(self, x):
        return complex_step(self.events, x, 4, strict=False)


def table(
    *,
    mode_damping=1.0,
    stiffness=400.0,
    damping=4.0,
    friction=1.0,
    t_event=0.1,
    t_after=0.05,
):
    """The 3-D body landing flat on 4 legs (d = 12, n = 4, rank Dh = 3).

    Parameters
    ----------
    mode_damping : float
        Growth of the leg damping with the number of legs touching (0: additive forces).
    stiffness, damping, friction : float
        Ground spring, leg damping, horizontal friction (per unit mass).
    t_event, t_after : float
        Flight time from ``x0`` to touchdown; ``t_final = t_event + t_after``.

    Returns
    -------
    Example
    """
    lx, ly, leg = 0.6, 0.4, 0.5
    feet = [[lx, ly, -leg], [-lx, ly, -leg], [-lx, -ly, -leg], [lx, -ly, -leg]]
    model = _Table(stiffness, damping, mode_damping, friction, (0.08, 0.12, 0.15), feet)
    rho = np.array([0.0, 0.0, leg, 0.0, 0.0, 0.3, 0.3, -0.2, -1.5, 0.2, -0.3, 0.5])
    T = float(t_event)
    x0 = flow_back(lambda x: model.field(x, 0), rho, T)
    ex = Example.from_model(
        model,
        n_events=4,
        dim=12,
        rho=rho,
        x0=x0,
        t_event=T,
        t_after=t_after,
        name="table",
        description=(
            "3-D rigid body landing flat on 4 legs (d = 12, n = 4 > rank Dh = 3, "
            f"mode_damping = {mode_damping})"
        ),
    )
    return check_start(ex, {"t_event": T, "t_after": float(t_after)})
