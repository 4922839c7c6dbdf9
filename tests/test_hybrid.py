"""HybridSystem: checked calls, sampling, the B-derivative at a point, flow derivatives.

(Simulation and event detection: tests/test_simulate.py.)
"""

from __future__ import annotations

import numba
import numpy as np
import pytest
import scipy.linalg

from bderiv import BDerivative, examples
from bderiv.analysis.checks import fd_check
from bderiv.analysis.system import HybridSystem

EPS = (1e-3, 1e-4, 1e-5)


def constant_system(rates, n=2, events=None):
    """Constant fields ``rates[mask]`` (2**n, d); events h_k = x_k - 1 unless given."""
    rates = np.asarray(rates, dtype=float)
    d = rates.shape[1]

    def field(x, mask):
        return rates[mask].copy()

    def ev(x):
        return x[:n] - 1.0

    return HybridSystem(field, events or ev, n_events=n, dim=d)


def fd_rel_errors(system, x0, T, fb, V):
    return fd_check(system, x0, T, V, fb(V), EPS).errors


def assert_shrinks(errs):
    worst = errs.max(axis=0)
    ratios = worst[1:] / worst[:-1]
    assert np.all((ratios > 0.03) & (ratios < 0.2)), (worst, ratios)


# ------------------------------------------------------------------------------------------
# construction and checked evaluations
# ------------------------------------------------------------------------------------------
def test_constructor_validation():
    f, h = (lambda x, m: x), (lambda x: x)  # noqa: E731
    with pytest.raises(TypeError, match="field must be callable"):
        HybridSystem(3, h, n_events=1, dim=1)
    with pytest.raises(TypeError, match="corner_field must be callable"):
        HybridSystem(f, h, n_events=1, dim=1, corner_field="no")
    with pytest.raises(ValueError, match="n_events must be an integer >= 1"):
        HybridSystem(f, h, n_events=0, dim=1)
    with pytest.raises(TypeError, match="dim must be an integer"):
        HybridSystem(f, h, n_events=1, dim=2.0)
    assert "n_events=1" in repr(HybridSystem(f, h, n_events=1, dim=1))
    # a function that cannot take its arguments, named by its role (Python's own TypeError
    # at the first call named none; a review), numba's by its Python code
    with pytest.raises(TypeError, match=r"events is called as events\(x\), but it takes "
                                        r"\(x, m\)"):
        HybridSystem(f, f, n_events=1, dim=1)
    with pytest.raises(TypeError, match=r"field is called as field\(x, mask\), but it takes "
                                        r"\(x\)"):
        HybridSystem(numba.njit(h), numba.njit(h), n_events=1, dim=1)
    with pytest.raises(TypeError, match=r"reset is called as reset\(x, mask, k\)"):
        HybridSystem(f, h, n_events=1, dim=1, reset=f)
    HybridSystem(f, np.negative, n_events=1, dim=1)  # a ufunc: not inspectable, taken
    HybridSystem(lambda x, *rest: x, lambda x, **kw: x, n_events=1, dim=1)


@pytest.mark.parametrize(
    ("field", "events", "match"),
    [
        (
            lambda x, m: np.ones(3),
            lambda x: x - 1,
            r"field\(x, mask=0\) must return an array of shape \(2,\), got shape \(3,\)",
        ),
        (lambda x, m: np.ones((2, 1)), lambda x: x - 1, r"shape \(2,\), got shape \(2, 1\)"),
        (
            lambda x, m: np.ones(2),
            lambda x: np.zeros(3) - 1,
            r"events\(x\) must return an array of shape \(2,\), got shape \(3,\)",
        ),
        (
            lambda x, m: np.array([1.0, np.nan]),
            lambda x: x - 1,
            r"field\(x, mask=0\) returned a non-finite value: entry \[1\] = nan",
        ),
        (
            lambda x, m: np.ones(2),
            lambda x: np.array([np.inf, -1.0]),
            r"events\(x\) returned a non-finite value",
        ),
    ],
)
def test_bad_user_functions_in_simulate(field, events, match):
    s = HybridSystem(field, events, n_events=2, dim=2)
    with pytest.raises(ValueError, match=match):
        s.simulate(np.zeros(2), 1.0)


def test_user_function_returning_strings_is_a_type_error():
    s = HybridSystem(lambda x, m: np.array(["a", "b"]), lambda x: x - 1, n_events=2, dim=2)
    with pytest.raises(TypeError, match="field"):
        s.calls.eval_field(np.zeros(2), 0)


def test_bad_jacobians_and_corner_field():
    s = HybridSystem(
        lambda x, m: np.ones(2),
        lambda x: x,
        n_events=2,
        dim=2,
        event_jacobian=lambda x: np.eye(3),
        field_jacobian=lambda x, m: np.full((2, 2), np.nan),
        corner_field=lambda x: np.ones((3, 2)),
    )
    with pytest.raises(
        ValueError,
        match=r"event_jacobian\(x\) must return an array of shape \(2, 2\), got shape \(3, 3\)",
    ):
        s.calls.eval_event_jacobian(np.zeros(2))
    with pytest.raises(ValueError, match=r"field_jacobian\(x, mask=1\) returned a non-finite"):
        s.calls.eval_field_jacobian(np.zeros(2), 1)
    with pytest.raises(
        ValueError,
        match=r"corner_field\(x\) must return an array of shape \(4, 2\), got shape \(3, 2\)",
    ):
        s.calls.sample_corners(np.zeros(2))
    with pytest.raises(ValueError, match=r"mask must be in \[0, 2\*\*2\)"):
        s.calls.eval_field_jacobian(np.zeros(2), 4)


def test_bad_outputs_name_the_call_with_its_arguments():
    """The names are formatted only when an output is refused: each still says which call
    with which mask and event gave it."""
    s = HybridSystem(lambda x, m: np.array([np.nan, 0.0]) if m == 2 else np.ones(2),
                     lambda x: x, n_events=2, dim=2, reset=lambda x, m, k: np.ones(3),
                     reset_jacobian=lambda x, m, k: np.eye(2)[:1])
    with pytest.raises(ValueError, match=r"field\(x, mask=2\) returned a non-finite value: "
                                         r"entry \[0\] = nan"):
        s.calls.eval_field(np.zeros(2), 2)
    s.calls.eval_field(np.zeros(2), 1)  # a good output is returned as it came
    with pytest.raises(ValueError, match=r"reset\(x, mask=1, k=0\) must return an array of "
                                         r"shape \(2,\), got shape \(3,\)"):
        s.calls.eval_reset(np.zeros(2), 1, 0)
    with pytest.raises(ValueError, match=r"reset_jacobian\(x, mask=1, k=1\) must return an "
                                         r"array of shape \(2, 2\), got shape \(1, 2\)"):
        s.calls.eval_reset_jacobian(np.zeros(2), 1, 1)


def test_bad_states():
    s = constant_system(np.ones((4, 2)))
    with pytest.raises(
        ValueError, match=r"x0 must have shape \(2,\) \(a state of this system\), got shape \(3,\)"
    ):
        s.simulate(np.zeros(3), 1.0)
    with pytest.raises(ValueError, match="x0 must be finite"):
        s.simulate(np.array([0.0, np.nan]), 1.0)
    with pytest.raises(TypeError, match="x0 must hold real numbers"):
        s.simulate(np.array([1 + 1j, 0]), 1.0)
    with pytest.raises(ValueError, match="t_final must be a finite number > 0, got -1.0"):
        s.simulate(np.zeros(2), -1.0)
    with pytest.raises(ValueError, match=r"rho must have shape \(2,\)"):
        s.bderivative(np.zeros(1))


def test_start_on_surface_is_refused():
    s = constant_system(np.ones((4, 2)))
    with pytest.raises(
        ValueError,
        match=r"x0 lies on the surface of event\(s\) \[1\].*start slightly before or after",
    ):
        s.simulate(np.array([0.0, 1.0]), 1.0)
    # just after the surface is fine: the start mask has bit 1 set
    assert s.calls.start_mask(np.array([0.0, 1.0 + 1e-12])) == 2


# ------------------------------------------------------------------------------------------
# bderivative at an event point
# ------------------------------------------------------------------------------------------
def test_bderivative_samples_the_model():
    rates = np.array([[1.0, 2.0], [1.5, 2.0], [1.0, 0.5], [2.0, 1.0]])
    s = constant_system(rates)
    bd = s.bderivative(np.ones(2))
    assert isinstance(bd, BDerivative)
    np.testing.assert_array_equal(bd.F, rates)
    np.testing.assert_allclose(bd.Dh, np.eye(2), atol=1e-9)


def test_bderivative_refuses_non_event_point_naming_residuals():
    s = constant_system(np.ones((4, 2)))
    with pytest.raises(ValueError, match=r"residuals above tol=1e-09 for events \[1\]"):
        s.bderivative(np.array([1.0, 0.9]))


@pytest.mark.parametrize(
    ("tol", "error", "match"),
    [
        (np.nan, ValueError, "tol must be a finite number >= 0, got nan"),
        (np.inf, ValueError, "tol must be a finite number >= 0, got inf"),
        (-1e-9, ValueError, "tol must be a finite number >= 0, got -1e-09"),
        ("1e-9", TypeError, "tol must be a real number, got str '1e-9'"),
        (None, TypeError, "tol must be a real number, got NoneType"),
    ],
)
def test_bderivative_tol_is_checked(tol, error, match):
    # tol=nan used to accept any point (every comparison with nan is False)
    s = constant_system(np.ones((4, 2)))
    with pytest.raises(error, match=match):
        s.bderivative(np.array([1.0, 0.5]), tol=tol)


def test_bderivative_transversality_names_mask_and_event():
    rates = np.ones((4, 2))
    rates[1] = [1.0, -0.5]
    s = constant_system(rates)
    with pytest.raises(
        ValueError,
        match=r"transversality violated at rho: event 1 has rate -0.5 <= 0 in region mask 0b01 ",
    ):
        s.bderivative(np.ones(2))
    # an event crossed downward at rho: the refusal says what bderivative(rho) assumes and
    # what takes such a group (it named only the rate: a review)
    with pytest.raises(ValueError, match=r"rho is entered from region 0, every event crossed "
                                         r"upward .*negate its h_k, or take flow_bderivative"):
        s.bderivative(np.ones(2))


# ------------------------------------------------------------------------------------------
# flow derivatives
# ------------------------------------------------------------------------------------------
def test_no_event_gives_the_classical_derivative():
    A = np.array([[-0.3, 1.0, 0.0], [-1.0, -0.2, 0.5], [0.1, 0.0, -0.4]])
    b = np.array([0.2, -0.1, 0.3])
    s = HybridSystem(
        lambda x, m: A @ x + b,
        lambda x: np.array([x[0] - 100.0]),
        n_events=1,
        dim=3,
        field_jacobian=lambda x, m: A,
    )
    x0 = np.array([0.5, -0.3, 0.2])
    T = 1.7
    fb = s.flow_bderivative(x0, T)
    assert fb.is_linear and fb.n_groups == 0
    np.testing.assert_allclose(fb.linear[0], scipy.linalg.expm(A * T), atol=1e-9)
    V = np.random.default_rng(0).standard_normal((4, 3))
    np.testing.assert_allclose(fb(V), V @ scipy.linalg.expm(A * T).T, atol=1e-9)
    np.testing.assert_allclose(fb.final_field, A @ fb.x_final + b, atol=1e-12)
    fd = s.flow_fd(x0, T, V, 1e-6)
    np.testing.assert_allclose(fd, fb(V), atol=1e-6)
    np.testing.assert_allclose(fb.piece(), scipy.linalg.expm(A * T), atol=1e-9)


def test_numerical_jacobians_match_analytic_flow_bderivative():
    ex = examples.network(2, seed=1)
    s = ex.system
    bare = HybridSystem(s.calls.eval_field, s.calls.eval_events, n_events=2, dim=2)
    fa = s.flow_bderivative(ex.x0, ex.t_final)
    fn = bare.flow_bderivative(ex.x0, ex.t_final)
    V = np.random.default_rng(3).standard_normal((20, 2))
    np.testing.assert_allclose(fn(V), fa(V), rtol=1e-7, atol=1e-8)


def test_close_but_not_simultaneous_events_are_separate_groups():
    ex = examples.network(2, seed=0)
    s = ex.system
    x0 = ex.x0.copy()
    x0[1] -= 0.02  # event 1 now happens about 0.02 later
    fb = s.flow_bderivative(x0, ex.t_final)
    assert fb.n_groups == 2
    assert fb.group_events == ((0,), (1,))
    assert fb.group_times[1] - fb.group_times[0] > 0.01
    # every group is a classical saltation: the whole map is linear
    V = np.random.default_rng(1).standard_normal((8, 2))
    np.testing.assert_allclose(fb(V), V @ fb.piece().T, rtol=1e-12, atol=1e-12)
    errs = fd_rel_errors(s, x0, ex.t_final, fb, V)
    assert_shrinks(errs)
    assert errs[:, -1].max() < 1e-3


def test_simultaneity_tol_merges_close_events():
    ex = examples.network(2, seed=0)
    x0 = ex.x0.copy()
    x0[1] -= 1e-11  # event 1 about 1e-11 later: within the integration accuracy
    fb = ex.system.flow_bderivative(x0, ex.t_final, simultaneity_tol=1e-6)
    assert fb.n_groups == 1 and fb.group_events == ((0, 1),)
    apart = ex.system.flow_bderivative(x0, ex.t_final, simultaneity_tol=1e-13)
    assert apart.group_events == ((0,), (1,))
    x0[1] -= 1e-6  # now beyond it: switched apart, merged by the map with the gap said
    traj = ex.system.simulate(x0, ex.t_final, simultaneity_tol=1e-5)
    assert [g.events for g in traj.groups] == [(0,), (1,)]
    gap = traj.groups[1].time - traj.groups[0].time
    assert 1e-8 < gap < 1e-5
    fb = ex.system.flow_bderivative(x0, ex.t_final, simultaneity_tol=1e-5)
    assert fb.group_events == ((0, 1),)
    np.testing.assert_allclose(fb.group_spreads, [gap], rtol=1e-3)


def test_flow_fd_validation():
    ex = examples.network(2)
    s = ex.system
    with pytest.raises(ValueError, match="eps must be a finite number > 0, got 0.0"):
        s.flow_fd(ex.x0, 1.5, np.ones(2), 0.0)
    with pytest.raises(ValueError, match=r"V must have shape \(\.\.\., 2\).*got shape \(3,\)"):
        s.flow_fd(ex.x0, 1.5, np.ones(3), 1e-3)
    with pytest.raises(ValueError, match="eps must be a finite number > 0, got nan"):
        s.flow_fd(ex.x0, 1.5, np.ones(2), np.nan)
    with pytest.raises(TypeError, match="eps must be a real number, got str"):
        s.flow_fd(ex.x0, 1.5, np.ones(2), "1e-3")
    # a NaN in V is V's fault (it used to be reported as a non-finite x0)
    with pytest.raises(ValueError, match=r"V must be finite, but vector V\[1\] = \[nan  1.\]"):
        s.flow_fd(ex.x0, 1.5, np.array([[1.0, 1.0], [np.nan, 1.0]]), 1e-3)
    out = s.flow_fd(ex.x0, 1.5, np.ones((2, 1, 2)), 1e-3)
    assert out.shape == (2, 1, 2)


def test_flow_fd_is_one_sided():
    # at the event point the map is not linear: fd(v) and -fd(-v) differ, fd(v) -> D(v)
    ex = examples.chair()
    s = ex.system
    fb = s.flow_bderivative(ex.x0, ex.t_final)
    rng = np.random.default_rng(4)
    v = rng.standard_normal(6)
    while fb.orders(v)[0].tolist() == fb.orders(-v)[0].tolist():
        v = rng.standard_normal(6)
    fd_p = s.flow_fd(ex.x0, ex.t_final, v, 1e-5)
    fd_m = s.flow_fd(ex.x0, ex.t_final, -v, 1e-5)
    np.testing.assert_allclose(fd_p, fb(v), rtol=1e-3, atol=1e-4)
    assert np.abs(fd_p + fd_m).max() > 1e-2


def test_flow_bderivative_transversality_names_mask_and_event():
    # the nominal trajectory jumps from mask 0 to 3; mask 1 (never visited) breaks it
    rates = np.ones((4, 2))
    rates[1] = [1.0, -0.5]
    s = constant_system(rates)
    with pytest.raises(
        ValueError,
        match=r"transversality violated at the event point at t=[0-9.]+: event 1 has rate -0.5 "
        r"<= 0 in region mask 0b01 ",
    ):
        s.flow_bderivative(np.zeros(2), 2.0)


def test_constant_fields_flow_bderivative_is_the_bderivative():
    # constant fields: D- = D+ = I, so the flow's B-derivative is M itself
    rates = np.array([[1.0, 1.0], [1.0, 2.0], [2.0, 1.0], [1.5, 1.5]])
    s = constant_system(rates)
    fb = s.flow_bderivative(np.zeros(2), 2.0)
    bd = s.bderivative(np.ones(2))
    V = np.random.default_rng(0).standard_normal((50, 2))
    np.testing.assert_allclose(fb(V), bd(V), rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(fb.final_field, rates[3])


def test_groups_keep_the_stops_event_jacobian_and_the_map_is_the_same():
    """A variational run's groups carry the event Jacobian the stop evaluated at their
    state; the assembly's map from it is the map of a Jacobian evaluated again."""
    import dataclasses

    from bderiv.analysis.assembly import flow_map_along
    from bderiv.models.integrate.options import SolverOptions
    from bderiv.models.integrate.run import run

    ex = examples.network(2, seed=1)
    s = ex.system
    options = SolverOptions(simultaneity_tol=1e-7)
    traj = run(s.calls, ex.x0, ex.t_final, options=options, variational=True)
    assert traj.groups
    for g in traj.groups:
        np.testing.assert_array_equal(g.event_jacobian, s.calls.eval_event_jacobian(g.state))
    assert all(g.event_jacobian is None
               for g in run(s.calls, ex.x0, ex.t_final, options=options).groups)
    again = dataclasses.replace(traj, groups=tuple(g._replace(event_jacobian=None)
                                                   for g in traj.groups))
    V = np.random.default_rng(3).standard_normal((50, s.dim))
    np.testing.assert_array_equal(flow_map_along(s, traj)(V), flow_map_along(s, again)(V))


def _pickled_field(x, mask):
    return np.array([1.0, 0.5 + 0.5 * mask])


def _pickled_events(x):
    return np.array([x[0] - 1.0])


@pytest.mark.parametrize("compiled", [False, True], ids=["python", "numba"])
def test_a_model_pickles_before_and_after_a_run(compiled):
    """A model of module-level functions (Python or numba) goes through pickle, as Dask or
    multiprocessing ship it: its thread-local state and its functions' wrappers made it
    refuse. The copy is the same model: the same flow map."""
    import pickle

    fns = (_pickled_field, _pickled_events)
    if compiled:
        fns = tuple(map(numba.njit, fns))
    system = HybridSystem(*fns, n_events=1, dim=2, params=None)
    for _ in range(2):  # before and after a run
        copy = pickle.loads(pickle.dumps(system))
        assert (copy.n_events, copy.dim, copy.on_compiled_path) == (1, 2, compiled)
        D, E = (s.flow_bderivative(np.zeros(2), 2.0)(np.eye(2)) for s in (copy, system))
        np.testing.assert_array_equal(D, E)
        # x1(2) = 0.5 t_e + (2 - t_e) with the crossing t_e = 1 - dx0: the images of the
        # unit vectors (rows) are (1, 0.5) and (0, 1)
        np.testing.assert_allclose(D, [[1.0, 0.5], [0.0, 1.0]], atol=1e-9)
