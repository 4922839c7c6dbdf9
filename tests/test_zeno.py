"""Impacts that accumulate (Zeno) and plastic landings nothing holds (mathematics.md
section 9, "Impacts that accumulate, and landings nothing holds"), on both integrators.

Oracles: the bouncing ball's closed forms (the k-th impact at ``t_1 + 2 (e + ... +
e^(k-1)) v_1 / g``, ``t_1 = sqrt(2 h / g)``, ``v_1 = g t_1``; the Zeno time ``t_1 (1 + 2 e /
(1 - e))``), the ball in a right-angled corner (walls acting on orthogonal components: the
floor's bounces are the ball's, from the corner), and a ball on a spring-damper ground
whose contact region holds it (its rest height ``-g / k``). Each path is the example's
compiled model or its Python twin (``compiled=``).
"""

from __future__ import annotations

import re

import numpy as np
import pytest

from bderiv import HybridSystem
from bderiv.examples import bounces

G = 9.81
PATHS = ["python", "compiled"]


def ball(path, **kw):
    ex = bounces.bouncing_ball(compiled=path == "compiled", **kw)
    assert (ex.system.compiled is not None) == (path == "compiled")
    return ex


def impact_times(e, height, until, g=G, count=10_000):
    """The ball's impact times below ``until``, at most ``count`` (closed form)."""
    t1 = np.sqrt(2 * height / g)
    v1 = g * t1
    times, t, k = [], t1, 0
    while t < until and k < count:
        times.append(t)
        k += 1
        t += 2 * e**k * v1 / g
    return np.array(times)


def zeno_time(e, height, g=G):
    return np.sqrt(2 * height / g) * (1 + 2 * e / (1 - e))


def ball_state(e, height, T, g=G):
    """The ball's state at T (closed form: free flight from the last impact before T)."""
    t_last = impact_times(e, height, T, g)[-1]
    k = len(impact_times(e, height, T, g))
    v = e**k * g * np.sqrt(2 * height / g)  # the rebound speed after the k-th impact
    s = T - t_last
    return np.array([v * s - 0.5 * g * s * s, v - g * s])


def accumulation_named(message):
    """The accumulation time a refusal names."""
    found = re.search(r"come before about t=([0-9.e+-]+)", message)
    assert found, message
    return float(found.group(1))


@pytest.mark.parametrize("path", PATHS)
@pytest.mark.parametrize(("e", "before"), [(0.3, 1e-3), (0.3, 1e-6), (0.5, 1e-4)])
def test_a_run_that_ends_before_the_zeno_time_is_the_closed_form(path, e, before):
    height = 1.0
    T = zeno_time(e, height) - before
    traj = ball(path, e=e, height=height).system.simulate([height, 0.0], T)
    times = impact_times(e, height, T)
    assert len(traj.groups) == len(times) >= 5  # enough bounces to show the accumulation
    np.testing.assert_allclose([g.time for g in traj.groups], times, rtol=1e-10)
    assert all(g.bounced == (0,) and g.mask_after == 0 for g in traj.groups)
    np.testing.assert_allclose(traj.x_final, ball_state(e, height, T), rtol=1e-8, atol=1e-10)
    assert traj.x_final[0] >= -1e-12  # never below the ground


@pytest.mark.parametrize("e", [0.3, 0.5, 0.8])
def test_a_run_past_the_zeno_time_is_refused_naming_it_on_both_paths(e):
    height = 1.0
    T = zeno_time(e, height) + 0.5
    messages = []
    for path in PATHS:
        with pytest.raises(ValueError, match=r"impacts of event 0 accumulate \(a Zeno") as err:
            ball(path, e=e, height=height).system.simulate([height, 0.0], T)
        message = str(err.value)
        # named: the accumulation time, the bounces that show it (the first five), the
        # ratio, the final time and what to do
        assert accumulation_named(message) == pytest.approx(zeno_time(e, height), rel=1e-9)
        shown = ", ".join(f"{t:.10g}" for t in impact_times(e, height, T, count=5))
        assert f"bounces, at t={shown}, come at" in message
        assert f"(ratio {e:.4g})" in message and f"t_final={T:.10g}" in message
        assert "End the run before the accumulation time" in message
        assert "region whose field holds the body" in message
        messages.append(message)
    assert messages[0] == messages[1]  # the same refusal on both integrators


@pytest.mark.parametrize("path", PATHS)
def test_the_flow_bderivative_past_the_zeno_time_is_refused(path):
    with pytest.raises(ValueError, match=r"accumulate \(a Zeno trajectory\)"):
        ball(path, e=0.3).system.flow_bderivative([1.0, 0.0], 3.0)


@pytest.mark.parametrize("path", PATHS)
def test_a_plastic_ball_is_refused_at_its_impact(path):
    """e = 0 stops the ball on the ground, whose region is the same free fall: nothing
    holds it (main's run fell through the floor, 31.9 m below it at t = 3)."""
    ex = ball(path, e=0.0)
    t1 = np.sqrt(2 / G)
    for run in (lambda: ex.system.simulate(ex.x0, 3.0),
                lambda: ex.system.flow_bderivative(ex.x0, 3.0)):
        with pytest.raises(ValueError, match=rf"reset of event 0 at t={t1:.10g} the state "
                                             r"stops on its surface .* nothing holds it") as err:
            run()
        assert "region 0b1 beyond the surface is the same as that of region 0b0" in \
            str(err.value)
        assert f"end the run before this time (t_final below {t1:.10g})" in str(err.value)
    # before the impact: the free fall
    traj = ex.system.simulate(ex.x0, 0.4)
    np.testing.assert_allclose(traj.x_final, [1 - G * 0.4**2 / 2, -G * 0.4], rtol=1e-12)


def corner_zeno(ex, e):
    """The ball in the right-angled corner: after the corner at t_event its vertical speed
    is e v_y up, and the floor's bounces accumulate 2 e v_y / (g (1 - e)) later."""
    up = e * -ex.rho[3]
    return ex.t_event + 2 * up / (G * (1 - e))


def corner_state(ex, e, T):
    """Closed form at T: the wall is hit once (at the corner), the floor as a ball's."""
    vx = -e * ex.rho[2]
    up = -e * ex.rho[3]  # rebound speed (positive) after the corner
    t, v = ex.t_event, up
    while True:
        flight = 2 * v / G
        if t + flight > T:
            s = T - t
            return np.array([vx * (T - ex.t_event), v * s - G * s * s / 2, vx, v - G * s])
        t, v = t + flight, e * v


@pytest.mark.parametrize("path", PATHS)
def test_ball_in_corner_bounces_to_before_its_zeno_time_and_is_refused_past_it(path):
    e = 0.5
    ex = bounces.ball_in_corner(e=e, compiled=path == "compiled")
    t_acc = corner_zeno(ex, e)
    T = t_acc - 1e-4
    traj = ex.system.simulate(ex.x0, T, simultaneity_tol=1e-7)
    assert traj.groups[0].events == (0, 1) and len(traj.groups) >= 6
    np.testing.assert_allclose(traj.x_final, corner_state(ex, e, T), rtol=1e-8, atol=1e-10)
    with pytest.raises(ValueError, match=r"impacts of event 0 accumulate") as err:
        ex.system.simulate(ex.x0, t_acc + 0.2, simultaneity_tol=1e-7)
    assert accumulation_named(str(err.value)) == pytest.approx(t_acc, rel=1e-9)


def _ground_ball(stiffness):
    """A ball with restitution 0.5 on a ground of region 1: a spring-damper with
    ``stiffness`` (it holds the ball), or ``None``: the same free fall (it does not)."""
    def field(x, mask):
        if mask & 1 and stiffness is not None:
            return np.array([x[1], -G - stiffness * x[0] - 20.0 * x[1]])
        return np.array([x[1], -G])

    def field_jacobian(x, mask):
        if mask & 1 and stiffness is not None:
            return np.array([[0.0, 1.0], [-stiffness, -20.0]])
        return np.array([[0.0, 1.0], [0.0, 0.0]])

    def reset(x, mask, k):  # the impact at touchdown only
        return np.array([x[0], -0.5 * x[1]]) if not mask & 1 else x.copy()

    return HybridSystem(field, lambda x: -x[:1], n_events=1, dim=2, reset=reset,
                        field_jacobian=field_jacobian)


def test_the_same_bounces_end_in_a_contact_that_holds_them_or_are_refused():
    """The accumulation is followed to the end where the ground's region holds the ball
    (the last rebound too small to tell lands in it, where it settles at -g / k), and
    refused where that region is the same free fall."""
    k, t_acc = 1e4, zeno_time(0.5, 1.0)
    traj = _ground_ball(k).simulate(np.array([1.0, 0.0]), t_acc + 3.0)
    assert traj.mask_final == 1 and traj.groups[-1].bounced == ()
    assert traj.groups[-1].time == pytest.approx(t_acc, abs=1e-6)
    np.testing.assert_allclose([g.time for g in traj.groups[:8]],
                               impact_times(0.5, 1.0, t_acc)[:8], rtol=1e-10)
    np.testing.assert_allclose(traj.x_final, [-G / k, 0.0], atol=1e-8)
    with pytest.raises(ValueError, match=r"accumulate .* nothing holds the state on the "
                                         r"surface after it"):
        _ground_ball(None).simulate(np.array([1.0, 0.0]), t_acc + 3.0)


def test_accumulation_time_of_geometric_intervals_and_not_of_a_converging_gait():
    from bderiv.models.events.zeno import accumulation_time

    e, height = 0.3, 2.0
    times = impact_times(e, height, np.inf, count=5)
    assert accumulation_time(times) == pytest.approx(zeno_time(e, height), rel=1e-12)
    # steps converging to a period of 1 (deviation halving): no accumulation
    steps = 1.0 + 0.2 * 0.5 ** np.arange(4)
    assert accumulation_time(np.concatenate(([0.0], np.cumsum(steps)))) is None
    # slowly converging to it (deviation shrinking by 0.99 a step: ratios consistent)
    steps = 1.0 + 0.5 * 0.99 ** np.arange(4)
    assert accumulation_time(np.concatenate(([0.0], np.cumsum(steps)))) is None
    # growing intervals (a wheel slowing down) and constant ones (e = 1)
    assert accumulation_time([0.0, 1.0, 2.5, 4.5, 7.0]) is None
    assert accumulation_time([0.0, 1.0, 2.0, 3.0, 4.0]) is None


def test_a_refusal_at_an_accumulation_the_contact_holds_says_what_it_follows():
    """A review: contact_system balls (e = 0.7, 0.9) whose bounces the compliant ground
    holds were refused at the accumulation time as a grazing lift-off (a rebound of 9e-9
    m/s, below what the run resolves; on one integrator or the other, by rounding), the
    message saying nothing of the bounces. The run's refusal now names the accumulation
    (ImpactWatch, shown the closed form's bounces); a model function's own error, and a
    refusal without such bounces, are left as they are."""
    from bderiv.models.events.crossings import EventGroup
    from bderiv.models.events.zeno import ImpactWatch

    system, t_acc = _ground_ball(1e4).calls, zeno_time(0.5, 1.0)
    watch = ImpactWatch(system, t_acc + 3.0)
    refusal = ValueError("transversality violated at t=2.999 before switching events [0]")
    assert watch.explained(refusal) is refusal
    groups = [EventGroup(t, (0,), 0, 0, np.array([0.0, -1.0]), np.array([0.0, 0.5]), None)
              for t in impact_times(0.5, 1.0, t_acc, count=6)]
    watch.see(groups)
    said = watch.explained(refusal)
    assert str(said).startswith(str(refusal))
    assert f"the impacts of event 0, which accumulate at about t={t_acc:.6}" in str(said)
    assert "End the run before" in str(said)
    user = ValueError("the user's own")
    user._bderiv_call = {"t": None}
    assert watch.explained(user) is user
