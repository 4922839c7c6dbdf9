"""The compiled DOP853 (bderiv.models.compiled) against solve_ivp(method="DOP853") and closed
forms.

Oracles: scipy's solve_ivp on the same problems with the same settings (end states, step
counts, field calls, event times and states, the variational system integrated as scipy
integrates it), and closed forms (the oscillator's rotation, exp(At) for linear systems,
the crossing times of cos t). Both integrators use scipy's tableau and control, so they
take the same number of steps. A step's error norm can differ in its leading digits when
it is round-off (its sums cancel, and BLAS sums in another order than the kernels): the
first error norm of the oscillator (4.5e-13) and of Van der Pol from (2, 0) are, which
moves the next steps by up to 2.3e-5 relative (measured); the controller forgets it
within a step or two, and the end states agree to a few ulp. Hence step times to 1e-4,
end states to 1e-12.
"""

from __future__ import annotations

import numba
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from numpy.testing import assert_allclose
from scipy.integrate import solve_ivp
from scipy.linalg import expm

from bderiv.models.compiled import integrate_stretch
from bderiv.models.compiled._integrate import drive_stretch

RTOL, ATOL = 1e-10, 1e-12


@numba.njit
def rotation(x, mask):
    return np.array([x[1], -x[0]])


@numba.njit
def rotation_jacobian(x, mask):
    return np.array([[0.0, 1.0], [-1.0, 0.0]])


@numba.njit
def pendulum(x, mask):
    return np.array([x[1], -np.sin(x[0])])


@numba.njit
def pendulum_jacobian(x, mask):
    return np.array([[0.0, 1.0], [-np.cos(x[0]), 0.0]])


@numba.njit
def van_der_pol(x, mask):  # mu = 1
    return np.array([x[1], (1.0 - x[0] ** 2) * x[1] - x[0]])


_rng = np.random.default_rng(19)
#: a stable-ish linear system of dimension 20
A20 = _rng.standard_normal((20, 20)) / np.sqrt(20.0) - 0.5 * np.eye(20)
X20 = _rng.standard_normal(20)


@numba.njit
def linear20(x, mask):
    return A20 @ x


@numba.njit
def linear20_jacobian(x, mask):
    return A20.copy()


def scipy_run(field, x0, t_final, jacobian=None, events=(), **kw):
    """solve_ivp(DOP853) of ``field`` (mask 0); with ``jacobian`` the variational system
    y = (x, Phi row-major), Phi' = J Phi, as the Python path of bderiv integrates it."""
    d = len(x0)
    kw = {"rtol": RTOL, "atol": ATOL, **kw}
    if jacobian is None:
        return solve_ivp(lambda t, y: field(y, 0), (0.0, t_final), x0, method="DOP853",
                         events=list(events), **kw)

    def rhs(t, y):
        x = np.ascontiguousarray(y[:d])
        return np.concatenate((field(x, 0), (jacobian(x, 0) @ y[d:].reshape(d, d)).ravel()))

    y0 = np.concatenate((x0, np.eye(d).ravel()))
    return solve_ivp(rhs, (0.0, t_final), y0, method="DOP853", events=list(events), **kw)


PROBLEMS = {
    "oscillator": (rotation, [0.3, -1.2], 30.0),
    "pendulum": (pendulum, [2.0, 0.0], 20.0),
    "van_der_pol": (van_der_pol, [2.0, 0.0], 20.0),
    "linear20": (linear20, X20, 10.0),
}


@pytest.mark.parametrize("tolerances", [(1e-10, 1e-12), (1e-6, 1e-9)], ids=["tight", "loose"])
@pytest.mark.parametrize("name", PROBLEMS)
def test_same_steps_and_end_state_as_solve_ivp(name, tolerances):
    field, x0, t_final = PROBLEMS[name]
    rtol, atol = tolerances
    s = integrate_stretch(field, x0, t_final, rtol=rtol, atol=atol)
    sol = scipy_run(field, np.asarray(x0, float), t_final, rtol=rtol, atol=atol)
    # the same step control: the same steps, but a step whose error norm is within
    # rounding of 1 may be accepted by one and rejected by the other (the compiled field
    # rounds differently: seen once in a few hundred runs, one rejection = 12 evaluations)
    assert abs(s.n_steps - (sol.t.size - 1)) <= 1 and abs(s.nfev - sol.nfev) <= 12
    assert s.t[-1] == t_final and s.t_end == t_final and not s.event
    # the step sizes follow the error norm, a difference of large terms whose rounding
    # differs with the field's (numba's sin against NumPy's, FMA contraction: seen 2e-4 on
    # an AMD EPYC at the loose tolerances), so the steps agree to 2e-3, the end states to
    # 1e-11 of the solution's size (5e-12 seen after 20 time units of van der Pol)
    if s.t.size == sol.t.size:
        assert_allclose(s.t, sol.t, rtol=2e-3)
    assert_allclose(s.x_end, sol.y[:, -1], rtol=1e-11, atol=1e-11 * np.abs(sol.y).max())


def test_oscillator_against_closed_form():
    x0, t_final = np.array([0.3, -1.2]), 10.0
    s = integrate_stretch(rotation, x0, t_final)
    c, sn = np.cos(s.t)[:, None], np.sin(s.t)[:, None]
    exact = np.hstack((x0[0] * c + x0[1] * sn, -x0[0] * sn + x0[1] * c))
    # DOP853's global error at rtol 1e-10 over 10 time units (about 1.6 periods): 8e-11
    assert_allclose(s.x, exact, atol=3e-10)


def test_event_of_cos_at_half_pi_both_directions():
    """x = (cos t, -sin t): cos t crosses 0 downward at pi/2 and upward at 3 pi/2."""

    @numba.njit
    def cosine(x):
        return np.array([x[0]])

    down = integrate_stretch(rotation, [1.0, 0.0], 10.0, mask=1, events=cosine)
    up = integrate_stretch(rotation, [1.0, 0.0], 10.0, mask=0, events=cosine)
    for s, t_cross in ((down, np.pi / 2), (up, 3 * np.pi / 2)):
        assert s.event and s.crossed.tolist() == [True]
        assert s.event_times[0] == s.t_end == s.t[-1]
        # the 7th-order dense output's error at rtol 1e-10 (measured 1.8e-11 to 1.1e-10)
        assert abs(s.t_end - t_cross) < 5e-10
        assert_allclose(s.x_end, [0.0, -np.sin(t_cross)], atol=5e-10)
        assert np.all(s.t[:-1] < s.t_end)


def test_only_the_crossing_that_flips_the_bit_stops():
    """cos t - 1/2 falls through 0 at pi/3 and rises at 5 pi/3: bit clear waits for the rise,
    bit set stops at the fall."""

    @numba.njit
    def above_half(x):
        return np.array([x[0] - 0.5])

    fall = integrate_stretch(rotation, [1.0, 0.0], 10.0, mask=1, events=above_half)
    rise = integrate_stretch(rotation, [1.0, 0.0], 10.0, mask=0, events=above_half)
    assert abs(fall.t_end - np.pi / 3) < 5e-10
    assert abs(rise.t_end - 5 * np.pi / 3) < 5e-10


@numba.njit
def pendulum_events(x):
    # three events: the angle 1.0 (watched upward: bit 0 clear), the velocity -0.8 and, a
    # hair later, -0.8 - 1e-7 (watched downward: bits 1, 2 set)
    return np.array([x[0] - 1.0, x[1] + 0.8, x[1] + 0.8 + 1e-7])


def _scipy_event(k, direction):
    def g(t, y):
        return pendulum_events(np.ascontiguousarray(y[:2]))[k]

    g.direction = direction
    return g


@pytest.mark.parametrize("variational", [False, True], ids=["state", "with_phi"])
def test_events_against_solve_ivp(variational):
    """Both velocity events cross in the same step: both are reported, each located; the
    stretch stops at the first. Times and states (and Phi) match solve_ivp's."""
    x0, mask = np.array([2.0, 0.0]), 0b110
    jac = pendulum_jacobian if variational else None
    s = integrate_stretch(pendulum, x0, 10.0, mask=mask, events=pendulum_events,
                          field_jacobian=jac)
    sol = scipy_run(pendulum, x0, 10.0, jacobian=jac,
                    events=[_scipy_event(0, 1), _scipy_event(1, -1), _scipy_event(2, -1)])
    firsts = [te[0] for te in sol.t_events]  # non-terminal: every crossing of each
    assert firsts[1] < firsts[2] < firsts[0]
    assert s.event and s.crossed.tolist() == [False, True, True]
    assert_allclose(s.event_times[1:], firsts[1:], rtol=1e-12)
    assert np.isnan(s.event_times[0]) and s.t_end == s.event_times[1]
    y_event = sol.y_events[1][0]
    assert_allclose(s.x_end, y_event[:2], rtol=1e-12)
    if variational:
        assert_allclose(s.phi_end, y_event[2:].reshape(2, 2), rtol=1e-10, atol=1e-12)
    # the run up to the stop took solve_ivp's steps
    steps = sol.t[sol.t < s.t_end]
    assert_allclose(s.t[:-1], steps, rtol=1e-4)


@numba.njit
def angle(x):
    return np.array([x[0] - 1.0])


@pytest.mark.parametrize(("mask", "direction"), [(1, -1), (0, 1)], ids=["down", "up"])
def test_one_direction_of_the_angle(mask, direction):
    """From angle 2 at rest: bit set stops where the angle falls through 1.0, bit clear
    where it rises through it on the swing back; as solve_ivp with that terminal event."""
    x0 = np.array([2.0, 0.0])
    s = integrate_stretch(pendulum, x0, 20.0, mask=mask, events=angle)

    def g(t, y):
        return y[0] - 1.0

    g.terminal, g.direction = True, direction
    sol = scipy_run(pendulum, x0, 20.0, events=[g])
    assert s.crossed.tolist() == [True] and np.sign(s.x_end[1]) == direction
    assert_allclose(s.t_end, sol.t_events[0][0], rtol=1e-12)
    assert_allclose(s.x_end, sol.y[:, -1], rtol=1e-12, atol=1e-14)
    assert s.n_steps == sol.t.size - 1 and s.nfev == sol.nfev


def test_phi_against_exp_At():
    t_final = 1.5
    s = integrate_stretch(linear20, X20, t_final, field_jacobian=linear20_jacobian)
    E = expm(A20 * t_final)
    assert_allclose(s.phi_end, E, atol=1e-10 * np.abs(E).max())
    assert_allclose(s.x_end, E @ X20, atol=1e-10 * np.abs(E @ X20).max())
    assert s.njev == s.nfev


def test_phi_of_the_oscillator_is_the_rotation():
    s = integrate_stretch(rotation, [1.0, 0.0], 2.0, field_jacobian=rotation_jacobian)
    c, sn = np.cos(2.0), np.sin(2.0)
    assert_allclose(s.phi_end, [[c, sn], [-sn, c]], atol=1e-10)


@pytest.mark.parametrize("name", ["pendulum", "linear20"])
def test_phi_error_controlled_as_the_python_path(name):
    """The variational system's error norm covers Phi (as solve_ivp does on the Python
    path's (x, Phi) vector): the same steps as solve_ivp on that system."""
    field, x0, _ = PROBLEMS[name]
    jac = {"pendulum": pendulum_jacobian, "linear20": linear20_jacobian}[name]
    x0 = np.asarray(x0, float)
    s = integrate_stretch(field, x0, 3.0, field_jacobian=jac)
    sol = scipy_run(field, x0, 3.0, jacobian=jac)
    plain = integrate_stretch(field, x0, 3.0)
    assert s.n_steps == sol.t.size - 1 and s.nfev == sol.nfev
    assert abs(s.t[1] - plain.t[1]) > 1e-3 * plain.t[1]  # Phi's error changes the steps
    d = x0.size
    assert_allclose(s.t, sol.t, rtol=1e-4)
    assert_allclose(s.x_end, sol.y[:d, -1], rtol=1e-12, atol=1e-12)
    assert_allclose(s.phi_end, sol.y[d:, -1].reshape(d, d), rtol=1e-11, atol=1e-12)


def test_max_step_and_per_component_atol_as_solve_ivp():
    atol = np.array([1e-12, 1e-8])
    s = integrate_stretch(van_der_pol, [2.0, 0.0], 8.0, atol=atol, max_step=0.05)
    sol = scipy_run(van_der_pol, np.array([2.0, 0.0]), 8.0, atol=atol, max_step=0.05)
    assert s.n_steps == sol.t.size - 1 and np.diff(s.t).max() <= 0.05 * (1 + 1e-12)
    assert_allclose(s.x_end, sol.y[:, -1], rtol=1e-12)


def test_first_step_is_honoured():
    s = integrate_stretch(pendulum, [2.0, 0.0], 1.0, first_step=1e-3)
    sol = scipy_run(pendulum, np.array([2.0, 0.0]), 1.0, first_step=1e-3)
    assert s.t[1] == 1e-3 == sol.t[1]
    assert_allclose(s.x_end, sol.y[:, -1], rtol=1e-12)


def test_start_time_and_record():
    s = integrate_stretch(rotation, [1.0, 0.0], 3.0, t0=1.0)
    assert s.t[0] == 1.0 and s.t[-1] == 3.0 and np.all(np.diff(s.t) > 0)
    assert s.x.shape == (s.t.size, 2) and s.n_steps == s.t.size - 1
    assert_allclose(s.x_end, [np.cos(2.0), -np.sin(2.0)], atol=1e-10)
    assert s.crossed.shape == (0,) and s.phi_end is None


def test_the_driver_compiles_once_for_all_fields():
    """Fields are passed as first-class functions: one compiled driver for every model."""
    for field, x0 in ((rotation, [1.0, 0.0]), (pendulum, [1.0, 0.0]), (linear20, X20)):
        integrate_stretch(field, x0, 0.5)
    integrate_stretch(pendulum, [1.0, 0.0], 0.5, field_jacobian=pendulum_jacobian,
                      events=pendulum_events)
    assert len(drive_stretch.signatures) == 1


@numba.njit
def linear_in_state(y, mask):
    """x' = A x with A (k, k) carried in the state: y = (x, A row-major), A' = 0, so that
    one compiled field integrates any linear system."""
    k = int(np.sqrt(y.size + 0.25) - 0.5)  # y.size = k + k * k
    out = np.zeros(y.size)
    for i in range(k):
        acc = 0.0
        for j in range(k):
            acc += y[k + i * k + j] * y[j]
        out[i] = acc
    return out


@settings(max_examples=25, deadline=None, derandomize=True)
@given(k=st.integers(1, 5), seed=st.integers(0, 2**32 - 1),
       rtol=st.sampled_from([1e-6, 1e-9, 1e-12]), t_final=st.floats(0.1, 5.0),
       max_step=st.sampled_from([np.inf, 0.3]))
def test_random_linear_systems_as_solve_ivp_and_exp_At(k, seed, rtol, t_final, max_step):
    rng = np.random.default_rng(seed)
    A = rng.standard_normal((k, k)) - 0.3 * np.eye(k)
    y0 = np.concatenate((rng.standard_normal(k), A.ravel()))
    s = integrate_stretch(linear_in_state, y0, t_final, rtol=rtol, atol=1e-12,
                          max_step=max_step)
    sol = solve_ivp(lambda t, y: linear_in_state(y, 0), (0.0, t_final), y0,
                    method="DOP853", rtol=rtol, atol=1e-12, max_step=max_step)
    scale = np.abs(sol.y).max()
    if s.n_steps == sol.t.size - 1 and s.nfev == sol.nfev:  # all 25 examples here
        assert_allclose(s.x_end, sol.y[:, -1], rtol=1e-12, atol=1e-12 * scale)
    else:  # an error norm within rounding of 1 may accept a step on one machine only
        assert abs(s.n_steps - (sol.t.size - 1)) <= 1
        assert_allclose(s.x_end, sol.y[:, -1], atol=100 * rtol * scale)
    exact = expm(A * t_final) @ y0[:k]
    # DOP853's global error: a few hundred rtol here (measured up to ~40 rtol)
    assert_allclose(s.x_end[:k], exact, atol=1e3 * rtol * max(1.0, np.abs(exact).max()))
    assert s.x_end[k:].tolist() == y0[k:].tolist()  # A' = 0 exactly


def test_the_field_may_overwrite_its_argument():
    """Each call gets a copy of the state: a field that clobbers x changes nothing."""

    @numba.njit
    def clobber(x, mask):
        out = np.array([x[1], -x[0]])
        x[:] = np.nan
        return out

    s = integrate_stretch(clobber, [1.0, 0.0], 2.0, field_jacobian=rotation_jacobian)
    ref = integrate_stretch(rotation, [1.0, 0.0], 2.0, field_jacobian=rotation_jacobian)
    assert np.array_equal(s.x, ref.x) and np.array_equal(s.phi_end, ref.phi_end)


# -- bad input ------------------------------------------------------------------------


def test_refuses_a_python_function():
    with pytest.raises(TypeError, match="field must be a numba.njit-compiled function"):
        integrate_stretch(lambda x, mask: -x, [1.0], 1.0)
    with pytest.raises(TypeError, match="events must be a numba.njit-compiled function"):
        integrate_stretch(rotation, [1.0, 0.0], 1.0, events=lambda x: x)


def test_refuses_a_function_that_does_not_compile():
    @numba.njit
    def typo(x, mask):
        return x.nonexistent

    with pytest.raises(TypeError, match=r"field does not compile as field\(x, mask\).*"
                                        r"nonexistent"):
        integrate_stretch(typo, [1.0], 1.0)


def test_refuses_another_signature():
    @numba.njit("float32[:](float32[:], int64)")
    def single(x, mask):
        return -x

    with pytest.raises(TypeError, match=r"field was compiled for .*float32.*give that "
                                        r"signature, or none"):
        integrate_stretch(single, [1.0], 1.0)


@pytest.mark.parametrize("body", ["strided", "matrix", "scalar"])
def test_refuses_another_return_type(body):
    @numba.njit
    def strided(x, mask):
        return np.concatenate((x, x))[::2]

    @numba.njit
    def matrix(x, mask):
        return np.zeros((2, 2))

    @numba.njit
    def scalar(x, mask):
        return x[0]

    fn = {"strided": strided, "matrix": matrix, "scalar": scalar}[body]
    with pytest.raises(TypeError, match=r"field must return array\(float64, 1d, C\).*"
                                        r"but returns"):
        integrate_stretch(fn, [1.0, 2.0], 1.0)


def test_wrong_length_names_function_region_and_state():
    @numba.njit
    def short(x, mask):
        return x[:1].copy()

    with pytest.raises(ValueError, match=r"field\(x, mask\) must return an array of shape "
                                         r"\(2,\), got shape \(1,\) in region mask 0b1 .*"
                                         r"at x = \[0.5, 2.0\]"):
        integrate_stretch(short, [0.5, 2.0], 1.0, mask=1)


def test_nan_on_the_way_names_the_state():
    """The field turns NaN where x[0] < 0.5 (at t = pi/3 on x = cos t): met mid-stretch."""

    @numba.njit
    def sour(x, mask):
        if x[0] < 0.5:
            return np.array([np.nan, -x[0]])
        return np.array([x[1], -x[0]])

    with pytest.raises(ValueError, match=r"field\(x, mask\) returned a non-finite value, "
                                         r"entry \[0\] = nan in region mask 0b0 .*at x = "
                                         r"\[0\.[0-4]\d*, -0\.8"):
        integrate_stretch(sour, [1.0, 0.0], 3.0)


def test_bad_jacobian_and_events_are_named():
    @numba.njit
    def inf_jacobian(x, mask):
        return np.full((2, 2), np.inf)

    @numba.njit
    def two_events_then_one(x):
        return np.array([x[0] - 2.0, 1.0]) if x[1] > -0.5 else np.array([1.0])

    with pytest.raises(ValueError, match=r"field_jacobian\(x, mask\) returned a non-finite "
                                         r"value, entry \[0, 0\] = inf"):
        integrate_stretch(rotation, [1.0, 0.0], 1.0, field_jacobian=inf_jacobian)
    with pytest.raises(ValueError, match=r"events\(x\) must return an array of shape \(2,\), "
                                         r"got shape \(1,\) in region mask 0b00"):
        integrate_stretch(rotation, [1.0, 0.0], 3.0, events=two_events_then_one)


def test_a_raise_in_the_field_propagates():
    @numba.njit
    def picky(x, mask):
        if x[0] < 0.0:
            raise ValueError("picky: x[0] < 0")
        return np.array([x[1], -x[0]])

    with pytest.raises(ValueError, match="picky"):
        integrate_stretch(picky, [1.0, 0.0], 3.0)


def test_step_size_underflow():
    """x' = x^2 from 1 blows up at t = 1 (solve_ivp: 'Required step size is less than
    spacing between numbers')."""

    @numba.njit
    def blow_up(x, mask):
        return x * x

    assert solve_ivp(lambda t, y: y * y, (0, 2), [1.0], method="DOP853", rtol=RTOL,
                     atol=ATOL).status == -1
    with pytest.raises(RuntimeError, match=r"step size underflow at t = 1\.0000000.*"
                                           r"region mask 0b0"):
        integrate_stretch(blow_up, [1.0], 2.0)


@pytest.mark.parametrize(
    ("kwargs", "error", "match"),
    [
        ({"rtol": 1e-16}, ValueError, r"rtol must be in \[2.22e-14, 1\), got 1e-16"),
        ({"atol": -1.0}, ValueError, r"atol must be a finite number > 0, got -1.0"),
        ({"atol": [1e-9]}, ValueError, r"atol must be a number or an array of shape \(2,\)"),
        ({"atol": [1e-9, 0.0]}, ValueError, r"atol must be finite and > 0 in every entry"),
        ({"t0": 5.0}, ValueError, r"t_final must be a finite number > 5, got 1.0"),
        ({"mask": -1}, ValueError, r"mask must be in \[0, 2\*\*63\) \(one bit per event\), "
                                   r"got -1"),
        ({"mask": 2**63}, ValueError, r"mask must be in \[0, 2\*\*63\)"),
        ({"mask": 1.0}, TypeError, r"mask must be an int, got float"),
        ({"max_step": 0.0}, ValueError, r"max_step must be a number > 0"),
        ({"first_step": -1.0}, ValueError, r"first_step must be a finite number > 0"),
    ],
)
def test_bad_arguments(kwargs, error, match):
    with pytest.raises(error, match=match):
        integrate_stretch(rotation, [1.0, 0.0], 1.0, **kwargs)


@pytest.mark.parametrize("x0", [[], [[1.0, 0.0]], [np.nan, 0.0]])
def test_bad_start_state(x0):
    with pytest.raises(ValueError, match="x0 must be"):
        integrate_stretch(rotation, x0, 1.0)
