"""Quadrupeds of example-robot-data, ready: their files, feet and standing postures.

Each entry is what a robot needs from its description file (the rest is
:func:`~bderiv.robots.legged.legged_robot`): the URDF's path in example-robot-data, the
foot frames in the order of the events, and a standing posture of the joints (the PD's
reference and the tangent coordinates' origin). Another robot is another entry, or a
direct call of ``legged_robot`` with its file. :func:`drop_state` places a robot level
above the ground with its feet at a given height, for a touchdown of several feet at once.
"""

from __future__ import annotations

import numpy as np

from .legged import LeggedRobot, legged_robot

__all__ = ["ROBOTS", "drop_state", "quadruped"]

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


def quadruped(name="solo12", *, joints=None, **law) -> LeggedRobot:
    """A bundled quadruped (:data:`ROBOTS`) as a :class:`~bderiv.robots.legged.LeggedRobot`.

    Parameters
    ----------
    name : str
        A key of :data:`ROBOTS`.
    joints : array_like, (nv - 6,), optional
        Another standing posture.
    **law
        Contact and posture parameters (:data:`bderiv.robots.legged.CONTACT`); defaults
        scaled to the robot's mass (stiffness and damping in proportion to Solo12's
        2.5 kg, the PD gains too), unless given.
    """
    if name not in ROBOTS:
        raise ValueError(f"name must be one of {', '.join(ROBOTS)}, got {name!r}")
    entry = ROBOTS[name]
    from ._files import require_pinocchio, robot_file
    from .legged import CONTACT

    pin = require_pinocchio()
    model = pin.buildModelFromUrdf(str(robot_file(entry["file"])), pin.JointModelFreeFlyer())
    q_ref = pin.neutral(model)
    q_ref[7:] = entry["joints"] if joints is None else joints
    scale = pin.computeTotalMass(model) / 2.5
    law = {**{k: v * scale if k != "ground" else v for k, v in CONTACT.items()}, **law}
    return legged_robot(model, entry["feet"], q_ref, **law)


def drop_state(robot: LeggedRobot, height, vz=0.0, *, velocity=None) -> np.ndarray:
    """The state of ``robot`` in its reference posture, level, its lowest foot ``height``
    above the ground and falling at ``vz`` (m/s, < 0 down); ``velocity`` (nv,) adds to
    the velocity.

    Returns
    -------
    ndarray, (2 nv,)
    """
    x = np.zeros(2 * robot.nv)
    low = robot.foot_positions(x)[:, 2].min()
    x[2] = robot.law["ground"] + height - low  # the base's height offset (level: e_z = dz)
    x[robot.nv + 2] = vz
    if velocity is not None:
        x[robot.nv:] += np.asarray(velocity, dtype=np.float64)
    return x
