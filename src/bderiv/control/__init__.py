"""Trajectory optimisation through contact on the flow's B-derivative (docs/control.md).

- :mod:`.parametric`: a model's flow in its state and its parameters (a parameter is a
  state that does not move): :class:`ParametricFlow` steps, each with its B-derivative and
  the piece of the event order the nominal trajectory took; :func:`augment` builds the
  augmented model from the functions of a ``params`` model.
- :mod:`.shooting`: Levenberg-Marquardt single shooting (hybrid-tools' rules), its
  Jacobian a piece of the flow's B-derivative.
- :mod:`.ilqr`: iLQR with piecewise-constant inputs, the backward pass on each step's
  piece, switches of event order detected and reported.
- :mod:`.models`: models with inputs (hybrid-tools' bouncing balls, the chair with
  thrusters).
"""

from .ilqr import ILQRResult, Iteration, cost_gradient, ilqr, rollout
from .models import ball_1d, ball_2d, controlled_chair
from .parametric import ParametricFlow, Step, StepEndsAtImpact, augment, nominal_orders
from .shooting import ShootingConfig, ShootingResult, shoot

__all__ = ["ILQRResult", "Iteration", "ParametricFlow", "ShootingConfig", "ShootingResult",
           "Step", "StepEndsAtImpact", "augment", "ball_1d", "ball_2d", "controlled_chair",
           "cost_gradient", "ilqr", "nominal_orders", "rollout", "shoot"]
