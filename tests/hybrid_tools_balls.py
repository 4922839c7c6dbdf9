"""hybrid-tools' 2-D bouncing ball written as a bderiv model, for the side-by-side checks
of the estimation tests (tests/test_estimate.py) and benchmark
(benchmarks/kalman_consistency.py). Its 1-D ball is :func:`bderiv.examples.bouncing_ball`.
"""

from __future__ import annotations

import numpy as np

from bderiv import HybridSystem


def ball_2d(e, g, floor):
    """hybrid-tools' 2-D ball: state (qx, qy, vx, vy), the floor at ``qy = floor``,
    restitution ``e``, gravity ``g``."""

    def field(x, mask):
        return np.array([x[2], x[3], 0.0, -g])

    def field_jacobian(x, mask):
        J = np.zeros((4, 4))
        J[0, 2] = J[1, 3] = 1.0
        return J

    def events(x):
        return np.array([floor - x[1]])

    def event_jacobian(x):
        return np.array([[0.0, -1.0, 0.0, 0.0]])

    def reset(x, mask, k):
        return np.array([x[0], x[1], x[2], -e * x[3]])

    def reset_jacobian(x, mask, k):
        return np.diag([1.0, 1.0, 1.0, -e])

    return HybridSystem(field, events, n_events=1, dim=4, field_jacobian=field_jacobian,
                        event_jacobian=event_jacobian, reset=reset,
                        reset_jacobian=reset_jacobian)
