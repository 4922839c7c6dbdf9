"""Models with resets (HybridSystem(reset=...)): simulation, the B-derivative at the event
point and of the flow, against closed forms and finite differences of the simulation; the
impacts example and its refused variant."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from bderiv import HybridSystem
from bderiv.analysis.assembly import group_bderivative
from bderiv.examples.impacts import (
    _FOOT,
    _functions,
    _tables,
    landing,
    landing_summary,
    summary_text,
)

U0, U1 = _FOOT[0][2], _FOOT[1][2]
P1 = _FOOT[1][1]


@pytest.fixture(scope="module")
def example():
    return landing()


def _system(model, **overrides):
    kwargs = dict(event_jacobian=model.event_jacobian, field_jacobian=model.field_jacobian,
                  reset=model.reset, reset_jacobian=model.reset_jacobian)
    kwargs.update(overrides)
    return HybridSystem(model.field, model.events, n_events=2, dim=10, **kwargs)


def _model(coupling=0.0):
    """The landing's functions (the default parameters) as attributes."""
    tables = _tables(0.4, 200.0, 4.0, 2000.0, 20.0, 30.0, 40.0, 6.0)
    return SimpleNamespace(**_functions(*tables, coupling))


def test_simulate_applies_the_resets_of_a_simultaneous_group(example):
    traj = example.system.simulate(example.x0, example.t_final, simultaneity_tol=1e-7)
    (group,) = traj.groups
    assert group.events == (0, 1) and abs(group.time - example.t_event) < 1e-9
    np.testing.assert_allclose(group.state, example.rho, atol=1e-8)
    expected = group.state.copy()
    expected[[U0, U1]] = 0.0  # the sliding stops, nothing else jumps
    assert np.array_equal(group.state_after, expected)
    i = int(np.flatnonzero(traj.t == group.time)[-1])  # the next stretch starts there
    assert np.array_equal(traj.x[i], group.state_after)
    assert np.array_equal(traj.x[i - 1], group.state)


def test_one_event_gives_the_saltation_matrix_with_reset(example):
    """n = 1 at the model level: Xi = R + (F+ - R F-) Dh^T / (Dh F-), the fields sampled
    before the jump and after it, from the model's functions directly."""
    model, system = _model(), example.system
    x = example.rho
    M = group_bderivative(system, x, (0,), 0)
    R = model.reset_jacobian(x, 0, 0)
    f_minus, f_plus = model.field(x, 0), model.field(model.reset(x, 0, 0), 1)
    dh = model.event_jacobian(x)[0]
    Xi = R + np.outer(f_plus - R @ f_minus, dh) / (dh @ f_minus)
    np.testing.assert_allclose(M.piece([0]), Xi, rtol=1e-14, atol=1e-14)


def test_separate_touchdowns_compose_two_saltations_and_match_the_simulation(example):
    x0 = example.x0.copy()
    x0[_FOOT[1][1]] += 2e-3  # foot 1 higher: it lands later, each event alone
    system = example.system
    D = system.flow_bderivative(x0, example.t_final)
    assert sorted(g.events for g in system.simulate(x0, example.t_final).groups) == [(0,), (1,)]
    rng = np.random.default_rng(1)
    V = rng.standard_normal((4, 10))
    errors = [np.abs(system.flow_fd(x0, example.t_final, V, e) - D(V)).max()
              for e in (1e-5, 1e-6)]
    assert errors[1] < 0.2 * errors[0] and errors[1] < 1e-4 * np.abs(D(V)).max()


def test_flow_bderivative_through_the_simultaneous_impact_converges_at_first_order(example):
    system = example.system
    D = system.flow_bderivative(example.x0, example.t_final)
    rng = np.random.default_rng(0)
    V = rng.standard_normal((6, 10))
    assert {tuple(o) for o in D.orders(V)[0]} == {(0, 1), (1, 0)}  # both touchdown orders
    DV = D(V)
    errors = [np.abs(system.flow_fd(example.x0, example.t_final, V, e) - DV).max()
              / np.abs(DV).max() for e in (1e-4, 1e-5, 1e-6)]
    assert errors[-1] < 1e-4
    for a, b in zip(errors, errors[1:], strict=False):
        assert 0.05 < b / a < 0.2  # O(eps)
    # the two orders give different pieces: the order matters
    M = system.bderivative(example.rho)
    assert np.abs(M.piece([0, 1]) - M.piece([1, 0])).max() > 1.0


def test_numerical_reset_jacobians_agree(example):
    model = _model()
    numerical = _system(model, reset_jacobian=None).bderivative(example.rho)
    exact = example.system.bderivative(example.rho)
    for order in ([0, 1], [1, 0]):
        np.testing.assert_allclose(numerical.piece(order), exact.piece(order), atol=1e-6)


def test_coupled_feet_are_refused_with_the_reason(example):
    coupled = landing(coupling=0.5)
    with pytest.raises(ValueError, match=r"at rho \(events \[0, 1\]\): the resets of events 0 "
                                         r"and 1 from region mask 0b00 .* do not commute"):
        coupled.system.bderivative(example.rho)
    with pytest.raises(ValueError, match=r"resets of events \[0, 1\], simultaneous at t=0.1, "
                                         r"do not commute: .* states 0.45 apart"):
        coupled.system.simulate(example.x0, example.t_final, simultaneity_tol=1e-7)
    # one foot at a time the coupled model is fine (no simultaneous impact)
    x0 = example.x0.copy()
    x0[P1] += 2e-3
    coupled.system.flow_bderivative(x0, example.t_final)


def test_a_reset_that_moves_a_pending_surface_is_refused(example):
    model = _model()

    def reset(x, mask, k):
        y = model.reset(x, mask, k)
        if not mask >> k & 1:
            y[_FOOT[1 - k][1]] += 0.01 * x[_FOOT[k][2]]  # lifts the other foot: moves h
        return y

    with pytest.raises(ValueError, match="move the surface of event 1, still pending"):
        _system(model, reset=reset, reset_jacobian=None).bderivative(example.rho)


def test_a_reset_that_jumps_across_another_surface_is_refused(example):
    model = _model()

    def reset(x, mask, k):
        y = model.reset(x, mask, k)
        if not mask >> k & 1:
            y[_FOOT[1 - k][1]] = -0.01  # the other foot put below the ground, not crossing
        return y

    x0 = example.x0.copy()
    x0[P1] += 2e-3
    with pytest.raises(ValueError, match="carry the state across the surface of event 0"):
        _system(model, reset=reset).simulate(x0, example.t_final)



def test_a_reset_that_puts_the_foot_back_above_the_ground_keeps_its_bit(example):
    """A foot put back above the ground it went through lands on the side it came from
    (a leg swap, mathematics.md section 9): its bit stays clear, and the next touchdown
    of that foot is a new crossing of the same event, upward again."""
    model = _model()

    def back(x, mask, k):
        y = model.reset(x, mask, k)
        y[_FOOT[k][1]] = 0.01
        return y

    x0 = example.x0.copy()
    x0[P1] += 2e-3
    traj = _system(model, reset=back).simulate(x0, example.t_final)
    first = traj.groups[0]
    assert first.events == (1,) and first.bounced == (1,)
    assert first.mask_after == first.mask_before == 0
    assert first.state_after[_FOOT[1][1]] == 0.01
    ones = [r for r in traj.events if r.event == 1]
    assert len(ones) >= 2 and all(r.direction == 1 for r in ones[:2])


def test_bad_reset_arguments_and_outputs_are_named():
    model = _model()
    with pytest.raises(TypeError, match="reset must be callable"):
        _system(model, reset=3)
    with pytest.raises(TypeError, match="reset_jacobian was given without reset"):
        _system(model, reset=None)
    bad = _system(model, reset=lambda x, mask, k: x[:3], reset_jacobian=None)
    with pytest.raises(ValueError, match=r"reset\(x, mask=0, k=0\) must return an array of "
                                         r"shape \(10,\), got shape \(3,\)"):
        bad.bderivative(landing().rho)


def test_the_summary_reports_the_checks():
    res = landing_summary(n_check=4, eps=(1e-4, 1e-5))
    assert res["groups"][0]["events"] == [0, 1]
    assert res["pieces"]["ranks"] == [8, 8]
    assert res["fd"]["max_errors"][1] < 1e-3 and 0.05 < res["fd"]["ratios"][0] < 0.2
    assert "do not commute" in res["refused"]
    text = summary_text(res)
    assert "u0 0.6 -> 0" in text and "refused" in text
