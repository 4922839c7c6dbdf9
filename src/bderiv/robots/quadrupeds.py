"""Quadrupeds of example-robot-data, ready: their files, feet and standing postures.

Each entry is what a robot needs from its description file (the rest is
:func:`~bderiv.robots.build.legged_robot`): the URDF's path in example-robot-data, the
foot frames in the order of the events, and a standing posture of the joints (the PD's
reference and the tangent coordinates' origin). Another robot is another entry, or a
direct call of ``legged_robot`` with its file. :func:`drop_state` places a robot level
above the ground with its feet at a given height, for a touchdown of several feet at once;
:func:`touchdown_figure` draws it (docs/robots.md).
"""

from __future__ import annotations

import numpy as np

from .._support._validate import check_number, check_state
from .build import legged_robot
from .legged import LeggedRobot

__all__ = ["ROBOTS", "SOLO12_PACE", "drop_state", "quadruped", "touchdown_figure"]

#: file, feet (event order) and standing joint posture of the bundled quadrupeds; the
#: postures are the files' "standing" states with the hip abduction at 0 (Solo12:
#: solo.srdf's ``straight_standing``), mirrored front to hind so that the four feet are
#: at one height
ROBOTS = {
    "solo12": {"file": "solo_description/robots/solo12.urdf",
               "feet": ("FL_FOOT", "FR_FOOT", "HL_FOOT", "HR_FOOT"),
               "joints": (0.0, 0.8, -1.6, 0.0, 0.8, -1.6, 0.0, -0.8, 1.6, 0.0, -0.8, 1.6)},
    "go1": {"file": "go1_description/urdf/go1.urdf",
            "feet": ("FL_foot", "FR_foot", "RL_foot", "RR_foot"),
            "joints": (0.0, 0.9, -1.8) * 4},
    "anymal": {"file": "anymal_b_simple_description/robots/anymal.urdf",
               "feet": ("LF_FOOT", "LH_FOOT", "RF_FOOT", "RH_FOOT"),
               "joints": (0.0, 0.6, -1.2, 0.0, -0.6, 1.2, 0.0, 0.6, -1.2, 0.0, -0.6, 1.2)},
}

#: Solo12's joints pacing (FR and HR tucked up, FL and HL to land together) at the hip
#: flexion t = 0.8729206446683678 (knee -2 t, hind legs mirrored) where FL's and HL's
#: normal rows are mass-orthogonal, ``J_FL M^-1 J_HL^T = 0`` (a root found by brentq):
#: with rigid frictionless feet (``sticking=False``) their impacts commute
#: (docs/robots.md, "Rigid contacts")
SOLO12_PACE = (0.0, 0.8729206446683678, -1.7458412893367356, 0.0, 1.1, -2.2,
               0.0, -0.8729206446683678, 1.7458412893367356, 0.0, -1.1, 2.2)


def quadruped(name="solo12", *, joints=None, contact="compliant", sticking=True,
              **law) -> LeggedRobot:
    """A bundled quadruped (:data:`ROBOTS`) as a :class:`~bderiv.robots.legged.LeggedRobot`.

    Parameters
    ----------
    name : str
        A key of :data:`ROBOTS`.
    joints : array_like, (nv - 6,), optional
        Another standing posture: one angle per joint (12), finite.
    contact, sticking
        As :func:`~bderiv.robots.build.legged_robot`'s.
    **law
        Contact and posture parameters (:data:`bderiv.robots.legged.CONTACT`); defaults
        scaled to the robot's mass (stiffness and damping in proportion to Solo12's
        2.5 kg, the PD gains too), unless given.
    """
    if not isinstance(name, str) or name not in ROBOTS:
        raise ValueError(f"name must be one of {', '.join(ROBOTS)}, got {name!r}")
    entry = ROBOTS[name]
    if joints is not None:
        n = len(entry["joints"])
        joints = check_state(joints, n, "joints", meaning=f"a standing posture of {name}: "
                             f"one angle per joint, {n}")
    from ._files import require_pinocchio, robot_file
    from .legged import CONTACT

    pin = require_pinocchio()
    model = pin.buildModelFromUrdf(str(robot_file(entry["file"])), pin.JointModelFreeFlyer())
    q_ref = pin.neutral(model)
    q_ref[7:] = entry["joints"] if joints is None else joints
    scale = pin.computeTotalMass(model) / 2.5
    law = {**{k: v * scale if k != "ground" else v for k, v in CONTACT.items()}, **law}
    return legged_robot(model, entry["feet"], q_ref, contact=contact, sticking=sticking,
                        **law)


def drop_state(robot: LeggedRobot, height, vz=0.0, *, velocity=None) -> np.ndarray:
    """The state of ``robot`` in its reference posture (the base's orientation as in
    ``robot.q_ref``), moved up or down so that its lowest foot is ``height`` above the
    ground, and falling at ``vz`` (m/s, < 0 down, the base's velocity in the world's
    vertical); ``velocity`` (nv,) adds to the velocity (in the model's coordinates: the
    base's in its own frame).

    Returns
    -------
    ndarray, (robot.system.dim,)
    """
    if not isinstance(robot, LeggedRobot):
        raise TypeError(f"robot must be a LeggedRobot (legged_robot, quadruped), got "
                        f"{type(robot).__name__}")
    height = check_number(height, "height", low=-np.inf, strict=False)
    vz = check_number(vz, "vz", low=-np.inf, strict=False)
    if velocity is not None:
        velocity = check_state(velocity, robot.nv, "velocity",
                               meaning=f"a velocity of the robot's model, nv = {robot.nv}")
    x = np.zeros(robot.system.dim)  # a rigid robot's contact latches (0: in the air)
    low = robot.foot_positions(x)[:, 2].min()
    # the base's tangent coordinates and velocity are in its own frame (q = q_ref exp6(e),
    # pinocchio's LOCAL velocity): a world vertical w is R^T w, R the reference's rotation
    up = robot.pin.XYZQUATToSE3(robot.q_ref[:7]).rotation[2]  # R^T e_z
    x[:3] = (robot.law["ground"] + height - low) * up
    x[robot.nv:robot.nv + 3] = vz * up
    if velocity is not None:
        x[robot.nv:2 * robot.nv] += velocity
    return x


def touchdown_figure(robot: LeggedRobot, x0, t_final, *, direction=None, eps=2e-3,
                     samples=600):
    """The feet's heights against time through a touchdown (needs matplotlib).

    Left: the run from ``x0`` over ``[0, t_final]``, its event groups marked. Right, near
    the first group: the same run and, dashed, the run from ``x0 + eps * direction`` (a
    perturbation that orders the feet), with the order in which its feet land: the piece
    of the flow's B-derivative that the perturbation meets (with feet whose forces add,
    as compliant feet's do, every order's piece is the same matrix: docs/robots.md).

    Returns
    -------
    matplotlib.figure.Figure
    """
    import matplotlib.pyplot as plt

    system = robot.system
    t = np.linspace(0.0, t_final, samples)
    nominal = system.simulate(x0, t_final, t_eval=t)
    fig, (ax, zoom) = plt.subplots(1, 2, figsize=(10.5, 4.0), constrained_layout=True)
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]

    def heights(xs):
        return 1e3 * np.array([robot.foot_positions(x)[:, 2] - robot.law["ground"]
                               for x in xs])

    h = heights(nominal.x)
    for k, foot in enumerate(robot.feet):
        ax.plot(1e3 * t, h[:, k], color=colors[k], label=foot, lw=1.5)
    for g in nominal.groups:
        ax.axvline(1e3 * g.time, color="0.5", ls=":", lw=1)
        ax.annotate(f"feet {', '.join(robot.feet[k] for k in g.events)}\nat once",
                    (1e3 * g.time, h.max() * 0.6),
                    xytext=(6, 0), textcoords="offset points", fontsize=8, color="0.3")
    ax.axhline(0.0, color="k", lw=0.8)
    ax.set_xlabel("time (ms)")
    ax.set_ylabel("foot height above the ground (mm)")
    ax.set_title(f"the {len(robot.feet)} feet's heights (a level drop: the curves "
                 "coincide)", fontsize=10)
    ax.legend(fontsize=8, loc="upper right")

    t0 = nominal.groups[0].time if nominal.groups else 0.5 * t_final
    window = np.linspace(max(0.0, t0 - 0.004), min(t_final, t0 + 0.004), samples)
    near = system.simulate(x0, window[-1], t_eval=window)
    hn = heights(near.x)
    if direction is None:
        direction = np.zeros_like(x0)
        direction[3], direction[4] = 1.0, 0.6  # roll and pitch: the feet land one by one
    moved = system.simulate(x0 + eps * np.asarray(direction), window[-1], t_eval=window)
    hm = heights(moved.x)
    for k in range(len(robot.feet)):
        zoom.plot(1e3 * window, hn[:, k], color=colors[k], lw=1.5)
        zoom.plot(1e3 * window, hm[:, k], color=colors[k], lw=1.2, ls="--")
    order = [robot.feet[rec.event] for rec in moved.events if rec.direction > 0]
    zoom.axhline(0.0, color="k", lw=0.8)
    zoom.set_xlabel("time (ms)")
    zoom.set_title("near touchdown: solid as dropped, dashed perturbed", fontsize=10)
    landing = nominal.groups[0].events if nominal.groups else robot.feet
    pieces = np.prod(range(1, len(landing) + 1))
    zoom.text(0.98, 0.97, "perturbed run lands " + " < ".join(order) + "\nits piece of the "
              f"B-derivative: one of {pieces} orders\n(feet whose forces add: all {pieces} "
              "are one matrix)", transform=zoom.transAxes, fontsize=8, ha="right", va="top")
    return fig
