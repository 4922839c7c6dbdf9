"""The compiled path end to end (issue 19): a model of numba dispatchers runs every stretch
in compiled code, and agrees with the same model on Python callables.

Oracles: the bundled examples' Python models (``examples.pronking``, ``examples.chair``),
integrated by solve_ivp, against numba twins written again from their formulas
(tests/compiled_models.py); closed forms (the grazing oscillator of test_excursions, a
linear model); the flow map with an analytic Jacobian against the computed ones.
"""

from __future__ import annotations

import io
import math
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
from bderiv.examples.gaits import apex_section as python_apex_section
from bderiv.models.compiled import JACOBIAN_MODES
from bderiv.models.compiled import _slices as slices
from bderiv.models.integrate.run import compiled_stops


def log_of(traj):
    return [(e.event, e.mask, e.direction) for e in traj.events]


def relative(a, b):
    return float(np.abs(a - b).max() / np.abs(b).max())


def agree(python, compiled, x0, t_final, **kw):
    """Both paths' trajectories and flow maps: event logs equal, end states to 1e-8, event
    times to 1e-8, flow maps to 1e-6 relative (and the compiled path ran compiled)."""
    assert compiled.compiled is not None and python.compiled is None
    tp, tc = (s.simulate(x0, t_final, **kw) for s in (python, compiled))
    assert log_of(tc) == log_of(tp) and len(tp.events) > 0
    assert_allclose([e.time for e in tc.events], [e.time for e in tp.events], atol=1e-8)
    assert relative(tc.x_final, tp.x_final) < 1e-8
    Dp, Dc = (s.flow_bderivative(x0, t_final) for s in (python, compiled))
    assert Dc.group_events == Dp.group_events
    V = np.random.default_rng(1).standard_normal((200, x0.size))
    assert relative(Dc(V), Dp(V)) < 1e-6
    return tp, tc


@pytest.mark.parametrize("legs", [2, 3])
@pytest.mark.parametrize("tilt", [0.0, 0.02], ids=["together", "apart"])
def test_pronking_on_both_paths(legs, tilt):
    """k feet land and lift off together (tilt 0: groups of k events) or one by one."""
    ex, compiled = pronking_pair(legs)
    x0 = ex.x0 + np.array([0.0, tilt, 0.0, 0.0])
    tp, _ = agree(ex.system, compiled, x0, 0.9, simultaneity_tol=1e-7)
    sizes = {len(g.events) for g in tp.groups}
    assert sizes == ({legs} if tilt == 0.0 else {1})


def test_chair_on_both_paths():
    ex, compiled = chair_pair()
    agree(ex.system, compiled, ex.x0, ex.t_final, simultaneity_tol=1e-7)


@pytest.mark.parametrize("shift", [-3e-9, 0.0, 3e-9], ids=["before", "at", "after"])
def test_a_group_at_the_final_time_on_both_paths(shift):
    """The chair's touchdown within simultaneity_tol of t_final (finaltime.py): switched just
    before it, or pending just after it; the same map on both paths."""
    ex, compiled = chair_pair()
    t_final = ex.t_event + shift
    Dp, Dc = (s.flow_bderivative(ex.x0, t_final) for s in (ex.system, compiled))
    assert Dc.stops_at_group and Dp.stops_at_group
    V = np.random.default_rng(3).standard_normal((200, 6))
    assert relative(Dc(V), Dp(V)) < 1e-6


A = np.array([[[-0.2, 1.0], [-1.0, -0.2]], [[-0.1, 2.0], [-0.5, 0.0]]])
B = np.array([[0.0, 0.3], [0.5, -1.0]])


@numba.njit
def linear_field(x, mask):
    return A[mask] @ x + B[mask]


@numba.njit
def linear_events(x):
    return np.array([x[0] - 0.4])


def test_linear_model_on_both_paths_and_against_its_closed_form():
    """x' = A_m x + b_m in two regions split by x_0 = 0.4: the closed form flow is
    exp(A t) (x + A^-1 b) - A^-1 b between crossings; the crossings recur."""
    from scipy.linalg import expm

    python = HybridSystem(lambda x, m: A[m] @ x + B[m], lambda x: np.array([x[0] - 0.4]),
                          n_events=1, dim=2, field_jacobian=lambda x, m: A[m])
    compiled = HybridSystem(linear_field, linear_events, n_events=1, dim=2)
    x0 = np.array([0.0, 1.0])
    tp, tc = agree(python, compiled, x0, 12.0, simultaneity_tol=1e-7)
    # the closed form along the compiled run's own crossing times
    x, t, mask = x0, 0.0, 0
    for e in tc.events:
        shift = np.linalg.solve(A[mask], B[mask])
        x = expm(A[mask] * (e.time - t)) @ (x + shift) - shift
        assert abs(x[0] - 0.4) < 1e-9
        t, mask = e.time, e.mask
    shift = np.linalg.solve(A[mask], B[mask])
    assert_allclose(tc.x_final, expm(A[mask] * (12.0 - t)) @ (x + shift) - shift, atol=1e-9)


@numba.njit
def grazing_field(x, mask):
    return np.array([x[1], -x[0] - (2.0 if mask & 1 else 0.0), 1.0])


@numba.njit
def grazing_events(x):
    return np.array([x[0] - C])


def test_excursions_inside_a_step_are_found_in_compiled_code():
    """test_excursions' oscillator: ten crossings inside steps, each one found."""
    x, log = closed_form(X0, T)
    traj = HybridSystem(grazing_field, grazing_events, n_events=1, dim=3).simulate(X0, T)
    assert_allclose([r.time for r in traj.events], log, atol=1e-8)
    assert_allclose(traj.x_final, x, atol=1e-8)


def test_return_map_and_orbit_on_both_paths():
    ex, compiled = pronking_pair(2)
    x0 = ex.x0 + np.array([0.01, 0.01, 0.0, 0.0])
    Rp = ex.system.return_map(x0, python_apex_section, t_max=2.0)
    Rc = compiled.return_map(x0, apex_section, t_max=2.0)
    assert abs(Rc.period - Rp.period) < 1e-9
    V = np.random.default_rng(2).standard_normal((100, 4))
    assert relative(Rc(V), Rp(V)) < 1e-6
    guess = ex.x0 + np.array([0.02, 0.01, 0.0, -0.05])
    op = ex.system.periodic_orbit(guess, python_apex_section, period_guess=0.5)
    oc = compiled.periodic_orbit(guess, apex_section, period_guess=0.5)
    assert_allclose(oc.x0, op.x0, atol=1e-9)
    assert abs(oc.period - op.period) < 1e-9


def test_flow_fd_on_both_paths():
    ex, compiled = pronking_pair(2)
    x0 = ex.x0 + np.array([0.0, 0.01, 0.0, 0.0])
    V = np.eye(4)
    fp, fc = (s.flow_fd(x0, 0.5, V, 1e-6) for s in (ex.system, compiled))
    assert relative(fc, fp) < 1e-6


# --- Jacobians computed in compiled code ------------------------------------------------

@numba.njit
def pendulum(x, mask):
    out = np.empty_like(x)
    out[0] = x[1]
    out[1] = -np.sin(x[0]) - (0.3 if mask & 1 else 0.05) * x[1] + (0.2 if mask & 1 else 0.0)
    return out


@numba.njit
def pendulum_real_only(x, mask):  # np.empty(2): float64 output, no complex version
    out = np.empty(2)
    out[0] = x[1]
    out[1] = -np.sin(x[0]) - (0.3 if mask & 1 else 0.05) * x[1] + (0.2 if mask & 1 else 0.0)
    return out


@numba.njit
def pendulum_abs(x, mask):  # complex-step of abs is wrong: caught, central differences
    out = np.empty_like(x)
    out[0] = x[1]
    out[1] = -np.sin(x[0]) - (0.3 if mask & 1 else 0.05) * np.abs(x[1] + 10.0) + 0.5
    return out


@numba.njit
def pendulum_jacobian(x, mask):
    return np.array([[0.0, 1.0], [-np.cos(x[0]), -(0.3 if mask & 1 else 0.05)]])


@numba.njit
def pendulum_events(x):
    return np.array([x[0] - 0.5])


def test_jacobian_modes_and_their_accuracy_against_the_analytic_jacobian():
    x0, t_final = np.array([0.0, 1.5]), 8.0
    exact = HybridSystem(pendulum, pendulum_events, n_events=1, dim=2,
                         field_jacobian=pendulum_jacobian)
    complex_step = HybridSystem(pendulum, pendulum_events, n_events=1, dim=2)
    central = HybridSystem(pendulum_real_only, pendulum_events, n_events=1, dim=2)
    modes = [JACOBIAN_MODES[s.compiled.jac_mode] for s in (exact, complex_step, central)]
    assert modes == ["given", "complex step", "central differences"]
    V = np.eye(2)
    D = exact.flow_bderivative(x0, t_final)
    assert D.n_groups == 2
    assert relative(complex_step.flow_bderivative(x0, t_final)(V), D(V)) < 1e-8
    assert relative(central.flow_bderivative(x0, t_final)(V), D(V)) < 1e-6


def test_a_wrong_complex_step_falls_back_to_central_differences():
    @numba.njit
    def jac(x, mask):
        return np.array([[0.0, 1.0], [-np.cos(x[0]), -(0.3 if mask & 1 else 0.05)]])

    system = HybridSystem(pendulum_abs, pendulum_events, n_events=1, dim=2)
    exact = HybridSystem(pendulum_abs, pendulum_events, n_events=1, dim=2, field_jacobian=jac)
    assert JACOBIAN_MODES[system.compiled.jac_mode] == "complex step"
    V, x0 = np.eye(2), np.array([0.0, 1.5])
    D = system.flow_bderivative(x0, 8.0)
    assert JACOBIAN_MODES[system.compiled.jac_mode] == "central differences"
    assert relative(D(V), exact.flow_bderivative(x0, 8.0)(V)) < 1e-6


def test_a_wrong_given_jacobian_is_refused():
    @numba.njit
    def wrong(x, mask):
        return np.array([[0.0, 1.0], [np.cos(x[0]), 0.0]])

    system = HybridSystem(pendulum, pendulum_events, n_events=1, dim=2, field_jacobian=wrong)
    with pytest.raises(ValueError, match="field_jacobian does not match field"):
        system.flow_bderivative(np.array([0.0, 1.5]), 1.0)


# --- bad input -------------------------------------------------------------------------

def test_a_mix_is_refused_naming_the_python_function():
    with pytest.raises(TypeError, match="so events must be too"):
        HybridSystem(pendulum, lambda x: np.array([x[0]]), n_events=1, dim=2)
    with pytest.raises(TypeError, match="so field_jacobian must be too"):
        HybridSystem(pendulum, pendulum_events, n_events=1, dim=2,
                     field_jacobian=lambda x, m: np.eye(2))
    ex, compiled = pronking_pair(2)
    with pytest.raises(TypeError, match="so section must be too"):
        compiled.return_map(ex.x0, python_apex_section)
    with pytest.raises(ValueError, match="method must be 'DOP853', got 'RK45'"):
        compiled.simulate(ex.x0, 1.0, method="RK45")


def test_python_field_with_compiled_events_stays_on_the_python_path():
    system = HybridSystem(pendulum.py_func, pendulum_events, n_events=1, dim=2)
    assert system.compiled is None
    assert len(system.simulate(np.array([0.0, 1.5]), 8.0).events) == 2


@numba.njit
def nan_beyond(x, mask):
    return np.array([x[1], math.nan if x[0] > 0.3 else -x[0]])


@numba.njit
def short_field(x, mask):
    return np.array([x[1]])


@numba.njit
def raising(x, mask):
    if x[0] > 0.3:
        raise ZeroDivisionError("the model divides by zero here")
    return np.array([x[1], -x[0]])


@numba.njit
def typo(x, mask):
    return np.array([x[1], -x[0]]) + undefined_name  # noqa: F821


def _closing_over(values):
    return numba.njit(lambda x, mask: np.array([x[1], -x[0]]) * values[0])


@numba.njit
def int_field(x, mask):
    return np.array([1, 2])


@pytest.mark.parametrize("field, error, message", [
    (_closing_over([2.0]), TypeError, r"field does not compile as field\(x, mask\) .*: it "
                                      r"reads the closed-over values = \[2\.0\] \(.*\), a "
                                      r"value numba cannot compile in: close over a NumPy "
                                      r"array, a tuple or a number instead"),
    (int_field, TypeError, r"field must return array\(float64, 1d, C\) \(a C-contiguous "
                           r"float64 array; return a new float64 array .* but returns "
                           r"array\(int64, 1d, C\)"),
    (nan_beyond, ValueError, r"field\(x, mask\) returned a non-finite value, entry \[1\] = "
                             r"nan in region mask 0b0 .* at x = \[0\.3"),
    (short_field, ValueError, r"field\(x, mask\) must return an array of shape \(2,\), got "
                              r"shape \(1,\) in region mask 0b0"),
    (raising, ValueError, r"field\(x, mask\) raised ZeroDivisionError: the model divides "
                          r"by zero here; in region mask 0b0 .* at x = \[0\.3"),
    (typo, TypeError, r"field does not compile as field\(x, mask\) with x float64\[::1\], "
                      r"mask int64"),
], ids=["closed-over list", "int array", "nan", "shape", "raises", "typo"])
def test_bad_compiled_functions_are_named(field, error, message):
    system = HybridSystem(field, linear_events, n_events=1, dim=2)
    with pytest.raises(error, match=message):
        system.simulate(np.array([0.0, 1.0]), 3.0)


@numba.njit
def raising_events(x):
    if x[0] > 0.2:
        raise ValueError("no contact model beyond 0.2")
    return np.array([x[0] - 0.4])


@numba.njit
def raising_jacobian(x, mask):
    if x[0] > 0.2:
        raise ValueError("no Jacobian beyond 0.2")
    return A[mask].copy()


@pytest.mark.parametrize("kind", ["events", "field_jacobian"])
def test_a_compiled_function_that_raises_is_named_with_the_state(kind):
    """An exception raised inside a compiled user function is caught in compiled code,
    with the state: the error names the function, its exception, the region and a state
    past the threshold at which it raised (the stretch started at x = [0, 1])."""
    if kind == "events":
        system = HybridSystem(linear_field, raising_events, n_events=1, dim=2)
        run = system.simulate
    else:
        system = HybridSystem(linear_field, linear_events, n_events=1, dim=2,
                              field_jacobian=raising_jacobian, check_jacobians=False)
        run = system.flow_bderivative
    call = "events\\(x\\)" if kind == "events" else "field_jacobian\\(x, mask\\)"
    with pytest.raises(ValueError, match=rf"{call} raised ValueError: no .* beyond 0\.2; in "
                                         rf"region mask 0b0 .* at x = \[") as info:
        run(np.array([0.0, 1.0]), 3.0)
    assert isinstance(info.value.__cause__, ValueError)
    x0 = float(str(info.value).split("at x = [")[1].split(",")[0])
    assert 0.2 < x0 < 0.4  # where it raised: past its threshold, before the event


def test_the_integrators_compilation_is_announced_once(caplog):
    """The driver's or the compiled run's compilation (a miss of the disk cache: numba's
    compile event) logs one warning per process; another function's does not."""
    from numba.core import event

    from bderiv.models.compiled import model as compiled_model
    from bderiv.models.compiled._integrate import drive_stretch
    from bderiv.models.compiled._run import run_stretches

    notice = compiled_model.COMPILE_NOTICE
    said, notice.said = notice.said, False
    try:
        with caplog.at_level("WARNING", logger="bderiv"):
            for dispatcher in (linear_field, run_stretches, drive_stretch):
                data = {"dispatcher": dispatcher, "args": (), "return_type": None}
                with event.trigger_event("numba:compile", data=data):
                    pass
    finally:
        notice.said = said
    notices = [r.getMessage() for r in caplog.records if "compiling the compiled" in
               r.getMessage()]
    assert notices == ["bderiv: compiling the compiled integrator for this machine (once: "
                       "about one to two minutes; later runs load it from numba's disk "
                       "cache)"]


@numba.njit
def nan_after_the_event(x, mask):
    return np.array([x[1], math.nan if mask else -x[0]])


def test_a_bad_field_at_a_stop_is_named():
    """The field of the region after a group is first evaluated at the stop (the
    transversality check after switching), checked in compiled code: the error names the
    function, the region and the state, as the driver's do."""
    system = HybridSystem(nan_after_the_event, linear_events, n_events=1, dim=2)
    with pytest.raises(ValueError, match=r"field\(x, mask\) returned a non-finite value, "
                                         r"entry \[1\] = nan in region mask 0b1 .* at x = "
                                         r"\[0\.4"):
        system.simulate(np.array([0.0, 1.0]), 3.0)


# --- slices of steps and Ctrl-C --------------------------------------------------------

def test_a_stretch_in_slices_takes_the_same_steps(monkeypatch):
    ex, compiled = pronking_pair(2)
    x0 = ex.x0 + np.array([0.0, 0.01, 0.0, 0.0])
    whole = compiled.flow_bderivative(x0, 0.9)
    traj = compiled.simulate(x0, 0.9)
    monkeypatch.setattr(slices, "SLICE_SECONDS", 0.0)  # one step per call of the driver
    monkeypatch.setattr(slices, "_cost", {})
    monkeypatch.setattr(slices, "FIRST_SLICE", 1)
    calls = []
    drive = slices.drive_stretch
    monkeypatch.setattr(slices, "drive_stretch", lambda *a: calls.append(1) or drive(*a))
    sliced = compiled.simulate(x0, 0.9)
    assert len(calls) > 40
    np.testing.assert_array_equal(sliced.t, traj.t)
    np.testing.assert_array_equal(sliced.x, traj.x)
    V = np.eye(4)
    np.testing.assert_array_equal(compiled.flow_bderivative(x0, 0.9)(V), whole(V))


def test_ctrl_c_stops_a_long_compiled_run_within_a_second(monkeypatch):
    """The run's stops in compiled code (the event Jacobian by complex step): the compiled
    run hands the stretch back when its step budget is spent, and the Python loop's driver
    calls (slices of steps) see the interrupt. Between the slices the run's bar of the
    simulated time moves, as on scipy's path (it was drawn only there)."""
    from bderiv._support import _progress

    pytest.importorskip("tqdm")
    system = HybridSystem(slow_rotation, far_event, n_events=1, dim=2)
    system.simulate(np.array([1.0, 0.0]), 1.0)  # compiled and warm
    assert compiled_stops(system.calls, None)
    buffer = io.StringIO()
    monkeypatch.setattr(_progress, "BAR_DELAY", 0.05)
    monkeypatch.setattr(_progress, "BAR_OPTIONS",
                        {"file": buffer, "disable": False, "leave": True})
    with ctrl_c_after(0.5) as start, pytest.raises(KeyboardInterrupt):
        system.simulate(np.array([1.0, 0.0]), LONG_RUN, max_step=1e-3)
    assert time.perf_counter() - start < 0.5 + 1.0
    last = buffer.getvalue().split("\r")[-1]
    assert last.startswith("simulate: ") and f"of {LONG_RUN:.4g} [" in last, last
    assert float(last.split("t = ")[1].split(" of")[0]) > 0  # it moved


def test_a_stopped_batch_stops_a_stretch_as_such():
    """A run of a stopped batch ends its stretch at the next slice with ``Cancelled``
    (the batch's own signal), not as an error of the model's functions: before, the
    stretch's catch-all said "a compiled function of the model raised Cancelled", a
    ValueError that a batch would have reported as that run's failure."""
    import threading

    from bderiv.models.compiled import Cancelled, stopped_by

    system = HybridSystem(slow_rotation, far_event, n_events=1, dim=2)
    system.simulate(np.array([1.0, 0.0]), 1.0)  # compiled and warm
    stop = threading.Event()
    stop.set()
    with stopped_by(stop), pytest.raises(Cancelled):
        system.calls.compiled.stretch(np.array([1.0, 0.0]), 0.0, LONG_RUN, 0, rtol=1e-6,
                                      atol=1e-9, max_step=1e-3, variational=False)


# --- resets that land back (crossings.landing), on the compiled path -------------------

GRAVITY, RESTITUTION = 9.81, 0.8


@numba.njit
def ball_field(x, mask):
    return np.array([x[1], -GRAVITY])


@numba.njit
def ball_events(x):
    return np.array([-x[0]])


@numba.njit
def ball_reset(x, mask, k):
    return np.array([x[0], -RESTITUTION * x[1]])


def test_a_bouncing_ball_on_both_paths_and_against_its_closed_form():
    """Each impact reverses the velocity (times e): the ball leaves the ground, the bit
    stays clear (a bounce), and the next impact is again upward for h = -height."""
    python = HybridSystem(ball_field.py_func, ball_events.py_func, n_events=1, dim=2,
                          reset=ball_reset.py_func)
    compiled = HybridSystem(ball_field, ball_events, n_events=1, dim=2, reset=ball_reset)
    x0, t_final = np.array([1.0, 0.0]), 2.5
    _, tc = agree(python, compiled, x0, t_final, simultaneity_tol=1e-7)
    assert all(g.bounced == (0,) and g.mask_after == 0 for g in tc.groups)
    assert [e.direction for e in tc.events] == [1] * len(tc.events)
    # closed form: the first fall, then flights of 2 e^j v / g
    v = math.sqrt(2.0 * GRAVITY)
    times = [v / GRAVITY]
    while times[-1] + 2 * RESTITUTION ** len(times) * v / GRAVITY < t_final:
        times.append(times[-1] + 2 * RESTITUTION ** len(times) * v / GRAVITY)
    assert_allclose([e.time for e in tc.events], times, atol=1e-9)
    up, dt = RESTITUTION ** len(times) * v, t_final - times[-1]
    assert_allclose(tc.x_final, [up * dt - 0.5 * GRAVITY * dt**2, up - GRAVITY * dt],
                    atol=1e-9)


def test_the_repr_of_a_compiled_model_says_how_it_runs():
    """Before its first run the functions are not checked yet; after it, how J and the
    event Jacobian are had and whether the stops are compiled (a Python event_jacobian
    keeps them in Python, and says so)."""
    compiled = HybridSystem(linear_field, linear_events, n_events=1, dim=2)
    assert repr(compiled) == ("HybridSystem(n_events=1, dim=2, compiled: functions checked "
                              "at the first use)")
    compiled.simulate(np.array([0.0, 1.0]), 1.0)
    # A[mask] @ x does not compile for a complex x: central differences
    assert repr(compiled) == ("HybridSystem(n_events=1, dim=2, compiled: field_jacobian: "
                              "central differences; event_jacobian: complex step; stops: "
                              "compiled)")
    python_jac = HybridSystem(linear_field, linear_events, n_events=1, dim=2,
                              event_jacobian=lambda x: np.array([[1.0, 0.0]]))
    python_jac.simulate(np.array([0.0, 1.0]), 1.0)
    assert repr(python_jac).endswith("event_jacobian: Python; stops: in Python "
                                     "(event_jacobian is not compiled for float64[::1] -> "
                                     "float64[:, ::1], or events do not compile for complex "
                                     "input))")
