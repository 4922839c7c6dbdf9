"""A new model of numba functions starts on their Python code (``BDERIV_INTEGRATOR=auto``):
its first answers come without compiling them, and after ``PYTHON_FIRST_SECONDS`` of runs
or when their Python code raises, the runs go on the compiled functions
(:mod:`bderiv.models.calls`, docs/design.md "Python first").

The oracle of each answer on Python code is the same model's answer on the compiled
integrator (a model compiled from its first use, policy ``compiled``): the compiled path is
checked against independent simulations elsewhere (test_compiled_path).
"""

from __future__ import annotations

import logging

import numba
import numpy as np
import pytest

from bderiv import HybridSystem, _limits
from bderiv.models import calls, python_first, readiness

X0 = np.array([0.0, 0.2])
T_FINAL = 2.0
V = np.random.default_rng(0).standard_normal((16, 2))


def only_compiled(x):
    """Stands for what numba compiles and Python refuses (a numba-only construct)."""
    raise NotImplementedError("this runs compiled only")


@numba.extending.overload(only_compiled)
def _only_compiled(x):
    return lambda x: x


def _functions(compiled_only=False):
    """A new model's functions: a field that bends at one event, freshly decorated (no
    signature compiled, no disk cache)."""

    def field(x, mask):
        out = np.empty_like(x)  # complex for complex x: the complex step
        out[0] = 1.0 + 0.0 * x[0]
        out[1] = 0.5 * x[0] - (1.0 + mask) * x[1]
        if compiled_only:
            out[0] = only_compiled(out[0])
        return out

    def events(x):
        return np.array([x[0] - 1.0])

    return numba.njit(field), numba.njit(events)


def _model(functions):
    field, events = functions
    return HybridSystem(field, events, n_events=1, dim=2)


@pytest.fixture
def auto(monkeypatch):
    monkeypatch.setenv(readiness.POLICY_VARIABLE, "auto")


def _compiled_answer():
    """The oracle: the same model compiled from its first use (policy ``compiled``)."""
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv(readiness.POLICY_VARIABLE, "compiled")
        model = _model(_functions())
        assert not model.calls.python_first
        D = model.flow_bderivative(X0, T_FINAL)
        assert model.compiled is not None
        return D(V)


def test_a_new_model_answers_on_its_python_code_without_compiling(auto):
    functions = _functions()
    model = _model(functions)
    assert model.calls.python_first
    D = model.flow_bderivative(X0, T_FINAL)
    assert model.calls.python_first and model.compiled is None
    assert all(f.signatures == [] for f in functions)  # nothing of the model compiled
    assert np.allclose(D(V), _compiled_answer(), rtol=1e-9, atol=1e-12)


def test_its_runs_go_compiled_once_their_time_is_spent(auto, monkeypatch, caplog):
    monkeypatch.setattr(_limits, "PYTHON_FIRST_SECONDS", 1e-4)  # spent in the first run
    caplog.set_level(logging.INFO, logger="bderiv")
    functions = _functions()
    model = _model(functions)
    D = model.flow_bderivative(X0, T_FINAL)
    assert not model.calls.python_first and model.compiled is not None
    assert functions[0].signatures  # compiled now
    assert "took 0.0001 s" in caplog.text
    assert np.allclose(D(V), _compiled_answer(), rtol=1e-9, atol=1e-12)


def test_on_scipy_after_its_python_code_the_jacobians_are_right(auto, monkeypatch):
    """Compiled while the integrator is not ready (its runs then go on scipy through the
    dispatchers, which take float input): a complex step decided on the Python code is
    decided again (it read the dispatchers' float casts: Jacobians of zero, a flow map 8 %
    off the finite differences in the demo)."""
    expected = _compiled_answer()
    monkeypatch.setattr(calls, "ready_now", lambda: False)
    functions = _functions()
    model = _model(functions)
    model.flow_bderivative(X0, T_FINAL)  # its numerical Jacobians decided on Python code
    model.calls.compile_from_now()
    assert not model.calls.python_first and model.compiled is None  # on scipy
    D = model.flow_bderivative(X0, T_FINAL)
    assert np.allclose(D(V), expected, rtol=1e-6, atol=1e-9)


def test_the_models_of_one_field_share_its_time_on_python(auto, caplog):
    """A sweep's models (one field, other parameters or starts): once the runs of one have
    spent the field's time on Python code, every model of it runs compiled, before any
    compilation."""
    caplog.set_level(logging.INFO, logger="bderiv")
    functions = _functions()
    first, second = _model(functions), _model(functions)
    assert first.calls.python_first and second.calls.python_first
    first.calls._time.left[0] = -1e-3  # the second spent by the first model's runs
    assert not second.calls.python_first and functions[0].signatures == []
    assert "spent" in caplog.text
    second.simulate(X0, T_FINAL)
    assert second.compiled is not None


def test_a_value_error_of_the_python_code_is_the_runs_own(auto):
    """Raised on purpose (a guard, a check of the model's own), it reaches the caller as
    the compiled function's would, with nothing compiled for it."""

    def field(x, mask):
        if mask == 1:
            raise ValueError("refused after the event")
        return np.ones_like(x)

    def events(x):
        return np.array([x[0] - 1.0])

    functions = numba.njit(field), numba.njit(events)
    model = _model(functions)
    with pytest.raises(ValueError, match="refused after the event"):
        model.simulate(X0, T_FINAL)
    assert functions[0].signatures == []


def test_a_field_compiled_meanwhile_runs_compiled(auto):
    functions = _functions()
    model = _model(functions)
    assert model.calls.python_first
    functions[0](X0.copy(), 0)  # compiled by its user
    assert not model.calls.python_first


def test_a_batch_goes_on_threads_once_compiled(auto, monkeypatch):
    """simulate_many runs a new model's runs one by one on its Python code, then decides
    again: the rest of the batch on the compiled integrator's threads."""
    from bderiv.models.integrate import many

    monkeypatch.setattr(_limits, "PYTHON_FIRST_SECONDS", 1e-4)
    workers, original = [], many._Workers.__init__

    def spy(self, one, indices, count):
        workers.append((indices, count))
        original(self, one, indices, count)

    monkeypatch.setattr(many._Workers, "__init__", spy)
    model = _model(_functions())
    X = X0 + 1e-3 * np.arange(40)[:, None] * np.array([0.0, 1.0])
    out = model.simulate_many(X, T_FINAL)
    assert workers and workers[0][0].start >= 1  # the first run on Python code, alone
    reference = _model(_functions()).scipy_path().simulate_many(X, T_FINAL)
    assert np.allclose(out.x_final, reference.x_final, rtol=1e-8, atol=1e-10)


def test_python_code_that_raises_is_run_compiled(auto, caplog):
    """numba compiles what Python refuses: the run is made again on the compiled
    functions, and the log says why."""
    caplog.set_level(logging.INFO, logger="bderiv")
    model = _model(_functions(compiled_only=True))
    assert model.calls.python_first
    D = model.flow_bderivative(X0, T_FINAL)
    assert not model.calls.python_first and model.compiled is not None
    assert "NotImplementedError: this runs compiled only" in caplog.text  # a warning
    assert np.allclose(D(V), _compiled_answer(), rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize("returns", ["float32", "int64", "view"])
def test_a_type_the_compiled_path_refuses_is_refused_from_the_first_run(auto, returns):
    """Python code returning float32, ints or a non-contiguous view ran for the model's
    first second and was refused only after it (the compiled function's TypeError): the
    same model worked, then failed (a review of the docs). The compiled function now
    decides at once, whose check names the type it takes."""
    def field(x, mask):
        if returns == "float32":
            return np.ones(2, dtype=np.float32)
        if returns == "int64":
            return np.ones(2, dtype=np.int64)
        return (np.ones(4) * x[0])[::2]

    for call in ("simulate", "eval_field"):  # in a run, and outside one
        model = HybridSystem(numba.njit(field), _functions()[1], n_events=1, dim=2)
        assert model.calls.python_first
        with pytest.raises(TypeError, match=r"field must return array\(float64, 1d, C\)"):
            model.simulate(X0, T_FINAL) if call == "simulate" else model.calls.eval_field(X0, 0)
    # on scipy (while the integrator compiles, or by policy) the dispatchers ran, and
    # scipy took their float32 until the integrator was ready
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv(readiness.POLICY_VARIABLE, "scipy")
        model = HybridSystem(numba.njit(field), _functions()[1], n_events=1, dim=2)
        assert not model.calls.python_first and model.compiled is None
        with pytest.raises(TypeError, match=r"field must return array\(float64, 1d, C\)"):
            model.simulate(X0, T_FINAL)


def test_errors_of_the_run_itself_are_not_compiled_for(auto):
    """A bad argument is refused as on the compiled path, without compiling the model."""
    functions = _functions()
    model = _model(functions)
    with pytest.raises(ValueError, match="t_final"):
        model.simulate(X0, -1.0)
    assert model.calls.python_first and functions[0].signatures == []


def test_only_new_uncached_models_under_auto_start_in_python(monkeypatch):
    def f(x, mask):
        return x

    monkeypatch.setenv(readiness.POLICY_VARIABLE, "auto")
    assert python_first.starts_in_python([numba.njit(f), None])
    assert not python_first.starts_in_python([f])  # a Python model: always Python
    cached = numba.njit(cache=True)(f)  # what its disk cache holds decides
    monkeypatch.setattr(readiness, "machine_has", lambda d: d is cached)
    monkeypatch.setattr(python_first, "machine_has", readiness.machine_has)
    assert not python_first.starts_in_python([cached])  # loads from disk in milliseconds
    assert python_first.starts_in_python([numba.njit(cache=True)(f)])  # not on disk yet
    monkeypatch.undo()
    monkeypatch.setenv(readiness.POLICY_VARIABLE, "auto")
    compiled = numba.njit(f)
    compiled(np.zeros(2), 0)
    assert not python_first.starts_in_python([compiled])  # compiled in this process already
    monkeypatch.setitem(readiness._state, "here", True)  # the integrator's compiling
    assert not python_first.starts_in_python([numba.njit(f)])  # process: its runs compile it
    monkeypatch.setitem(readiness._state, "here", False)
    for policy in ("compiled", "scipy"):
        monkeypatch.setenv(readiness.POLICY_VARIABLE, policy)
        assert not python_first.starts_in_python([numba.njit(f)])
