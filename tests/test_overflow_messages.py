"""A compiled model whose run leaves the floating-point range: the error says that the
integration blew up, not that a function of the model raised (the driver's own step-size
arithmetic divided by zero) or returned a non-finite value (at a state that already was).

The tests run on the compiled integrator (conftest sets ``BDERIV_INTEGRATOR=compiled``),
but the last, which runs the same model's Python functions on scipy's ``solve_ivp``.
"""

from __future__ import annotations

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


def test_finite_time_blow_up_underflow_names_it():
    """x' = x**2 from 1 escapes to infinity at t = 1: the step size underflows there, and
    the error says that a blow-up may be why."""
    with pytest.raises(RuntimeError, match=r"step size underflow at t = 1\.0000000000.* "
                                           r"a solution that escapes to infinity near this t"):
        _system(square).simulate(np.array([1.0, 0.0]), 2.0)


def test_the_model_s_own_division_by_zero_is_still_named():
    """The other way round: a field that divides by zero itself is named, with its state
    (its exception is a status code of the driver, never the blow-up message)."""
    with pytest.raises(ValueError, match=r"field\(x, mask\) raised ZeroDivisionError: "
                                         r"division by zero; in region mask 0b0 .* at "
                                         r"x = \[0.0, 0.0\]"):
        _system(inverse).simulate(np.array([0.0, 0.0]), 1.0)


@pytest.mark.filterwarnings("ignore:overflow encountered:RuntimeWarning")
@pytest.mark.filterwarnings("ignore:invalid value encountered:RuntimeWarning")
@pytest.mark.parametrize("how", ["simulate", "flow_bderivative"])
def test_the_python_path_says_the_same(how):
    """The same blow-up on scipy's path: it said that the field returned -inf (called at
    a state that was -inf already), and flow_bderivative that "x must be finite, got
    [inf 0.]", an x0 the caller never gave."""
    system = HybridSystem(fast_growth.py_func, clock.py_func, n_events=1, dim=2)
    assert system.compiled is None  # Python functions: scipy's solve_ivp
    with pytest.raises(ValueError) as info:
        getattr(system, how)(np.array([1e300, 0.0]), 2.0)
    message = str(info.value)
    assert message.startswith("the integration blew up at t = 0.1"), message
    assert "in region mask 0b0 (bit k set = event k happened): the state grew beyond" \
        in message
    assert "x must be finite" not in message and "returned a non-finite" not in message
