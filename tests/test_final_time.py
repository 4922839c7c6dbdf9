"""Event groups at the final time of a flow map (issue 27 item 7b).

When a group lies at ``t_final`` the flow map ``x -> Phi(t_final, x)`` is piecewise
linear: the directions whose events come before ``t_final`` meet their jumps, the others
do not. Oracles: the closed form of a constant-field model, and one-sided differences of
an event-detecting simulation written here with solve_ivp (a restart at every crossing)
converging O(eps) on the chair.
"""

from __future__ import annotations

import pickle

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from bderiv import BDerivative, HybridSystem, examples
from bderiv.models.events.finaltime import FinalTimeMap, pending_at_final_time


def _constant_model(reset=None):
    """``x' = (1, 1)`` before and ``(1, 3)`` after ``h = x0 - 1``."""
    return HybridSystem(lambda x, m: np.array([1.0, 3.0 if m & 1 else 1.0]),
                        lambda x: np.array([x[0] - 1.0]), n_events=1, dim=2,
                        field_jacobian=lambda x, m: np.zeros((2, 2)),
                        event_jacobian=lambda x: np.array([[1.0, 0.0]]), reset=reset)


def exact(V, dt=0.0):
    """The B-derivative of ``(x, T) -> Phi(T, x)`` at the origin, T = 1: the event
    happens at ``1 - v0`` and the final time at ``1 + dt``."""
    V = np.atleast_2d(V)
    late = np.maximum(V[:, 0] + dt, 0.0)
    return np.column_stack((V[:, 0] + dt, V[:, 1] + dt + 2.0 * late))


V = np.array([[-1.0, 0.0], [1.0, 0.0], [0.0, 1.0], [-1.0, 5.0], [2.0, -3.0], [-0.5, -0.5],
              [1e-3, 7.0], [-1e-3, 7.0]])


@pytest.fixture(scope="module", params=[1.0, 1.0 + 1e-12, 1.0 - 1e-12, 1.0 + 5e-8, 1.0 - 5e-8],
                ids=["T=1", "T=1+1e-12", "T=1-1e-12", "T=1+5e-8", "T=1-5e-8"])
def at_final(request):
    return request.param, _constant_model().flow_bderivative(np.zeros(2), request.param)


def test_group_at_the_final_time_is_the_pl_map(at_final):
    T, D = at_final
    assert D.stops_at_group and D.n_groups == 1
    assert D.jumps[-1].n_events == 2  # the event and the final time
    # the closed form at T = 1; the final time T - 1 away moves the map by O(T - 1)
    np.testing.assert_allclose(D(V), exact(V), atol=1e-7)
    for dt in (0.5, -0.5, 1e-3, -1e-3):
        np.testing.assert_allclose(D(V, dt=dt), exact(V, dt), atol=1e-7)
    np.testing.assert_allclose(D.inverse(D(V)), V, atol=1e-12)


def test_pieces_and_tangents(at_final):
    _, D = at_final
    # order [0, 1]: the event before the final time (its jump); [1, 0]: after (none)
    np.testing.assert_allclose(D.piece([[0, 1]], with_time=True),
                               [[1, 0, 1], [2, 1, 3]], atol=1e-7)
    np.testing.assert_allclose(D.piece([[1, 0]], with_time=True),
                               [[1, 0, 1], [0, 1, 1]], atol=1e-7)
    U = V[V[:, 0] != 0]  # off the boundary between the two pieces (a tie at v0 = 0)
    times, order = D.event_times(U)[0]
    np.testing.assert_allclose(times[:, 0], -U[:, 0], atol=1e-7)
    assert (order[:, 0] == np.where(U[:, 0] > 0, 0, 1)).all()
    slope = np.where(U[:, 0] > 0, 3.0, 1.0)  # d x1 / d (v0 + v1) on each piece
    np.testing.assert_allclose(D.jvp(U, np.ones_like(U)),
                               np.column_stack((np.ones(len(U)), slope)), atol=1e-7)
    W = np.array([0.0, 1.0]) * np.ones_like(U)  # the gradient of x1
    np.testing.assert_allclose(D.vjp(U, W), np.column_stack((slope - 1.0, np.ones(len(U)))),
                               atol=1e-7)


def test_apply_orders_at_the_final_time(at_final):
    """A group at the final time: ``apply_orders`` gives ``D(V)`` and ``D.orders(V)``."""
    _, D = at_final
    W, orders = D.apply_orders(V)
    np.testing.assert_array_equal(W, D(V))
    for got, want in zip(orders, D.orders(V), strict=True):
        np.testing.assert_array_equal(got, want)


def test_pickled_map_stops_at_the_group_too(at_final):
    _, D = at_final
    again = pickle.loads(pickle.dumps(D))
    assert again.stops_at_group
    np.testing.assert_array_equal(again(V, dt=0.25), D(V, dt=0.25))


@pytest.mark.parametrize("T, jump", [(1.0 + 1e-6, True), (1.0 - 1e-6, False)])
def test_outside_the_window_the_map_is_classical(T, jump):
    D = _constant_model().flow_bderivative(np.zeros(2), T)
    assert not D.stops_at_group
    expected = np.column_stack((V[:, 0], V[:, 1] + 2.0 * V[:, 0] * jump))
    np.testing.assert_allclose(D(V), expected, atol=1e-9)


def test_resets_at_the_final_time_are_refused():
    model = _constant_model(reset=lambda x, m, k: x + np.array([0.0, 1.0]))
    with pytest.raises(ValueError, match="discontinuous there and has no B-derivative"):
        model.flow_bderivative(np.zeros(2), 1.0)


def _either_side(gap):
    """Event 0 at 1 - gap, event 1 at 1 + gap from the origin; event 0 speeds x_0 up from
    1 to 3, event 1 changes no field."""
    return HybridSystem(lambda x, m: np.array([1.0 + 2.0 * (m & 1), 1.0]),
                        lambda x: x - np.array([1 - gap, 1 + gap]),
                        n_events=2, dim=2, field_jacobian=lambda x, m: np.zeros((2, 2)),
                        event_jacobian=lambda x: np.eye(2))


def test_groups_on_both_sides_of_the_final_time_further_apart_than_the_tolerance():
    # each within 1e-7 of T = 1, 1.2e-7 apart (was refused): event 0 is switched before T,
    # event 1 is the group at the final time
    D = _either_side(6e-8).flow_bderivative(np.zeros(2), 1.0, simultaneity_tol=1e-7)
    assert D.group_events == ((0,), (1,)) and D.stops_at_group
    assert D.group_spreads == (0.0, 0.0)
    # event 0 (x_0 = 1 - 6e-8) speeds x_0 up from 1 to 3: its saltation v_0 -> 3 v_0;
    # event 1 (x_1 = 1 + 6e-8) at the final time changes no field
    np.testing.assert_allclose(D(V), np.column_stack((3.0 * V[:, 0], V[:, 1])), atol=1e-6)


def test_groups_on_both_sides_of_the_final_time_within_the_tolerance_are_merged():
    # 6e-8 apart (was refused): one group at the final time, its spread said; the map is
    # that of the two events and the final time at one point
    D = _either_side(3e-8).flow_bderivative(np.zeros(2), 1.0, simultaneity_tol=1e-7)
    assert D.group_events == ((0, 1),) and D.stops_at_group
    np.testing.assert_allclose(D.group_spreads, [6e-8], rtol=1e-3)
    # closed form at the simultaneous point: event 0 before T (v_0 > 0) speeds x_0 up
    # from 1 to 3 for the time v_0 (event 1 changes no field)
    np.testing.assert_allclose(D(V), np.column_stack((V[:, 0] + 2.0 * np.maximum(V[:, 0], 0.0),
                                                      V[:, 1])), atol=1e-6)


def test_final_time_map_validation():
    bd = BDerivative(np.eye(1), np.array([[1.0], [2.0]]))
    fm = FinalTimeMap(bd)
    assert repr(fm) == "FinalTimeMap(n_events=2, dim=1)"
    with pytest.raises(TypeError, match="group must be a BDerivative, got ndarray"):
        FinalTimeMap(np.eye(1))
    resets = np.broadcast_to(np.eye(1), (2, 1, 1, 1)).copy()
    with pytest.raises(ValueError, match="resets at the final time"):
        FinalTimeMap(BDerivative(np.eye(1), np.array([[1.0], [2.0]]), resets=resets))
    from bderiv.analysis.flowmap import FlowBDerivative

    with pytest.raises(TypeError, match=r"jumps\[0\] must be a BDerivative, got FinalTimeMap "
                                        r"\(only the last jump may be one\)"):
        FlowBDerivative([np.eye(1)] * 3, [fm, bd])
    flow = FlowBDerivative([np.eye(1)] * 2, [fm])
    with pytest.raises(ValueError, match="no triangulation is offered"):
        flow.triangulation()


def test_pending_events():
    h = np.array([-1e-12, -1.0, 0.0, -2e-7])
    rate = np.array([1.0, 1.0, -1.0, 1.0])
    assert pending_at_final_time(h, rate, 1e-7) == [0]
    assert pending_at_final_time(h, rate, 3e-7) == [0, 3]


# -- the chair, landing at t_final ---------------------------------------------------------


def reference_flow(field, events, x0, T):
    """Phi(T, x0) by an event-detecting simulation (solve_ivp, a restart at each crossing,
    the region from the signs of the events)."""
    x = np.array(x0, float)
    n = len(events(x))
    mask = sum(1 << k for k in range(n) if events(x)[k] > 0)
    t = 0.0
    while t < T:
        funcs = []
        for k in range(n):
            def ev(_t, y, k=k):
                return events(y)[k]
            ev.terminal, ev.direction = True, -1 if mask >> k & 1 else 1
            funcs.append(ev)
        sol = solve_ivp(lambda _t, y, m=mask: field(y, m), (t, T), x, events=funcs,
                        method="DOP853", rtol=1e-12, atol=1e-14)
        t, x = float(sol.t[-1]), sol.y[:, -1]
        if sol.status == 0:
            break
        for k in range(n):
            if sol.t_events[k].size:
                mask ^= 1 << k
    return x


def test_chair_landing_at_the_final_time_converges():
    ex = examples.chair()
    system = ex.system
    T = ex.t_event
    D = system.flow_bderivative(ex.x0, T)
    assert D.stops_at_group
    L0 = D.linear[0]
    rng = np.random.default_rng(3)
    cand = rng.standard_normal((200, system.dim))
    times = D.jumps[0].group.event_times(cand @ L0.T)[0]  # the contacts' first-order times
    kinds = {"later": (times > 0.05).all(1), "earlier": (times < -0.05).all(1),
             "mixed": (times.min(1) < -0.05) & (times.max(1) > 0.05)}
    W = np.concatenate([cand[sel][:2] for sel in kinds.values()])
    assert len(W) == 6
    field, events = system.calls.eval_field, system.calls.eval_events
    base = reference_flow(field, events, ex.x0, T)
    DW = D(W)
    errors = []
    for eps in (1e-4, 1e-5):
        fd = np.array([(reference_flow(field, events, ex.x0 + eps * w, T) - base) / eps
                       for w in W])
        errors.append(np.abs(DW - fd).max() / np.abs(fd).max())
    assert errors[1] < 1e-3, errors
    assert errors[1] < 0.2 * errors[0], errors
    # the jump applied to every direction (the map before this fix) is far off
    applied = D.linear[1] @ D.jumps[0].group(W @ L0.T).T
    assert np.abs(applied.T - fd).max() / np.abs(fd).max() > 0.1


# -- events apart from each other, each within simultaneity_tol of the final time ----------
# (reliability, fourth pass, items 3 and 6: a run that ends just before a group and one that
# stops on its first event must answer alike; before, one refused and the other grouped
# them silently)


def _three_field(x, mask):
    """Constant in each region: events 0 and 1 change the rates of the later components."""
    b0, b1 = float(mask & 1), float(mask >> 1 & 1)
    return np.array([1.0 + 0.5 * b1 + 0.0 * x[0], 1.0 + 0.3 * b0 + 0.0 * x[0],
                     1.0 + 0.2 * b0 + 0.1 * b1 + 0.0 * x[0]])


def _three_events(x):  # events 0, 1, 2 cross 1e-8 apart from the origin, event 0 at t = 1
    return x - np.array([1.0, 1.0 + 1e-8, 1.0 + 2e-8])


def _three_event_jacobian(x):
    return np.eye(3)


@pytest.fixture(scope="module")
def three_models():
    """The model on both integrators: Python functions (solve_ivp) and the same functions
    compiled with numba (the compiled run)."""
    import numba

    python = HybridSystem(_three_field, _three_events, n_events=3, dim=3,
                          field_jacobian=lambda x, m: np.zeros((3, 3)),
                          event_jacobian=_three_event_jacobian)
    compiled = HybridSystem(numba.njit(_three_field), numba.njit(_three_events),
                            n_events=3, dim=3, event_jacobian=numba.njit(_three_event_jacobian))
    return {"python": python, "compiled": compiled}


def _three_exact(V, eps=1e-3):
    """The PL map at the point where the three events cross at once (T = 1), by an exact
    event-driven run of the piecewise-constant field (straight lines between events) from
    ``eps v``, minus the run from 0, over eps: exact for a PL flow."""
    def end(x):
        x, t, mask = np.array(x, float), 0.0, 0
        while True:
            F = _three_field(x, mask)
            left = [((1.0 - x[k]) / F[k], k) for k in range(3) if not mask >> k & 1]
            dt, k = min(left) if left else (np.inf, -1)
            if t + dt >= 1.0:
                return x + (1.0 - t) * F
            x, t, mask = x + dt * F, t + dt, mask | 1 << k
    base = end(np.zeros(3))
    return np.array([(end(eps * v) - base) / eps for v in V])


@pytest.mark.parametrize("path", ["python", "compiled"])
@pytest.mark.parametrize("T", [1.0, 1.0 - 1e-10, 1.0 - 5e-9], ids=["T=1", "T=1-1e-10", "T=1-5e-9"])
def test_events_apart_within_the_tolerance_of_the_final_time_are_one_group(three_models, path,
                                                                           T):
    """Events 0, 1, 2 cross 1e-8 apart, each within simultaneity_tol = 1e-7 of T: one group
    at the final time, on both integrators and whether the run stops on event 0 (T = 1) or
    ends just before it; the spread is said and the map is the group's at the point where
    the three are simultaneous (to the first order of the spread)."""
    D = three_models[path].flow_bderivative(np.zeros(3), T)
    assert D.stops_at_group and D.group_events[-1] == (0, 1, 2)
    # from T = 1 on, after event 0, events 1 and 2 come at the rates 1.3 and 1.2
    np.testing.assert_allclose(D.group_spreads[-1], 2e-8 / 1.2 if T == 1.0 else 2e-8, rtol=1e-3)
    rng = np.random.default_rng(5)
    V = np.concatenate([rng.standard_normal((20, 3)), np.eye(3), -np.eye(3)])
    np.testing.assert_allclose(D(V), _three_exact(V), atol=1e-6)


@pytest.mark.parametrize("path", ["python", "compiled"])
@pytest.mark.parametrize("T", [1.0, 1.0 - 1e-10], ids=["T=1", "T=1-1e-10"])
def test_a_tolerance_below_the_spread_leaves_event_0_alone_at_the_final_time(three_models,
                                                                              path, T):
    """Below the spread, event 0 alone is the group at the final time: the map moves the
    later components by (0.3, 0.2) v_0 where event 0 comes before T (closed form)."""
    D = three_models[path].flow_bderivative(np.zeros(3), T, simultaneity_tol=5e-9)
    assert D.stops_at_group and D.group_events[-1] == (0,) and D.group_spreads == (0.0,)
    rng = np.random.default_rng(5)
    V = np.concatenate([rng.standard_normal((20, 3)), np.eye(3), -np.eye(3)])
    exact = V + np.maximum(V[:, :1], 0.0) * np.array([0.0, 0.3, 0.2])
    np.testing.assert_allclose(D(V), exact, atol=1e-8)
