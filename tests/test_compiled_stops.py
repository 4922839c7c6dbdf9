"""The compiled run (models/compiled/_run.py): a compiled model's plain stops decided in
compiled code, with the bits of the stop-by-stop Python loop.

The oracle is the Python loop of models/integrate/run.py on the same compiled stretches
(itself checked against closed forms and the solve_ivp path elsewhere): the compiled run
must record the same trajectory to the bit, hand every stop it cannot decide back to it,
and say nothing else; the closed form of test_excursions' oscillator
check a run whose stops go back and forth between the two.
"""

from __future__ import annotations

import numba
import numpy as np
import pytest
from compiled_models import apex_section, chair_pair, pronking_pair
from numpy.testing import assert_allclose
from test_compiled_path import (  # test_excursions' oscillator, a bouncing ball
    GRAVITY,
    RESTITUTION,
    ball_events,
    ball_field,
    ball_reset,
    grazing_events,
    grazing_field,
)
from test_excursions import X0, C, T, closed_form

from bderiv import HybridSystem
from bderiv.models.compiled import EVENT_JAC_COMPLEX_STEP, EVENT_JAC_NONE
from bderiv.models.compiled import model as compiled_model
from bderiv.models.events import locate
from bderiv.models.integrate import run as run_module

locate_tightened = locate.tightened


def python_stops(monkeypatch):
    """Every stop decided by the Python loop from now on (the compiled run not used)."""
    monkeypatch.setattr(run_module, "compiled_stops", lambda system, section: False)


def same_trajectory(a, b):
    """Two trajectories equal to the bit, groups and sensitivities included."""
    for name in ("t", "x", "masks", "x_final"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    assert a.events == b.events and a.mask_final == b.mask_final
    assert len(a.groups) == len(b.groups) and len(a.linear) == len(b.linear)
    for g, h in zip(a.groups, b.groups, strict=True):
        assert (g.time, g.events, g.mask_before, g.mask_after) == \
            (h.time, h.events, h.mask_before, h.mask_after)
        np.testing.assert_array_equal(g.state, h.state)
        np.testing.assert_array_equal(g.state_after, h.state_after)
        if g.event_jacobian is None:
            assert h.event_jacobian is None
        else:
            np.testing.assert_array_equal(g.event_jacobian, h.event_jacobian)
    for p, q in zip(a.linear, b.linear, strict=True):
        np.testing.assert_array_equal(p, q)


def both_ways(monkeypatch, system, run):
    """``run(system)`` with the compiled run, then with the Python loop alone."""
    fast = run(system)
    with monkeypatch.context() as m:
        python_stops(m)
        slow = run(system)
    return fast, slow


@numba.njit
def oscillator_event_jacobian(x):
    return np.array([[1.0, 0.0, 0.0]])


def models():
    """``(name, system, x0, t_final)`` of compiled models with a compiled event Jacobian."""
    out = []
    for legs in (2, 3):
        ex, system = pronking_pair(legs)
        for tilt in (0.0, 0.02):
            out.append((f"pronking{legs}-tilt{tilt}", system,
                        ex.x0 + np.array([0.0, tilt, 0.0, 0.0]), 0.9))
    ex, system = chair_pair()
    out.append(("chair", system, ex.x0, ex.t_final))
    for shift in (-3e-9, 0.0, 3e-9):  # a group within simultaneity_tol of t_final
        out.append((f"chair-final{shift}", system, ex.x0, ex.t_event + shift))
    return out


MODELS = models()


@pytest.mark.parametrize("case", MODELS, ids=[m[0] for m in MODELS])
def test_the_compiled_stops_give_the_python_loops_bits(monkeypatch, case):
    _, system, x0, t_final = case
    for kw in ({"simultaneity_tol": 1e-7}, {"simultaneity_tol": 0.0}):
        fast, slow = both_ways(monkeypatch, system, lambda s, kw=kw: s.simulate(x0, t_final, **kw))
        same_trajectory(fast, slow)
    # samples at given times, on the dense output of the stretch that holds each: times
    # at the start, inside stretches, at the groups and at the final time
    times = np.unique(np.r_[0.0, np.linspace(0.0, t_final, 23)[1:-1],
                            [g.time for g in fast.groups], t_final])
    for t_eval in (times, ()):
        fast, slow = both_ways(monkeypatch, system,
                               lambda s, t_eval=t_eval: s.simulate(x0, t_final, t_eval=t_eval))
        same_trajectory(fast, slow)
    fast, slow = both_ways(monkeypatch, system, lambda s: s.flow_bderivative(x0, t_final))
    V = np.random.default_rng(0).standard_normal((50, x0.size))
    np.testing.assert_array_equal(fast(V), slow(V))
    assert fast.group_events == slow.group_events


def counting(monkeypatch):
    """Count the calls of the compiled run and the Python loop's stretches from now on."""
    calls = {"compiled": 0, "python": 0}

    def counted(name, fn):
        def call(*args, **kwargs):
            calls[name] += 1
            return fn(*args, **kwargs)
        return call

    monkeypatch.setattr(compiled_model.CompiledModel, "run_stretches",
                        counted("compiled", compiled_model.CompiledModel.run_stretches))
    monkeypatch.setattr(run_module, "_python_stretch",
                        counted("python", run_module._python_stretch))
    return calls


def test_a_plain_run_is_one_compiled_call(monkeypatch):
    """Two pronking strides (touchdowns and lift-offs of both feet together): one call of
    the compiled run and no stretch of the Python loop, once the event Jacobian is
    checked."""
    ex, system = pronking_pair(2)
    system.simulate(ex.x0, 0.9)  # the first stop checks the given event Jacobian
    calls = counting(monkeypatch)
    traj = system.simulate(ex.x0, 0.9, simultaneity_tol=1e-7)
    assert [len(g.events) for g in traj.groups] == [2, 2, 2, 2]
    assert calls == {"compiled": 1, "python": 0}
    # samples at given times, or none, are taken in the same call
    for t_eval in (np.linspace(0.0, 0.9, 7), ()):
        calls.update(compiled=0, python=0)
        system.simulate(ex.x0, 0.9, t_eval=t_eval)
        assert calls == {"compiled": 1, "python": 0}


@numba.njit
def tilted_events(x):
    """Events written for any dtype (complex input: complex step)."""
    out = np.empty(2, dtype=x.dtype)
    out[0] = x[0] - 1.0 + 0.1 * np.sin(x[1])
    out[1] = x[0] + 0.2 * x[1] ** 2 - 1.5
    return out


@numba.njit
def tilted_event_jacobian(x):
    return np.array([[1.0, 0.1 * np.cos(x[1]), 0.0], [1.0, 0.4 * x[1], 0.0]])


@numba.njit
def tilted_field(x, mask):
    """Carried across both surfaces (x[0] grows), a region's rates its own."""
    return np.array([1.0 + 0.2 * (mask & 1), 0.5 + 0.3 * (mask >> 1 & 1), -0.1 * x[0]])


def test_without_a_given_event_jacobian_its_complex_step_is_compiled(monkeypatch):
    """Events that compile for complex input and no ``event_jacobian``: the Jacobian is
    their complex step in compiled code (the analytic one to rounding), checked once, and
    the stops are compiled, with the Python loop's bits and the given Jacobian's map."""
    given = HybridSystem(tilted_field, tilted_events, n_events=2, dim=3,
                         event_jacobian=tilted_event_jacobian)
    system = HybridSystem(tilted_field, tilted_events, n_events=2, dim=3)
    assert system.compiled.event_jac_mode == EVENT_JAC_COMPLEX_STEP
    x = np.array([0.3, -0.7, 2.0])
    assert_allclose(system.calls.eval_event_jacobian(x), tilted_event_jacobian(x), rtol=1e-14,
                    atol=1e-15)
    assert system.calls.event_jacobian_checked() and run_module.compiled_stops(system.calls, None)
    x0 = np.zeros(3)
    fast, slow = both_ways(monkeypatch, system, lambda s: s.flow_bderivative(x0, 3.0))
    assert fast.group_events == given.flow_bderivative(x0, 3.0).group_events
    assert len(fast.group_events) == 2
    V = np.random.default_rng(4).standard_normal((20, 3))
    np.testing.assert_array_equal(fast(V), slow(V))
    assert_allclose(fast(V), given.flow_bderivative(x0, 3.0)(V), rtol=1e-12, atol=1e-12)


@numba.njit
def kinked_events(x):
    """Not complex-analytic: ``conj`` is the identity on reals, and its complex step -1."""
    return np.array([np.conj(x[0]) - C])


@numba.njit
def python_event_jacobian_field(x, mask):
    return np.array([x[1], -x[0], 1.0])


def test_events_that_are_not_complex_analytic_keep_the_python_stops():
    system = HybridSystem(grazing_field, kinked_events, n_events=1, dim=3)
    assert system.compiled.event_jac_mode == EVENT_JAC_COMPLEX_STEP
    J = system.calls.eval_event_jacobian(np.array([0.5, 0.2, 0.0]))  # checked: wrong, numerical
    assert_allclose(J, [[1.0, 0.0, 0.0]], atol=1e-8)
    assert system.compiled.event_jac_mode == EVENT_JAC_NONE
    assert not run_module.compiled_stops(system.calls, None)
    traj = system.simulate(X0, T)
    x, log = closed_form(X0, T)
    assert_allclose([r.time for r in traj.events], log, atol=1e-8)


def test_a_users_function_that_keeps_the_python_stops_is_named(caplog, monkeypatch):
    """A compiled model whose reset or event_jacobian is a Python function, or whose
    events are not complex-analytic, had every stop in the Python loop: 10-20x slower per
    run, silently (a ball's two walls: 1.9 against 0.1 ms). Said at WARNING, with what to
    compile, once per model's functions (a review: a copy with other parameters, as a
    sweep makes, said it again); nothing when the stops are compiled."""
    from bderiv.models.compiled import _notice

    monkeypatch.setattr(_notice, "_TOLD", set())  # what other tests' models were told

    def python_reset(x, mask, k):
        return np.array([x[0], -RESTITUTION * x[1]])

    cases = [({"reset": ball_reset}, None),
             ({"reset": python_reset}, "its reset is not compiled"),
             ({"reset": ball_reset, "event_jacobian": lambda x: np.array([[-1.0, 0.0]])},
              "its event_jacobian is not compiled")]
    for kwargs, words in cases:
        caplog.clear()
        with caplog.at_level("WARNING", logger="bderiv"):
            system = HybridSystem(ball_field, ball_events, n_events=1, dim=2, **kwargs)
            system.simulate(np.array([1.0, 0.0]), 1.0)
            system.simulate(np.array([1.0, 0.0]), 1.0)
            again = HybridSystem(ball_field, ball_events, n_events=1, dim=2, **kwargs)
            again.simulate(np.array([1.0, 0.0]), 1.0)
        said = [r.getMessage() for r in caplog.records if "Python loop" in r.getMessage()]
        if words is None:
            assert said == []
        else:
            assert len(said) == 1 and words in said[0] and "numba.njit" in said[0]
    caplog.clear()
    with caplog.at_level("WARNING", logger="bderiv"):
        HybridSystem(grazing_field, kinked_events, n_events=1, dim=3).simulate(X0, 0.5)
    assert any("not complex-analytic" in r.getMessage() and "Python loop" in r.getMessage()
               for r in caplog.records)


def test_a_python_event_jacobian_keeps_the_python_stops():
    system = HybridSystem(python_event_jacobian_field, grazing_events, n_events=1, dim=3,
                          event_jacobian=lambda x: np.array([[1.0, 0.0, 0.0]]))
    assert system.compiled.event_jac_mode == EVENT_JAC_NONE
    assert not run_module.compiled_stops(system.calls, None)


def test_stops_handed_back_inside_a_run_against_the_closed_form(monkeypatch):
    """test_excursions' oscillator: its first crossing, inside a step, is searched by the
    Python loop (handed back), the stops after it decided in compiled code; ten crossings
    at the closed form's times, and the same bits as the Python loop alone."""
    system = HybridSystem(grazing_field, grazing_events, n_events=1, dim=3,
                          event_jacobian=oscillator_event_jacobian)
    system.simulate(X0, 1.0)  # the event Jacobian checked
    with monkeypatch.context() as m:
        calls = counting(m)
        fast = system.simulate(X0, T)
    assert calls["python"] >= 1 and calls["compiled"] >= 2  # handed back, and on again
    with monkeypatch.context() as m:
        python_stops(m)
        slow = system.simulate(X0, T)
    same_trajectory(fast, slow)
    x, log = closed_form(X0, T)
    assert_allclose([r.time for r in fast.events], log, atol=1e-8)
    assert_allclose(fast.x_final, x, atol=1e-8)


def test_undecided_events_are_settled_in_compiled_code(monkeypatch):
    """Both feet land at once, and with simultaneity_tol 0 the other foot's time at the stop
    is known worse than the tolerance: the stretch is integrated again, tighter, until it
    is decided (locate.settle), in compiled code; the Python loop's bits."""
    ex, system = pronking_pair(2)
    system.flow_bderivative(ex.x0, 0.9)  # checked Jacobians
    with monkeypatch.context() as m:
        calls = counting(m)
        fast = system.flow_bderivative(ex.x0, 0.9, simultaneity_tol=0.0)
    assert calls["python"] == 0
    tightened = []
    with monkeypatch.context() as m:
        python_stops(m)
        m.setattr(locate, "tightened", lambda o: tightened.append(o) or locate_tightened(o))
        slow = system.flow_bderivative(ex.x0, 0.9, simultaneity_tol=0.0)
    assert tightened  # the Python loop integrated a stretch again: the case is the test's
    assert fast.group_events == slow.group_events
    V = np.random.default_rng(7).standard_normal((20, 4))
    np.testing.assert_array_equal(fast(V), slow(V))


def test_the_return_map_and_orbit_with_compiled_stops(monkeypatch):
    ex, system = pronking_pair(2)
    x0 = ex.x0 + np.array([0.01, 0.01, 0.0, 0.0])
    fast, slow = both_ways(monkeypatch, system,
                           lambda s: s.return_map(x0, apex_section, t_max=2.0))
    assert fast.period == slow.period
    V = np.random.default_rng(2).standard_normal((20, 4))
    np.testing.assert_array_equal(fast(V), slow(V))
    guess = ex.x0 + np.array([0.02, 0.01, 0.0, -0.05])
    fast, slow = both_ways(monkeypatch, system,
                           lambda s: s.periodic_orbit(guess, apex_section, period_guess=0.5))
    np.testing.assert_array_equal(fast.x0, slow.x0)


def refusal(system, call):
    with pytest.raises((ValueError, RuntimeError)) as info:
        call(system)
    return type(info.value), str(info.value)


def test_refusals_are_the_python_loops(monkeypatch):
    """A stop the compiled run refuses is handed back and refused by the Python loop, with
    its message (a run with more groups than max_groups)."""
    _, system = pronking_pair(2)
    system.simulate(np.array([0.66, 0.0, 0.0, 0.0]), 0.9)  # the event Jacobian checked
    call = lambda s: s.simulate(np.array([0.66, 0.0, 0.0, 0.0]), 0.9, max_groups=1)  # noqa: E731
    fast, slow = both_ways(monkeypatch, system, lambda s: refusal(s, call))
    assert fast == slow


def test_events_within_the_tolerance_but_apart_are_switched_alike(monkeypatch):
    """Touchdowns apart but within a large simultaneity_tol: each switched at its own time,
    by the compiled run as by the Python loop, to the bit."""
    _, system = pronking_pair(2)
    run = lambda s: s.simulate(np.array([0.71, 0.02, 0.0, 0.0]), 0.9,  # noqa: E731
                               simultaneity_tol=0.2)
    fast, slow = both_ways(monkeypatch, system, run)
    same_trajectory(fast, slow)
    assert [g.events for g in fast.groups][:2] in ([(0,), (1,)], [(1,), (0,)])


# --- resets in the compiled run --------------------------------------------------------

def test_a_bouncing_ball_in_one_compiled_call(monkeypatch):
    """Each impact sends the ball back up (a bounce: the bit stays clear): the compiled
    run applies the reset and decides where it lands, with the Python loop's bits and the
    closed form's impact times (the first fall, then flights of 2 e^j v / g)."""
    system = HybridSystem(ball_field, ball_events, n_events=1, dim=2, reset=ball_reset)
    x0, t_final = np.array([1.0, 0.0]), 2.5
    system.simulate(x0, t_final)  # the event Jacobian (complex step) checked
    assert run_module.compiled_stops(system.calls, None)
    with monkeypatch.context() as m:
        calls = counting(m)
        fast = system.simulate(x0, t_final)
    assert calls == {"compiled": 1, "python": 0}
    with monkeypatch.context() as m:
        python_stops(m)
        slow = system.simulate(x0, t_final)
    same_trajectory(fast, slow)
    assert all(g.bounced == (0,) for g in fast.groups)
    v = np.sqrt(2.0 * GRAVITY)
    times = [v / GRAVITY]
    while times[-1] + 2 * RESTITUTION ** len(times) * v / GRAVITY < t_final:
        times.append(times[-1] + 2 * RESTITUTION ** len(times) * v / GRAVITY)
    assert len(fast.groups) == len(times) == 4
    assert_allclose([e.time for e in fast.events], times, atol=1e-9)
    fast_map, slow_map = both_ways(monkeypatch, system,
                                   lambda s: s.flow_bderivative(x0, t_final))
    V = np.random.default_rng(5).standard_normal((20, 2))
    np.testing.assert_array_equal(fast_map(V), slow_map(V))


def test_the_landing_with_resets_compiled(monkeypatch):
    """examples.impacts.landing(compiled=True): two feet land together, their resets stop
    the sliding (plastic); trajectory, groups and flow map as the Python loop's."""
    from bderiv.examples.impacts import landing

    ex = landing(compiled=True)
    system = ex.system
    assert system.compiled.reset is not None
    system.simulate(ex.x0, ex.t_final)
    assert run_module.compiled_stops(system.calls, None)
    fast, slow = both_ways(monkeypatch, system,
                           lambda s: s.simulate(ex.x0, ex.t_final, simultaneity_tol=1e-7))
    same_trajectory(fast, slow)
    assert [g.events for g in fast.groups][:1] == [(0, 1)]
    fast, slow = both_ways(monkeypatch, system, lambda s: s.flow_bderivative(ex.x0, ex.t_final))
    V = np.random.default_rng(6).standard_normal((20, 10))
    np.testing.assert_array_equal(fast(V), slow(V))


@numba.njit
def pair_field(x, mask):
    return np.array([1.0 + 0.0 * x[0], 1.0 + 0.0 * x[0], 0.0 * x[0]])


@numba.njit
def pair_events(x):
    return np.array([x[0] - 1.0, x[1] - 1.0])


@numba.njit
def clashing_reset(x, mask, k):
    """Resets that do not commute: event 0 doubles x[2], event 1 adds one to it."""
    y = x.copy()
    y[2] = 2.0 * x[2] if k == 0 else x[2] + 1.0
    return y


def test_resets_that_do_not_commute_are_refused_as_by_the_python_loop(monkeypatch):
    system = HybridSystem(pair_field, pair_events, n_events=2, dim=3, reset=clashing_reset)
    system.simulate(np.array([0.0, 0.5, 1.0]), 0.9)  # the event Jacobian checked
    call = lambda s: s.simulate(np.array([0.0, 0.0, 1.0]), 2.0, simultaneity_tol=1e-7)  # noqa: E731
    fast, slow = both_ways(monkeypatch, system, lambda s: refusal(s, call))
    assert fast == slow and "do not commute" in fast[1]
