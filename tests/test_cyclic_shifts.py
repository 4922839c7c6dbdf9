"""A coordinate declared cyclic that the model depends on is refused, whatever its period.

The model: a hopper ``(x, y, vx, vy)`` in flight over a floor ``y = floor(x)``; at the
impact (event ``floor(x) - y`` crossed upward) its controller sets ``vx = VT`` and
``vy = VUP`` (a bounce: it leaves the floor at once). On the apex section ``-vy`` a gait
found with x cyclic is periodic in ``(y, vx)`` at one x only: the next strides land
elsewhere on the floor and their apex heights drift. Two floors:

- a wave ``A sin(2 pi x)`` of period 1, which a shift of x by 1 cannot tell from a flat
  floor (the check of a single shift by 1 passed it, and an "orbit" came back);
- a bump ``B exp(-((x - XC) / W)^2)`` under the gait's landing point only, which the
  guess's stride and its shifted copies land far from: only the return map's derivative
  along x at the iterates sees it.

The oracle: the strides in closed form (ballistic flight, the impact by a root search on
the floor written here), the false orbit solved in ``y`` at x = 0 by the same, and the
apex heights of the strides that follow it.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.optimize import brentq

from bderiv import HybridSystem
from bderiv.models.section import Section

G, VT, VUP = 9.81, 1.0, 3.0
A = 0.05  # the wave's amplitude
B, XC, W = 0.05, 0.29, 0.03  # the bump's height, centre and width


def wave(x):
    return A * math.sin(2 * math.pi * x), 2 * math.pi * A * math.cos(2 * math.pi * x)


def bump(x):
    e = B * math.exp(-(((x - XC) / W) ** 2))
    return e, -2 * (x - XC) / W**2 * e


def hopper(floor):
    def field(x, mask):
        return np.array([x[2], x[3], 0.0, -G])

    def field_jacobian(x, mask):
        J = np.zeros((4, 4))
        J[0, 2] = J[1, 3] = 1.0
        return J

    def events(x):
        return np.array([floor(x[0])[0] - x[1]])

    def event_jacobian(x):
        return np.array([[floor(x[0])[1], -1.0, 0.0, 0.0]])

    def reset(x, mask, k):
        return np.array([x[0], x[1], VT, VUP])

    def reset_jacobian(x, mask, k):
        return np.diag([1.0, 1.0, 0.0, 0.0])

    return HybridSystem(field, events, n_events=1, dim=4, field_jacobian=field_jacobian,
                        event_jacobian=event_jacobian, reset=reset,
                        reset_jacobian=reset_jacobian)


SECTION = Section(lambda x: -x[3], 4, lambda x: np.array([0.0, 0.0, 0.0, -1.0]))


def stride(floor, x, y, vx):
    """The next apex ``(x, y)`` from the apex ``(x, y, vx, 0)``, in closed form."""

    def gap(t):  # floor - height of the falling hopper: crosses 0 upward at the impact
        return floor(x + vx * t)[0] - (y - 0.5 * G * t * t)

    grid = np.linspace(0.0, 2.0, 4001)
    values = [gap(t) for t in grid]
    i = next(i for i in range(1, grid.size) if values[i] > 0.0)
    t = brentq(gap, grid[i - 1], grid[i], xtol=1e-15, rtol=1e-15)
    x_hit, y_hit = x + vx * t, y - 0.5 * G * t * t
    rise = VUP / G
    return x_hit + VT * rise, y_hit + 0.5 * VUP * rise


def false_orbit_heights(floor, strides=5):
    """The apex height y* at x = 0 that one stride returns to (the "orbit" with x cyclic),
    and the apex heights of the strides that follow from it."""
    top = 0.5 * VUP**2 / G
    y_star = brentq(lambda y: stride(floor, 0.0, y, VT)[1] - y, top - 0.2, top + 0.2,
                    xtol=1e-14)
    x, y, heights = 0.0, y_star, []
    for _ in range(strides):
        x, y = stride(floor, x, y, VT)
        heights.append(y)
    return y_star, np.array(heights)


def test_the_oracle_has_no_gait_with_x_cyclic():
    for floor in (wave, bump):
        y_star, heights = false_orbit_heights(floor)
        assert heights[0] == pytest.approx(y_star, abs=1e-12)  # one stride repeats ...
        assert np.ptp(heights) > 0.02  # ... the next ones do not
    # the wave is invisible to a shift by its period, visible to others
    assert stride(wave, 1.0, 0.45, VT)[1] == pytest.approx(stride(wave, 0.0, 0.45, VT)[1],
                                                           abs=1e-12)
    assert abs(stride(wave, math.sqrt(2), 0.45, VT)[1] - stride(wave, 0.0, 0.45, VT)[1]) > 0.01


def test_a_floor_of_period_one_is_not_cyclic():
    system = hopper(wave)
    guess = np.array([0.0, 0.5, 0.9, 0.0])
    # the stride from the guess, the bderiv run against the closed form (the model is right)
    returned = system.simulate(guess, 3.0, section=SECTION).x_final
    np.testing.assert_allclose(returned[:2], stride(wave, 0.0, 0.5, 0.9), atol=1e-9)
    with pytest.raises(ValueError, match=r"coordinate 0 is not cyclic: shifting it by "
                                         r"1\.41421 .* the field, events, resets or section "
                                         r"depend on it"):
        system.periodic_orbit(guess, SECTION, period_guess=1.0, cyclic=[0])


def test_a_bump_under_the_orbit_alone_is_seen_by_the_derivative():
    system = hopper(bump)
    guess = np.array([0.0, 0.5, 0.5, 0.0])  # lands at x = 0.16, far from the bump
    # the shifted strides from the guess see a flat floor, as the start's check does
    base = stride(bump, 0.0, 0.5, 0.5)
    for c in (math.sqrt(2), -(math.sqrt(5) - 1) / 2):
        moved = stride(bump, c, 0.5, 0.5)
        assert abs(moved[0] - c - base[0]) < 1e-9 and abs(moved[1] - base[1]) < 1e-9
    # the orbit lands on the bump's flank: apex heights 0.509, 0.459, 0.459, ...
    y_star, heights = false_orbit_heights(bump)
    x_hit = stride(bump, 0.0, y_star, VT)[0] - VT * VUP / G
    assert abs(bump(x_hit)[1]) > 0.5
    with pytest.raises(ValueError, match=r"coordinate 0 is not cyclic: at x = .* the return "
                                         r"map's derivative along it is not the shift itself: "
                                         r"a shift of coordinate 0 by c moves the return by "
                                         r"\d\.\d+ c beyond the shift \(coordinate 1 most"):
        system.periodic_orbit(guess, SECTION, period_guess=1.0, cyclic=[0])
