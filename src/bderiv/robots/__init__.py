"""Robots from their description files (the extra ``robots``: Pinocchio and
example-robot-data): a legged robot's model whose events are its feet touching the ground.

Why a sub-package: it is the one place that imports Pinocchio (inside its functions, so
``import bderiv.robots`` works without it and says what to install at the first call),
and it builds ordinary :class:`~bderiv.analysis.system.HybridSystem` models on top of the
package, as :mod:`bderiv.symbolic` does from equations. docs/robots.md is its guide.

- :mod:`~bderiv.robots.legged`: :func:`legged_robot` (a Pinocchio model or URDF and the
  foot frames), the contact law, the tangent coordinates of the free-flying base;
- :mod:`~bderiv.robots.quadrupeds`: Solo12, Go1, ANYmal from example-robot-data
  (:func:`quadruped`), :func:`drop_state` and :func:`touchdown_figure`;
- :mod:`~bderiv.robots._lie`: the base's coordinate rate on SE(3) and its derivative;
- :mod:`~bderiv.robots._files`: the description files found, Pinocchio required.
"""

from .legged import CONTACT, LeggedRobot, legged_robot
from .quadrupeds import ROBOTS, drop_state, quadruped, touchdown_figure

__all__ = ["CONTACT", "ROBOTS", "LeggedRobot", "drop_state", "legged_robot", "quadruped",
           "touchdown_figure"]
