"""A trajectory that turns around the intersection of two surfaces and spirals into it in
finite time (crossings that accumulate: mathematics.md section 9), on both integrators.

The model: events ``h_0 = x``, ``h_1 = y``; a constant field in each quadrant, ``(-1, K)``
in the first, ``(-K, -1)`` in the second, ``(1, -K)`` in the third, ``(K, 1)`` in the
fourth. From ``(x0, y0)`` in the first quadrant the crossings of the axes come at
``x0``, then at intervals ``(y0 + K x0) K^j`` (``j = 0, 1, ...``): they accumulate at
``x0 + (y0 + K x0) / (1 - K)``, every crossing transversal. Oracle: that closed form.
A run past it is refused at it (sides.check_carried, zeno.ImpactWatch).
"""

from __future__ import annotations

import re

import numpy as np
import pytest
from compiled_models import on_path

X0 = np.array([1.0, 1e-3])
#: the field of each quadrant's mask (bit 0: x > 0, bit 1: y > 0) in units (1, K)
VELOCITY = {3: ((-1.0, 0.0), (0.0, 1.0)), 2: ((0.0, -1.0), (-1.0, 0.0)),
            0: ((1.0, 0.0), (0.0, -1.0)), 1: ((0.0, 1.0), (1.0, 0.0))}


def field(x, mask):
    K = x[2]
    out = np.empty(2)
    if mask == 3:
        out[0], out[1] = -1.0, K
    elif mask == 2:
        out[0], out[1] = -K, -1.0
    elif mask == 0:
        out[0], out[1] = 1.0, -K
    else:
        out[0], out[1] = K, 1.0
    return out


def field_jacobian(x, mask):
    return np.zeros((2, 2))


def events(x):
    return x[:2].copy()


def event_jacobian(x):
    return np.eye(2)


def spiral(path, K):
    return on_path(path, field, field_jacobian, events, event_jacobian, n_events=2, dim=2,
                   params=np.array([K]))


def closed_form(K, T):
    """The state at T < the accumulation time, quadrant by quadrant, and the crossings'
    times before it."""
    x, t, mask, times = X0.copy(), 0.0, 3, []
    while True:
        v = np.array(VELOCITY[mask][0]) + K * np.array(VELOCITY[mask][1])
        axis = 0 if mask in (3, 0) else 1  # the axis this quadrant's field reaches
        dt = -x[axis] / v[axis]
        if t + dt > T:
            return x + (T - t) * v, times
        x, t = x + dt * v, t + dt
        times.append(t)
        x[axis] = 0.0
        mask ^= 1 << axis


def accumulation(K):
    return X0[0] + (X0[1] + K * X0[0]) / (1 - K)


@pytest.mark.parametrize("path", ["python", "compiled"])
def test_a_run_that_ends_before_the_accumulation_is_the_closed_form(path):
    K = 0.5
    T = accumulation(K) - 0.01
    traj = spiral(path, K).simulate(X0, T)
    x, times = closed_form(K, T)
    np.testing.assert_allclose(traj.x_final, x, rtol=0, atol=1e-9)
    np.testing.assert_allclose([g.time for g in traj.groups], times, rtol=0, atol=1e-9)


@pytest.mark.parametrize("path", ["python", "compiled"])
@pytest.mark.parametrize(("K", "what"), [(0.5, "simulate"), (0.5, "flow_bderivative"),
                                         (0.05, "simulate"), (0.003, "simulate")])
def test_a_run_past_the_accumulation_is_refused_at_it_not_followed_across_a_surface(
        path, K, what):
    """Near the accumulation the turns fall below the integration accuracy: the state is
    left a rounding across a surface that the next region's field carries further across
    (sides.check_carried), or the crossings come around at one instant
    (zeno.ImpactWatch). Followed (main), every later sample was across a surface."""
    system = spiral(path, K)
    with pytest.raises(ValueError, match=r"crosses at once") as info:
        if what == "simulate":
            system.simulate(X0, 3.0)
        else:
            system.flow_bderivative(X0, 3.0)
    t = float(re.search(r"at t=([0-9.e+-]+)", str(info.value)).group(1))
    assert t == pytest.approx(accumulation(K), abs=1e-8)
