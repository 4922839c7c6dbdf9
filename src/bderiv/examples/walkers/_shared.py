"""What both walkers share: their parameters' check and the gait by Newton's method."""

from __future__ import annotations

import numpy as np

from .._common import perturbed_start


def _positive(**values):
    for name, v in values.items():
        if not (np.isfinite(v) and v > 0):
            raise ValueError(f"{name} must be a finite number > 0, got {v}")


def _orbit(ex, perturbation, section, gradient, kwargs):
    """``periodic_orbit`` of a walker from ``ex.x0 + perturbation``, awaiting the return
    for two steps' time by default."""
    kwargs.setdefault("section_gradient", gradient)
    kwargs.setdefault("period_guess", 2.0 * ex.t_event)
    return ex.system.periodic_orbit(perturbed_start(ex, perturbation), section, **kwargs)
