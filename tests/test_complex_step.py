"""A Python model without Jacobians is not silently slow (users' fourth pass, item 1).

A missing Jacobian is had by the complex step where the user's function takes complex input
and the step matches a central difference at its first use (per function and mask), else
by central differences; a build that spends most of its time in numerical Jacobians says
so at WARNING with their real count and time. Oracles: the chair's Jacobians written out
by hand (its example), closed forms.
"""

from __future__ import annotations

import logging
import math

import numba
import numpy as np
import pytest

from bderiv import HybridSystem, _limits, complex_step_jacobian, examples
from bderiv.models import numerical_jacobians as jacobians_module


@pytest.fixture(scope="module")
def chair():
    return examples.chair()


def bare(system, field=None, events=None):
    """The model's own Python functions, no Jacobians given."""
    return HybridSystem(field or system.field, events or system.events, n_events=2, dim=6)


def test_a_complex_analytic_field_gets_its_jacobian_by_the_complex_step(chair):
    model = bare(chair.system)
    D = model.flow_bderivative(chair.x0, chair.t_final)
    jacobians, calls, _ = model.numerical_jacobian_cost["field_jacobian"]
    # d = 6 calls a Jacobian, and one check by central differences per region (2 here)
    assert calls <= 6 * jacobians + 2 * 120, (jacobians, calls)
    exact = chair.system.flow_bderivative(chair.x0, chair.t_final)  # hand-written Jacobians
    V = np.random.default_rng(0).standard_normal((16, 6))
    np.testing.assert_allclose(D(V), exact(V), rtol=1e-10, atol=1e-10 * np.abs(exact(V)).max())


def _float_only(field):
    """``field`` written into a float array: it does not take complex input."""
    def out(x, mask):
        y = np.zeros(6)
        y[:] = field(x, mask)
        return y
    return out


def _not_analytic(field):
    """``field`` of the real part of the state: takes complex input, wrong complex step."""
    return lambda x, mask: field(np.real(x), mask)


@pytest.mark.parametrize("wrap", [_float_only, _not_analytic], ids=["float-only", "not-analytic"])
def test_a_field_without_a_usable_complex_step_gets_central_differences(chair, wrap, caplog):
    model = bare(chair.system, field=wrap(chair.system.field))
    with caplog.at_level(logging.INFO, logger="bderiv"):
        D = model.flow_bderivative(chair.x0, chair.t_final)
    jacobians, calls, _ = model.numerical_jacobian_cost["field_jacobian"]
    assert calls >= 4 * 6 * jacobians  # 4 or more calls per variable: central differences
    assert any("field_jacobian not given: computing it by central differences" in r.message
               for r in caplog.records)
    exact = chair.system.flow_bderivative(chair.x0, chair.t_final)
    V = np.random.default_rng(1).standard_normal((16, 6))
    np.testing.assert_allclose(D(V), exact(V), rtol=1e-6, atol=1e-6 * np.abs(exact(V)).max())


def test_a_build_mostly_in_numerical_jacobians_says_so_once(chair, caplog, monkeypatch):
    monkeypatch.setattr(jacobians_module, "SLOW_BUILD_SECONDS", 0.0)  # every build counts
    model = bare(chair.system, field=_float_only(chair.system.field))
    with caplog.at_level(logging.WARNING, logger="bderiv"):
        model.flow_bderivative(chair.x0, chair.t_final)
        jacobians, calls, _ = model.numerical_jacobian_cost["field_jacobian"]
        model.flow_bderivative(chair.x0, chair.t_final)
    warned = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert len(warned) == 1, warned  # once per model and method
    # the real count of the build (the cost counted)
    assert f"field_jacobian: {jacobians:,} Jacobians, {calls:,} calls" in warned[0]
    assert "flow_bderivative took" in warned[0] and "central differences" in warned[0]
    assert "bderiv.complex_step_jacobian" in warned[0]
    assert "write its functions with numba (@numba.njit)" in warned[0]  # Python functions
    quick = bare(chair.system)  # the complex step: the build is no longer mostly Jacobians
    monkeypatch.setattr(jacobians_module, "SLOW_BUILD_SECONDS", 1e9)
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="bderiv"):
        quick.flow_bderivative(chair.x0, chair.t_final)
    assert not caplog.records


def test_complex_step_jacobian_closed_form():
    J = complex_step_jacobian(lambda y: np.array([y[0] * np.sin(y[1]), np.exp(y[0] * y[1]),
                                                  y[1] ** 3]), [2.0, 0.5])
    expected = [[np.sin(0.5), 2.0 * np.cos(0.5)], [0.5 * np.exp(1.0), 2.0 * np.exp(1.0)],
                [0.0, 0.75]]
    np.testing.assert_allclose(J, expected, rtol=1e-15)
    # tiny and huge coordinates: the step follows |x_j|
    J = complex_step_jacobian(lambda y: np.array([y[0] ** 2 + 3.0 * y[1]]), [1e-100, 1e100])
    np.testing.assert_allclose(J, [[2e-100, 3.0]], rtol=1e-15)


def test_complex_step_jacobian_of_a_function_that_reuses_its_output():
    """A function that fills and returns one buffer at every call (the last call's values
    are all a stacked output would hold) gets every column; and one of three outputs from
    two coordinates (m != d)."""
    buf = np.empty(3, dtype=np.complex128)

    def fun(y):
        buf[0], buf[1], buf[2] = y[0] * y[1], y[0] ** 2, np.sin(y[1])
        return buf

    J = complex_step_jacobian(fun, [2.0, 3.0])
    np.testing.assert_allclose(J, [[3.0, 2.0], [4.0, 0.0], [0.0, np.cos(3.0)]], rtol=1e-15)
    assert J.flags.c_contiguous and J.dtype == np.float64


def test_complex_step_jacobian_refuses_a_function_without_complex_input():
    with pytest.raises(TypeError, match=r"fun does not take complex input \(it raised "
                                        r"(ComplexWarning|TypeError)"):
        complex_step_jacobian(lambda y: np.array([math.sin(y[0])]), [1.0])
    with pytest.raises(ValueError, match=r"x must be a finite 1-d array"):
        complex_step_jacobian(lambda y: y, [np.nan])
    with pytest.raises(ValueError, match=r"fun must return a 1-d array, got shape \(\)"):
        complex_step_jacobian(lambda y: y[0], [1.0])


def _compile_starts(name):
    """A list whose length counts numba's compilations (attempts too) of functions named
    ``name`` from now on, and the listener to unregister."""
    from numba.core import event

    starts = []

    class Count(event.Listener):
        def on_start(self, ev):
            if ev.data["dispatcher"].py_func.__name__ == name:
                starts.append(ev.data["dispatcher"])

        def on_end(self, ev):
            pass

    listener = Count()
    event.register("numba:compile", listener)
    return starts, listener


@pytest.mark.parametrize("python", [True, False])
def test_the_slow_build_warning_points_python_models_to_numba(python, caplog, monkeypatch):
    """Models of numba functions are on the compiled path already: only Python ones are
    told of it."""
    monkeypatch.setattr(jacobians_module, "SLOW_BUILD_SECONDS", 0.0)
    numerical = jacobians_module.NumericalJacobians()
    with caplog.at_level(logging.WARNING, logger="bderiv"):
        with numerical.watch("flow_bderivative", python=python):
            numerical._cost["field_jacobian"] = [3, 30, 1.0]  # all the build's time
    (message,) = [r.getMessage() for r in caplog.records]
    assert ("@numba.njit" in message) is python, message


def test_a_numba_model_on_scipy_gets_its_jacobian_by_the_complex_step(monkeypatch, caplog):
    """A numba model's field on the scipy path (while the integrator compiles, or as here
    under BDERIV_INTEGRATOR=scipy) gets the complex state as complex128, the version the
    compiled path compiles for its complex step: its Jacobian by the complex step, not
    by central differences under a message that blamed the field."""
    from numba.core import event

    monkeypatch.setenv("BDERIV_INTEGRATOR", "scipy")
    compiled = examples.chair(compiled=True).system
    model = HybridSystem(compiled.field, compiled.events, n_events=2, dim=6)
    ex = examples.chair()
    with caplog.at_level(logging.INFO, logger="bderiv"):
        D = model.flow_bderivative(ex.x0, ex.t_final)
    assert model.calls.compiled is None  # the run went on scipy
    assert any("field_jacobian not given: computing it by complex step" in r.message
               for r in caplog.records)
    jacobians, calls, _ = model.numerical_jacobian_cost["field_jacobian"]
    assert calls <= 6 * jacobians + 2 * 120, (jacobians, calls)
    exact = ex.system.flow_bderivative(ex.x0, ex.t_final)  # hand-written Jacobians
    V = np.random.default_rng(2).standard_normal((16, 6))
    np.testing.assert_allclose(D(V), exact(V), rtol=1e-10, atol=1e-10 * np.abs(exact(V)).max())

    # a field whose complex version does not compile: central differences, and numba tries
    # to compile that version once, not at every Jacobian
    @numba.njit
    def float_only_field(x, mask):
        y = np.zeros(x.size)
        for i in range(x.size):
            y[i] = x[i] * (1.0 + mask)
        return y

    @numba.njit
    def one_event(x):
        return np.array([x[0] - 1.0])

    starts, listener = _compile_starts("float_only_field")
    try:
        plain = HybridSystem(float_only_field, one_event, n_events=1, dim=2)
        with caplog.at_level(logging.INFO, logger="bderiv"):
            F = plain.flow_bderivative(np.array([0.5, 0.0]), 1.0)
    finally:
        event.unregister("numba:compile", listener)
    assert len(starts) == 2, starts  # float64, then complex128 once
    assert any("field_jacobian not given: computing it by central differences" in r.message
               for r in caplog.records)
    # x' = x before x0 = 1, 2 x after: x0(1) = e^2 x0^2, x1(1) = e^2 x0 x1 (x0 = 0.5, x1 = 0)
    np.testing.assert_allclose(F(np.eye(2)), [[np.e ** 2, 0.0], [0.0, np.e ** 2 / 2]],
                               rtol=1e-7)

    # a second model of the same functions does not try the complex version again
    starts, listener = _compile_starts("float_only_field")
    try:
        HybridSystem(float_only_field, one_event, n_events=1, dim=2).flow_bderivative(
            np.array([0.5, 0.0]), 1.0)
    finally:
        event.unregister("numba:compile", listener)
    assert starts == [], starts


def _drag(x, mask):
    """Falling against quadratic drag: |v| v is not complex-analytic, and at v = 0 its
    complex step (0) and its derivative (0) agree."""
    return np.array([x[1], -1.0 - 0.3 * np.abs(x[1]) * x[1]])


def _drag_jacobian(x, mask):
    return np.array([[0.0, 1.0], [0.0, -0.6 * abs(x[1])]])


def _floor(x):
    return np.array([x[0] + 5.0])


def test_a_complex_step_that_matches_only_where_it_starts_is_not_trusted():
    """The complex step is held to central differences at the first state of each region
    and beside it: from rest, the drag's complex step matched at v = 0 and was 16 % wrong
    along the fall. Compiled, the flow map is now that of the hand-written Jacobian; in
    Python, where central differences cannot resolve |v| v at rest to the accuracy they
    need, the build says so instead of answering wrong."""
    x0 = np.array([1.0, 0.0])
    exact = HybridSystem(_drag, _floor, n_events=1, dim=2, field_jacobian=_drag_jacobian,
                         event_jacobian=lambda x: np.array([[1.0, 0.0]]))
    E = exact.flow_bderivative(x0, 2.0)(np.eye(2))
    compiled = HybridSystem(numba.njit(_drag), numba.njit(_floor), n_events=1, dim=2)
    D = compiled.flow_bderivative(x0, 2.0)
    assert compiled.calls.compiled is not None  # the compiled path's check
    np.testing.assert_allclose(D(np.eye(2)), E, rtol=1e-6, atol=1e-6 * np.abs(E).max())
    with pytest.raises(ValueError, match=r"field\(x, mask=0b1\) .* not accurate enough"
                                         r".*pass field_jacobian"):
        HybridSystem(_drag, _floor, n_events=1, dim=2).flow_bderivative(x0, 2.0)


def _field_complex_on_one_side(x, mask):
    """Takes complex input where x0 > 0.5 only (math.sin refuses it on the other side).
    Continuous at x0 = 0.5 (its Jacobian has a kink there): a jump of the field inside a
    region would add a saltation that no Jacobian holds, and the flow map of the
    hand-written Jacobian would not be the flow's (the compiled path's central
    differences, straddling the jump, caught it)."""
    if x[0].real > 0.5:
        return np.array([x[1], -x[0]])
    return np.array([x[1], -math.sin(x[0]) + (math.sin(0.5) - 0.5)])


def _hand_written_flow_map(x0, T):
    """The flow map of :func:`_field_complex_on_one_side` with its Jacobian written out
    (a matrix whose rows are the images of the unit vectors)."""
    exact = HybridSystem(
        _field_complex_on_one_side, lambda x: np.array([x[0] + 5.0]), n_events=1, dim=2,
        field_jacobian=lambda x, mask: np.array(
            [[0.0, 1.0], [-1.0 if x[0] > 0.5 else -math.cos(x[0]), 0.0]]),
        event_jacobian=lambda x: np.array([[1.0, 0.0]]))
    return exact.flow_bderivative(x0, T)(np.eye(2))


@pytest.mark.parametrize("compile_it", [False, True], ids=["python", "numba-python-first"])
def test_a_complex_step_that_fails_later_gives_way_to_central_differences(
        compile_it, monkeypatch, caplog):
    """A complex step decided at the first state and refused at a later one: central
    differences from there, and the flow map of the hand-written Jacobian (it returned no
    Jacobian, and scipy's step failed on it)."""
    monkeypatch.setenv("BDERIV_INTEGRATOR", "auto")  # a numba model starts on Python code
    field, events = _field_complex_on_one_side, (lambda x: np.array([x[0] + 5.0]))
    if compile_it:
        field, events = numba.njit(field), numba.njit(lambda x: np.array([x[0] + 5.0]))
    x0 = np.array([1.0, 0.0])
    with caplog.at_level(logging.INFO, logger="bderiv"):
        D = HybridSystem(field, events, n_events=1, dim=2).flow_bderivative(x0, 2.0)
    E = _hand_written_flow_map(x0, 2.0)
    np.testing.assert_allclose(D(np.eye(2)), E, rtol=1e-6, atol=1e-6 * np.abs(E).max())
    assert any("central differences from now on" in r.getMessage() for r in caplog.records)


@pytest.mark.parametrize("seconds", [1e-3, 0.05])
def test_a_model_compiled_during_its_run_gives_the_same_flow_map(seconds, monkeypatch):
    """The numba model of the test above, its time on Python code cut so that it is
    compiled before or during its run (a loaded machine does this at 1 s): the compiled
    path's central differences give the hand-written Jacobian's flow map too."""
    monkeypatch.setenv("BDERIV_INTEGRATOR", "auto")
    monkeypatch.setattr(_limits, "PYTHON_FIRST_SECONDS", seconds)
    x0 = np.array([1.0, 0.0])
    D = HybridSystem(numba.njit(_field_complex_on_one_side),
                     numba.njit(lambda x: np.array([x[0] + 5.0])), n_events=1,
                     dim=2).flow_bderivative(x0, 2.0)
    E = _hand_written_flow_map(x0, 2.0)
    np.testing.assert_allclose(D(np.eye(2)), E, rtol=1e-6, atol=1e-6 * np.abs(E).max())


def test_a_damaged_cache_of_the_complex_version_is_not_taken_for_a_refusal(monkeypatch):
    """The complex step passes on the error that names a damaged disk cache (the compiled
    path raises it too), instead of falling back to central differences under a message
    that blames the function."""
    from bderiv._support import _numdiff
    from bderiv._support._errors import DamagedCacheError
    from bderiv.models.compiled import _checks
    from bderiv.models.user_functions import _contiguous_args

    @numba.njit
    def float_only(x):
        y = np.zeros(x.size)
        for i in range(x.size):
            y[i] = x[i]
        return y

    monkeypatch.setattr(_checks, "damaged_entry", lambda fn, args: "its index is damaged")
    with pytest.raises(DamagedCacheError, match="float_only .*its index is damaged"):
        _numdiff.complex_step(_contiguous_args(float_only), np.array([1.0, 2.0]), 2)


def _pendulum(x, mask):
    """Analytic, started at rest at angle 0: a state with zero components."""
    return np.array([x[1], np.cos(x[0]) - 0.5])


@pytest.mark.parametrize("policy", ["scipy", "compiled"])
def test_an_analytic_field_from_rest_keeps_its_complex_step(policy, monkeypatch, caplog):
    """The complex step is held to central differences beside the first state, at least
    half of NEAR of each variable's scale away and along the first state's scales: with a
    variable that is 0 there (a body at rest) 2e-5 beside it and the differences along its
    own scale there, they lost 1e-5 to rounding, and a right complex step was taken for a
    wrong one (central differences, 5x the calls, 1e-10 off; a second review)."""
    monkeypatch.setenv("BDERIV_INTEGRATOR", policy)
    event = numba.njit(lambda x: np.array([x[0] - 0.5]))
    model = HybridSystem(numba.njit(_pendulum), event, n_events=1, dim=2)
    with caplog.at_level(logging.INFO, logger="bderiv"):
        D = model.flow_bderivative(np.zeros(2), 3.0)
    messages = " ".join(r.getMessage() for r in caplog.records)
    assert "central differences" not in messages, messages
    exact = HybridSystem(_pendulum, lambda x: np.array([x[0] - 0.5]), n_events=1, dim=2,
                         field_jacobian=lambda x, mask: np.array([[0.0, 1.0],
                                                                  [-np.sin(x[0]), 0.0]]),
                         event_jacobian=lambda x: np.array([[1.0, 0.0]]))
    E = exact.flow_bderivative(np.zeros(2), 3.0)(np.eye(2))
    np.testing.assert_allclose(D(np.eye(2)), E, rtol=1e-12, atol=1e-12 * np.abs(E).max())


@pytest.mark.parametrize("field", [_pendulum, lambda x, mask: np.array([x[1], abs(x[0])]),
                                   lambda x, mask: np.array([float(x[1]), x[0]])],
                         ids=["complex-step", "central-differences", "refused-at-once"])
def test_the_cost_counts_every_call_of_the_field_the_jacobians_made(field):
    """The calls of the checks that choose the method (a central difference at the first
    state, a complex step and a difference beside it) count in the cost, as those of the
    Jacobians do, and a complex step refused at its first call counts one call, not d:
    the cost's calls are the field's calls, counted here."""
    calls = []

    def counted(x, mask):
        calls.append(1)
        return field(x, mask)

    model = HybridSystem(counted, lambda x: np.array([x[0] - 0.5]), n_events=1, dim=2,
                         event_jacobian=lambda x: np.array([[1.0, 0.0]]))
    for x in (np.array([0.3, -0.2]), np.array([0.4, 0.1]), np.array([0.2, 0.5])):
        model.calls.eval_field_jacobian(x, 0)
    jacobians, counted_calls, _ = model.numerical_jacobian_cost["field_jacobian"]
    assert jacobians == 3
    assert counted_calls == len(calls), (counted_calls, len(calls))
