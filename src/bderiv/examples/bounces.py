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

Both models' region beyond a wall is the same free flight: the surfaces carry nothing but
the reset. With ``e < 1`` the bounces on the floor accumulate (a Zeno trajectory), and a
run past their accumulation time is refused, naming it; ``e = 0`` stops the ball on the
ground, where nothing holds it: refused at the impact (mathematics.md section 9, "Impacts
that accumulate, and landings nothing holds"). Both models come compiled with numba
(``compiled=True``: the compiled integrator) or as Python functions, the same equations.
"""

from __future__ import annotations

import numpy as np
from numba.extending import register_jitable

from ._common import Example, check_start

__all__ = ["ball_in_corner", "bouncing_ball"]

_G = 9.81


def _check_restitution(e):
    e = float(e)
    if not 0.0 <= e <= 1.0:
        raise ValueError(f"the restitution e must be between 0 and 1, got {e}")
    return e


def _ball_functions(e, g) -> dict:
    """The bouncing ball's functions and their Jacobians (all regions share the field):
    plain functions, for Python as they are and for numba compiled."""

    def field(x, mask):
        return np.array([x[1], -g])

    def field_jacobian(x, mask):
        return np.array([[0.0, 1.0], [0.0, 0.0]])

    def events(x):
        return np.array([-x[0]])

    def event_jacobian(x):
        return np.array([[-1.0, 0.0]])

    def reset(x, mask, k):
        return np.array([x[0], -e * x[1]])

    def reset_jacobian(x, mask, k):
        return np.array([[1.0, 0.0], [0.0, -e]])

    return {"field": field, "events": events, "event_jacobian": event_jacobian,
            "field_jacobian": field_jacobian, "reset": reset, "reset_jacobian": reset_jacobian}


def bouncing_ball(*, e=0.8, height=1.0, g=_G, t_after=0.1, compiled=False) -> Example:
    """A ball dropped from rest at ``height``: it bounces with restitution ``e``.

    Parameters
    ----------
    e : float
        Coefficient of restitution, in [0, 1] (the rebound speed is ``e`` times the impact
        speed). With ``e < 1`` the impacts accumulate at the Zeno time ``t_1 (1 + 2 e /
        (1 - e))``: a run past it is refused at the bounce that shows it, naming it
        (:class:`bderiv.models.events.zeno.ImpactWatch`); ``e = 0`` stops the ball on the
        ground, where nothing holds it (the ground's region has the same free fall):
        refused at the impact (module docstring).
    height : float
        Height of the start point ``x0 = (height, 0)``, > 0.
    g : float
        Gravity, > 0.
    t_after : float
        ``t_final = t_event + t_after``, > 0, within the first flight after the bounce
        (before the second impact, ``2 e v_1 / g`` later; any ``t_after > 0`` with
        ``e = 0``).
    compiled : bool
        The model's functions compiled with numba (they run on the compiled integrator),
        else Python functions: the same equations either way.

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
    height, g, t_after = float(height), float(g), float(t_after)
    if not (np.isfinite(height) and height > 0 and np.isfinite(g) and g > 0):
        raise ValueError(f"height and g must be > 0, got height={height}, g={g}")
    fall = float(np.sqrt(2.0 * height / g))
    flight = 2.0 * e * fall  # from the first impact to the second: 2 e v_1 / g
    if not (np.isfinite(t_after) and t_after > 0 and (e == 0 or t_after < flight)):
        raise ValueError(
            f"t_after must be > 0 and end the run within the first flight after the bounce "
            f"(before the second impact, {flight:.6g} s after the first with e={e:g}, "
            f"height={height:g}, g={g:g}), got t_after={t_after}")
    ex = Example.from_functions(_ball_functions(e, g), compiled=compiled, n_events=1,
                                dim=2, rho=np.array([0.0, -g * fall]),
                                x0=np.array([height, 0.0]), t_event=fall, t_after=t_after,
                                name="bouncing-ball",
                                description=f"ball dropped from {height:g} m, restitution "
                                f"{e:g} (d = 2, n = 1)")
    return check_start(ex, {"e": e, "height": height, "g": g})


@register_jitable
def _reflection(normals, e, k):
    """The reflection of wall k, ``v -> v - (1 + e) (n_k . v) n_k`` on the velocity (4, 4):
    linear in x, its own Jacobian."""
    J = np.eye(4)
    for i in range(2):
        for j in range(2):
            J[2 + i, 2 + j] -= (1.0 + e) * normals[k, i] * normals[k, j]
    return J


def _corner_functions(angle, e, g) -> dict:
    """Free flight under gravity between two walls: events, reflections, Jacobians, as
    plain functions (for Python as they are and for numba compiled); the walls' inward
    unit normals (the floor's, and the wall's at ``angle`` from the floor) as
    ``"normals"``."""
    normals = np.array([[0.0, 1.0], [np.sin(angle), -np.cos(angle)]])
    Dh = np.zeros((2, 4))
    Dh[:, :2] = -normals

    def field(x, mask):
        return np.array([x[2], x[3], 0.0, -g])

    def field_jacobian(x, mask):
        J = np.zeros((4, 4))
        J[0, 2] = J[1, 3] = 1.0
        return J

    def events(x):
        return Dh @ x

    def event_jacobian(x):
        return Dh.copy()

    def reset_jacobian(x, mask, k):
        return _reflection(normals, e, k)

    def reset(x, mask, k):
        return _reflection(normals, e, k) @ x

    return {"field": field, "events": events, "event_jacobian": event_jacobian,
            "field_jacobian": field_jacobian, "reset": reset,
            "reset_jacobian": reset_jacobian, "normals": normals}


def ball_in_corner(*, angle=np.pi / 2, e=0.8, speed=2.0, g=_G, t_event=0.2,
                   t_after=0.1, compiled=False) -> Example:
    """A ball thrown into the corner between the floor and a wall at ``angle`` from it.

    Parameters
    ----------
    angle : float
        Angle of the corner in radians, in (0, pi): the ball lives in the wedge between
        the floor (direction 0) and the wall (direction ``angle``).
    e : float
        Restitution of both walls, in [0, 1]. Its bounces on the floor after the corner
        accumulate as the bouncing ball's do (:func:`bouncing_ball`): a run past that
        time is refused, naming it.
    speed : float
        Speed of the ball at the corner, > 0; its velocity there is along
        ``-(n_0 + n_1)`` (into both walls).
    g : float
        Gravity along ``-y``, >= 0.
    t_event : float
        Flight time from ``x0`` to the corner (``x0`` in closed form: the free flight
        backward), > 0; ``x0`` must be inside the wedge (refused otherwise, naming the
        parameters: a slow ball flown back far starts below the floor).
    t_after : float
        ``t_final = t_event + t_after``, > 0.
    compiled : bool
        The model's functions compiled with numba (they run on the compiled integrator),
        else Python functions: the same equations either way.

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
    speed, g, t_event, t_after = float(speed), float(g), float(t_event), float(t_after)
    if not 0.0 < angle < np.pi:
        raise ValueError(f"angle must be in (0, pi) radians, got {angle}")
    if not (np.isfinite(speed) and speed > 0 and np.isfinite(g) and g >= 0
            and np.isfinite(t_event) and t_event > 0 and np.isfinite(t_after)
            and t_after > 0):
        raise ValueError(f"speed, t_event and t_after must be > 0 and g >= 0, got "
                         f"speed={speed}, g={g}, t_event={t_event}, t_after={t_after}")
    functions = _corner_functions(angle, e, g)
    normals = functions.pop("normals")
    into = -(normals[0] + normals[1])
    v = speed * into / np.linalg.norm(into)
    acc = np.array([0.0, -g])
    v0 = v - acc * t_event  # free flight backward from the corner
    p0 = -v0 * t_event - 0.5 * acc * t_event**2
    degrees = np.degrees(angle)
    # inside the wedge at x0 (check_start), the flight stays inside it up to the corner:
    # each wall's distance along it is quadratic in time, zero and decreasing at the
    # corner, so positive before it when positive at x0
    ex = Example.from_functions(functions, compiled=compiled, n_events=2, dim=4,
                                rho=np.array([0.0, 0.0, *v]), x0=np.array([*p0, *v0]),
                                t_event=t_event, t_after=t_after, name="ball-in-corner",
                                description=f"ball thrown into a {degrees:.4g}-degree "
                                f"corner, restitution {e:g}, both walls hit at once "
                                f"(d = 4, n = 2)")
    return check_start(ex, {"angle": angle, "speed": speed, "g": g, "t_event": t_event})
