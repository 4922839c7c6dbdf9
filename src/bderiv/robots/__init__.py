"""Robots from their description files (the extra ``robots``: Pinocchio and
example-robot-data): a legged robot's model whose events are its feet touching the ground.

Why a sub-package: it is the one place that imports Pinocchio (inside its functions, so
``import bderiv.robots`` works without it and says what to install at the first call),
and it builds ordinary :class:`~bderiv.analysis.system.HybridSystem` models on top of the
package, as :mod:`bderiv.symbolic` does from equations. docs/robots.md is its guide.

- :mod:`~bderiv.robots.build`: :func:`legged_robot` (a Pinocchio model or URDF and the
  foot frames);
- :mod:`~bderiv.robots.legged`: compliant feet: the contact law, the tangent coordinates
  of the free-flying base;
- :mod:`~bderiv.robots.rigid`: rigid feet (``contact="rigid"``): the plastic impact, the
  constrained stance, the refusal of simultaneous impacts that do not commute;
- :mod:`~bderiv.robots.quadrupeds`: Solo12, Go1, ANYmal from example-robot-data
  (:func:`quadruped`), :func:`drop_state` and :func:`touchdown_figure`;
- :mod:`~bderiv.robots.gaits`: Solo12 pronking, a periodic orbit through four-foot
  touchdowns and lift-offs, and its stability;
- :mod:`~bderiv.robots._lie`: the base's coordinate rate on SE(3) and its derivative;
- :mod:`~bderiv.robots._files`: the description files found, Pinocchio required.
"""

from .build import legged_robot
from .legged import CONTACT, LeggedRobot
from .quadrupeds import ROBOTS, SOLO12_PACE, drop_state, quadruped, touchdown_figure
from .rigid import RigidLeggedRobot

__all__ = ["CONTACT", "ROBOTS", "SOLO12_PACE", "LeggedRobot", "RigidLeggedRobot",
           "drop_state", "legged_robot", "quadruped", "touchdown_figure"]
