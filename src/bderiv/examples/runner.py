"""A running gait: the pronking body advancing, its forward speed driven toward a target.

State ``(x, z, theta, vx, vz, omega)`` (d = 6): the body of :func:`bderiv.examples.gaits.pronking`
(vertical motion and pitch, legs, contacts, thrust; its state is ``(z, theta, vz,
omega)``) with a forward position ``x`` and speed ``vx``. In stance every foot on the
ground pushes forward with ``f_x = traction * (v_target - vx)`` (per unit mass, shared by
the legs like the other forces): a speed controller acting through the contacts. The
force acts at the foot, so it also pitches the body (``-r_z f_x``, ``r_z`` the foot's
height below the centre of mass). In flight ``vx`` is constant.

Nothing depends on ``x``: it is a **cyclic coordinate**. On the periodic gait the speed
is back to its value after every stance, which the controller allows only at
``vx = v_target``, and ``x`` advances by ``v_target * period`` per stride. Solve it with
``periodic_orbit(..., cyclic=[0])`` (:func:`running_orbit`); the apex section ``-vz``
(:func:`apex_section`) does not depend on ``x`` either.
"""

from __future__ import annotations

import numpy as np

from ._common import Example, check_start, compile_function, perturbed_start
from .gaits import (
    FEET,
    INERTIA,
    LEG,
    body,
    foot_heights,
    foot_heights_jacobian,
    foot_offset,
    pronking,
    stance,
)

__all__ = ["apex_section", "apex_section_gradient", "compiled_apex_section", "running",
           "running_orbit"]


# The running model (d = 6): plain functions of ``x = (x, z, theta, vx, vz, omega, push,
# v_target, *q)``, the state followed by the forward force's gain per leg, the target speed
# and the pronking body's constants ``q`` (:meth:`~bderiv.examples.gaits.Body.values`): for
# Python as they are and for numba compiled once (no compilation per set of values).
#: where the body's constants start in the parameters (after ``push`` and ``v_target``)
BODY = 2


def field(x, mask):
    """The running body's field in region ``mask``: the pronking body's equations
    (:func:`~bderiv.examples.gaits.stance`) on ``(z, theta, vz, omega)`` and the forward
    force: (6,)."""
    push, v_target, q = x[6], x[7], x[6 + BODY:]
    out = np.empty_like(x[:6])
    az, alpha = stance(x[1], x[2], x[4], x[5], mask, q)
    ax = 0.0 * x[3]
    for k in range(q.size - FEET):
        if mask >> k & 1:
            fx = push * (v_target - x[3])
            ax = ax + fx
            # the force acts at the foot, r_z below the centre of mass: -r_z f_x
            alpha = alpha - foot_offset(q[FEET + k], q[LEG], x[2])[1] * fx / q[INERTIA]
    out[0], out[1], out[2] = x[3], x[4], x[5]
    out[3], out[4], out[5] = ax, az, alpha
    return out


def events(x):
    """The feet's event values ``-height_k``: (legs,)."""
    return foot_heights(x[1], x[2], x[6 + BODY:])


def event_jacobian(x):
    """The Jacobian of :func:`events` by the state: (legs, 6)."""
    return foot_heights_jacobian(x[2], x[6 + BODY:], 6, 1, 2)


def apex_section(x):
    """The apex section ``-vz``: crossed upward when the body starts to fall."""
    return -x[4]


#: :func:`apex_section` compiled: the section of a compiled model (``running(...,
#: compiled=True)``)
compiled_apex_section = compile_function(apex_section)


def apex_section_gradient(x):
    """Gradient of :func:`apex_section`: ``-e_4``."""
    return -np.eye(6)[4]


def running(*, v_target=1.0, traction=8.0, t_after=0.05, compiled=False, **params):
    """The running body at the apex of its gait, moving at ``v_target``.

    Parameters
    ----------
    v_target : float
        The forward speed the stance controller drives toward.
    traction : float
        Gain of the forward force per unit mass (shared by the legs).
    t_after : float
        ``t_final = t_event + t_after`` (the legs still touch then).
    compiled : bool
        The model's functions compiled with numba (the section is then
        :data:`compiled_apex_section`), else Python functions: the same equations. The
        speed, the traction and the body's constants are the system's parameters: the
        functions are compiled once per process.
    **params
        The pronking body's parameters (:func:`bderiv.examples.gaits.pronking`: stiffness,
        damping, gain, legs, apex, ...).

    Returns
    -------
    Example
        ``x0 = (0, apex, 0, v_target, 0, 0)``; ``rho`` the touchdown state of the
        symmetric gait, ``t_event`` the fall time. :func:`running_orbit` finds the gait.
    """
    base = pronking(t_after=t_after, **params)
    p = body(**{k: v for k, v in params.items() if k != "apex"})
    x0 = np.array([0.0, base.x0[0], 0.0, v_target, 0.0, 0.0])
    rho = np.array([v_target * base.t_event, base.rho[0], 0.0, v_target, base.rho[2], 0.0])
    n = p.a.size
    push = 2.0 / n * float(traction)  # shared by the legs like the other forces
    ex = Example.from_functions(
        {"field": field, "events": events, "event_jacobian": event_jacobian},
        params=np.concatenate(([push, float(v_target)], p.values())), compiled=compiled,
        n_events=n, dim=6, rho=rho, x0=x0, t_event=base.t_event, t_after=t_after, name="running",
        description=(f"planar body running on {n} compliant legs at a target speed "
                     f"{v_target:g} (d = 6, n = {n}; the forward position is cyclic)"),
    )
    return check_start(ex, {"v_target": float(v_target), "t_after": float(t_after)})


def running_orbit(example=None, *, perturbation=(0.0, 0.02, 0.01, -0.3, 0.0, -0.05),
                  **kwargs):
    """The running gait, found with the forward position cyclic, from a perturbed apex.

    Parameters
    ----------
    example : Example, optional
        Default :func:`running`.
    perturbation : array_like, shape (6,)
        Added to ``example.x0`` for the guess (a wrong speed, tilted, pitching).
    **kwargs
        Passed to :meth:`HybridSystem.periodic_orbit
        <bderiv.analysis.system.HybridSystem.periodic_orbit>` (``cyclic=[0]`` by default).

    Returns
    -------
    PeriodicOrbit
        ``advance[0]``: the forward distance per stride.
    """
    ex = running() if example is None else example
    guess = perturbed_start(ex, perturbation)
    kwargs.setdefault("period_guess", 0.5)
    kwargs.setdefault("cyclic", [0])
    kwargs.setdefault("section_gradient", apex_section_gradient)
    section = compiled_apex_section if ex.compiled else apex_section
    return ex.system.periodic_orbit(guess, section, **kwargs)
