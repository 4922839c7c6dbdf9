"""A compiled model whose run leaves the floating-point range: the error says that the
integration blew up, not that a function of the model raised (the driver's own step-size
arithmetic divided by zero) or returned a non-finite value (at a state that already was).

The tests run on the compiled integrator (conftest sets ``BDERIV_INTEGRATOR=compiled``),
but the last ones, which run the same model's Python functions on scipy's ``solve_ivp``:
there the blow-up error comes alone, without the RuntimeWarnings of scipy's overflowing
arithmetic on the way (pytest's filters turn those into errors, raised before it).
"""

from __future__ import annotations

import warnings

import numba
import numpy as np
import pytest

from bderiv import HybridSystem
from bderiv.models.compiled import integrate_stretch


@numba.njit
def huge_rate(x, mask):
    return np.array([1e200, 1.0])


@numba.njit
def fast_growth(x, mask):
    return np.array([100.0 * x[0], 1.0])


@numba.njit
def square(x, mask):
    return np.array([x[0] * x[0], 1.0])


@numba.njit
def inverse(x, mask):
    return np.array([1.0 / x[0], 1.0])


@numba.njit
def clock(x):
    return np.array([x[1] - 5.0])


def _system(field):
    return HybridSystem(field, clock, n_events=1, dim=2)


@pytest.mark.parametrize("how", ["simulate", "flow_bderivative"])
def test_step_control_overflow_is_not_blamed_on_the_model(how):
    """|field| = 1e200 at |x| = 1: the initial step's error norm overflows, the step is 0
    and the driver divides by it (ZeroDivisionError in compiled code). Said as a blow-up
    of the stretch, with the sizes that caused it, the ZeroDivisionError its cause."""
    with pytest.raises(ValueError) as info:
        getattr(_system(huge_rate), how)(np.array([1.0, 0.0]), 2.0)
    message = str(info.value)
    assert message.startswith("the integration blew up in the stretch of region mask 0b0 "), \
        message
    assert "from t = 0.0, x = [1.0, 0.0] (|x| up to 1, |field(x, mask)| up to 1e+200)" in message
    assert "step-size control overflowed (ZeroDivisionError" in message
    assert "not in a function of the model" in message
    assert "rescale them, or stop the run before the blow-up" in message
    assert "compiled function of the model raised" not in message
    assert isinstance(info.value.__cause__, ZeroDivisionError)


def test_integrate_stretch_says_it_blew_up():
    """The one-stretch entry point: a ValueError naming the blow-up, not the driver's raw
    ZeroDivisionError."""
    with pytest.raises(ValueError, match=r"the integration blew up in the stretch .* from "
                                         r"t = 0.0, x = \[1.0, 0.0\] .*up to 1e\+200"):
        integrate_stretch(huge_rate, [1.0, 0.0], 2.0)


def test_a_state_beyond_the_float_range_is_not_blamed_on_the_field():
    """x' = 100 x from 1e300: the state overflows within a step (inf, then NaN) and the
    field, called there, returns NaN; the error names the state and the time, not the
    field."""
    with pytest.raises(ValueError) as info:
        _system(fast_growth).simulate(np.array([1e300, 0.0]), 2.0)
    message = str(info.value)
    assert message.startswith("the integration blew up at t = 0.1"), message
    assert "the state grew beyond the floating-point range" in message
    assert "x = [nan, 0.1" in message
    assert "returned a non-finite value" not in message


@pytest.mark.parametrize("python", [False, True], ids=["compiled", "python"])
def test_finite_time_blow_up_underflow_names_it(python):
    """x' = x**2 from 1 escapes to infinity at t = 1: the step size underflows there, and
    the error says that a blow-up may be why, with the state, on either integrator
    (scipy's path said "solve_ivp failed at t=1: Required step size is less than spacing
    between numbers", without the state or the why)."""
    system = HybridSystem(square.py_func, clock.py_func, n_events=1, dim=2) if python \
        else _system(square)
    with pytest.raises(RuntimeError, match=r"step size underflow at t = 1\.0000000000.* "
                                           r"in region mask 0b0 .*, x = \[5\d{13}\.\d+, 1\.0"
                                           r".* a solution that escapes to infinity near this t"):
        system.simulate(np.array([1.0, 0.0]), 2.0)


def test_the_model_s_own_division_by_zero_is_still_named():
    """The other way round: a field that divides by zero itself is named, with its state
    (its exception is a status code of the driver, never the blow-up message)."""
    with pytest.raises(ValueError, match=r"field\(x, mask\) raised ZeroDivisionError: "
                                         r"division by zero; in region mask 0b0 .* at "
                                         r"x = \[0.0, 0.0\]"):
        _system(inverse).simulate(np.array([0.0, 0.0]), 1.0)


@pytest.mark.parametrize("how", ["simulate", "flow_bderivative"])
def test_the_python_path_says_the_same(how):
    """The same blow-up on scipy's path: it said that the field returned -inf (called at
    a state that was -inf already), and flow_bderivative that "x must be finite, got
    [inf 0.]", an x0 the caller never gave. Under pytest's filters (warnings are errors)
    scipy's "overflow encountered in dot" was raised before it."""
    system = HybridSystem(fast_growth.py_func, clock.py_func, n_events=1, dim=2)
    assert system.compiled is None  # Python functions: scipy's solve_ivp
    with pytest.raises(ValueError) as info:
        getattr(system, how)(np.array([1e300, 0.0]), 2.0)
    message = str(info.value)
    assert message.startswith("the integration blew up at t = 0.1"), message
    assert "in region mask 0b0 (bit k set = event k happened): the state grew beyond" \
        in message
    assert "x must be finite" not in message and "returned a non-finite" not in message


def _python_system(field=fast_growth.py_func):
    return HybridSystem(field, clock.py_func, n_events=1, dim=2)


@pytest.mark.parametrize("how", ["simulate", "flow_bderivative"])
def test_the_python_path_s_blow_up_shows_no_runtime_warning(how):
    """scipy's RuntimeWarnings of its overflow (its dot products of the stages and of the
    dense output, steps before the state reaches inf) came before the error: dropped."""
    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always")
        with pytest.raises(ValueError, match="the integration blew up at t = 0.1"):
            getattr(_python_system(), how)(np.array([1e300, 0.0]), 2.0)
    assert not [w for w in seen if issubclass(w.category, RuntimeWarning)], \
        [str(w.message) for w in seen]


def test_scipy_s_warnings_of_a_run_that_ends_well_are_given():
    """The same run stopped short of the blow-up (t_final = 0.105, x near 3.6e304): scipy's
    dense output overflowed, and nothing else says so: its warnings are given, from scipy's
    line, when its solve_ivp call returns."""
    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always")
        trajectory = _python_system().simulate(np.array([1e300, 0.0]), 0.105)
    assert np.all(np.isfinite(trajectory.x_final))
    assert "overflow encountered in dot" in {str(w.message) for w in seen}
    assert all(w.category is RuntimeWarning and "scipy" in w.filename for w in seen), \
        [(str(w.message), w.filename) for w in seen]


def test_the_user_s_own_runtime_warning_is_given_at_once():
    """A model's function's own floating-point warning is NumPy's, at once and where it was
    made: under pytest's filters an error raised inside the function."""

    def field(x, mask):
        return np.array([np.float64(1.0) / (x[1] - x[1]), 1.0])

    with pytest.warns(RuntimeWarning, match="divide by zero encountered in scalar divide") \
            as seen:
        with pytest.raises(ValueError, match="returned a non-finite value"):
            _python_system(field).simulate(np.array([1.0, 0.0]), 1.0)
    assert seen[0].filename == __file__
    with pytest.raises(RuntimeWarning, match="divide by zero encountered in scalar divide"):
        _python_system(field).simulate(np.array([1.0, 0.0]), 1.0)
