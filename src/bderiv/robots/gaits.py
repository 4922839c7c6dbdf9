"""A gait of Solo12: pronking, all four feet landing and lifting off at one instant.

The model (docs/robots.md, "A gait"): Solo12 with compliant feet (:mod:`bderiv.robots.legged`)
and a hopping controller that is the PD posture law with two references: the flight
posture (solo.srdf's standing joints) while every foot is in the air, and the legs
extended by ``extension`` (each knee opened by it, each hip turned back by half of it)
while any foot is down. The extension pushes the body up in stance (the energy that the
feet's damping and friction take), and the legs fold back in flight; the hop's height
settles where the two balance. Both laws are ordinary :class:`LeggedRobot` models (one
per reference), so the field of each region and its Jacobian are theirs: the stance
robot's coordinates are the flight robot's shifted by the extension (the joints are
``q_ref + e``).

**Symmetry.** Solo12's URDF is not quite symmetric: the upper legs' centres of mass sit
1.4e-5 m off the legs' planes in x with a sign that turns them by half a turn rather than
mirroring them, and the shoulders' products of inertia ``I_xy`` (4.7e-5 kg m^2) have the
signs of a left-right mirror only. :func:`symmetric_solo12` sets both to 0; the robot is
then symmetric under the two mirrors of its body (front-hind and left-right: ``MIRRORS``),
the states they fix (a level base, no horizontal or angular velocity, the legs mirrored)
are an invariant subspace, and on it the four feet are at one height: an orbit there
lands and lifts off its four feet at once, exactly.

The section is the apex, ``-v_z = 0`` (the base's vertical velocity in its own frame,
crossed upward as the robot starts to fall); the horizontal position and the yaw
(coordinates ``CYCLIC``) do not change the motion on the symmetric orbit and are left out
of the fixed-point equation (``periodic_orbit(..., cyclic=CYCLIC)``). ``APEX`` is the
orbit's apex state (7 numbers: the rest follow by symmetry), for a start.
"""

from __future__ import annotations

import numpy as np

from ..analysis.system import HybridSystem
from ._files import require_pinocchio, robot_file
from .build import legged_robot
from .legged import CONTACT
from .quadrupeds import ROBOTS

__all__ = ["APEX", "CYCLIC", "PERIOD", "PRONK", "Pronking", "mirrors", "pronking",
           "pronking_figure", "pronking_orbit", "symmetric_solo12"]

#: the hopping law: the legs' extension in stance (rad) and the feet's damping (N s/m;
#: lower than CONTACT's 50 so that a modest push sustains the hop); the rest is CONTACT's
PRONK = {"extension": 0.6, "damping": 20.0}
#: the orbit's apex with ``PRONK``: the base's height (m), then the front left leg's joint
#: offsets from the flight posture (HAA, HFE, KFE; rad) and their rates (rad/s); the other
#: legs mirror it (:meth:`Pronking.apex_state`). Found by ``pronking_orbit`` (residual 6e-12)
APEX = (0.32315291253542411, 0.0067918517989590367, 0.020405259731043672,
        0.0050931461466747607, -0.088563913907917666, -0.74025618142489980,
        -0.21118119406640892)
#: the orbit's period (s) with ``PRONK``
PERIOD = 0.34303777181337647
#: the cyclic coordinates: the base's x and y (tangent coordinates) and its yaw
CYCLIC = (0, 1, 5)
#: per leg (FL, FR, HL, HR), the signs of (HAA, HFE, KFE) that mirror the front left leg
LEG_SIGNS = np.array([[1, 1, 1], [-1, 1, 1], [1, -1, -1], [-1, -1, -1]], dtype=np.float64)


def symmetric_solo12():
    """Solo12's Pinocchio model (free-flying base) with the two asymmetries of its URDF
    removed (module docstring): the upper legs' x offset of the centre of mass and the
    shoulders' ``I_xy``."""
    pin = require_pinocchio()
    model = pin.buildModelFromUrdf(str(robot_file(ROBOTS["solo12"]["file"])),
                                   pin.JointModelFreeFlyer())
    for j in range(2, model.njoints):
        inertia = model.inertias[j]
        lever, rot = inertia.lever.copy(), inertia.inertia.copy()
        if model.names[j].endswith("_HFE"):
            lever[0] = 0.0
        if model.names[j].endswith("_HAA"):
            rot[0, 1] = rot[1, 0] = 0.0
        model.inertias[j] = pin.Inertia(inertia.mass, lever, rot)
    return model


def mirrors(nv=18):
    """The two mirrors of Solo12's body on the state ``(e, v)``: front-hind (x -> -x) and
    left-right (y -> -y), each ``(G, feet)``: G (2 nv, 2 nv) linear in the tangent
    coordinates (the reflection of SE(3) commutes with its exponential) and ``feet`` the
    permutation of the feet (foot k goes to ``feet[k]``). The model is equivariant:
    ``field(G x, mask') = G field(x, mask)``, ``mask'`` the mask permuted."""
    out = []
    # x -> -x: the base's (x, y, z, roll, pitch, yaw) by (-, +, +, +, -, -); FL <-> HL and
    # FR <-> HR, the hip and knee angles negated (rotations about y), HAA kept
    # y -> -y: (+, -, +, -, +, -); FL <-> FR and HL <-> HR, HAA negated (about x)
    for base, feet, joint in (((-1, 1, 1, 1, -1, -1), (2, 3, 0, 1), (1, -1, -1)),
                              ((1, -1, 1, -1, 1, -1), (1, 0, 3, 2), (-1, 1, 1))):
        g = np.zeros((nv, nv))
        g[:6, :6] = np.diag(base)
        for k, m in enumerate(feet):
            g[6 + 3 * m:9 + 3 * m, 6 + 3 * k:9 + 3 * k] = np.diag(joint)
        G = np.zeros((2 * nv, 2 * nv))
        G[:nv, :nv] = G[nv:, nv:] = g
        out.append((G, feet))
    return out


class Pronking:
    """Solo12 pronking (module docstring).

    Attributes
    ----------
    robot, stance : LeggedRobot
        The flight law (the reference of the coordinates) and the stance law (the legs
        extended); ``robot``'s ``state``, ``configuration``, ``foot_positions`` serve both.
    extension : ndarray, (2 nv,)
        The stance reference's offset in the state: ``stance``'s state is ``x - extension``.
    system : HybridSystem
        Four events (the feet), d = 36; region 0 (all in the air) the flight law, any
        other the stance law.
    """

    def __init__(self, extension=PRONK["extension"], **law):
        law = {**CONTACT, "damping": PRONK["damping"], **law}
        model = symmetric_solo12()
        nv = model.nv
        q_ref = require_pinocchio().neutral(model)
        q_ref[7:] = ROBOTS["solo12"]["joints"]
        delta = (LEG_SIGNS * np.array([0.0, -0.5, 1.0]) * extension).ravel()
        q_stance = q_ref.copy()
        q_stance[7:] += delta
        feet = ROBOTS["solo12"]["feet"]
        self.robot = legged_robot(model, feet, q_ref, **law)
        self.stance = legged_robot(model, feet, q_stance, **law)
        self.nv, self.law = nv, self.robot.law
        self.extension = np.zeros(2 * nv)
        self.extension[6:nv] = delta
        # the robots' unchecked functions (the system checks its states itself)
        self.system = HybridSystem(self._field, self.robot._events, n_events=4, dim=2 * nv,
                                   field_jacobian=self._field_jacobian,
                                   event_jacobian=self.robot._event_jacobian)

    def field(self, x, mask) -> np.ndarray:
        """(2 nv,): the flight robot's field in region 0, the stance robot's (at its
        coordinates ``x - extension``) in the others."""
        return self._field(self.robot._x(x), self.robot._mask(mask))

    def field_jacobian(self, x, mask) -> np.ndarray:
        """(2 nv, 2 nv): the field's Jacobian (the shift of coordinates is a translation)."""
        return self._field_jacobian(self.robot._x(x), self.robot._mask(mask))

    def _field(self, x, mask) -> np.ndarray:
        if mask:
            return self.stance._field(x - self.extension, mask)
        return self.robot._field(x, mask)

    def _field_jacobian(self, x, mask) -> np.ndarray:
        if mask:
            return self.stance._field_jacobian(x - self.extension, mask)
        return self.robot._field_jacobian(x, mask)

    def section(self, x) -> float:
        """The apex section ``-v_z`` (the base's vertical velocity, in its frame)."""
        return -x[self.nv + 2]

    def section_gradient(self, x) -> np.ndarray:
        """(2 nv,): the section's gradient, constant."""
        out = np.zeros(2 * self.nv)
        out[self.nv + 2] = -1.0
        return out

    def apex_state(self, apex=APEX) -> np.ndarray:
        """The symmetric apex state (2 nv,) of ``apex`` (as :data:`APEX`): the base level at
        its height, at rest but for the legs, which mirror the front left one."""
        x = np.zeros(2 * self.nv)
        x[2] = apex[0]
        x[6:self.nv] = (LEG_SIGNS * np.asarray(apex[1:4])).ravel()
        x[self.nv + 6:] = (LEG_SIGNS * np.asarray(apex[4:7])).ravel()
        return x


def pronking(extension=PRONK["extension"], **law) -> Pronking:
    """Solo12 pronking: :class:`Pronking` (``extension`` in rad; ``law`` overrides
    :data:`~bderiv.robots.legged.CONTACT` and ``PRONK``'s damping)."""
    return Pronking(extension, **law)


def pronking_orbit(gait: Pronking, guess=None, **options):
    """The pronking orbit by ``periodic_orbit`` from ``guess`` (default the stored apex),
    on the apex section with the cyclic coordinates :data:`CYCLIC`; ``options`` go to
    :meth:`~bderiv.analysis.system.HybridSystem.periodic_orbit`.

    Returns
    -------
    PeriodicOrbit
    """
    guess = gait.apex_state() if guess is None else guess
    options = {"period_guess": PERIOD, "cyclic": CYCLIC, **options}
    return gait.system.periodic_orbit(guess, gait.section,
                                      section_gradient=gait.section_gradient, **options)


def pronking_figure(gait: Pronking, orbit, stability=None, strides=2, samples=800):
    """The orbit over ``strides`` strides (the base's height and the feet's, the event
    groups marked) and, if given, the stability's multipliers against the unit circle
    (needs matplotlib).

    Returns
    -------
    matplotlib.figure.Figure
    """
    import matplotlib.pyplot as plt

    T = strides * orbit.period
    t = np.linspace(0.0, T, samples)
    traj = gait.system.simulate(orbit.x0, T, t_eval=t, rtol=1e-12, atol=1e-13)
    feet = np.array([gait.robot.foot_positions(x)[:, 2] for x in traj.x]) - gait.law["ground"]
    width = (1, 0.45) if stability is not None else (1,)
    fig, axes = plt.subplots(1, len(width), figsize=(10.5, 3.8), constrained_layout=True,
                             gridspec_kw={"width_ratios": width}, squeeze=False)
    ax = axes[0, 0]
    ax.plot(1e3 * t, 1e3 * traj.x[:, 2], color="k", lw=1.6, label="base (its origin)")
    for k, foot in enumerate(gait.robot.feet):
        ax.plot(1e3 * t, 1e3 * feet[:, k], lw=[3.5, 2.5, 1.5, 0.8][k], label=foot)
    for g in traj.groups:
        ax.axvline(1e3 * g.time, color="0.5", ls=":", lw=1)
        ax.annotate("4 feet " + ("down" if g.directions[0] > 0 else "up"),
                    (1e3 * g.time, 1e3 * traj.x[:, 2].max() * 0.36), rotation=90,
                    xytext=(3, 0), textcoords="offset points", fontsize=8, color="0.3")
    ax.axhline(0.0, color="k", lw=0.8)
    ax.set_xlabel("time from the apex (ms)")
    ax.set_ylabel("height above the ground (mm)")
    ax.set_title(f"Solo12 pronking: period {1e3 * orbit.period:.2f} ms (the four feet's "
                 "curves coincide)", fontsize=10)
    ax.legend(fontsize=8, loc="center")
    if stability is not None:
        ax = axes[0, 1]
        circle = np.exp(1j * np.linspace(0, 2 * np.pi, 200))
        ax.plot(circle.real, circle.imag, color="0.6", lw=0.8)
        mult = next(iter(stability.multipliers.values()))
        ax.plot(mult.real, mult.imag, "o", ms=4, color="C3")
        ax.set_aspect("equal")
        ax.set_title(f"Floquet multipliers (growth rate {stability.growth_rate:.4f})",
                     fontsize=10)
        ax.set_xlabel("Re")
        ax.set_ylabel("Im")
    return fig
