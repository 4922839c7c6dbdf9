"""The compass gait's default start at slopes other than Garcia et al.'s 0.009 (a review:
at slope 0.012 it led Newton's method to another, unstable, orbit, as the orbit's default
perturbation did at 0.001; at 0.014 it did not step at all).

Oracle: Garcia et al.'s stride map written here from their equations (leg mass 0,
``g = l = 1``) and integrated by scipy: the orbit found is its fixed point, perturbations
of it shrink over simulated strides where the gait is stable, grow beyond
``STABLE_SLOPE``, and central differences of it put the period doubling there.
"""

from __future__ import annotations

import numpy as np
import pytest
from garcia_walker import garcia_stride

from bderiv.examples import walkers


def _gait(slope):
    """(theta, theta') after the heel strike of the orbit found from the defaults."""
    orbit = walkers.compass_gait_orbit(walkers.compass_gait(slope=slope))
    (strike,) = [g for g in orbit.trajectory.groups if g.directions == (1,)]
    return strike.state_after[[0, 2]]


def _distances(z, slope, strides, kick=(1e-4, -1e-4)):
    """|z_k - z| over ``strides`` simulated strides from ``z + kick``."""
    w, out = z + np.array(kick), []
    for _ in range(strides):
        w = garcia_stride(w, slope)
        out.append(np.linalg.norm(w - z))
    return np.array(out)


@pytest.mark.parametrize("slope", [0.001, 0.012, 0.014])
def test_the_default_start_finds_the_stable_gait(slope):
    z = _gait(slope)
    assert np.abs(garcia_stride(z, slope) - z).max() < 1e-9  # a fixed point of Garcia's map
    assert z[0] > 0.0 and z[1] < 0.0  # a step from theta > 0, falling forward
    dist = _distances(z, slope, 25)
    # attracting: the kick of 1.4e-4 shrinks below a hundredth of itself
    assert dist[-1] < 1e-2 * np.hypot(1e-4, 1e-4), dist


def test_beyond_the_stable_slope_the_default_finds_the_same_gait_unstable():
    slope = 0.02
    z = _gait(slope)
    assert np.abs(garcia_stride(z, slope) - z).max() < 1e-9
    # the long-period gait continued: theta* near Garcia et al.'s 0.97 slope^(1/3)
    assert abs(z[0] / slope ** (1 / 3) - 0.97) < 0.02
    dist = _distances(z, slope, 8, kick=(1e-7, -1e-7))
    assert dist[-1] > 10 * np.hypot(1e-7, 1e-7), dist  # repelling: documented


def test_the_stable_slope_is_where_the_stride_maps_multiplier_crosses_one():
    h = 1e-6
    radii = []
    for slope in (walkers.STABLE_SLOPE - 1e-4, walkers.STABLE_SLOPE + 1e-4):
        z = _gait(slope)
        J = np.column_stack([(garcia_stride(z + h * d, slope)
                              - garcia_stride(z - h * d, slope)) / (2 * h) for d in np.eye(2)])
        radii.append(np.abs(np.linalg.eigvals(J)).max())
    assert radii[0] < 1.0 < radii[1], radii


@pytest.mark.parametrize("slope, error, words", [
    (-0.01, ValueError, "slope must be a finite number > 0, got -0.01"),
    (2.0, ValueError, r"slope must be in \(0, pi/2\) radians, got 2.0"),
    ("0.01", TypeError, "slope must be a real number, got str"),
])
def test_the_gait_start_refuses_a_slope_no_walker_goes_down(slope, error, words):
    """A negative slope gave complex numbers (a cube root), silently."""
    with pytest.raises(error, match=words):
        walkers.long_gait_start(slope)
