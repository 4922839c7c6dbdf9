"""HybridSystem.simulate_many: a batch of start states, each run exactly as simulate's."""

from __future__ import annotations

import io
import time

import numpy as np
import pytest
from compiled_models import LONG_RUN, ctrl_c_after, far_event, pronking_pair, slow_rotation

from bderiv import HybridSystem, _progress, examples


def same_run(a, b):
    """Two trajectories are the same to the bit: samples, masks, event log, groups."""
    np.testing.assert_array_equal(a.t, b.t)
    np.testing.assert_array_equal(a.x, b.x)
    np.testing.assert_array_equal(a.masks, b.masks)
    np.testing.assert_array_equal(a.x_final, b.x_final)
    assert a.events == b.events and a.mask_final == b.mask_final
    assert [(g.time, g.events, g.mask_before, g.mask_after) for g in a.groups] == \
        [(g.time, g.events, g.mask_before, g.mask_after) for g in b.groups]


def starts(x0, m, spread, seed=0):
    return x0 + spread * np.random.default_rng(seed).standard_normal((m, x0.size))


def test_python_model_batch_is_a_loop_of_simulate():
    ex = examples.chair()
    X0 = starts(ex.x0, 6, 1e-3).reshape(2, 3, -1)
    runs = ex.system.simulate_many(X0, ex.t_final, simultaneity_tol=1e-9, rtol=1e-9)
    assert len(runs) == 6 and runs.x_final.shape == (2, 3, 6) and runs.mask_final.shape == (2, 3)
    for i, x0 in enumerate(X0.reshape(-1, 6)):
        alone = ex.system.simulate(x0, ex.t_final, simultaneity_tol=1e-9, rtol=1e-9)
        same_run(runs[i], alone)
        np.testing.assert_array_equal(runs.x_final.reshape(-1, 6)[i], alone.x_final)
        assert runs.mask_final.reshape(-1)[i] == alone.mask_final
    assert sum(len(r.events) for r in runs) > 0  # the runs cross events


def test_compiled_model_batch_is_a_loop_of_simulate():
    ex, system = pronking_pair(2)
    X0 = starts(ex.x0, 5, 1e-3, seed=1)
    runs = system.simulate_many(X0, ex.t_final, simultaneity_tol=1e-7)
    assert [traj is not None for traj in runs] == [True] * 5
    for x0, traj in zip(X0, runs, strict=True):
        same_run(traj, system.simulate(x0, ex.t_final, simultaneity_tol=1e-7))
    assert all(len(traj.events) for traj in runs)


def test_one_state_and_an_empty_batch():
    ex = examples.chair()
    one = ex.system.simulate_many(ex.x0, ex.t_final)
    assert len(one) == 1 and one.x_final.shape == (6,) and one.mask_final.shape == ()
    same_run(one[0], ex.system.simulate(ex.x0, ex.t_final))
    none = ex.system.simulate_many(np.empty((0, 6)), ex.t_final)
    assert len(none) == 0 and none.x_final.shape == (0, 6)


@pytest.mark.parametrize("X0, message", [
    (np.zeros((3, 5)), r"X0 must have shape \(\.\.\., 6\) \(start states.*got shape \(3, 5\)"),
    (1.0, r"X0 must have shape .*got a scalar"),
    (np.array([[0.0] * 6, [0.0, np.nan, 0, 0, 0, 0]]), r"X0 must be finite, but vector X0\[1\]"),
])
def test_bad_start_states_are_named(X0, message):
    ex = examples.chair()
    with pytest.raises(ValueError, match=message):
        ex.system.simulate_many(X0, ex.t_final)


def test_bad_settings_are_refused_before_any_run():
    ex = examples.chair()
    with pytest.raises(TypeError, match="X0"):
        ex.system.simulate_many("abc", ex.t_final)
    with pytest.raises(ValueError, match="t_final"):
        ex.system.simulate_many(starts(ex.x0, 2, 1e-3), -1.0)
    with pytest.raises(ValueError, match="simultaneity_tol"):
        ex.system.simulate_many(starts(ex.x0, 2, 1e-3), 1.0, simultaneity_tol=np.nan)


def test_a_failed_run_names_its_start_state():
    F = np.array([[1.0, 0.0], [1.0, 0.0]])
    s = HybridSystem(lambda x, mask: F[mask], lambda x: x[:1] - 1.0, n_events=1, dim=2)
    X0 = np.array([[0.0, 0.0], [1.0, 0.0]])  # the second starts on the surface
    with pytest.raises(ValueError, match=r"the run from X0\[1\] = \[1. 0.\]: x0 lies on"):
        s.simulate_many(X0, 2.0)


def test_progress_callback_after_each_run_and_the_bar(monkeypatch):
    ex = examples.chair()
    X0 = starts(ex.x0, 3, 1e-3)
    seen = []
    ex.system.simulate_many(X0, ex.t_final, progress=lambda done, total: seen.append(
        (done, total)))
    assert seen == [(1, 3), (2, 3), (3, 3)]
    pytest.importorskip("tqdm")
    buffer = io.StringIO()
    monkeypatch.setattr(_progress, "SIMULATION_BAR_DELAY", 0.0)
    monkeypatch.setattr(_progress, "SIMULATION_BAR_REFRESH", 0.0)
    monkeypatch.setattr(_progress, "SIMULATION_BAR",
                        {"file": buffer, "disable": False, "leave": True})
    ex.system.simulate_many(X0, ex.t_final)  # the default: a bar once it lasts
    assert "simulate_many: " in buffer.getvalue() and "3 of 3 runs" in buffer.getvalue()


def test_ctrl_c_stops_a_long_compiled_batch_within_a_second():
    system = HybridSystem(slow_rotation, far_event, n_events=1, dim=2)
    system.simulate(np.array([1.0, 0.0]), 1.0)  # compiled and warm
    X0 = np.tile([1.0, 0.0], (3, 1))  # each run: 1e7 steps
    with ctrl_c_after(0.3) as start, pytest.raises(KeyboardInterrupt):
        system.simulate_many(X0, LONG_RUN, max_step=1e-3)
    assert time.perf_counter() - start < 0.3 + 1.0


def test_flow_fd_is_the_difference_of_simulations():
    ex = examples.chair()
    V = np.random.default_rng(2).standard_normal((3, 6))
    eps, tol = 1e-6, 1e-13
    FD = ex.system.flow_fd(ex.x0, ex.t_final, V, eps, simultaneity_tol=tol)
    options = {"simultaneity_tol": tol, "rtol": 1e-12, "atol": 1e-13}  # checks.FD_OPTIONS
    base = ex.system.simulate(ex.x0, ex.t_final, **options).x_final
    for v, fd in zip(V, FD, strict=True):
        moved = ex.system.simulate(ex.x0 + eps * v, ex.t_final, **options).x_final
        np.testing.assert_array_equal(fd, (moved - base) / eps)
