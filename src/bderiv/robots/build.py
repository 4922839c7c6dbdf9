"""A legged robot from its description: :func:`legged_robot` loads a Pinocchio model or a
URDF and builds the robot with compliant feet (:mod:`bderiv.robots.legged`) or rigid ones
(:mod:`bderiv.robots.rigid`)."""

from __future__ import annotations

from .._support._validate import check_bool
from ._checks import check_law
from ._files import require_pinocchio, robot_file
from .legged import CONTACT, LeggedRobot
from .rigid import RigidLeggedRobot

__all__ = ["legged_robot"]


def _load(source, pin):
    if isinstance(source, pin.Model):
        model = source
    else:
        model = pin.buildModelFromUrdf(str(robot_file(source)), pin.JointModelFreeFlyer())
    if model.njoints < 2 or model.joints[1].shortname() != "JointModelFreeFlyer":
        raise ValueError("the model must have a free-flying base as its first joint "
                         "(buildModelFromUrdf(path, pinocchio.JointModelFreeFlyer())), got "
                         f"{model.joints[1].shortname() if model.njoints > 1 else 'no joint'}")
    other = [(model.names[j], model.joints[j].shortname()) for j in range(2, model.njoints)
             if model.joints[j].nq != 1 or model.joints[j].nv != 1]
    if other:
        raise ValueError(f"the joints after the base must each have one coordinate "
                         f"(revolute or prismatic: q = q_ref + e), got {other}")
    return model


def legged_robot(source, feet, q_ref=None, *, contact="compliant", sticking=True,
                 **law) -> LeggedRobot:
    """A legged robot as a hybrid system (:mod:`bderiv.robots.legged`'s docstring).

    Parameters
    ----------
    source : pinocchio.Model, str or os.PathLike
        A model with a free-flying base, or a URDF: a path, or a file of example-robot-data
        such as ``"solo_description/robots/solo12.urdf"`` (loaded with a free-flyer).
    feet : str or sequence of str
        The foot frames, each once; event k is foot k's touchdown (one name: a robot
        of one foot).
    q_ref : array_like, (nq,), optional
        The reference configuration (tangent coordinates, PD posture), its base
        quaternion ``q_ref[3:7]`` (x, y, z, w) of unit norm to 1e-9 (used as given, not
        normalised); default the model's neutral configuration.
    contact : {"compliant", "rigid"}
        Compliant feet (the spring-damper of the module docstring), or rigid: a plastic
        impact at touchdown and the feet then held (:mod:`bderiv.robots.rigid`).
    sticking : bool
        Rigid feet only: hold a landed foot's 3-D velocity (True) or its normal velocity
        alone (False, a frictionless ground).
    **law
        Contact and posture parameters, :data:`~bderiv.robots.legged.CONTACT` by default
        (rigid feet use ``kp``, ``kd``, ``ground``).

    Returns
    -------
    LeggedRobot
        Its ``system`` is the :class:`~bderiv.analysis.system.HybridSystem`; a
        :class:`~bderiv.robots.rigid.RigidLeggedRobot` for rigid feet.
    """
    if contact not in ("compliant", "rigid"):
        raise ValueError(f"contact must be 'compliant' or 'rigid', got {contact!r}")
    sticking = check_bool(sticking, "sticking")
    law = check_law(law, CONTACT)
    pin = require_pinocchio()
    model = _load(source, pin)
    q_ref = pin.neutral(model) if q_ref is None else q_ref  # feet, q_ref: LeggedRobot's checks
    if contact == "rigid":
        return RigidLeggedRobot(model, feet, q_ref, {**CONTACT, **law}, sticking)
    return LeggedRobot(model, feet, q_ref, {**CONTACT, **law})
