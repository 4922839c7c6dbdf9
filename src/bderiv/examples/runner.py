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

from ._common import Example, complex_step_jacobian
from .gaits import _Pronking, body, pronking

__all__ = ["apex_section", "apex_section_gradient", "running", "running_orbit"]

#: the pronking body's coordinates (z, theta, vz, omega) in the running state
_BODY = np.array([1, 2, 4, 5])


class _Running:
    def __init__(self, body: _Pronking, traction: float, v_target: float):
        self.body, self.traction, self.v_target = body, traction, v_target

    def field(self, x, mask):
        mask = int(mask)
        y = x[_BODY]
        vz, omega, az, alpha = self.body.field(y, mask)
        _, height, _ = self.body._feet(y)
        share = 2.0 / self.body.legs
        ax = 0.0 * x[0]
        for k in range(self.body.legs):
            if mask >> k & 1:
                fx = share * self.traction * (self.v_target - x[3])
                ax = ax + fx
                # the foot is height_k - z below the centre of mass (< 0): -r_z f_x
                alpha = alpha - (height[k] - x[1]) * fx / self.body.inertia
        return np.array([x[3], vz, omega, ax, az, alpha])

    def field_jacobian(self, x, mask):
        return complex_step_jacobian(lambda y: self.field(y, mask), x, 6)

    def events(self, x):
        return self.body.events(x[_BODY])

    def event_jacobian(self, x):
        D = np.zeros((self.body.legs, 6))
        D[:, _BODY] = self.body.event_jacobian(x[_BODY])
        return D


def apex_section(x):
    """The apex section ``-vz``: crossed upward when the body starts to fall."""
    return -x[4]


def apex_section_gradient(x):
    """Gradient of :func:`apex_section`: ``-e_4``."""
    return -np.eye(6)[4]


def running(*, v_target=1.0, traction=8.0, t_after=0.05, **params):
    """The running body at the apex of its gait, moving at ``v_target``.

    Parameters
    ----------
    v_target : float
        The forward speed the stance controller drives toward.
    traction : float
        Gain of the forward force per unit mass (shared by the legs).
    t_after : float
        ``t_final = t_event + t_after`` (the legs still touch then).
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
    model = _Running(body(**{k: v for k, v in params.items() if k != "apex"}),
                     float(traction), float(v_target))
    x0 = np.array([0.0, base.x0[0], 0.0, v_target, 0.0, 0.0])
    rho = np.array([v_target * base.t_event, base.rho[0], 0.0, v_target, base.rho[2], 0.0])
    n = model.body.legs
    return Example.from_model(
        model, n_events=n, dim=6, rho=rho, x0=x0, t_event=base.t_event, t_after=t_after,
        name="running",
        description=(f"planar body running on {n} compliant legs at a target speed "
                     f"{v_target:g} (d = 6, n = {n}; the forward position is cyclic)"),
    )


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
        <bderiv.models.system.HybridSystem.periodic_orbit>` (``cyclic=[0]`` by default).

    Returns
    -------
    PeriodicOrbit
        ``advance[0]``: the forward distance per stride.
    """
    ex = running() if example is None else example
    guess = ex.x0 + np.asarray(perturbation, dtype=np.float64)
    kwargs.setdefault("period_guess", 0.5)
    kwargs.setdefault("cyclic", [0])
    kwargs.setdefault("section_gradient", apex_section_gradient)
    return ex.system.periodic_orbit(guess, apex_section, **kwargs)
