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
