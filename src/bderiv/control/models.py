"""Models with inputs, written over the augmented state ``z = (x, p)`` (``p' = 0``).

Each returns a :class:`~bderiv.control.parametric.ParametricFlow`: the functions take
``z`` of length d + m and the field's last m entries are 0 (:mod:`.parametric` says why
a parameter is a state that does not move). Compiled with numba by default and kept in
numba's disk cache (:func:`bderiv.examples._common.compile_function`).

- :func:`ball_1d`: hybrid-tools' 1-D bouncing ball, ``x = (q, q')``,
  ``p = (u, e, g)``: ``q'' = -g + u``, at ``q = 0`` (falling) ``q' -> -e q'``.
- :func:`ball_2d`: its 2-D ball, ``x = (qx, qy, qx', qy')``, ``p = (ux, uy, e, g, h)``:
  ``qx'' = ux``, ``qy'' = -g + uy``, at ``qy = h`` (falling) ``qy' -> -e qy'``.
- :func:`controlled_chair`: the chair of :func:`bderiv.examples.chair` (d = 6, two legs
  on compliant ground, ``mode_damping`` making the two touchdown orders differ) with two
  inputs ``p = (a_z, a_theta)``: a vertical acceleration and an angular acceleration of
  the body (thrusters), held over each control step.
"""

from __future__ import annotations

import numpy as np
from numba.extending import register_jitable

from ..analysis.system import HybridSystem
from ..examples._common import compile_function
from ..examples.chair import _functions as chair_functions
from ..examples.chair import chair
from ..models.integrate.options import SolverOptions
from .parametric import ParametricFlow

__all__ = ["ball_1d", "ball_2d", "controlled_chair"]

_G = 9.81


def _ball_functions(d, vertical, ground):
    """Free flight ``x'' = u (+ gravity on the vertical)``; ``p = (u_0 .. u_{d/2-1}, e, g
    [, h])``; the event: the ball below ``h`` (``ground``: index of h in z, or -1: 0)."""
    half = d // 2

    def field(z, mask):
        out = np.zeros_like(z)
        for i in range(half):
            out[i] = z[half + i]
            out[half + i] = z[d + i]
        out[half + vertical] = out[half + vertical] - z[d + half + 1]
        return out

    if ground >= 0:
        def events(z):
            return np.array([z[ground] - z[vertical]])
    else:
        def events(z):
            return np.array([-z[vertical]])

    def reset(z, mask, k):
        out = z.copy()
        out[half + vertical] = -z[d + half] * z[half + vertical]
        return out

    return field, events, reset


def _ball(d, vertical, ground, p, compiled, options):
    fns = _ball_functions(d, vertical, ground)
    if compiled:
        fns = [compile_function(f) for f in fns]
    field, events, reset = fns
    system = HybridSystem(field, events, n_events=1, dim=d + len(p), reset=reset)
    flow = ParametricFlow(system, len(p), options=options)
    flow.defaults = np.array(p, dtype=np.float64)
    return flow


def ball_1d(*, e=0.8, g=_G, compiled=True, simultaneity_tol=1e-7) -> ParametricFlow:
    """hybrid-tools' 1-D bouncing ball (``bouncing_ball``): ``x = (q, q')``,
    ``p = (u, e, g)``; ``flow.defaults`` = ``(0, e, g)``."""
    return _ball(2, 0, -1, (0.0, e, g), compiled, SolverOptions(simultaneity_tol=simultaneity_tol))


def ball_2d(*, e=0.8, g=_G, h=0.0, compiled=True, simultaneity_tol=1e-7) -> ParametricFlow:
    """hybrid-tools' 2-D bouncing ball (``bouncing_ball_2d``): ``x = (qx, qy, qx', qy')``,
    ``p = (ux, uy, e, g, h)``; ``flow.defaults`` = ``(0, 0, e, g, h)``."""
    return _ball(4, 1, 8, (0.0, 0.0, e, g, h), compiled,
                 SolverOptions(simultaneity_tol=simultaneity_tol))


def _chair_legs(ex):
    """The chair's legs ``(a_k, b_k)`` (2, 2), read off its model: at its event point
    ``rho`` both feet are on the ground (height ``z + a sin + b cos = 0``) and the event
    Jacobian's pitch column is ``-(a cos - b sin)``."""
    z, theta = ex.rho[1], ex.rho[2]
    c, s = np.cos(theta), np.sin(theta)
    rx, rz = -np.asarray(ex.system.calls.eval_event_jacobian(ex.rho))[:, 2], -z
    return np.column_stack((rx * c + rz * s, rz * c - rx * s))


def _chair_functions(K, C, kappa, Ct, inertia, legs):
    """The chair's own field, events and event Jacobian (``bderiv.examples.chair``) over
    ``z = (x, a_z, a_theta)`` (8,): the inputs added to the vertical and the angular
    acceleration."""
    base = {k: register_jitable(f) for k, f in
            chair_functions(K, C, kappa, Ct, inertia, legs).items()}
    base_field, base_events, base_jacobian = (base["field"], base["events"],
                                              base["event_jacobian"])

    def field(z, mask):
        out = np.zeros_like(z)
        out[:6] = base_field(z[:6], mask)
        out[4] = out[4] + z[6]
        out[5] = out[5] + z[7]
        return out

    def events(z):
        return base_events(z[:6])

    def event_jacobian(z):
        out = np.zeros((2, 8))
        out[:, :6] = base_jacobian(z[:6])
        return out

    return field, events, event_jacobian


def controlled_chair(*, mode_damping=5.0, stiffness=400.0, damping=4.0, friction=1.0,
                     inertia=0.1, compiled=True, simultaneity_tol=1e-7):
    """The chair with a vertical and an angular acceleration as inputs.

    Parameters
    ----------
    mode_damping, stiffness, damping, friction, inertia : float
        As :func:`bderiv.examples.chair` (``mode_damping`` 5 by default: the two
        touchdown orders' pieces then differ by about half their norm).
    compiled : bool
    simultaneity_tol : float
        The window of the steps' B-derivatives (:class:`ParametricFlow`).

    Returns
    -------
    flow : ParametricFlow
        d = 6, m = 2; ``flow.x0`` the chair's start (both feet land together at
        ``t = 0.1`` without input), ``flow.defaults`` = (0, 0).
    """
    ex = chair(mode_damping=mode_damping, stiffness=stiffness, damping=damping,
               friction=friction, inertia=inertia)
    fns = _chair_functions(float(stiffness), float(damping), float(mode_damping),
                           float(friction), float(inertia), _chair_legs(ex))
    if compiled:
        fns = [compile_function(f) for f in fns]
    system = HybridSystem(fns[0], fns[1], n_events=2, dim=8, event_jacobian=fns[2])
    flow = ParametricFlow(system, 2, options=SolverOptions(simultaneity_tol=simultaneity_tol))
    flow.x0, flow.defaults = ex.x0.copy(), np.zeros(2)
    return flow
