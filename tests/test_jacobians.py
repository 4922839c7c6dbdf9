"""A model's Jacobians (issue 27 items 2, 3, 4).

Numerical Jacobians against their closed forms (steep and kinked features, resets with
large shears) and refused where no step resolves the function; given Jacobians checked
against central differences (a wrong one refused, every example model passing);
``check_jacobians``; ``bderivative(rho)`` refusing resets that do not commute as maps; the
reset existence check at 1e200 scale. Oracles: closed forms, ``tests/reference.py``, and
finite differences of an event-detecting simulation written here with solve_ivp.
"""

from __future__ import annotations

import logging

import numpy as np
import pytest
import reference as ref
from scipy.integrate import solve_ivp

from bderiv import BDerivative, HybridSystem, check_jacobians, examples
from bderiv.models.section import Section

# ----------------------------------------------------------------------------------
# item 2: numerical Jacobians
# ----------------------------------------------------------------------------------
K_HERTZ = 4e9


def _steep(x, mask):
    """A Hertz contact force at penetration -x0 and a tanh switch of width 1e-5."""
    return np.array([K_HERTZ * max(-x[0], 0.0) ** 1.5, np.tanh(x[1] / 1e-5)])


@pytest.mark.parametrize("depth", [1e-3, 1e-5, 1e-8])
def test_numerical_jacobian_of_steep_features_is_the_closed_form(depth):
    system = HybridSystem(_steep, lambda x: x[:1], n_events=1, dim=2)
    for v in (0.0, 3e-6):
        J = system.calls.eval_field_jacobian(np.array([-depth, v]), 1)
        exact = np.diag([-1.5 * K_HERTZ * depth**0.5, 1e5 / np.cosh(v / 1e-5) ** 2])
        np.testing.assert_allclose(J, exact, rtol=1e-7, atol=0.0)  # zeros exactly 0


def _shear_reset(c):
    return lambda x, mask, k: x + np.array([0.0, 0.0, c * (1.0 + x[0])])


@pytest.mark.parametrize("c", [1e6, 1e10])
@pytest.mark.parametrize("x2", [0.0, 2.5])
def test_numerical_reset_jacobian_of_a_large_shear_is_the_closed_form(c, x2):
    # d x2'/d x2 = 1 beside d x2'/d x0 = c: scipy's absolute step 0.05 lost it to rounding
    system = HybridSystem(lambda x, mask: np.ones(3), lambda x: x[:1] - 1.0, n_events=1,
                          dim=3, reset=_shear_reset(c))
    R = system.calls.eval_reset_jacobian(np.array([1.0, 0.5, x2]), 0, 0)
    exact = np.eye(3)
    exact[2, 0] = c
    np.testing.assert_allclose(R, exact, rtol=1e-7, atol=0.0)


def test_a_numerical_jacobian_no_step_resolves_is_refused_with_its_entry():
    # a switch of width 1e-20: every step the ladder tries sees a jump (the complex step,
    # exact there, is had where the field takes complex input: float() here does not)
    field = lambda x, mask: np.array([x[1], np.tanh(float(x[0]) / 1e-20)])  # noqa: E731
    system = HybridSystem(field, lambda x: x[:1] - 1.0, n_events=1, dim=2)
    with pytest.raises(ValueError, match=r"numerical Jacobian of field\(x, mask=0b1\) at x = "
                                         r".*entry \[1, 0\] .*estimated error .*pass "
                                         r"field_jacobian"):
        system.calls.eval_field_jacobian(np.zeros(2), 1)
    # a row 0 at x, whose entries need to be 0 exactly: the refusal still names its entry
    sign = lambda x, mask: np.array([x[1], 0.0 if x[0] == 0 else np.sign(x[0])])  # noqa: E731
    system = HybridSystem(sign, lambda x: x[:1] - 1.0, n_events=1, dim=2)
    with pytest.raises(ValueError, match=r"entry \[1, 0\] \(output 1 by x_0\)"):
        system.calls.eval_field_jacobian(np.zeros(2), 0)
    # a reset with a steep step 1e-14 from the point (at large steps it looks like the
    # identity, which larger steps must not claim): named with its mask and event
    # (float() of the state: no complex step, which would give the local derivative)
    reset = lambda x, mask, k: x + np.array([0.0, 1e-3 * (float(x[1]) > 1e-14)])  # noqa: E731
    system = HybridSystem(lambda x, mask: np.ones(2), lambda x: x[:1] - 1.0, n_events=1,
                          dim=2, reset=reset)
    with pytest.raises(ValueError, match=r"numerical Jacobian of reset\(x, mask=0b0, k=0\) "
                                         r".*entry \[1, 1\].*pass reset_jacobian"):
        system.calls.eval_reset_jacobian(np.array([1.0, 0.0]), 0, 0)


def test_the_cost_of_numerical_jacobians_is_reported(caplog):
    ex = examples.network(2, seed=1)
    given = ex.system
    bare = HybridSystem(given.calls.eval_field, given.calls.eval_events, n_events=2, dim=2)
    assert repr(bare) == ("HybridSystem(n_events=2, dim=2, numerical: event_jacobian, "
                          "field_jacobian)")
    assert repr(given) == "HybridSystem(n_events=2, dim=2)"
    with caplog.at_level(logging.INFO, logger="bderiv"):
        bare.flow_bderivative(ex.x0, ex.t_final)
    cost = bare.numerical_jacobian_cost
    assert set(cost) == {"event_jacobian", "field_jacobian"}
    jacobians, calls, seconds = cost["field_jacobian"]
    assert jacobians > 10 and calls >= 4 * jacobians and seconds > 0
    notes = [r.getMessage() for r in caplog.records if "not given" in r.getMessage()]
    assert len(notes) == 2 and "pass field_jacobian" in " ".join(notes)  # once per kind
    given.flow_bderivative(ex.x0, ex.t_final)
    assert given.numerical_jacobian_cost == {}


# ----------------------------------------------------------------------------------
# the Hertz bar (issue 27 item 2's reproducer): refused without Jacobians, right with
# ----------------------------------------------------------------------------------
M_BAR, G_BAR, C_BAR = 1e-3, 9.81, 0.5
ARM = np.array([-0.01, 0.015])  # signed leg offsets
I_BAR = M_BAR * 0.012**2 / 3
ATOL_BAR = np.array([1e-17, 1e-16, 1e-14, 1e-13])


def _bar_events(x):
    return -(x[0] + ARM * np.sin(x[1]))


def _bar_event_jacobian(x):
    return np.array([[-1.0, -a * np.cos(x[1]), 0.0, 0.0] for a in ARM])


def _bar_forces(x, mask):
    z, th, zd, thd = x
    h = -(z + ARM * np.sin(th))
    hd = -(zd + ARM * np.cos(th) * thd)
    on = (mask >> np.arange(2)) & 1
    return on * (K_HERTZ * np.maximum(h, 0.0) ** 1.5 + C_BAR * hd), on, h


def _bar_field(x, mask):
    f = _bar_forces(x, mask)[0]
    return np.array([x[2], x[3], -G_BAR + f.sum() / M_BAR,
                     np.sum(ARM * np.cos(x[1]) * f) / I_BAR])


def _bar_field_jacobian(x, mask):
    z, th, zd, thd = x
    f, on, h = _bar_forces(x, mask)
    J = np.zeros((4, 4))
    J[0, 2] = J[1, 3] = 1.0
    for j in np.flatnonzero(on):
        a = ARM[j]
        dh = np.array([-1.0, -a * np.cos(th), 0.0, 0.0])
        dhd = np.array([0.0, a * np.sin(th) * thd, -1.0, -a * np.cos(th)])
        df = 1.5 * K_HERTZ * max(h[j], 0.0) ** 0.5 * dh + C_BAR * dhd
        J[2] += df / M_BAR
        J[3] += a * np.cos(th) * df / I_BAR
        J[3, 1] -= a * np.sin(th) * f[j] / I_BAR
    return J


def _simulate(field, events, x0, t_final):
    """The flow of a region-switching model: solve_ivp per region, restarted at every
    crossing (bits of the crossed events flipped), independent of bderiv."""
    x, t = np.array(x0, float), 0.0
    mask = int(sum(1 << k for k, h in enumerate(events(x)) if h > 0))
    while t < t_final:
        def stop(tt, y, k, t0=t, side=1.0):
            return side if tt == t0 else events(y)[k]
        terminal = []
        for k in range(2):
            side = 1.0 if mask >> k & 1 else -1.0

            def ev(tt, y, k=k, t0=t, side=side):
                return stop(tt, y, k, t0, side)

            ev.terminal, ev.direction = True, -side
            terminal.append(ev)
        sol = solve_ivp(lambda tt, y, m=mask: field(y, m), (t, t_final), x, events=terminal,
                        rtol=1e-12, atol=ATOL_BAR, method="DOP853")
        t, x = float(sol.t[-1]), sol.y[:, -1].copy()
        if sol.status == 0:
            break
        h = events(x)
        for k in range(2):
            if sol.t_events[k].size or (h[k] > 0) != bool(mask >> k & 1):
                mask ^= 1 << k
    return x


def _bar_start():
    """The state 1 ms before both legs touch down together (level, falling at 1 m/s)."""
    rho = np.array([0.0, 0.0, -1.0, 0.0])
    return solve_ivp(lambda t, x: _bar_field(x, 0), (1e-3, 0.0), rho, rtol=1e-13,
                     atol=ATOL_BAR, method="DOP853").y[:, -1]


def test_the_hertz_bar_without_jacobians_is_refused_at_its_touchdown():
    # the contact force is max(h, 0)**1.5 at h ~ 1e-19 just after touchdown: no step
    # resolves its curvature there, and the central differences say so (a field that
    # does not take complex input: its values through float())
    def float_field(x, mask):
        return _bar_field(np.array(x, dtype=float), mask)

    bare = HybridSystem(float_field, _bar_events, n_events=2, dim=4)
    with pytest.raises(ValueError, match=r"numerical Jacobian of field\(x, mask=0b11\).*"
                                         r"pass field_jacobian"):
        bare.flow_bderivative(_bar_start(), 1.1e-3)


def test_the_hertz_bar_without_jacobians_is_exact_by_the_complex_step():
    # the same bar written with NumPy, which a complex state flows through: its missing
    # Jacobians by the complex step, exact where no finite difference resolves them
    x0, T = _bar_start(), 1.1e-3
    bare = HybridSystem(_bar_field, _bar_events, n_events=2, dim=4)
    D = bare.flow_bderivative(x0, T)
    assert bare.numerical_jacobian_cost["field_jacobian"][1] < 20 * 4 * \
        bare.numerical_jacobian_cost["field_jacobian"][0]  # mostly 4 calls a Jacobian
    V = np.random.default_rng(0).standard_normal((3, 4)) * np.array([1e-3, 1e-2, 1.0, 30.0])
    base = _simulate(_bar_field, _bar_events, x0, T)
    errors = []
    for eps in (1e-5, 1e-6):  # one-sided differences of the reference simulation
        fd = np.array([(_simulate(_bar_field, _bar_events, x0 + eps * v, T) - base) / eps
                       for v in V])
        errors.append(np.abs(fd - D(V)).max(axis=0) / np.abs(D(V)).max(axis=0))
    assert errors[1].max() < 0.2 * errors[0].max() and errors[1].max() < 3e-3


def test_the_hertz_bar_with_jacobians_matches_finite_differences_of_a_simulation():
    x0, T = _bar_start(), 1.1e-3
    model = HybridSystem(_bar_field, _bar_events, n_events=2, dim=4,
                         event_jacobian=_bar_event_jacobian,
                         field_jacobian=_bar_field_jacobian)
    D = model.flow_bderivative(x0, T)
    V = np.random.default_rng(0).standard_normal((3, 4)) * np.array([1e-3, 1e-2, 1.0, 30.0])
    base = _simulate(_bar_field, _bar_events, x0, T)
    errors = []
    for eps in (1e-5, 1e-6):
        fd = np.array([(_simulate(_bar_field, _bar_events, x0 + eps * v, T) - base) / eps
                       for v in V])
        errors.append(np.abs(fd - D(V)).max(axis=0) / np.abs(D(V)).max(axis=0))
    # one-sided differences of a PL map: the error shrinks with eps (O(eps))
    assert errors[1].max() < 0.2 * errors[0].max() and errors[1].max() < 3e-3


# ----------------------------------------------------------------------------------
# item 3: given Jacobians are checked
# ----------------------------------------------------------------------------------
F_SHEAR = np.array([[1.0, 1.0, 0.5], [1.0, 2.0, -0.5], [2.0, 1.0, 0.3], [1.5, 1.5, 0.2]])
SHEAR = np.array([[0.3, 0.6, 0.0], [-0.2, 0.1, 0.0]])  # reset k: x2 += SHEAR[k] @ x


def _shear_system(reset_jacobian, **kwargs):
    return HybridSystem(lambda x, mask: F_SHEAR[mask], lambda x: x[:2] - 1.0, n_events=2,
                        dim=3, event_jacobian=lambda x: np.eye(2, 3),
                        field_jacobian=lambda x, mask: np.zeros((3, 3)),
                        reset=lambda x, mask, k: x + np.array([0.0, 0.0, SHEAR[k] @ x]),
                        reset_jacobian=reset_jacobian, **kwargs)


def _shear_jacobian(x, mask, k):
    R = np.eye(3)
    R[2] += SHEAR[k]
    return R


def test_a_wrong_reset_jacobian_is_refused_and_the_right_one_gives_the_exact_map():
    rho = np.array([1.0, 1.0, 0.5])
    wrong = _shear_system(lambda x, mask, k: 3.0 * np.eye(3))
    with pytest.raises(ValueError, match=r"reset_jacobian does not match reset\(x, mask=0b00, "
                                         r"k=0\) at x = .*component 2 of J v .*check_jacobians="
                                         r"False"):
        wrong.bderivative(rho)
    V = np.random.default_rng(5).standard_normal((40, 3))
    R = np.zeros((4, 2, 3, 3))
    for b in range(4):
        for k in range(2):
            R[b, k] = _shear_jacobian(rho, b, k)
    exact = np.array([ref.ref_reset_flow(np.eye(2, 3), F_SHEAR, R, v)[0] for v in V])
    np.testing.assert_allclose(_shear_system(_shear_jacobian).bderivative(rho)(V), exact,
                               rtol=1e-12, atol=1e-12)
    # unchecked, the wrong Jacobian is used as given (the check is what stops it)
    unchecked = _shear_system(lambda x, mask, k: 3.0 * np.eye(3), check_jacobians=False)
    assert np.abs(unchecked.bderivative(rho)(V) - exact).max() > 1.0


def test_wrong_field_and_event_jacobians_are_refused_naming_the_mask():
    ex = examples.network(2, seed=1)
    s = ex.system
    typo = HybridSystem(s.calls.eval_field, s.calls.eval_events, n_events=2, dim=2,
                        field_jacobian=lambda x, mask: -s.calls.eval_field_jacobian(x, mask))
    with pytest.raises(ValueError, match=r"field_jacobian does not match field\(x, "
                                         r"mask=0b00\)"):
        typo.flow_bderivative(ex.x0, ex.t_final)
    transposed = HybridSystem(s.calls.eval_field, s.calls.eval_events, n_events=2, dim=2,
                              event_jacobian=lambda x: s.calls.eval_event_jacobian(x).T + 0.1)
    with pytest.raises(ValueError, match=r"event_jacobian does not match events\(x\)"):
        transposed.bderivative(ex.rho)
    with pytest.raises(TypeError, match="check_jacobians must be True or False, got str"):
        HybridSystem(s.calls.eval_field, s.calls.eval_events, n_events=2, dim=2,
                     check_jacobians="no")


def test_a_section_gradient_is_checked_once():
    section = Section(lambda x: x[0] ** 2 - x[1], 2, lambda x: np.array([2 * x[0], 1.0]))
    with pytest.raises(ValueError, match=r"section_gradient does not match section\(x\)"):
        section.gradient(np.array([0.7, 0.2]))
    right = Section(lambda x: x[0] ** 2 - x[1], 2, lambda x: np.array([2 * x[0], -1.0]))
    np.testing.assert_array_equal(right.gradient(np.array([0.7, 0.2])), [1.4, -1.0])
    assert right.check is False  # checked once; later calls use the gradient as given


def test_a_correct_jacobian_of_a_function_kinked_at_the_point_is_not_refused():
    # the Hertz force at h = 1e-19: central differences converge like sqrt(step), far from
    # the Jacobian at every step, but toward it: not a wrong Jacobian
    x = np.array([-1e-19, 0.0, -1.0, 0.0])
    model = HybridSystem(_bar_field, _bar_events, n_events=2, dim=4,
                         field_jacobian=_bar_field_jacobian)
    np.testing.assert_array_equal(model.calls.eval_field_jacobian(x, 3), _bar_field_jacobian(x, 3))
    wrong = HybridSystem(_bar_field, _bar_events, n_events=2, dim=4,
                         field_jacobian=lambda x, mask: 1.01 * _bar_field_jacobian(x, mask))
    with pytest.raises(ValueError, match="field_jacobian does not match"):
        wrong.calls.eval_field_jacobian(np.array([-1e-5, 0.001, -0.5, 0.3]), 3)


# ----------------------------------------------------------------------------------
# check_jacobians
# ----------------------------------------------------------------------------------
EXAMPLES = {
    "chair": examples.chair, "network": lambda: examples.network(3),
    "network extended": lambda: examples.network(3, extended=True),
    "table": examples.table, "pronking": examples.pronking, "running": examples.running,
    "landing": examples.landing,
}


@pytest.mark.parametrize("name", sorted(EXAMPLES))
def test_every_example_model_passes(name):
    ex = EXAMPLES[name]()
    report = check_jacobians(ex.system, ex.rho)
    n = ex.system.n_events
    resets = n * (1 << n) if ex.system.calls.has_resets else 0
    assert len(report.rows) == 1 + (1 << n) + resets
    assert report.passed, str(report)
    assert repr(report) == f"JacobianReport({len(report.rows)} checks, all passed)"


def test_the_report_names_the_wrong_jacobians():
    rho = np.array([1.0, 1.0, 0.5])
    report = check_jacobians(_shear_system(lambda x, mask, k: 3.0 * np.eye(3)), rho)
    failed = [(r.function, r.mask, r.event) for r in report.failures]
    assert failed == [("reset_jacobian", m, k) for m in range(4) for k in range(2)]
    assert all(r.passed for r in report.rows if r.function != "reset_jacobian")
    assert repr(report).startswith("JacobianReport(13 checks, 8 failed; first: "
                                   "reset_jacobian(mask=0b00, k=0)")
    text = str(report)
    assert "FAILED: component 2" in text and text.count("\n") == 13
    # numerical rows: the estimate's own accuracy, failed where the model would refuse
    steep = HybridSystem(lambda x, mask: np.array([x[1], np.tanh(x[0] / 1e-20)]),
                         lambda x: x[:1] - 1.0, n_events=1, dim=2)
    report = check_jacobians(steep, np.zeros(2), section=lambda x: x[1] - x[0],
                             section_gradient=lambda x: np.array([-1.0, 1.0]))
    kinds = [(r.function, r.mask, r.given, r.passed) for r in report.rows]
    assert kinds == [("event_jacobian", None, False, True),
                     ("field_jacobian", 0, False, False), ("field_jacobian", 1, False, False),
                     ("section_gradient", None, True, True)]
    # a numerical Jacobian with zero entries (events x_0 - 1: [1, 0]) is not 'error inf'
    assert np.isfinite(report.rows[0].error) and report.rows[0].error < 1e-9
    assert " inf " not in str(report)


def test_check_jacobians_refuses_bad_arguments():
    system = examples.network(9).system
    with pytest.raises(ValueError, match=r"n=9 events has 2\*\*9 masks: pass masks="):
        check_jacobians(system, np.zeros(9))
    report = check_jacobians(system, np.zeros(9), masks=[0, 511])
    assert [r.mask for r in report.rows] == [None, 0, 511] and report.passed
    with pytest.raises(ValueError, match=r"masks must be in \[0, 2\*\*9\), got 512"):
        check_jacobians(system, np.zeros(9), masks=[512])
    with pytest.raises(ValueError, match=r"x must have shape \(9,\)"):
        check_jacobians(system, np.zeros(3))
    with pytest.raises(TypeError, match="seed must be an integer"):
        check_jacobians(system, np.zeros(9), masks=[0], seed=0.5)


# ----------------------------------------------------------------------------------
# item 4: the event point checks what the simulation checks
# ----------------------------------------------------------------------------------
def test_resets_that_do_not_commute_as_maps_are_refused_at_rho_as_in_simulate():
    # reset 0 doubles x2, reset 1 adds 1: after both, (2 x2 + 1) or 2 (x2 + 1), 1 apart;
    # their Jacobians (diag(1, 1, 2) and I) commute, so only the maps tell
    def reset(x, mask, k):
        y = x.copy()
        y[2] = 2.0 * x[2] if k == 0 else x[2] + 1.0
        return y

    def reset_jacobian(x, mask, k):
        return np.diag([1.0, 1.0, 2.0 if k == 0 else 1.0])

    system = HybridSystem(lambda x, mask: F_SHEAR[mask], lambda x: x[:2] - 1.0, n_events=2,
                          dim=3, event_jacobian=lambda x: np.eye(2, 3), reset=reset,
                          reset_jacobian=reset_jacobian)
    with pytest.raises(ValueError, match=r"at rho .*do not commute: applied in the order "
                                         r"\(0, 1\) and \(1, 0\) they give states 1 apart"):
        system.bderivative(np.array([1.0, 1.0, 0.5]))
    with pytest.raises(ValueError, match=r"states 1 apart"):
        system.simulate(np.array([0.0, 0.0, 0.5]), 2.0)


@pytest.mark.parametrize("scale", [1e160, 1e200, 1e300])
def test_the_reset_existence_check_holds_at_extreme_scales(scale):
    rng = np.random.default_rng(9)
    Dh, F, R = ref.random_reset_system(rng, 3, 5)
    BDerivative(scale * Dh, F / scale, resets=scale * R)  # compatible: accepted
    Dh, F, R = ref.random_reset_system(rng, 3, 5, compatible=False)
    with pytest.raises(ValueError) as info:
        BDerivative(Dh, F, resets=R)
    unscaled = str(info.value)
    with pytest.raises(ValueError) as info:
        BDerivative(scale * Dh, F / scale, resets=scale * R)
    assert "do not commute" in unscaled and "nan" not in str(info.value)
    # the relative gap is scale-free: the same number at any power of ten (to rounding)
    gap = [float(m.split("differ by ")[1].split(" ")[0]) for m in (unscaled, str(info.value))]
    np.testing.assert_allclose(gap[1], gap[0], rtol=1e-2)


@pytest.mark.parametrize("c", [1.0, 1e100, 1e200])
def test_commuting_resets_at_extreme_scales_with_numerical_jacobians(c):
    # x2 += c SHEAR[k] @ x: numerical reset Jacobians with entries c, the existence check
    # on their products (c**2 overflows at 1e200), the map against the reference flow
    system = HybridSystem(lambda x, mask: F_SHEAR[mask], lambda x: x[:2] - 1.0, n_events=2,
                          dim=3, reset=lambda x, mask, k: x + np.array([0.0, 0.0,
                                                                        c * SHEAR[k] @ x]))
    rho = np.array([1.0, 1.0, 0.5])
    R = np.zeros((4, 2, 3, 3))
    for b in range(4):
        for k in range(2):
            R[b, k] = np.eye(3)
            R[b, k, 2] += c * SHEAR[k]
    V = np.random.default_rng(2).standard_normal((20, 3))
    exact = np.array([ref.ref_reset_flow(np.eye(2, 3), F_SHEAR, R, v)[0] for v in V])
    np.testing.assert_allclose(system.bderivative(rho)(V), exact, rtol=1e-9,
                               atol=1e-9 * c)


def test_a_correct_jacobian_is_not_refused_where_the_values_round_alike():
    # f0 = 0.4 (1 + 0.1 y**2) at y = 2e-8: 0.1 y**2 is below half an ulp of 1, so the two
    # values of a central difference are equal at all but the first steps and every
    # estimate from there on is 0 with no disagreement; the derivative 0.08 y (1.7e-9) is
    # known only to within their rounding. Was refused with a tolerance of 2e-22 (the
    # estimates' error taken as 0): found on a located state of test_grouping's model.
    from bderiv._support import _numdiff

    x = np.array([-1.66533444e-17, 2.08184585e-08])

    def f(x):
        return np.array([0.4 * (1 + 0.1 * x[1] ** 2), 0.3 * (1 + 0.2 * np.sin(x[0]))])

    J = np.array([[0.0, 0.08 * x[1]], [0.06 * np.cos(x[0]), 0.0]])
    assert _numdiff.compare(f, x, J).passed
    for wrong in ([[0.0, 1.0], [0.06, 0.0]], [[0.0, 0.08 * x[1]], [0.12, 0.0]]):
        assert not _numdiff.compare(f, x, np.array(wrong)).passed  # still seen: 1e-7, 1e-8


def test_an_output_that_cancels_to_rounding_does_not_refuse_its_zero_row():
    """A free body's angular acceleration, 1e-15 of rounding beside its 9.81 m/s^2 fall,
    has a zero row in its exact Jacobian and central differences of about 1e-15: it was
    refused with a tolerance of 1e-21, and a robot of one rigid body (four corners) had no
    flow B-derivative (a review). Mismatches within CHECK_ROUND_FLOOR eps of the largest
    output's size pass; a wrong term above that is still refused."""
    from bderiv._support import _numdiff

    x = np.array([0.3, -1.7])

    def f(x):  # output 1 is 0 in exact arithmetic, rounding of terms of size ~10 here
        a, b = 9.81 * np.sin(x[0]) * x[1], 7.3 * x[0] * np.cos(x[1])
        return np.array([a + b, (a + b) - a - b])

    J = np.array([[9.81 * np.cos(x[0]) * x[1] + 7.3 * np.cos(x[1]),
                   9.81 * np.sin(x[0]) - 7.3 * x[0] * np.sin(x[1])], [0.0, 0.0]])
    noise = [f(x + t * np.array([1.0, 0.7]))[1] for t in np.linspace(0, 1e-3, 200)]
    assert np.count_nonzero(noise) > 10  # the second output is rounding, not 0
    assert _numdiff.compare(f, x, J).passed
    for wrong in (1e-9, 1e-6):
        J_wrong = J.copy()
        J_wrong[1, 0] = wrong
        assert not _numdiff.compare(f, x, J_wrong).passed
