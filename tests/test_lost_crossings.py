"""Crossings lost after a stop that leaves the state a rounding across a surface.

A located crossing can leave the switched event a rounding on the side it came from (the
1 g bar's liftoff at t = 0.0011885 leaves h_1 = +4e-22 with bit 1 clear). Read by its
sign, the next stretch started "across": when the event left its surface and came back
within the first step, no step end was below it, and the crossing was lost (three in
1.3 ms, the tip ending inside the ground with no contact force; a ball's last eight
impacts before its Zeno point). The excursion screen now searches the steps from such a
start for that return, on both integrators, and after every stop the run checks that
every event is on the side its bit says or within its window of the surface.

The oracles are independent of bderiv: an event-detecting simulation written here
(solve_ivp, tight tolerances, a restart at every event with the event read on its side
there) and its one-sided finite differences, and the bouncing ball's closed form.
"""

from __future__ import annotations

import math
from functools import cache

import numba
import numpy as np
import pytest
from test_grouping import simulate_ref as grouping_ref

from bderiv import HybridSystem
from bderiv.models.compiled import rules
from bderiv.models.events import excursions
from bderiv.models.integrate import run as run_module

# ------------------------------------------------------------------------------------------
# the 1 g bar on two springy legs (legs 1 and 1.5 cm, stiffness 1e6 N/m): state (z [m],
# th [rad], zd [m/s], thd [rad/s]); event k: tip k below the ground
# ------------------------------------------------------------------------------------------
M, G, K, C = 1e-3, 9.81, 1e6, 6.0
LEVER = np.array([0.01, 0.015])
SIDE = np.array([-1.0, 1.0])
INERTIA = M * 0.012**2 / 3
SCALE = np.array([1e-3, 1e-2, 1.0, 30.0])  # the components' magnitudes
REF_ATOL = np.array([1e-17, 1e-16, 1e-14, 1e-13])


@numba.njit
def bar_events(x):
    out = np.empty(2)
    for j in range(2):
        out[j] = -(x[0] + SIDE[j] * LEVER[j] * np.sin(x[1]))
    return out


@numba.njit
def bar_event_jacobian(x):
    J = np.zeros((2, 4))
    for j in range(2):
        J[j, 0] = -1.0
        J[j, 1] = -SIDE[j] * LEVER[j] * np.cos(x[1])
    return J


@numba.njit
def bar_field(x, mask):
    out = np.zeros(4)
    out[0], out[1], out[2] = x[2], x[3], -G
    for j in range(2):
        if mask >> j & 1:
            arm = SIDE[j] * LEVER[j] * np.cos(x[1])
            f = K * -(x[0] + SIDE[j] * LEVER[j] * np.sin(x[1])) + C * -(x[2] + arm * x[3])
            out[2] += f / M
            out[3] += arm * f / INERTIA
    return out


@numba.njit
def bar_field_jacobian(x, mask):
    J = np.zeros((4, 4))
    J[0, 2] = J[1, 3] = 1.0
    for j in range(2):
        if mask >> j & 1:
            arm = SIDE[j] * LEVER[j] * np.cos(x[1])
            darm = -SIDE[j] * LEVER[j] * np.sin(x[1])
            f = K * -(x[0] + SIDE[j] * LEVER[j] * np.sin(x[1])) + C * -(x[2] + arm * x[3])
            # df/d(z, th, zd, thd)
            df = np.array([-K, -K * arm - C * darm * x[3], -C, -C * arm])
            for i in range(4):
                J[2, i] += df[i] / M
                J[3, i] += arm * df[i] / INERTIA
            J[3, 1] += darm * f / INERTIA
    return J


def bar(path):
    """The bar as a Python model (its functions' Python code) or a compiled one."""
    fns = (bar_field, bar_events, bar_event_jacobian, bar_field_jacobian)
    if path == "python":
        fns = tuple(fn.py_func for fn in fns)
    field, events, event_jacobian, field_jacobian = fns
    return HybridSystem(field, events, n_events=2, dim=4, event_jacobian=event_jacobian,
                        field_jacobian=field_jacobian)


#: just before a liftoff of leg 1 whose stop leaves h_1 a rounding above 0 (bit clear)
X_LIFTOFF = np.array([1.2846895859273634e-07, -1.2008928194784011e-05,
                      0.006242258887719302, -0.621520091456417])
#: the bar dropped from rest at 1 mm: it hops on both legs and comes to rest
X_DROP = np.array([1e-3, 0.0, 0.0, 0.0])


# ------------------------------------------------------------------------------------------
# the independent reference: restart at every event, each event read on its side there
# ------------------------------------------------------------------------------------------
def simulate_ref(x0, T, *, rtol=1e-13, atol=REF_ATOL / 10):
    """Final state and event log ``[(t, k), ...]`` of the bar from ``x0`` to ``T`` by
    test_grouping's reference (solve_ivp DOP853, a restart at every event, each event read
    on its side there)."""
    return grouping_ref(bar_field.py_func, bar_events.py_func, x0, T, rtol=rtol, atol=atol)


#: directions of the flow maps' checks, in the components' magnitudes
DIRECTIONS = np.random.default_rng(0).standard_normal((4, 4)) * SCALE


@cache
def differences(x0, T, eps):
    """One-sided differences of the reference along ``DIRECTIONS``: shape (4, 4)."""
    x0 = np.array(x0)
    base = simulate_ref(x0, T)[0]
    return np.array([(simulate_ref(x0 + eps * v, T)[0] - base) / eps for v in DIRECTIONS])


def scaled_error(FD, DV):
    """The largest difference, each component relative to its largest ``|DV|``."""
    return float((np.abs(FD - DV).max(axis=0) / np.abs(DV).max(axis=0)).max())


def assert_groups_are_the_references(times, events, log):
    """The groups' times (G,) and events (G tuples) are the reference's event log."""
    ours = [(t, k) for t, group in zip(times, events, strict=True) for k in group]
    assert [k for _, k in ours] == [k for _, k in log]
    np.testing.assert_allclose([t for t, _ in ours], [t for t, _ in log], rtol=0, atol=1e-9)


def assert_sides_agree(system, x, mask):
    """The final region is the one the signs of the events say."""
    h = system.calls.eval_events(x)
    assert mask == sum(1 << k for k in range(h.size) if h[k] > 0), (mask, h)


# ------------------------------------------------------------------------------------------
# the bar after the liftoff (three crossings in 1.3 ms were lost)
# ------------------------------------------------------------------------------------------
@pytest.mark.parametrize("path", ["python", "compiled"])
def test_the_crossings_after_a_liftoff_that_leaves_a_rounding_are_found(path):
    system, T = bar(path), 1.3e-3
    x_ref, log = simulate_ref(X_LIFTOFF, T)
    assert [k for _, k in log[-3:]] == [1, 1, 1] and len(log) == 8
    traj = system.simulate(X_LIFTOFF, T)
    assert_groups_are_the_references([g.time for g in traj.groups],
                                      [g.events for g in traj.groups], log)
    # main: mask 0 and h_1 = +4.5e-8, the tip inside the ground with no contact force
    assert traj.mask_final == 0b10
    assert_sides_agree(system, traj.x_final, traj.mask_final)
    np.testing.assert_allclose(traj.x_final / SCALE, x_ref / SCALE, rtol=0, atol=1e-8)
    fb = system.flow_bderivative(X_LIFTOFF, T)
    assert_groups_are_the_references(fb.group_times, fb.group_events, log)
    DV = fb(DIRECTIONS)
    errors = [scaled_error(differences(tuple(X_LIFTOFF), T, eps), DV) for eps in (1e-8, 1e-9)]
    # O(eps): eight contacts of a stiff leg make the second-order term large (main, on the
    # Python path: 100 %)
    assert 3 < errors[0] / errors[1] < 30 and errors[1] < 1e-2, errors


# ------------------------------------------------------------------------------------------
# the bar dropped from 1 mm: hopping for 0.053 s and 0.06 s (main lost eight crossings)
# ------------------------------------------------------------------------------------------
@pytest.mark.parametrize("path", ["python", "compiled"])
def test_the_hopping_bars_flow_map_matches_the_references_differences(path):
    T = 0.053
    fb = bar(path).flow_bderivative(X_DROP, T)
    log = simulate_ref(X_DROP, T)[1]
    assert len(log) == 41
    assert_groups_are_the_references(fb.group_times, fb.group_events, log)
    DV = fb(DIRECTIONS)
    errors = [scaled_error(differences(tuple(X_DROP), T, eps), DV) for eps in (1e-8, 1e-9)]
    assert 3 < errors[0] / errors[1] < 30 and errors[1] < 1e-2, errors


@pytest.mark.parametrize("path", ["python", "compiled"])
def test_the_bar_hops_to_rest_over_sixty_milliseconds(path):
    """By 0.06 s the bar rests on both legs (damped: its flow map contracts to 1e-10 of
    the directions); main ended in free flight inside the ground, its map 1e5 off."""
    system, T = bar(path), 0.06
    x_ref, log = simulate_ref(X_DROP, T)
    fb = system.flow_bderivative(X_DROP, T)
    assert_groups_are_the_references(fb.group_times, fb.group_events, log)
    traj = system.simulate(X_DROP, T)
    assert traj.mask_final == 0b11
    assert_sides_agree(system, traj.x_final, traj.mask_final)
    np.testing.assert_allclose(traj.x_final / SCALE, x_ref / SCALE, rtol=0, atol=1e-8)
    DV = fb(DIRECTIONS)
    for eps in (1e-5, 1e-6):  # differences at the reference's accuracy: 1e-8 of |v|
        FD = differences(tuple(X_DROP), T, eps)
        assert np.abs((FD - DV) / SCALE).max() < 1e-6


# ------------------------------------------------------------------------------------------
# the bouncing ball (e = 0.8) up to 4.063 s, 39 impacts before its Zeno point 4.0637
# ------------------------------------------------------------------------------------------
E, G_BALL = 0.8, 9.81


@numba.njit
def ball_field(x, mask):
    return np.array([x[1], -G_BALL])


@numba.njit
def ball_events(x):
    return np.array([-x[0]])


@numba.njit
def ball_reset(x, mask, k):
    return np.array([x[0], -E * x[1]])


def ball(path):
    fns = (ball_field, ball_events, ball_reset)
    if path == "python":
        fns = tuple(fn.py_func for fn in fns)
    field, events, reset = fns
    return HybridSystem(field, events, n_events=1, dim=2, reset=reset)


def ball_flow(x, T):
    """The ball's state at T from x = (q, v), q > 0, in closed form, and its impact
    times (the quadratic formula; the rebound velocity -e v)."""
    q, v, t, times = float(x[0]), float(x[1]), 0.0, []
    while True:
        hit = (v + math.sqrt(v * v + 2 * G_BALL * q)) / G_BALL
        if t + hit > T:
            s = T - t
            return np.array([q + v * s - 0.5 * G_BALL * s * s, v - G_BALL * s]), times
        t, q, v = t + hit, 0.0, -E * (v - G_BALL * hit)
        times.append(t)


@pytest.mark.parametrize("path", ["python", "compiled"])
def test_the_balls_variational_run_sees_every_impact_before_its_zeno_point(path):
    x0, T = np.array([1.0, 0.0]), 4.063
    x_T, times = ball_flow(x0, T)
    assert len(times) == 39
    fb = ball(path).flow_bderivative(x0, T)
    # main: 31 impacts, then "an event group with resets at the final time"
    assert fb.group_events == ((0,),) * 39
    np.testing.assert_allclose(fb.group_times, times, rtol=0, atol=1e-9)
    step = 1e-7  # the flow is smooth at x0 (one event per impact): central differences
    J = np.column_stack([(ball_flow(x0 + step * e, T)[0] - ball_flow(x0 - step * e, T)[0])
                         / (2 * step) for e in np.eye(2)])
    np.testing.assert_allclose(fb(np.eye(2)).T, J, rtol=1e-5, atol=1e-6)
    traj = ball(path).simulate(x0, T)
    np.testing.assert_allclose(traj.x_final, x_T, rtol=0, atol=1e-9)


# ------------------------------------------------------------------------------------------
# the invariant: after every stop, each event on the side its bit says or within its window
# ------------------------------------------------------------------------------------------
def test_the_compiled_rule_of_the_sides():
    window = np.array([1e-9, 1e-9, 0.0])
    assert rules.wrong_side(np.array([-1.0, 2.0, 3.0]), 0b110, window) == -1
    assert rules.wrong_side(np.array([1e-19, -1e-19, 0.0]), 0b110, window) == -1  # roundings
    assert rules.wrong_side(np.array([1e-3, 2.0, 3.0]), 0b110, window) == 0
    assert rules.wrong_side(np.array([-1.0, 2.0, -1e-300]), 0b110, window) == 2


@pytest.mark.parametrize("path", ["python", "compiled"])
def test_a_stop_that_breaks_the_invariant_is_refused(monkeypatch, path):
    """A switch that also flips the bit of leg 0, 6e-7 below the ground (window 1e-17):
    refused at that stop, naming the time, the event, its value, window and mask."""
    switch = run_module.switch

    def broken(*args, **kwargs):
        group, new, x_after = switch(*args, **kwargs)
        return group, new ^ 0b01, x_after

    monkeypatch.setattr(run_module, "compiled_stops", lambda system, section: False)
    monkeypatch.setattr(run_module, "switch", broken)
    with pytest.raises(ValueError, match=r"after the stop at t=3\.31116\d*e-05 event 0 is on "
                       r"the wrong side of its surface: h_0 = -5\.96e-07, beyond its window "
                       r"[\d.e-]+ \(the accuracy of the stop\), where region mask 0b01"):
        bar(path).simulate(X_LIFTOFF, 1.3e-3)


def test_the_screen_searches_a_step_rising_from_a_start_across():
    """h = t (t - 1) + 1e-19 sampled at 0, 1, 2 (one step: start, midpoint, end): a
    rounding across at the start, across at both samples after it, below in between; an
    event still on its way to its side (falling) is not searched."""
    times = np.array([0.0, 1.0, 2.0])
    h = (times * (times - 1.0) + 1e-19)[:, None]
    assert rules.start_dip_steps(h).tolist() == [[0, 0]]
    j, t = excursions._start_dip(h, np.array([1e-12]), times,
                                 lambda s, k: s * (s - 1.0) + 1e-19)
    assert j == 0 and t == pytest.approx(0.5, abs=1e-6)
    # within tol: a return when a later sample is clearly across (h(2) = 2 > tol), else not
    j, t = excursions._start_dip(h, np.array([1.0]), times,
                                 lambda s, k: s * (s - 1.0) + 1e-19)
    assert j == 0 and t == pytest.approx(0.5, abs=1e-6)
    assert excursions._start_dip(h, np.array([3.0]), times,
                                 lambda s, k: s * (s - 1.0) + 1e-19) is None
    falling = np.array([[1e-11], [0.6e-11], [0.2e-11], [-0.2e-11], [-0.6e-11]])
    assert rules.start_dip_steps(falling).size == 0
    assert rules.start_dip_steps(-h).size == 0  # below at the start: the integrator sees it
