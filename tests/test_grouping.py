"""Which events cross together at a stop, and where a stretch starts (issue 27 items 5, 6).

Oracles: closed forms (windows, constant-field flows and their saltation products), and
one-sided finite differences of ``simulate_ref``, an event-detecting simulation written
here with solve_ivp (no bderiv), whose convergence in O(eps) shows which answer is right.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from bderiv.analysis.system import HybridSystem
from bderiv.models.events.crossings import group_tolerance
from bderiv.models.events.locate import (
    GLOBAL_ERROR_FACTOR,
    classify,
    state_error,
    windows,
)
from bderiv.models.events.sides import on_side_at_start
from bderiv.models.integrate.options import SolverOptions


# ------------------------------------------------------------------------------------------
# the independent reference: restart at every event, flip the bits of those that crossed
# ------------------------------------------------------------------------------------------
def simulate_ref(field, events, x0, T, *, rtol, atol):
    """Final state and event log ``[(t, k), ...]`` of the flow from ``x0`` to ``T``."""
    x, t = np.array(x0, dtype=float), 0.0
    n = len(events(x))
    mask = sum(1 << k for k in range(n) if events(x)[k] > 0)
    log = []
    while t < T:
        funcs = []
        for k in range(n):
            side = 1.0 if mask >> k & 1 else -1.0

            def ev(tt, y, k=k, t0=t, side=side):  # read on its side at the restart
                return side if tt == t0 else events(y)[k]

            ev.terminal, ev.direction = True, -side
            funcs.append(ev)
        sol = solve_ivp(lambda _t, y, m=mask: field(y, m), (t, T), x, events=funcs,
                        rtol=rtol, atol=atol, method="DOP853")
        assert sol.status != -1, sol.message
        t, x = float(sol.t[-1]), sol.y[:, -1].copy()
        if sol.status == 0:
            break
        h = events(x)
        for k in range(n):  # located, or crossed inside the same step
            if sol.t_events[k].size or (h[k] > 0) != bool(mask >> k & 1):
                mask ^= 1 << k
                log.append((t, k))
    return x, log


def fd_errors(field, events, x0, T, V, DV, eps, **tols):
    """Norm-relative errors of one-sided differences against ``DV``: shape (len(eps),)."""
    base = simulate_ref(field, events, x0, T, **tols)[0]
    errs = []
    for e in eps:
        fd = np.array([(simulate_ref(field, events, x0 + e * v, T, **tols)[0] - base) / e
                       for v in V])
        errs.append(float((np.linalg.norm(fd - DV, axis=1) / np.linalg.norm(DV, axis=1)).max()))
    return np.array(errs)


def assert_order_eps(errs, eps, below=1e-3):
    """Errors that shrink like eps (a factor 10 per step, within [3, 30]) to ``below``."""
    ratios = errs[:-1] / errs[1:]
    assert np.all((ratios > 3) & (ratios < 30)) and errs[-1] < below, (errs, eps)


# ------------------------------------------------------------------------------------------
# the window of each event (closed forms)
# ------------------------------------------------------------------------------------------
def test_state_error_is_per_component_and_keeps_the_carried_bound():
    err = state_error(1e-12, 1e-10, np.array([1e-3, 500.0]), carried=np.array([0.0, 1.0]))
    np.testing.assert_allclose(err, [10 * (1e-12 + 1e-13), 1.0])
    assert GLOBAL_ERROR_FACTOR == 10.0


def test_an_event_is_not_widened_by_a_coordinate_it_does_not_depend_on():
    Dh = np.array([[1.0, -2.0, 0.0], [0.0, 0.5, 0.0]])  # no event reads x_2 (500 mm)
    scale = np.array([1e-3, 2.0, 500.0])
    tol = group_tolerance(Dh, SolverOptions(rtol=1e-8, atol=1e-9), scale)
    step = 1e-9 + 1e-8 * scale
    np.testing.assert_allclose(tol, 10 * np.array([step[0] + 2 * step[1], 0.5 * step[1]]))


def test_the_window_adds_the_time_uncertainty_of_the_event_that_stopped():
    # event 1 (rate 1e-4) stopped the integrator: its value known to 1e-11, so the stop's
    # time to 1e-7, over which event 0 (rate 2) moves by 2e-7
    Dh, rate, err = np.eye(3), np.array([2.0, 1e-4, -3.0]), np.array([1e-9, 1e-11, 1e-9])
    window, u = windows(Dh, rate, err, fired=[1])
    assert u == pytest.approx(1e-7)
    np.testing.assert_allclose(window, [1e-9 + 2e-7, 1e-11 + 1e-11, 1e-9 + 3e-7])
    assert windows(Dh, rate, err, fired=[])[1] == 0.0


def test_classify_groups_events_at_the_stop_and_flags_undecided_ones():
    h = np.array([0.0, -1e-9, 2e-9, -1e-6, -1e-3, 1e-9])
    rate = np.array([1.0, 1.0, 1.0, 1.0, 1.0, -1.0])
    window = np.full(6, 5e-9)
    c = classify(h, rate, window, fired=[0], simultaneity_tol=1e-5)
    # 1, 2 at the stop; 3 within the tolerance but not at the stop (switched at its own
    # time); 4 later; 5 moves away
    assert (c.group, c.near, c.undecided) == ([0, 1, 2], [3], [])
    c = classify(h, rate, window, fired=[0], simultaneity_tol=1e-9)
    assert (c.group, c.near, c.undecided) == ([0, 1, 2], [], [1, 2])


# ------------------------------------------------------------------------------------------
# item 5: a far unrelated coordinate does not merge events (closed form)
# ------------------------------------------------------------------------------------------
# constant fields, events a = 0 and b = 0: a reaches 0 at t = 1; b, 5e-8 behind, speeds up
# to 2 once a has crossed and reaches 0 at t = 1 + 2.5e-8. p is a position in mm (or m)
# that no event or field reads.
GAP = 5e-8


def far_system(unit):
    F = np.array([[1.0, 1.0], [1.0, 2.0], [3.0, 1.0], [3.0, 2.0]])

    def field(x, mask):
        return np.array([F[mask, 0], F[mask, 1], unit])

    def events(x):
        return x[:2].copy()

    def event_jacobian(x):
        return np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])

    def field_jacobian(x, mask):
        return np.zeros((3, 3))

    return HybridSystem(field, events, n_events=2, dim=3, event_jacobian=event_jacobian,
                        field_jacobian=field_jacobian), F


def saltation(F_before, F_after, k):
    """``I + (F+ - F-) e_k^T / F-_k`` for event h = x_k (3 x 3, the third row zero)."""
    S = np.eye(3)
    S[:2, k] += (F_after - F_before) / F_before[k]
    return S


@pytest.mark.parametrize("unit", [1000.0, 1.0])  # p in mm (x_2 = 500 .. 2500) or in m
def test_an_unrelated_coordinate_in_mm_does_not_merge_events(unit):
    system, F = far_system(unit)
    x0 = np.array([-1.0, -1.0 - GAP, 500.0 * unit / 1000.0])
    # simultaneity_tol=1e-7 above the gap: merged, the gap said, in either unit alike
    merged = system.flow_bderivative(x0, 2.0)
    assert merged.group_events == ((0, 1),)
    np.testing.assert_allclose(merged.group_spreads, [GAP / 2], rtol=1e-3)
    fb = system.flow_bderivative(x0, 2.0, simultaneity_tol=1e-9)
    assert fb.group_events == ((0,), (1,))
    np.testing.assert_allclose(np.diff(fb.group_times), [GAP / 2], rtol=1e-3)
    # the exact map: event 0 then event 1, whatever the direction (constant fields)
    S = saltation(F[1], F[3], 1) @ saltation(F[0], F[1], 0)
    V = np.random.default_rng(0).standard_normal((16, 3))
    np.testing.assert_allclose(fb(V), V @ S.T, rtol=1e-9, atol=1e-9)


# ------------------------------------------------------------------------------------------
# item 5 on the 1 g bar of the issue: liftoffs 5e-8 apart, a position in mm
# ------------------------------------------------------------------------------------------
BAR_M, BAR_G, BAR_K, BAR_C = 1e-3, 9.81, 1e6, 6.0
BAR_L, BAR_S = np.array([0.01, 0.015]), np.array([-1.0, 1.0])
BAR_I = BAR_M * 0.012**2 / 3
BAR_ATOL = np.array([1e-17, 1e-16, 1e-14, 1e-13])  # the reference's per-component atol


def bar_events(x):
    return -(x[0] + BAR_S * BAR_L * np.sin(x[1]))


def bar_event_jacobian(x):
    J = np.zeros((2, x.size))
    J[:, 0], J[:, 1] = -1.0, -BAR_S * BAR_L * np.cos(x[1])
    return J


def bar_field(x, mask, control=0.0):
    """Field of the 1 g bar on two springy legs, state (z, th, zd, thd); ``control`` adds
    a balance torque in double support."""
    z, th, zd, thd = x[:4]
    arm = BAR_S * BAR_L * np.cos(th)
    h = bar_events(x)
    hd = -(zd + arm * thd)
    touching = np.array([mask & 1, mask >> 1 & 1], dtype=float)
    f = touching * (BAR_K * h + BAR_C * hd)
    torque = np.sum(arm * f) + (control * (-1e-4 * th - 1e-6 * thd) if mask == 3 else 0.0)
    return np.array([zd, thd, -BAR_G + f.sum() / BAR_M, torque / BAR_I])


def bar_field_jacobian(x, mask, control=0.0):
    z, th, zd, thd = x[:4]
    J = np.zeros((4, 4))
    J[0, 2] = J[1, 3] = 1.0
    h = bar_events(x)
    for j in range(2):
        if mask >> j & 1:
            a, da = BAR_S[j] * BAR_L[j] * np.cos(th), -BAR_S[j] * BAR_L[j] * np.sin(th)
            dh = np.array([-1.0, -a, 0.0, 0.0])
            dhd = np.array([0.0, -da * thd, -1.0, -a])
            df = BAR_K * dh + BAR_C * dhd
            f = BAR_K * h[j] + BAR_C * -(zd + a * thd)
            J[2] += df / BAR_M
            J[3] += a * df / BAR_I
            J[3, 1] += da * f / BAR_I
    if mask == 3:
        J[3, 1] -= control * 1e-4 / BAR_I
        J[3, 3] -= control * 1e-6 / BAR_I
    return J


def controlled_bar(speed):
    """The bar with its balance controller and a horizontal position moving at ``speed``
    (1000 mm/s or 1 m/s), read by no event and no field term."""

    def field(x, mask):
        return np.append(bar_field(x, mask, control=1.0), speed)

    def field_jacobian(x, mask):
        J = np.zeros((5, 5))
        J[:4, :4] = bar_field_jacobian(x, mask, control=1.0)
        return J

    system = HybridSystem(field, bar_events, n_events=2, dim=5,
                          event_jacobian=bar_event_jacobian, field_jacobian=field_jacobian)
    return system, field


def test_bar_liftoffs_5e8_apart_are_not_merged_by_a_position_in_mm():
    # rho: leg 1 lifting off (h_1 = 0, rate -1.3), leg 0 still 4e-8 deep (rate -0.8); the
    # start is 1e-5 s earlier, in double support
    th = np.arcsin(4e-8 / BAR_L.sum())
    rho = np.array([-BAR_L[1] * np.sin(th), th, 1.0, 20.0, 0.0])
    results = {}
    for speed in (1000.0, 1.0):  # the position in mm, or in m
        system, field = controlled_bar(speed)
        start = rho.copy()
        start[4] = 500.0 * speed / 1000.0
        x0 = solve_ivp(lambda _t, x, f=field: f(x, 3), (1e-5, 0.0), start, rtol=1e-13,
                       atol=np.append(BAR_ATOL, 1e-12), method="DOP853").y[:, -1]
        assert np.all(bar_events(x0) > 0)
        merged = system.flow_bderivative(x0, 1e-4)  # within 1e-7: merged, in either unit
        assert merged.group_events == ((0, 1),) and 2e-8 < merged.group_spreads[0] < 1e-7
        results[speed] = (system, field, x0, system.flow_bderivative(x0, 1e-4,
                                                                      simultaneity_tol=1e-9))
    system, field, x0, fb = results[1000.0]
    assert fb.group_events == ((1,), (0,))
    log = simulate_ref(field, bar_events, x0, 1e-4, rtol=1e-13,
                       atol=np.append(BAR_ATOL, 1e-12))[1]
    assert [k for _, k in log] == [1, 0]
    gap = log[1][0] - log[0][0]
    assert 2e-8 < gap < 1e-7
    np.testing.assert_allclose(np.diff(fb.group_times), [gap], rtol=1e-3)
    V = np.random.default_rng(0).standard_normal((6, 5)) * [1e-3, 1e-2, 1.0, 30.0, 1.0]
    eps = (1e-5, 1e-6, 1e-7)
    errs = fd_errors(field, bar_events, x0, 1e-4, V, fb(V), eps, rtol=1e-13,
                     atol=np.append(BAR_ATOL, 1e-12))
    assert_order_eps(errs, eps)


# ------------------------------------------------------------------------------------------
# item 6a: events within each other's time uncertainty are located until decided
# ------------------------------------------------------------------------------------------
# README's two-event model with event 1 approached at rate 1e-4: from SLOW_X0 both events
# happen at t = 1 (the reference puts them < 1e-12 apart); event 1's time is known only to
# about its value's error / 1e-4, which at the default tolerances is about 1e-7.
SLOW = 1e-4


def slow_field(x, mask):
    a = 0.4 if mask & 0b10 else 1.0
    b = SLOW if mask == 0 else (0.3 if mask & 1 else 1.0)
    return np.array([a * (1 + 0.1 * x[1] ** 2), b * (1 + 0.2 * np.sin(x[0]))])


def slow_field_jacobian(x, mask):
    a = 0.4 if mask & 0b10 else 1.0
    b = SLOW if mask == 0 else (0.3 if mask & 1 else 1.0)
    return np.array([[0.0, a * 0.2 * x[1]], [b * 0.2 * np.cos(x[0]), 0.0]])


def slow_events(x):
    return np.array([x[0] + 0.1 * x[1] ** 2, x[1]])


SLOW_SYSTEM = HybridSystem(slow_field, slow_events, n_events=2, dim=2,
                           field_jacobian=slow_field_jacobian,
                           event_jacobian=lambda x: np.array([[1.0, 0.2 * x[1]], [0.0, 1.0]]))
SLOW_X0 = solve_ivp(lambda _t, x: slow_field(x, 0), (1.0, 0.0), [0.0, 0.0], rtol=1e-13,
                    atol=1e-16, method="DOP853").y[:, -1]
SLOW_TOLS = {"rtol": 1e-13, "atol": 1e-16}


def test_a_slow_approach_is_located_until_the_events_are_decided_simultaneous():
    log = simulate_ref(slow_field, slow_events, SLOW_X0, 1.5, **SLOW_TOLS)[1]
    assert sorted(k for _, k in log) == [0, 1] and abs(log[1][0] - log[0][0]) < 1e-11
    V = np.random.default_rng(0).standard_normal((8, 2))
    fb = SLOW_SYSTEM.flow_bderivative(SLOW_X0, 1.5)  # was refused, advising a wrong tol
    assert fb.group_events == ((0, 1),)
    assert len({tuple(o) for o in fb.orders(V)[0]}) == 2  # V meets both orders
    eps = (1e-5, 1e-6, 1e-7)
    assert_order_eps(fd_errors(slow_field, slow_events, SLOW_X0, 1.5, V, fb(V), eps,
                               **SLOW_TOLS), eps)
    # a tolerance below the default location uncertainty: the stretch is located more
    # tightly, the events stay one group (split, the map was 100 % off for half of V)
    fine = SLOW_SYSTEM.flow_bderivative(SLOW_X0, 1.5, simultaneity_tol=1e-9)
    assert fine.group_events == ((0, 1),)
    np.testing.assert_allclose(fine(V), fb(V), rtol=1e-6)


def test_deciding_simultaneous_events_integrates_the_variational_equations_once():
    # the tighter integrations that decide are of the state alone; the first stretch is
    # kept when they decide the group it found (at the floor rtol, numerical Jacobians
    # in the variational equations took minutes)
    calls = []

    def counted(x, mask):
        calls.append(mask)
        return slow_field_jacobian(x, mask)

    system = HybridSystem(slow_field, slow_events, n_events=2, dim=2, field_jacobian=counted,
                          event_jacobian=lambda x: np.array([[1.0, 0.2 * x[1]], [0, 1.0]]))
    V = np.random.default_rng(1).standard_normal((8, 2))
    maps = []
    for tol in (1e-3, 1e-9):  # decided at once; undecided down to rtol = 2.2e-14
        calls.clear()
        maps.append(system.flow_bderivative(SLOW_X0, 1.5, simultaneity_tol=tol))
        assert maps[-1].group_events == ((0, 1),)
        maps[-1] = (maps[-1](V), len(calls))
    np.testing.assert_array_equal(maps[1][0], maps[0][0])
    assert maps[1][1] == maps[0][1]


def test_events_apart_within_the_tolerance_are_merged_and_their_gap_said():
    # event 0 now about 1e-8 after event 1: within the default tolerance 1e-7, so merged
    # (was refused), with the gap the reference gives; a tolerance below it separates them
    x0 = SLOW_X0 - [1e-8, 0.0]
    log = simulate_ref(slow_field, slow_events, x0, 1.5, **SLOW_TOLS)[1]
    assert [k for _, k in log] == [1, 0]
    gap = log[1][0] - log[0][0]
    merged = SLOW_SYSTEM.flow_bderivative(x0, 1.5)
    assert merged.group_events == ((0, 1),)
    assert merged.group_spreads[0] == pytest.approx(gap, rel=0.05)
    fb = SLOW_SYSTEM.flow_bderivative(x0, 1.5, simultaneity_tol=gap / 3)
    assert fb.group_events == ((1,), (0,))
    assert np.diff(fb.group_times)[0] == pytest.approx(gap, rel=0.05)


# ------------------------------------------------------------------------------------------
# item 6b: a stretch that starts exactly on a surface
# ------------------------------------------------------------------------------------------
def test_a_stretch_starting_on_a_surface_does_not_stop_at_once():
    # y = -t + t^2 from y(0) = 0 (exactly on h = y, bit clear): it dips and crosses upward
    # at t = 1, inside the first step; solve_ivp alone places the root at the start
    def h(_t, y):
        return y[0]

    h.terminal, h.direction = True, 1
    sol = solve_ivp(lambda t, y: [-1.0 + 2.0 * t], (0.0, 10.0), [0.0], first_step=2.0,
                    events=on_side_at_start([h], 0.0, 0b0, 1), method="DOP853")
    assert sol.t_events[0] == pytest.approx([1.0], abs=1e-12)
    later, = on_side_at_start([h], 0.0, 0b1, 1)  # bit set: read on the positive side
    assert (later.terminal, later.direction) == (True, 1)
    assert later(0.0, [0.0]) > 0 and later(0.0, [-1.0]) == -1.0 and later(1.0, [0.0]) == 0.0


def test_the_bar_hops_on_after_a_stop_exactly_on_a_surface():
    # from rest at 1 mm: 16 landings and liftoffs; after a liftoff at t = 0.0305 the state
    # lands with h_1 == 0.0 exactly (was refused as a grazing crossing at once)
    system = HybridSystem(bar_field, bar_events, n_events=2, dim=4,
                          event_jacobian=bar_event_jacobian, field_jacobian=bar_field_jacobian)
    x0, T = np.array([1e-3, 0.0, 0.0, 0.0]), 0.04
    fb = system.flow_bderivative(x0, T)
    log = simulate_ref(bar_field, bar_events, x0, T, rtol=1e-12, atol=BAR_ATOL)[1]
    ours = [(t, k) for t, g in zip(fb.group_times, fb.group_events, strict=True) for k in g]
    assert [k for _, k in ours] == [k for _, k in log] and len(log) == 16
    np.testing.assert_allclose([t for t, _ in ours], [t for t, _ in log], atol=1e-9)
    V = np.random.default_rng(0).standard_normal((6, 4)) * [1e-3, 1e-2, 1.0, 30.0]
    eps = (1e-6, 1e-7, 1e-8)  # 16 bounces: the second-order term is large
    assert_order_eps(fd_errors(bar_field, bar_events, x0, T, V, fb(V), eps, rtol=1e-12,
                               atol=BAR_ATOL), eps, below=1e-2)
