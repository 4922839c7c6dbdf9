"""Event-detecting simulation: trajectory, event groups, solver options, bad input."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import RK23
from test_hybrid import constant_system

from bderiv import examples
from bderiv.analysis.system import HybridSystem
from bderiv.models.integrate.options import SolverOptions
from bderiv.models.integrate.run import GLOBAL_ERROR_FACTOR, group_tolerance
from bderiv.models.integrate.trajectory import Trajectory


# ------------------------------------------------------------------------------------------
# simulation and event detection
# ------------------------------------------------------------------------------------------
def test_simulate_result():
    s = constant_system(np.array([[1.0, 1.0], [1.0, 2.0], [2.0, 1.0], [3.0, 3.0]]))
    traj = s.simulate(np.zeros(2), 2.0)
    assert isinstance(traj, Trajectory)
    assert traj.t[0] == 0 and traj.t[-1] == pytest.approx(2.0)
    assert np.all(np.diff(traj.t) >= 0)
    assert traj.x.shape == (traj.t.size, 2) and traj.masks.shape == traj.t.shape
    np.testing.assert_array_equal(traj.x[-1], traj.x_final)
    # both events at t = 1 together: one group with the default tolerance or two stops
    assert {e.event for e in traj.events} == {0, 1}
    assert traj.mask_final == 3
    # exact: after t = 1 the field is (3, 3)
    np.testing.assert_allclose(traj.x_final, [4.0, 4.0], rtol=1e-10)


def test_without_resets_the_state_does_not_jump_at_a_group():
    s = constant_system(np.array([[1.0, 1.0], [1.0, 2.0], [2.0, 1.0], [3.0, 3.0]]))
    assert not s.calls.has_resets
    traj = s.simulate(np.zeros(2), 2.0, simultaneity_tol=1e-9)
    (group,) = traj.groups
    assert np.array_equal(group.state_after, group.state)
    i = int(np.flatnonzero(traj.t == group.time)[-1])  # the next stretch starts at the stop
    assert np.array_equal(traj.x[i], group.state) and np.array_equal(traj.x[i - 1], group.state)


def test_two_surfaces_crossed_in_one_step_are_both_detected():
    seen = []

    def events(x):
        seen.append(x.copy())
        return np.array([x[0] - 1.0, x[1] - 1.0005])

    s = HybridSystem(lambda x, m: np.array([1.0, 1.0 + 0.5 * (m & 1)]), events, n_events=2, dim=2)
    traj = s.simulate(np.zeros(2), 3.0, simultaneity_tol=0.0)
    seen = np.array(seen)
    # the integrator evaluated the events beyond both surfaces before any point between them
    beyond = np.flatnonzero((seen[:, 0] > 1.0) & (seen[:, 1] > 1.0005))
    between = np.flatnonzero((seen[:, 0] > 1.0 + 1e-9) & (seen[:, 1] < 1.0005 - 1e-9))
    assert beyond.size and (between.size == 0 or beyond[0] < between[0])
    assert [e.event for e in traj.events] == [0, 1]
    t0, t1 = traj.events[0].time, traj.events[1].time
    assert t0 == pytest.approx(1.0, abs=1e-12)
    assert t1 == pytest.approx(1.0 + 0.0005 / 1.5, abs=1e-12)
    assert [g.events for g in traj.groups] == [(0,), (1,)]


@pytest.mark.parametrize("tol", [0.0, 1e-12, 1e-9])
def test_nearly_coincident_crossings_are_never_lost(tol):
    # event 1 crosses 1e-13 before event 0, inside the same step
    def events(x):
        return np.array([x[0] - 1.0, x[0] - 1.0 + 1e-13, x[1] - 2.0])

    s = HybridSystem(lambda x, m: np.array([1.0, 1.0]), events, n_events=3, dim=2)
    traj = s.simulate(np.zeros(2), 3.0, simultaneity_tol=tol)
    assert sorted(e.event for e in traj.events) == [0, 1, 2]
    assert traj.mask_final == 7
    if tol >= 1e-12:
        assert traj.groups[0].events == (0, 1)


def test_grouping_tolerance():
    rates = np.array([[1.0, 1.0], [1.0, 1.0], [1.0, 1.0], [1.0, 1.0]])
    s = constant_system(rates)
    x0 = np.array([0.0, -1e-12])  # event 1 happens 1e-12 after event 0: below the accuracy
    assert [g.events for g in s.simulate(x0, 2.0, simultaneity_tol=1e-5).groups] == [(0, 1)]
    x0 = np.array([0.0, -1e-6])  # event 1 happens 1e-6 after event 0
    assert [g.events for g in s.simulate(x0, 2.0, simultaneity_tol=1e-8).groups] == [
        (0,),
        (1,),
    ]
    # within the tolerance but 1e-6 apart, far above the solver's accuracy: each is switched
    # at its own time (switching event 1 early would move the state)
    traj = s.simulate(x0, 2.0, simultaneity_tol=1e-5)
    assert [g.events for g in traj.groups] == [(0,), (1,)]
    np.testing.assert_allclose(np.diff([g.time for g in traj.groups]), [1e-6], rtol=1e-6)


def test_downward_crossing_into_a_region_that_pushes_back_is_an_error():
    # x' = 1 - 2 y after the event (y = t): x comes back down through the surface at
    # t = 0.75, a downward crossing (allowed), but region 0 pushes x up again at once
    s = HybridSystem(
        lambda x, m: np.array([1.0 if m == 0 else 1.0 - 2.0 * x[1], 1.0]),
        lambda x: np.array([x[0] - 0.25]),
        n_events=1,
        dim=2,
    )
    with pytest.raises(
        ValueError,
        match=r"transversality violated at t=0.75 after switching events \[0\]: event 0 has "
        r"rate -1 <= 0 in region mask 0b0 .*would cross back\); event 0 crossed downward "
        r"\(the rate is that of -h_0",
    ):
        s.simulate(np.zeros(2), 1.0)
    assert s.simulate(np.zeros(2), 0.7).mask_final == 1


def test_switch_into_a_region_that_pushes_back_is_an_error():
    s = HybridSystem(
        lambda x, m: np.array([1.0 if m == 0 else -1.0]),
        lambda x: x - 0.5,
        n_events=1,
        dim=1,
    )
    with pytest.raises(
        ValueError,
        match=r"transversality violated at t=0.5 after switching events \[0\]: event 0 has "
        r"rate -1 <= 0 in region mask 0b1 .*would cross back",
    ):
        s.simulate(np.zeros(1), 1.0)


# ------------------------------------------------------------------------------------------
# a group is checked against the model (issue 9, item 5)
# ------------------------------------------------------------------------------------------
# constant fields, events x_k = 1: from (0, -0.5) event 0 happens at t = 1, event 1 at t = 2
# (x_1 moves at 0.5 in region 0b01); by hand x(3) = (3, 3). Grouping event 1 with event 0
# at t = 1 would move x_1 at 2 from t = 1 on: x(3) = (3, 4.5).
GAP_RATES = np.array([[1.0, 1.0], [1.0, 0.5], [1.0, 1.0], [1.0, 2.0]])
GAP_X0 = np.array([0.0, -0.5])


def test_simultaneity_tol_larger_than_the_gap_keeps_the_true_state():
    # (reliability, fourth pass, item 6: was refused) the run switches each event at its
    # own time, so the state is the hand-computed one; the flow map merges the two groups
    # and says how far apart they were
    s = constant_system(GAP_RATES)
    traj = s.simulate(GAP_X0, 3.0, simultaneity_tol=1.0)
    assert [(round(g.time, 9), g.events) for g in traj.groups] == [(1.0, (0,)), (2.0, (1,))]
    np.testing.assert_allclose(traj.x_final, [3.0, 3.0], rtol=1e-10)
    fb = s.flow_bderivative(GAP_X0, 3.5, simultaneity_tol=1.25)  # t_final 1.5 after both
    assert fb.group_events == ((0, 1),) and not fb.stops_at_group
    np.testing.assert_allclose(fb.group_spreads, [1.0], rtol=1e-9)
    assert "spreads=[1.0]" in repr(fb)


def test_simultaneity_tol_below_the_gap_gives_the_true_state():
    traj = constant_system(GAP_RATES).simulate(GAP_X0, 3.0, simultaneity_tol=0.1)
    assert [(round(g.time, 9), g.events) for g in traj.groups] == [(1.0, (0,)), (2.0, (1,))]
    np.testing.assert_allclose(traj.x_final, [3.0, 3.0], rtol=1e-10)


def test_group_tolerance_formula():
    Dh = np.array([[1.0, -2.0], [0.0, 0.5]])
    tol = group_tolerance(Dh, SolverOptions(rtol=1e-8, atol=1e-9), scale=10.0)
    step = 1e-9 + 1e-8 * 10.0
    np.testing.assert_allclose(tol, GLOBAL_ERROR_FACTOR * step * np.array([3.0, 0.5]))


def test_examples_group_with_a_wide_window():
    # the examples' start points reach rho to within the integration accuracy: a wide
    # window groups all events, and the check accepts them
    ex = examples.network(4, extended=True)
    traj = ex.system.simulate(ex.x0, ex.t_final, simultaneity_tol=1e-3)
    assert [g.events for g in traj.groups] == [(0, 1, 2, 3)]


# ------------------------------------------------------------------------------------------
# solver options and numeric arguments (issue 9, items 7 and 12)
# ------------------------------------------------------------------------------------------
def test_solver_options_defaults_and_overrides():
    o = SolverOptions()
    assert (o.rtol, o.atol, o.method, o.max_step) == (1e-10, 1e-12, "DOP853", np.inf)
    assert o.with_overrides(rtol=1e-9, method=None).rtol == 1e-9
    assert o.with_overrides() is o
    assert SolverOptions.resolve(None, atol=1e-8) == SolverOptions(atol=1e-8)
    tight = SolverOptions(rtol=1e-12)
    assert SolverOptions.resolve(None, tight) is tight
    assert SolverOptions.resolve(None, tight, rtol=1e-7).rtol == 1e-7
    assert SolverOptions.resolve(o, tight, rtol=1e-10) == o  # agrees: no conflict
    with pytest.raises(ValueError, match=r"rtol=1e-07 and options.rtol=1e-10 disagree"):
        SolverOptions.resolve(o, tight, rtol=1e-7)
    # simultaneity_tol: the options' own, else the function's default
    tol = SolverOptions(simultaneity_tol=1e-9)
    assert SolverOptions.resolve(o, tol).simultaneity_tol == 1e-9
    assert SolverOptions.resolve(tol, o).simultaneity_tol == 1e-9
    assert SolverOptions.resolve(o, tol, simultaneity_tol=0).simultaneity_tol == 0.0
    with pytest.raises(ValueError, match=r"simultaneity_tol=0.0 and options.simultaneity_tol"
                                         r"=1e-09 disagree"):
        SolverOptions.resolve(tol, o, simultaneity_tol=0.0)
    assert o.solve_ivp_kwargs() == {"rtol": 1e-10, "atol": 1e-12, "method": "DOP853",
                                    "max_step": np.inf}
    assert SolverOptions(method=RK23).method is RK23
    with pytest.raises(AttributeError):
        o.rtol = 1.0
    with pytest.raises(TypeError, match="options must be a SolverOptions, got dict"):
        SolverOptions.resolve({"rtol": 1e-9})


@pytest.mark.parametrize(
    ("kwargs", "error", "match"),
    [
        ({"rtol": np.nan}, ValueError, "rtol must be a finite number > 0, got nan"),
        ({"atol": np.nan}, ValueError, "atol must be a finite number > 0, got nan"),
        ({"rtol": np.inf}, ValueError, "rtol must be a finite number > 0, got inf"),
        ({"rtol": 0.0}, ValueError, "rtol must be a finite number > 0, got 0.0"),
        ({"rtol": 1e-20}, ValueError, r"rtol must be in \[2.22e-14, 1\).*got 1e-20"),
        ({"rtol": 2.0}, ValueError, r"rtol must be in \[2.22e-14, 1\)"),
        ({"atol": -1.0}, ValueError, "atol must be a finite number > 0, got -1.0"),
        ({"atol": np.inf}, ValueError, "atol must be a finite number > 0, got inf"),
        ({"max_step": 0.0}, ValueError, "max_step must be a number > 0, got 0.0"),
        ({"max_step": np.nan}, ValueError, "max_step must be a number > 0, got nan"),
        ({"method": "Euler"}, ValueError, "method must be one of RK45, .*got 'Euler'"),
        ({"method": 3}, ValueError, "method must be one of"),
        ({"rtol": "1e-9"}, TypeError, "rtol must be a real number, got str '1e-9'"),
        ({"atol": True}, TypeError, "atol must be a real number, got bool"),
        ({"atol": 1j}, TypeError, "atol must be a real number, got complex"),
    ],
)
def test_bad_solver_options(kwargs, error, match):
    with pytest.raises(error, match=match):
        SolverOptions(**kwargs)
    s = constant_system(np.ones((4, 2)))
    # the public methods check them before integrating (rtol=nan used to hang solve_ivp)
    for call in (
        lambda: s.simulate(np.zeros(2), 1.0, **kwargs),
        lambda: s.flow_bderivative(np.zeros(2), 2.0, **kwargs),
        lambda: s.flow_fd(np.zeros(2), 2.0, np.ones(2), 1e-3, **kwargs),
    ):
        with pytest.raises(error, match=match):
            call()


@pytest.mark.parametrize(
    ("name", "value", "error", "match"),
    [
        ("t_final", np.nan, ValueError, "t_final must be a finite number > 0, got nan"),
        ("t_final", np.inf, ValueError, "t_final must be a finite number > 0, got inf"),
        ("t_final", 0.0, ValueError, "t_final must be a finite number > 0, got 0.0"),
        ("t_final", "2", TypeError, "t_final must be a real number, got str '2'"),
        ("t_final", np.ones(1), TypeError, "t_final must be a real number, got ndarray"),
        ("simultaneity_tol", np.nan, ValueError,
         "simultaneity_tol must be a finite number >= 0, got nan"),
        ("simultaneity_tol", np.inf, ValueError,
         "simultaneity_tol must be a finite number >= 0, got inf"),
        ("simultaneity_tol", "0", TypeError, "simultaneity_tol must be a real number"),
    ],
)
def test_bad_times(name, value, error, match):
    s = constant_system(np.ones((4, 2)))
    kwargs = {"t_final": 2.0, "simultaneity_tol": 1e-9, name: value}
    with pytest.raises(error, match=match):
        s.simulate(np.zeros(2), kwargs.pop("t_final"), **kwargs)


def test_negative_simultaneity_tol():
    s = constant_system(np.ones((4, 2)))
    with pytest.raises(ValueError, match="simultaneity_tol must be a finite number >= 0"):
        s.simulate(np.zeros(2), 2.0, simultaneity_tol=-1.0)


def test_options_object_and_keywords_agree():
    s = constant_system(np.array([[1.0, 1.0], [1.0, 2.0], [2.0, 1.0], [3.0, 3.0]]))
    a = s.simulate(np.zeros(2), 2.0, options=SolverOptions(rtol=1e-6, method="RK45"))
    b = s.simulate(np.zeros(2), 2.0, rtol=1e-6, method="RK45")
    np.testing.assert_array_equal(a.t, b.t)
    c = s.simulate(np.zeros(2), 2.0, method=RK23)  # an OdeSolver class works too
    np.testing.assert_allclose(c.x_final, [4.0, 4.0], rtol=1e-8)
    # simultaneity_tol travels in the options value too; a keyword that disagrees with it
    # is refused, naming both
    d = s.simulate(np.zeros(2), 2.0, options=SolverOptions(simultaneity_tol=1e-9))
    e = s.simulate(np.zeros(2), 2.0, simultaneity_tol=1e-9)
    np.testing.assert_array_equal(d.t, e.t)
    assert d.simultaneity_tol == e.simultaneity_tol == 1e-9
    assert s.simulate(np.zeros(2), 2.0).simultaneity_tol == 1e-12  # simulate's default
    for kw in ({"rtol": 1e-7}, {"simultaneity_tol": 1e-8}):
        with pytest.raises(ValueError, match=rf"{next(iter(kw))}=1e-0\d and options\."):
            s.simulate(np.zeros(2), 2.0, options=SolverOptions(rtol=1e-6,
                                                               simultaneity_tol=1e-9), **kw)
    with pytest.raises(ValueError, match=r"simultaneity_tol=0.5 and options.simultaneity_tol"):
        s.flow_bderivative(np.zeros(2), 2.0, simultaneity_tol=0.5,
                           options=SolverOptions(simultaneity_tol=1e-7))


def test_one_event_jacobian_per_stop():
    """The excursion screen, settle and switch look at a stop's state through one set of
    evaluations (stopcalls.StopCalls): one event Jacobian per stretch end, on both paths."""
    ex = examples.chair()
    s = ex.system
    calls = []
    counted = HybridSystem(s.field, s.events, n_events=2, dim=6,
                           event_jacobian=lambda x: calls.append(1)
                           or s.calls.eval_event_jacobian(x),
                           field_jacobian=s.field_jacobian)
    traj = counted.simulate(ex.x0, 1.0)
    assert len(traj.groups) == 5
    assert len(calls) == len(traj.groups) + 1  # each stop, and the end at t_final
