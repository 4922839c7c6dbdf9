"""The examples end to end: flow_bderivative against finite differences of simulation.

The real check of the library: for every example, many random tangent vectors (covering
several event orders) and vectors within 1e-6 of the boundaries between pieces, the one-sided
finite difference ``(Phi(x0 + eps v) - Phi(x0)) / eps`` of an event-detecting simulation
converges to ``flow_bderivative(x0, T)(v)`` with error O(eps): at eps = 1e-3, 1e-4, 1e-5 the
error shrinks by a factor close to 10 each time.
"""

from __future__ import annotations

import pickle

import numpy as np
import pytest

from bderiv import examples
from bderiv.analysis.checks import fd_check
from bderiv.analysis.flowmap import FlowBDerivative
from bderiv.analysis.system import HybridSystem

EPS = (1e-3, 1e-4, 1e-5)


def boundary_vectors(fb, rng, count, delta=1e-6, tries=200):
    """Vectors within ``delta`` (relative) of a boundary between pieces of group 0."""
    d = fb.dim
    out = []
    for _ in range(tries):
        if len(out) >= count:
            break
        a, b = rng.standard_normal((2, d))
        oa, ob = fb.orders(np.stack([a, b]))[0]
        if np.array_equal(oa, ob):
            continue
        lo, hi = 0.0, 1.0  # order(a + lo (b - a)) == oa, order at hi differs
        for _ in range(60):
            mid = 0.5 * (lo + hi)
            if np.array_equal(fb.orders(a + mid * (b - a))[0], oa):
                lo = mid
            else:
                hi = mid
        s = lo if len(out) % 2 == 0 else hi
        v = a + s * (b - a)
        out.append(v + delta * np.linalg.norm(v) * rng.standard_normal(d) / np.sqrt(d))
    assert len(out) == count, "could not find vectors near piece boundaries"
    return np.array(out)


def fd_errors(ex, fb, V, eps_values=EPS):
    """Relative errors (m, len(eps)) of flow_fd against fb(V)."""
    return fd_check(ex.system, ex.x0, ex.t_final, V, fb(V), eps_values).errors


def assert_first_order(errs):
    """Errors shrink in proportion to eps (ratio ~ 0.1 per decade), per vector and overall."""
    worst = errs.max(axis=0)
    ratios = worst[1:] / worst[:-1]
    assert np.all((ratios > 0.03) & (ratios < 0.2)), f"max errors {worst}, ratios {ratios}"
    # each vector: O(eps) bound with a common constant, and no vector stalls
    const = errs[:, 0] / EPS[0]
    assert np.all(errs[:, -1] <= 3 * const * EPS[-1] + 1e-7), errs
    assert worst[-1] < 5e-3, worst


def check_example(ex, n_random, n_boundary, seed=0, min_orders=2):
    rng = np.random.default_rng(seed)
    fb = ex.system.flow_bderivative(ex.x0, ex.t_final)
    assert isinstance(fb, FlowBDerivative)
    assert fb.n_groups == 1 and fb.group_events[0] == tuple(range(ex.system.n_events))
    V = rng.standard_normal((n_random, ex.system.dim))
    orders = fb.orders(V)[0]
    assert len({tuple(o) for o in orders}) >= min_orders
    if n_boundary:
        V = np.concatenate([V, boundary_vectors(fb, rng, n_boundary)])
    errs = fd_errors(ex, fb, V)
    assert_first_order(errs)
    return errs


# ------------------------------------------------------------------------------------------
# construction of each example: x0 reaches rho with all events at t_event
# ------------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    "make",
    [
        examples.chair,
        lambda: examples.chair(mode_damping=0.0),
        examples.table,
        lambda: examples.network(3),
        lambda: examples.network(4, extended=True),
    ],
    ids=["chair", "chair-additive", "table", "network3", "network4-extended"],
)
def test_example_reaches_event_point(make):
    ex = make()
    s = ex.system
    assert np.all(s.calls.eval_events(ex.x0) < 0)
    np.testing.assert_allclose(s.calls.eval_events(ex.rho), 0, atol=1e-14)
    traj = s.simulate(ex.x0, ex.t_final, simultaneity_tol=1e-9)
    assert len(traj.groups) == 1
    g = traj.groups[0]
    assert g.events == tuple(range(s.n_events))
    assert g.time == pytest.approx(ex.t_event, abs=1e-9)
    np.testing.assert_allclose(g.state, ex.rho, atol=1e-9)
    assert traj.mask_final == (1 << s.n_events) - 1
    assert ex.t_final > ex.t_event and ex.description and ex.name


# ------------------------------------------------------------------------------------------
# finite differences converge to the B-derivative (CI subset)
# ------------------------------------------------------------------------------------------
def test_chair_fd_convergence():
    errs = check_example(examples.chair(), n_random=8, n_boundary=4)
    assert errs[:, -1].max() < 1e-3


def test_network_fd_convergence():
    check_example(examples.network(3), n_random=8, n_boundary=4, min_orders=3)


def test_network_extended_fd_convergence():
    check_example(examples.network(3, extended=True), n_random=6, n_boundary=2)


def test_table_fd_convergence():
    check_example(examples.table(), n_random=5, n_boundary=1, min_orders=3)


@pytest.mark.slow
@pytest.mark.parametrize(
    "make",
    [
        lambda: examples.chair(mode_damping=0.0),
        lambda: examples.network(6, seed=3),
        lambda: examples.network(6, extended=True, seed=4),
        lambda: examples.table(mode_damping=3.0),
    ],
    ids=["chair-additive", "network6", "network6-extended", "table-damped"],
)
def test_fd_convergence_more(make):
    check_example(make(), n_random=16, n_boundary=6)


@pytest.mark.slow
def test_network_n20_fd():
    ex = examples.network(20)
    fb = ex.system.flow_bderivative(ex.x0, ex.t_final)
    V = np.random.default_rng(5).standard_normal((2, 20))
    errs = fd_errors(ex, fb, V)
    assert_first_order(errs)


# ------------------------------------------------------------------------------------------
# example-specific properties
# ------------------------------------------------------------------------------------------
def test_chair_mode_damping_gives_two_pieces():
    bd = examples.chair().system.bderivative(examples.chair().rho)
    assert np.abs(bd.piece([0, 1]) - bd.piece([1, 0])).max() > 1.0
    ex0 = examples.chair(mode_damping=0.0)
    bd0 = ex0.system.bderivative(ex0.rho)
    np.testing.assert_allclose(bd0.piece([0, 1]), bd0.piece([1, 0]), atol=1e-12)


def test_chair_event_jacobian_analytic_vs_numerical():
    ex = examples.chair()
    s = ex.system
    bare = HybridSystem(s.calls.eval_field, s.calls.eval_events, n_events=2, dim=6)
    np.testing.assert_allclose(
        bare.calls.eval_event_jacobian(ex.rho), s.calls.eval_event_jacobian(ex.rho), atol=1e-9
    )
    for mask in range(4):
        np.testing.assert_allclose(
            bare.calls.eval_field_jacobian(ex.rho, mask),
            s.calls.eval_field_jacobian(ex.rho, mask),
            atol=1e-7,
            rtol=1e-8,
        )


def test_table_rank_deficient():
    ex = examples.table()
    bd = ex.system.bderivative(ex.rho)
    assert bd.n_events == 4 and np.linalg.matrix_rank(bd.Dh) == 3
    assert not bd.full_rank
    # the yaw is invisible to the events
    assert np.all(bd.Dh[:, 5] == 0)


def test_network_orders_differ_from_first_order_impact_times():
    ex = examples.network(3)
    bd = ex.system.bderivative(ex.rho)
    V = np.random.default_rng(2).standard_normal((400, 3))
    _, order = bd.event_times(V)
    naive = np.argsort(-(V @ bd.Dh.T) / bd.rates[0], axis=1, kind="stable")
    differ = np.flatnonzero(np.any(order != naive, axis=1))
    assert differ.size > 10
    # on such a vector the naive piece is wrong and the true one agrees with simulation
    fb = ex.system.flow_bderivative(ex.x0, ex.t_final)
    W = np.linalg.solve(fb.linear[0], V[differ[:2]].T).T  # start perturbations hitting V
    fd = ex.system.flow_fd(ex.x0, ex.t_final, W, 1e-5)
    np.testing.assert_allclose(fd, fb(W), rtol=0, atol=1e-4 * np.abs(fb(W)).max())
    for w, o in zip(W, naive[differ[:2]], strict=True):
        wrong = fb.piece([o]) @ w
        assert np.abs(wrong - fb(w)).max() > 1e-3


def test_network_corner_field_matches_field():
    ex = examples.network(5, extended=True, seed=1)
    s = ex.system
    x = np.random.default_rng(0).standard_normal(10) * 0.3
    table = s.calls.sample_corners(x)
    loop = np.array([s.calls.eval_field(x, m) for m in range(32)])
    np.testing.assert_allclose(table, loop, rtol=1e-13, atol=1e-14)


@pytest.mark.parametrize("extended", [False, True])
def test_network_analytic_jacobians(extended):
    ex = examples.network(4, extended=extended, seed=2)
    s = ex.system
    bare = HybridSystem(s.calls.eval_field, s.calls.eval_events, n_events=4, dim=s.dim)
    x = ex.x0 * 0.5
    np.testing.assert_allclose(bare.calls.eval_event_jacobian(x), s.calls.eval_event_jacobian(x),
                               atol=1e-9)
    for mask in (0, 5, 15):
        np.testing.assert_allclose(
            bare.calls.eval_field_jacobian(x, mask), s.calls.eval_field_jacobian(x, mask),
            atol=1e-8
        )


def test_network_n16_sampling_is_fast_and_right():
    ex = examples.network(16)
    s = ex.system
    bd = s.bderivative(ex.rho)
    assert bd.F.shape == (1 << 16, 16)
    rng = np.random.default_rng(0)
    for mask in rng.integers(0, 1 << 16, 20):
        np.testing.assert_allclose(bd.F[mask], s.calls.eval_field(ex.rho, int(mask)), rtol=1e-13)
    np.testing.assert_allclose(bd.Dh, s.calls.eval_event_jacobian(ex.rho))


@pytest.mark.slow
def test_network_n20_bderivative():
    ex = examples.network(20)
    bd = ex.system.bderivative(ex.rho)
    assert bd.F.shape == (1 << 20, 20)
    V = np.random.default_rng(0).standard_normal((100, 20))
    assert np.isfinite(bd(V)).all()


@pytest.mark.parametrize(
    "make",
    [examples.chair, examples.table, lambda: examples.network(3),
     lambda: examples.network(4, extended=True)],
    ids=["chair", "table", "network3", "network4-extended"],
)
def test_flow_map_inverse_round_trips(make):
    ex = make()
    fb = ex.system.flow_bderivative(ex.x0, ex.t_final)
    rng = np.random.default_rng(6)
    V = rng.standard_normal((200, fb.dim))
    assert len({tuple(o) for o in fb.orders(V)[0]}) >= 2  # several pieces crossed
    W = fb(V)
    tol = 1e-10 * np.abs(V).max()
    np.testing.assert_allclose(fb.inverse(W), V, rtol=0, atol=tol)
    W = rng.standard_normal((200, fb.dim))
    np.testing.assert_allclose(fb(fb.inverse(W)), W, rtol=0, atol=1e-10 * np.abs(W).max())


def test_example_flow_bderivative_pickles():
    ex = examples.chair()
    fb = ex.system.flow_bderivative(ex.x0, ex.t_final)
    fb2 = pickle.loads(pickle.dumps(fb))
    V = np.random.default_rng(0).standard_normal((5, 6))
    np.testing.assert_array_equal(fb(V), fb2(V))


def test_network_rejects_bad_n():
    with pytest.raises(ValueError, match=r"n must be an integer in \[1, 24\], got 0"):
        examples.network(0)


def test_chair_corners_closed_form():
    # at touchdown the springs are relaxed: only damping and friction act, by hand
    ex = examples.chair(mode_damping=1.0, damping=4.0, friction=1.0, inertia=0.1)
    F = ex.system.bderivative(ex.rho).F
    _, z, th, vx, vz, om = ex.rho
    legs = np.array([[-0.5, -0.4], [0.6, -0.4 + (-1.1) * np.tan(0.1)]])
    rx = legs[:, 0] * np.cos(th) - legs[:, 1] * np.sin(th)
    rz = legs[:, 0] * np.sin(th) + legs[:, 1] * np.cos(th)
    vfx, vfz = vx - om * rz, vz + om * rx
    np.testing.assert_allclose(F[0], [vx, vz, om, 0.0, -9.81, 0.0], rtol=1e-14)
    for mask, c in ((1, 4.0), (2, 4.0), (3, 8.0)):
        legs_on = [k for k in range(2) if mask >> k & 1]
        fz = -c * vfz[legs_on]
        fx = -1.0 * vfx[legs_on]
        expect = [
            vx,
            vz,
            om,
            fx.sum(),
            -9.81 + fz.sum(),
            (rx[legs_on] @ fz - rz[legs_on] @ fx) / 0.1,
        ]
        np.testing.assert_allclose(F[mask], expect, rtol=1e-13, atol=1e-13)


def test_table_jacobians_complex_step_vs_scipy():
    ex = examples.table()
    s = ex.system
    bare = HybridSystem(s.calls.eval_field, s.calls.eval_events, n_events=4, dim=12)
    np.testing.assert_allclose(
        bare.calls.eval_event_jacobian(ex.rho), s.calls.eval_event_jacobian(ex.rho), atol=1e-9
    )
    for mask in (0, 15):
        np.testing.assert_allclose(
            bare.calls.eval_field_jacobian(ex.rho, mask),
            s.calls.eval_field_jacobian(ex.rho, mask),
            atol=1e-7,
            rtol=1e-8,
        )
