"""HybridSystem.simulate_many: a batch of start states, each run exactly as simulate's."""

from __future__ import annotations

import itertools
import math
import threading
import time

import numba
import numpy as np
import pytest
from compiled_models import LONG_RUN, ctrl_c_after, far_event, pronking_pair, slow_rotation

from bderiv import HybridSystem, examples
from bderiv.models.compiled import HANDOFF, CompiledModel
from bderiv.models.compiled import model as compiled_model
from bderiv.models.integrate import many


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


def test_progress_callback_after_each_run_and_the_bar(bars_drawn):
    ex = examples.chair()
    X0 = starts(ex.x0, 3, 1e-3)
    seen = []
    ex.system.simulate_many(X0, ex.t_final, progress=lambda done, total: seen.append(
        (done, total)))
    assert seen == [(1, 3), (2, 3), (3, 3)]
    ex.system.simulate_many(X0, ex.t_final)  # the default: a bar once it lasts
    text = bars_drawn.getvalue()
    assert "simulate_many: " in text and "3 of 3 runs" in text
    assert "simulate: " not in text  # the batch's bar only, not its runs'


def test_ctrl_c_stops_a_long_compiled_batch_within_a_second(monkeypatch):
    """One thread: the run Ctrl-C lands in stops too (the threaded batch: further down)."""
    monkeypatch.setattr(many, "worker_count", lambda m: 1)
    system = HybridSystem(slow_rotation, far_event, n_events=1, dim=2)
    system.simulate(np.array([1.0, 0.0]), 1.0)  # compiled and warm
    X0 = np.tile([1.0, 0.0], (3, 1))  # each run: 1e7 steps
    with ctrl_c_after(0.3) as start, pytest.raises(KeyboardInterrupt):
        system.simulate_many(X0, LONG_RUN, max_step=1e-3)
    assert time.perf_counter() - start < 0.3 + 1.0


# --- a compiled model's batch on threads ------------------------------------------------

@pytest.fixture
def three_threads(monkeypatch):
    """Batches on three threads whatever the cores (threads also interleave on one core);
    the names of the threads each run was made on are collected."""
    monkeypatch.setattr(many, "worker_count", lambda m: max(1, min(m, 3)))
    seen, real_run = [], many.run

    def run(*args, **kwargs):
        seen.append(threading.current_thread().name)
        return real_run(*args, **kwargs)

    monkeypatch.setattr(many, "run", run)
    return seen


def worker_threads():
    return [t for t in threading.enumerate() if t.name.startswith("bderiv.simulate_many")]


def wait_for_workers(seconds):
    """Wait until the batch's threads have ended (their runs going stop at a slice's end)."""
    for thread in worker_threads():
        thread.join(seconds)
    return not worker_threads()


def mixed_starts(x0, m, seed=4):
    """Pronking starts: the even ones tilted (the feet land apart), the odd ones level
    (both feet together)."""
    rng = np.random.default_rng(seed)
    X0 = np.tile(x0, (m, 1))
    X0[:, [0, 2]] += 1e-3 * rng.standard_normal((m, 2))
    X0[::2, [1, 3]] += 1e-3 * rng.standard_normal(((m + 1) // 2, 2))
    return X0


def test_threaded_batch_is_a_loop_of_simulate_to_the_bit(three_threads, monkeypatch):
    codes, real = [], CompiledModel.run_stretches

    def counted(self, *args, **kwargs):
        out = real(self, *args, **kwargs)
        codes.append(None if out is None else int(out[0]))
        return out

    monkeypatch.setattr(CompiledModel, "run_stretches", counted)
    calls = itertools.count()  # every other compiled run hands its stretch back after 5 steps
    monkeypatch.setattr(compiled_model, "slice_budget",
                        lambda key: 5 if next(calls) % 2 else 10**6)
    ex, system = pronking_pair(2, fresh=True)  # a fresh model: its first run goes alone
    X0 = mixed_starts(ex.x0, 24)
    seen = []
    runs = system.simulate_many(X0, ex.t_final, simultaneity_tol=1e-7,
                                progress=lambda done, total: seen.append(
                                    (done, total, threading.current_thread().name)))
    assert HANDOFF in codes and codes.count(HANDOFF) < len(codes)  # both kinds of stop
    assert three_threads[0] == "MainThread"  # the first run alone, the others on threads
    assert all(name.startswith("bderiv.simulate_many") for name in three_threads[1:])
    assert seen == [(i, 24, "MainThread") for i in range(1, 25)]
    assert not worker_threads()
    for x0, traj in zip(X0, runs, strict=True):
        alone = system.simulate(x0, ex.t_final, simultaneity_tol=1e-7)
        same_run(traj, alone)
        assert [g.events for g in traj.groups] == [g.events for g in alone.groups]
    np.testing.assert_array_equal(runs.x_final, [traj.x_final for traj in runs])
    assert {len(traj.groups) for traj in runs} == {1, 2}  # together, and apart


def test_a_warm_model_runs_the_whole_batch_on_threads(three_threads):
    ex, system = pronking_pair(2)
    system.simulate(ex.x0, ex.t_final)  # its event Jacobian checked at the first stop
    X0 = mixed_starts(ex.x0, 6, seed=5)
    runs = system.simulate_many(X0, ex.t_final, simultaneity_tol=1e-7)
    assert len(three_threads) == 6
    assert all(name.startswith("bderiv.simulate_many") for name in three_threads)
    for x0, traj in zip(X0, runs, strict=True):
        same_run(traj, system.simulate(x0, ex.t_final, simultaneity_tol=1e-7))


def test_a_python_model_and_one_without_compiled_event_jacobian_stay_in_this_thread(
        three_threads):
    ex = examples.chair()
    ex.system.simulate_many(starts(ex.x0, 3, 1e-3), ex.t_final)
    ex2, twin = pronking_pair(2)
    plain = HybridSystem(twin.compiled.named["field"], twin.compiled.named["events"],
                         n_events=2, dim=4)
    plain.simulate_many(starts(ex2.x0, 3, 1e-3), ex2.t_final)
    assert three_threads == ["MainThread"] * 6


@numba.njit
def late_failure(x, mask):
    """Moves along x[0]; raises past x[0] = 2.5 when the flag x[1] is set."""
    if x[0] > 2.5 and x[1] > 0.5:
        raise ZeroDivisionError("the model divides by zero here")
    return np.array([1.0, 0.0])


@numba.njit
def stripes(x):
    return np.array([math.sin(3.0 * x[0])])


@numba.njit
def stripes_jacobian(x):
    J = np.zeros((1, 2))
    J[0, 0] = 3.0 * math.cos(3.0 * x[0])
    return J


def test_a_threaded_batch_raises_the_first_failing_run_in_order(three_threads):
    """Run 5 fails late (after three crossings), run 9 at once (it starts on the surface):
    the error is run 5's, as the loop raises it, whichever thread failed first."""
    system = HybridSystem(late_failure, stripes, n_events=1, dim=2,
                          event_jacobian=stripes_jacobian)
    X0 = np.column_stack((np.linspace(0.1, 0.2, 16), np.zeros(16)))
    X0[5, 1] = 1.0
    X0[9, 0] = 0.0  # sin(0) = 0: on the surface
    system.simulate(X0[0], 3.0)
    with pytest.raises(ValueError, match=r"the run from X0\[5\] = \[0\.1333.* 1\. *\]: "
                                         r"field\(x, mask\) raised ZeroDivisionError"):
        system.simulate_many(X0, 3.0)
    assert wait_for_workers(60.0)
    with pytest.raises(ValueError, match=r"the run from X0\[7\] = .*x0 lies on"):
        system.simulate_many(np.delete(X0, 5, axis=0)[1:], 3.0)  # run 9 is now 7
    assert wait_for_workers(60.0)


@numba.njit
def far_event_jacobian(x):
    return np.array([[1.0, 0.0]])


def test_ctrl_c_stops_a_threaded_batch_within_a_second(monkeypatch):
    """Two threads, sixteen runs of 1e7 steps each (seconds): Ctrl-C returns at once, no run
    starts after it, and the two runs going stop at their next slice of steps."""
    monkeypatch.setattr(many, "worker_count", lambda m: 2)
    starts, real_run = [], many.run

    def run(*args, **kwargs):
        starts.append(time.perf_counter())
        return real_run(*args, **kwargs)

    monkeypatch.setattr(many, "run", run)
    system = HybridSystem(slow_rotation, far_event, n_events=1, dim=2,
                          event_jacobian=far_event_jacobian, check_jacobians=False)
    system.simulate(np.array([1.0, 0.0]), 1.0)  # compiled and warm
    X0 = np.tile([1.0, 0.0], (16, 1))
    with ctrl_c_after(0.3) as start, pytest.raises(KeyboardInterrupt):
        system.simulate_many(X0, LONG_RUN, max_step=1e-3)  # seconds a run
    stopped = time.perf_counter()
    assert stopped - start < 0.3 + 1.0
    assert wait_for_workers(1.0)  # the runs going stopped too
    assert 2 <= len(starts) < 16 and max(starts) < stopped


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


# -- the batch's memory ---------------------------------------------------------------------

def test_a_batch_too_large_is_refused_before_its_start_states_are_copied():
    """10**10 start states (a broadcast view: no memory of its own) would take terabytes of
    runs: refused by a ValueError that says so, before X0 is copied (numpy's MemoryError
    came out of the copy), whatever the record."""
    import tracemalloc

    ex = examples.chair()
    X0 = np.broadcast_to(ex.x0, (10**10, ex.system.dim))
    for t_eval, samples in ((None, 2), ((), 0), ([0.05, 0.1], 2)):
        tracemalloc.start()
        try:
            with pytest.raises(ValueError, match=rf"^the 10000000000 runs of simulate_many "
                                                 rf"\(at least [\d.]+ [KM]?i?B a run: its final "
                                                 rf"state and {samples} samples; .*\) would take "
                                                 rf"[\d.]+ [TP]iB, more than the memory limit "
                                                 rf"of .*: pass fewer start states at a time "
                                                 rf"\(the batch in chunks.*t_eval=\(\)"):
                ex.system.simulate_many(X0, ex.t_final, t_eval=t_eval)
        finally:
            peak = tracemalloc.get_traced_memory()[1]
            tracemalloc.stop()
        assert peak < 1 << 20


def test_a_batch_that_grows_too_large_is_refused_as_its_runs_finish(monkeypatch):
    """What the runs hold is counted as they finish: 20000 runs of the chair keep about
    2 KiB each (every step, the groups), twice the floor checked up front, so with 32 MiB
    left the batch is refused after its first run, by the projection of what is left
    (it went on, run after run, until memory was gone: 28 KiB a run of the compiled
    pronking gait, 28 GB for 10**6 runs)."""
    from bderiv._support import _validate

    ex = examples.chair()
    monkeypatch.setattr(_validate, "memory_headroom", lambda: 32 << 20)
    done = []

    def progress(count, total):
        done.append(count)
        assert count < 3, "the batch went on"

    X0 = np.broadcast_to(ex.x0, (20_000, ex.system.dim))
    with pytest.raises(ValueError, match=r"^simulate_many's batch \(1 of 20000 runs done, "
                                         r"about [\d.]+ KiB a run\) holds [\d.]+ KiB and going "
                                         r"on needs about [\d.]+ MiB more, but the process may "
                                         r"take only 32.0 MiB .*: pass fewer start states"):
        ex.system.simulate_many(X0, ex.t_final, progress=progress)
    assert done == []
    # a run's own bytes: its samples, groups and final state
    run = ex.system.simulate(ex.x0, ex.t_final)
    assert many.run_bytes(run) > run.t.nbytes + run.x.nbytes + run.masks.nbytes + 500 * len(
        run.groups)
    # the small batches of use are not checked against the memory at all (under 1 MiB)
    assert len(ex.system.simulate_many(X0[:3], ex.t_final, progress=False)) == 3


def test_a_batch_on_threads_that_grows_too_large_is_refused_and_its_threads_end(monkeypatch):
    """The check as runs finish holds on the threads' path too: with room for the first
    runs' checks and then 16 MiB, 20000 runs of the compiled pronking gait (about 2.6 KiB
    each: 50 MiB) are refused by the calling thread, and no worker thread is left
    running."""
    from bderiv._support import _validate

    ex, system = pronking_pair(2)
    X0 = starts(ex.x0, 20_000, 1e-3, seed=3)
    system.simulate_many(X0[:4], ex.t_final, progress=False)  # compiled, Jacobian checked
    assert many.threaded(system.calls)
    reads = []

    def room():
        reads.append(1)
        return 10**9 if len(reads) < 7 else 16 << 20

    monkeypatch.setattr(_validate, "memory_headroom", room)
    done = []

    def progress(count, total):
        done.append(count)
        assert count < 200, "the batch went on"

    with pytest.raises(ValueError, match=r"^simulate_many's batch \(\d+ of 20000 runs done"):
        system.simulate_many(X0, ex.t_final, progress=progress)
    assert 0 < len(done) < 100
    deadline = time.monotonic() + 5.0
    while time.monotonic() < deadline and any(
            t.name.startswith("bderiv.simulate_many") for t in threading.enumerate()):
        time.sleep(0.05)
    assert not any(t.name.startswith("bderiv.simulate_many") for t in threading.enumerate())


def test_each_run_of_a_batch_has_its_own_sample_times():
    """A review: on the compiled run every run's Trajectory.t was a view of one array
    (t_eval's rows), so shifting one run's times moved every run's. Each run's are its
    own, as on the Python loop."""
    ex, system = pronking_pair(2)
    system.simulate(ex.x0, 0.9)  # the first stop checks the event Jacobian: compiled after
    X0 = np.array([ex.x0, ex.x0 + 1e-3])
    times = np.linspace(0.0, 0.9, 10)
    runs = system.simulate_many(X0, 0.9, t_eval=times)
    runs[0].t[:] += 100.0
    np.testing.assert_array_equal(runs[1].t, times)
    np.testing.assert_array_equal(times, np.linspace(0.0, 0.9, 10))
    alone = system.simulate(ex.x0, 0.9, t_eval=times)
    alone.t[:] += 1.0
    np.testing.assert_array_equal(times, np.linspace(0.0, 0.9, 10))


def test_a_ragged_nest_of_starts_or_vectors_is_named():
    """NumPy's "setting an array element with a sequence" named no argument (a review)."""
    ex, system = pronking_pair(2)
    ragged = [list(ex.x0), list(ex.x0[:3])]
    with pytest.raises(ValueError, match="X0 must be an array, or a nest of lists of equal "
                                         "lengths, got a ragged nest"):
        system.simulate_many(ragged, 0.9)
    D = system.flow_bderivative(ex.x0, 0.9)
    for call in (D, D.orders, D.event_times, D.apply_orders):
        with pytest.raises(ValueError, match="V must be an array, or a nest of lists"):
            call(ragged)
