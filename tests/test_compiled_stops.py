"""The compiled run (models/compiled/_run.py): a compiled model's plain stops decided in
compiled code, with the bits of the stop-by-stop Python loop.

The oracle is the Python loop of models/integrate/run.py on the same compiled stretches
(itself checked against closed forms and the solve_ivp path elsewhere): the compiled run
must record the same trajectory to the bit, hand every stop it cannot decide back to it,
and say nothing else; the closed form of test_excursions' oscillator
check a run whose stops go back and forth between the two.
"""

from __future__ import annotations

import time

import numba
import numpy as np
import pytest
from compiled_models import (
    LONG_RUN,
    apex_section,
    chair_pair,
    ctrl_c_after,
    far_event,
    pronking_pair,
    slow_rotation,
)
from numpy.testing import assert_allclose
from test_excursions import X0, C, T, closed_form

from bderiv import HybridSystem
from bderiv.models.compiled import model as compiled_model
from bderiv.models.integrate import run as run_module


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
def oscillator_field(x, mask):
    """test_excursions' oscillator (its excursions fall inside steps), the clock x[2]."""
    return np.array([x[1], -x[0] - (2.0 if mask & 1 else 0.0), 1.0])


@numba.njit
def oscillator_events(x):
    return np.array([x[0] - C])


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


def test_a_model_without_compiled_event_jacobian_keeps_the_python_stops():
    ex, system = pronking_pair(2)
    field, events = system.compiled.named["field"], system.compiled.named["events"]
    plain = HybridSystem(field, events, n_events=2, dim=4)
    assert plain.compiled.event_jacobian is None
    assert not run_module.compiled_stops(plain, None)
    assert run_module.compiled_stops(system, None) == system.event_jacobian_checked()


def test_stops_handed_back_inside_a_run_against_the_closed_form(monkeypatch):
    """test_excursions' oscillator: its first crossing, inside a step, is searched by the
    Python loop (handed back), the stops after it decided in compiled code; ten crossings
    at the closed form's times, and the same bits as the Python loop alone."""
    system = HybridSystem(oscillator_field, oscillator_events, n_events=1, dim=3,
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


@pytest.mark.parametrize("call", [
    lambda s: s.simulate(np.array([0.66 + 0.05, 0.02, 0.0, 0.0]), 0.9, simultaneity_tol=0.2),
    lambda s: s.simulate(np.array([0.66, 0.0, 0.0, 0.0]), 0.9, max_groups=1),
], ids=["grouped-but-not-at-the-stop", "max_groups"])
def test_refusals_are_the_python_loops(monkeypatch, call):
    """A stop the compiled run refuses is handed back and refused by the Python loop, with
    its message (an event grouped by a large tolerance but not at the stop; a run with more
    groups than max_groups)."""
    _, system = pronking_pair(2)
    system.simulate(np.array([0.66, 0.0, 0.0, 0.0]), 0.9)  # the event Jacobian checked
    fast, slow = both_ways(monkeypatch, system, lambda s: refusal(s, call))
    assert fast == slow


@numba.njit
def far_event_jacobian(x):
    return np.array([[1.0, 0.0]])


def test_ctrl_c_stops_a_long_run_of_compiled_stops_within_a_second():
    system = HybridSystem(slow_rotation, far_event, n_events=1, dim=2,
                          event_jacobian=far_event_jacobian)
    system.simulate(np.array([1.0, 0.0]), 1.0)  # compiled and warm
    assert run_module.compiled_stops(system, None)
    with ctrl_c_after(0.3) as start, pytest.raises(KeyboardInterrupt):
        system.simulate(np.array([1.0, 0.0]), LONG_RUN, max_step=1e-3)
    assert time.perf_counter() - start < 0.3 + 1.0
