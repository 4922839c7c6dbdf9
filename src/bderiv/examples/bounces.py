"""Bounces: impacts whose reset sends the state back to the side it came from.

- :func:`bouncing_ball`: a ball on the ground, state ``(q, v)`` (height, vertical velocity),
  field ``(v, -g)``, event ``h = -q`` (the ball below the ground), reset ``(q, -e v)``. At
  the impact the ball is on the surface and leaves it upward: the event's bit stays clear
  (a bounce), and the next impact is again an upward crossing of ``h`` (mathematics.md
  section 9, "Where a reset lands").
- :func:`ball_in_corner`: a point mass in the plane, state ``(x, y, vx, vy)``, gravity
  along ``-y``, between two walls through the origin: the floor ``y = 0`` (event 0) and a
  wall at ``angle`` from it (event 1), the ball inside the wedge between them. Event k is
  ``h_k = -n_k . p``, ``n_k`` the wall's inward unit normal (the ball behind wall k); the
  impact on wall k reflects the normal velocity with restitution ``e``:
  ``v -> v - (1 + e) (n_k . v) n_k``. Its event point ``rho`` is the ball at the corner,
  hitting both walls at once. At a right angle the two reflections act on orthogonal
  components, commute and leave each other's wall alone (the flow has a B-derivative
  there); at any other angle they do not commute and the model is refused at the corner.
"""

from __future__ import annotations

import numpy as np

from ..models.system import HybridSystem
from ._common import Example

__all__ = ["ball_in_corner", "bouncing_ball"]

_G = 9.81


def _check_restitution(e):
    e = float(e)
    if not 0.0 <= e <= 1.0:
        raise ValueError(f"the restitution e must be between 0 and 1, got {e}")
    return e


class _Ball:
    """The bouncing ball's functions and their Jacobians (all regions share the field)."""

    def __init__(self, e, g):
        self.e, self.g = e, g

    def field(self, x, mask):
        return np.array([x[1], -self.g])

    def field_jacobian(self, x, mask):
        return np.array([[0.0, 1.0], [0.0, 0.0]])

    def events(self, x):
        return np.array([-x[0]])

    def event_jacobian(self, x):
        return np.array([[-1.0, 0.0]])

    def reset(self, x, mask, k):
        return np.array([x[0], -self.e * x[1]])

    def reset_jacobian(self, x, mask, k):
        return np.diag([1.0, -self.e])


def bouncing_ball(*, e=0.8, height=1.0, g=_G, t_after=0.1) -> Example:
    """A ball dropped from rest at ``height``: it bounces with restitution ``e``.

    Parameters
    ----------
    e : float
        Coefficient of restitution, in [0, 1] (the rebound speed is ``e`` times the impact
        speed; ``e = 0`` leaves the ball on the ground: refused at the impact, the state
        would stay on the surface).
    height : float
        Height of the start point ``x0 = (height, 0)``, > 0.
    g : float
        Gravity, > 0.
    t_after : float
        ``t_final = t_event + t_after``, within the first flight after the bounce.

    Returns
    -------
    Example
        ``rho = (0, -sqrt(2 g height))`` the first impact, at ``t_event = sqrt(2 height /
        g)``; d = 2, n = 1. In closed form, the k-th impact (k = 1, 2, ...) is at
        ``t_1 + 2 (e + ... + e^(k-1)) v_1 / g`` and the velocity after it is ``e^k v_1``,
        ``v_1 = sqrt(2 g height)``.

    Examples
    --------
    >>> ex = bouncing_ball(e=0.5)
    >>> M = ex.system.bderivative(ex.rho)
    >>> M.n_events, M.dim
    (1, 2)
    """
    e = _check_restitution(e)
    height, g = float(height), float(g)
    if not (height > 0 and g > 0):
        raise ValueError(f"height and g must be > 0, got height={height}, g={g}")
    model = _Ball(e, g)
    system = HybridSystem(model.field, model.events, n_events=1, dim=2,
                          event_jacobian=model.event_jacobian,
                          field_jacobian=model.field_jacobian, reset=model.reset,
                          reset_jacobian=model.reset_jacobian)
    fall = float(np.sqrt(2.0 * height / g))
    return Example(system=system, rho=np.array([0.0, -g * fall]),
                   x0=np.array([height, 0.0]), t_event=fall,
                   t_final=float(f"{fall + float(t_after):.15g}"), name="bouncing-ball",
                   description=f"ball dropped from {height:g} m, restitution {e:g} "
                   f"(d = 2, n = 1)")


class _Corner:
    """Free flight under gravity between two walls: events, reflections, Jacobians."""

    def __init__(self, angle, e, g):
        self.e, self.g = e, g
        # inward unit normals: the floor's, and the wall's at `angle` from the floor
        self.normals = np.array([[0.0, 1.0], [np.sin(angle), -np.cos(angle)]])
        self.Dh = np.zeros((2, 4))
        self.Dh[:, :2] = -self.normals

    def field(self, x, mask):
        return np.array([x[2], x[3], 0.0, -self.g])

    def field_jacobian(self, x, mask):
        J = np.zeros((4, 4))
        J[0, 2] = J[1, 3] = 1.0
        return J

    def events(self, x):
        return self.Dh @ x

    def event_jacobian(self, x):
        return self.Dh.copy()

    def reset_jacobian(self, x, mask, k):
        """The reflection of wall k (linear in x: its own Jacobian)."""
        n = self.normals[k]
        J = np.eye(4)
        J[2:, 2:] -= (1.0 + self.e) * np.outer(n, n)
        return J

    def reset(self, x, mask, k):
        return self.reset_jacobian(x, mask, k) @ x


def ball_in_corner(*, angle=np.pi / 2, e=0.8, speed=2.0, g=_G, t_event=0.2,
                   t_after=0.1) -> Example:
    """A ball thrown into the corner between the floor and a wall at ``angle`` from it.

    Parameters
    ----------
    angle : float
        Angle of the corner in radians, in (0, pi): the ball lives in the wedge between
        the floor (direction 0) and the wall (direction ``angle``).
    e : float
        Restitution of both walls, in [0, 1].
    speed : float
        Speed of the ball at the corner, > 0; its velocity there is along
        ``-(n_0 + n_1)`` (into both walls).
    g : float
        Gravity along ``-y``, >= 0.
    t_event : float
        Flight time from ``x0`` to the corner (``x0`` in closed form: the free flight
        backward), > 0.
    t_after : float
        ``t_final = t_event + t_after``.

    Returns
    -------
    Example
        ``rho = (0, 0, vx, vy)``, the ball hitting both walls at once (n = 2, d = 4). At a
        right angle ``system.bderivative(rho)`` has two pieces (which wall is hit first);
        at other angles it is refused (the reflections do not commute).

    Examples
    --------
    >>> ex = ball_in_corner()
    >>> sorted(tuple(int(k) for k in o) for o, _ in ex.system.bderivative(ex.rho).pieces())
    [(0, 1), (1, 0)]
    """
    angle, e = float(angle), _check_restitution(e)
    speed, g, t_event = float(speed), float(g), float(t_event)
    if not 0.0 < angle < np.pi:
        raise ValueError(f"angle must be in (0, pi) radians, got {angle}")
    if not (speed > 0 and g >= 0 and t_event > 0):
        raise ValueError(f"speed and t_event must be > 0 and g >= 0, got speed={speed}, "
                         f"g={g}, t_event={t_event}")
    model = _Corner(angle, e, g)
    system = HybridSystem(model.field, model.events, n_events=2, dim=4,
                          event_jacobian=model.event_jacobian,
                          field_jacobian=model.field_jacobian, reset=model.reset,
                          reset_jacobian=model.reset_jacobian)
    into = -(model.normals[0] + model.normals[1])
    v = speed * into / np.linalg.norm(into)
    acc = np.array([0.0, -g])
    v0 = v - acc * t_event  # free flight backward from the corner
    p0 = -v0 * t_event - 0.5 * acc * t_event**2
    degrees = np.degrees(angle)
    return Example(system=system, rho=np.array([0.0, 0.0, *v]), x0=np.array([*p0, *v0]),
                   t_event=t_event, t_final=float(f"{t_event + float(t_after):.15g}"),
                   name="ball-in-corner",
                   description=f"ball thrown into a {degrees:.4g}-degree corner, restitution "
                   f"{e:g}, both walls hit at once (d = 4, n = 2)")
