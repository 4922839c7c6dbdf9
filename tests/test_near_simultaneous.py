"""Starts just off a simultaneous touchdown (reliability, fourth pass, item 6).

The chair's two feet touch down at once from ``x0``; a start moved by 1e-9 (as an optimiser's
or a filter's iterate is) puts the touchdowns about 1e-9 apart: measurably apart (beyond the
integration accuracy) but within the flow maps' ``simultaneity_tol`` of 1e-7. Before, both
integrators refused such a start. The policy (docs/mathematics.md section 7, "Events close
together"): the run switches each event at its own time, so the trajectory is the true one,
and the flow map merges the two groups into the group's B-derivative at the nearby point
where the touchdowns are simultaneous, saying how far apart they were
(``FlowBDerivative.group_spreads``).

Oracles: an event-detecting simulation written here with solve_ivp (a restart at every
crossing, tight tolerances): its event times, its final state, and its one-sided finite
differences, which converge O(eps) to the merged map for steps far above the gap.
"""

from __future__ import annotations

import numpy as np
import pytest
from test_grouping import simulate_ref

from bderiv import examples

SHIFT = np.array([0.0, 0.0, 1e-8, 0.0, 0.0, 0.0])  # the body's angle moved by 1e-8


def reference(field, events, x0, T):
    """``(Phi(T, x0), [(time, event), ...])`` by test_grouping's event-detecting solve_ivp
    run (a restart at every crossing), at tight tolerances."""
    return simulate_ref(field, events, x0, T, rtol=1e-13, atol=1e-15)


@pytest.fixture(scope="module", params=["python", "compiled"])
def chair(request):
    return examples.chair(compiled=request.param == "compiled")


@pytest.fixture(scope="module")
def truth():
    ex = examples.chair()
    start = ex.x0 + SHIFT
    calls = ex.system.calls
    return start, reference(calls.eval_field, calls.eval_events, start, ex.t_final)


def test_the_run_switches_each_touchdown_at_its_own_time(chair, truth):
    start, (x_final, log) = truth
    assert [k for _, k in log] in ([0, 1], [1, 0])
    gap = log[1][0] - log[0][0]
    assert 1e-9 < gap < 2e-8  # apart, and within the tolerance 1e-7
    traj = chair.system.simulate(start, chair.t_final, simultaneity_tol=1e-7)
    assert [g.events for g in traj.groups] == [(k,) for _, k in log]
    np.testing.assert_allclose(np.diff([g.time for g in traj.groups]), [gap], rtol=1e-2)
    np.testing.assert_allclose(traj.x_final, x_final, rtol=1e-8, atol=1e-10)


def test_the_flow_map_merges_them_and_says_the_gap(chair, truth):
    start, (x_final, log) = truth
    D = chair.system.flow_bderivative(start, chair.t_final)  # was refused on both paths
    assert D.group_events == ((0, 1),) and not D.stops_at_group
    np.testing.assert_allclose(D.group_spreads, [log[1][0] - log[0][0]], rtol=1e-2)
    assert "spreads=" in repr(D)
    # the group's map at the simultaneous point: that of the unshifted start, to O(1e-9)
    V = np.random.default_rng(7).standard_normal((12, 6))
    at_rho = chair.system.flow_bderivative(chair.x0, chair.t_final)
    np.testing.assert_allclose(D(V), at_rho(V), rtol=1e-5, atol=1e-5 * np.abs(at_rho(V)).max())


def test_the_merged_map_is_the_finite_differences_of_steps_above_the_gap(truth):
    """Directions in both touchdown orders: one-sided differences of the reference converge
    O(eps) to the merged map for steps 1e-4 and 1e-5, whose event-time shifts are 1e3 to
    1e4 times the gap."""
    ex = examples.chair()
    start, (base, _) = truth
    D = ex.system.flow_bderivative(start, ex.t_final)
    L0 = D.linear[0]
    cand = np.random.default_rng(3).standard_normal((200, 6))
    times = D.jumps[0].event_times(cand @ L0.T)[0]
    first = times.argmin(axis=1)
    W = np.concatenate([cand[first == 0][:2], cand[first == 1][:2]])  # both orders
    assert len(W) == 4
    field, events = ex.system.calls.eval_field, ex.system.calls.eval_events
    errors = []
    for eps in (1e-4, 1e-5):
        fd = np.array([(reference(field, events, start + eps * w, ex.t_final)[0] - base) / eps
                       for w in W])
        errors.append(np.abs(D(W) - fd).max() / np.abs(fd).max())
    assert errors[1] < 1e-3, errors
    assert errors[1] < 0.2 * errors[0], errors


def test_a_tolerance_below_the_gap_gives_the_separated_events(chair, truth):
    start, (_, log) = truth
    D = chair.system.flow_bderivative(start, chair.t_final, simultaneity_tol=1e-11)
    assert D.group_events == tuple((k,) for _, k in log) and D.group_spreads == (0.0, 0.0)
