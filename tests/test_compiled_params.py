"""CompiledModel with parameters: the functions take the state followed by the values.

Oracle: the closed form of a decay ``x_i' = -r_i x_i`` (``x_i(t) = exp(-r_i t)``, the
sensitivity ``diag(exp(-r_i t))``), its rates read from the parameters; a failed check's
message, evaluated again in Python with the parameters appended.
"""

from __future__ import annotations

import numba
import numpy as np
import pytest
from numpy.testing import assert_allclose

from bderiv.analysis.system import HybridSystem
from bderiv.models.compiled import CompiledModel


@numba.njit
def decay(x, mask):  # x = (x_0, x_1, r_0, r_1)
    return np.array([-x[2] * x[0], -x[3] * x[1]])


@numba.njit
def decay_jacobian(x, mask):
    J = np.zeros((2, 2))
    J[0, 0], J[1, 1] = -x[2], -x[3]
    return J


@numba.njit
def below_half(x):  # event 0 crossed upward where x_0 falls below 0.5
    return np.array([0.5 - x[0]])


@numba.njit
def log_decay(x, mask):  # not finite where a rate is negative
    return np.array([np.log(x[2]) * x[0], -x[3] * x[1]])


@pytest.mark.parametrize("rates", [(1.0, 2.0), (0.5, 3.0)])
def test_the_parameters_follow_the_state(rates):
    model = CompiledModel(decay, below_half, decay_jacobian, n_events=1, dim=2,
                          params=rates)
    out = model.stretch(np.concatenate((np.ones(2), np.eye(2).ravel())), 0.0, 10.0, 0,
                        rtol=1e-12, atol=1e-14, max_step=np.inf, variational=True)
    t = np.log(2.0) / rates[0]  # exp(-r_0 t) = 0.5
    assert out.t_end == pytest.approx(t, rel=1e-10)
    decayed = np.exp(-np.array(rates) * t)
    assert_allclose(out.y_end[:2], decayed, rtol=1e-10)
    assert_allclose(out.y_end[2:].reshape(2, 2), np.diag(decayed), rtol=1e-9, atol=1e-12)
    assert_allclose(model.jacobian([1.0, 1.0], 0), -np.diag(rates), rtol=0)
    assert_allclose(model.fields([0.5, 2.0], [0]), [[-rates[0] * 0.5, -rates[1] * 2.0]])
    assert_allclose(model.events_rows(np.array([[0.25, 0.0]])), [[0.25]])


def test_a_model_without_parameters_is_unchanged():
    @numba.njit
    def field(x, mask):
        return -x.copy()

    @numba.njit
    def events(x):  # the state alone, nothing appended (else a NaN: refused)
        return np.array([0.5 - x[0] if x.size == 1 else np.nan])

    out = CompiledModel(field, events, n_events=1, dim=1).stretch(
        np.ones(1), 0.0, 10.0, 0, rtol=1e-12, atol=1e-14, max_step=np.inf,
        variational=False)
    assert out.t_end == pytest.approx(np.log(2.0), rel=1e-10)


def test_a_failed_check_is_evaluated_with_the_parameters():
    model = CompiledModel(log_decay, below_half, n_events=1, dim=2, params=[-1.0, 1.0])
    with pytest.raises(ValueError, match=r"field\(x, mask\) returned a non-finite value, "
                                         r"entry \[0\] = nan in region mask 0"):
        model.stretch(np.ones(2), 0.0, 1.0, 0, rtol=1e-9, atol=1e-12, max_step=np.inf,
                      variational=False)


@pytest.mark.parametrize("compiled", [True, False])
def test_a_hybrid_system_with_parameters_on_either_path(compiled):
    """``HybridSystem(..., params=p)``: the functions take the state followed by ``p``,
    the methods the state alone; the event at x_0 = 0.5 comes at log(2) / r_0."""
    fns = (decay, below_half, decay_jacobian)
    if not compiled:
        fns = tuple(f.py_func for f in fns)
    rates = np.array([0.5, 3.0])
    system = HybridSystem(fns[0], fns[1], n_events=1, dim=2, field_jacobian=fns[2],
                          event_jacobian=lambda x: np.array([[-1.0, 0.0]]), params=rates)
    assert (system.compiled is not None) == compiled
    assert_allclose(system.calls.eval_field([1.0, 2.0], 0), [-0.5, -6.0], rtol=0)
    assert_allclose(system.calls.eval_field_jacobian([1.0, 2.0], 0), -np.diag(rates), rtol=0)
    traj = system.simulate(np.ones(2), 2.0, rtol=1e-12, atol=1e-14)
    assert traj.groups[0].time == pytest.approx(np.log(2.0) / 0.5, rel=1e-9)
    assert_allclose(traj.x_final, np.exp(-rates * 2.0) * [1.0, 1.0], rtol=1e-9)


@pytest.mark.parametrize("params, error, message", [
    ([[1.0, 2.0]], ValueError, r"params must be a 1-d array of parameter values, got "
                               r"shape \(1, 2\)"),
    ([1.0, np.nan], ValueError, r"params must be finite, but params\[1\] = nan"),
    ([1.0, 2j], TypeError, "params"),
])
def test_bad_parameters_are_refused(params, error, message):
    with pytest.raises(error, match=message):
        HybridSystem(decay, below_half, n_events=1, dim=2, params=params)
