"""Estimation through simultaneous events: a hybrid Kalman filter on B-derivatives.

:class:`HybridKalmanFilter` predicts the mean by simulation and the covariance through the
flow's B-derivative; at event groups the Gaussian crosses the piecewise-linear map by
sigma directions, by the exact mixture of the pieces weighted by the probability of each
event order, or by one piece (a salted filter). docs/estimation.md is the worked example.
"""

from .kalman import HybridKalmanFilter, ModeEstimate, SplitPriorWarning
from .localmap import LocalMap, group_offsets
from .pushforward import PushForward, push_mixture, push_piece, push_sigma

__all__ = ["HybridKalmanFilter", "LocalMap", "ModeEstimate", "PushForward",
           "SplitPriorWarning", "group_offsets", "push_mixture", "push_piece", "push_sigma"]
