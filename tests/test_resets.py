"""Tables with resets (mathematics.md section 9): BDerivative(Dh, F, resets=R) against the
oracles of tests/reference.py (the sampled trajectory followed in physical time, and the
products of saltation matrices with resets), the existence check, the low-rank form."""

from __future__ import annotations

import pickle

import numpy as np
import pytest
import reference as ref

from bderiv import BDerivative
from bderiv.engine._engines.resets import LowRankResets

SIZES = [(1, 1), (1, 3), (2, 2), (2, 4), (3, 3), (3, 5), (4, 6)]


@pytest.fixture(params=SIZES, ids=lambda s: f"n{s[0]}d{s[1]}")
def system(request):
    n, d = request.param
    rng = np.random.default_rng(100 * n + d)
    Dh, F, R = ref.random_reset_system(rng, n, d)
    return Dh, F, R, BDerivative(Dh, F, resets=R), rng


def test_apply_and_event_times_follow_the_sampled_trajectory(system):
    Dh, F, R, bd, rng = system
    V = rng.standard_normal((40, Dh.shape[1]))
    W = bd(V)
    times, orders = bd.event_times(V)
    for q in range(V.shape[0]):
        w, t, order = ref.ref_reset_flow(Dh, F, R, V[q])
        ref.assert_maps_close(Dh, F, V[q:q + 1], W[q:q + 1], w[None], rtol=1e-12)
        np.testing.assert_allclose(times[q], t, rtol=1e-12, atol=1e-12 * np.abs(t).max())
        assert np.array_equal(orders[q], order)


def test_pieces_are_the_products_of_saltation_matrices_with_resets(system):
    Dh, F, R, bd, rng = system
    n = Dh.shape[0]
    for order in ref.all_orders(n):
        expected = ref.ref_reset_piece(Dh, F, R, order)
        np.testing.assert_allclose(bd.piece(order), expected, rtol=1e-12,
                                   atol=1e-12 * np.abs(expected).max())
    V = rng.standard_normal((20, Dh.shape[1]))
    for v in V:
        w, order = ref.ref_reset_apply_by_pieces(Dh, F, R, v)
        assert np.array_equal(bd.orders(v), order)
        np.testing.assert_allclose(bd(v), w, rtol=1e-11, atol=1e-11 * np.abs(w).max())


def test_inverse_homogeneity_and_the_flow_direction(system):
    Dh, F, R, bd, rng = system
    V = rng.standard_normal((200, Dh.shape[1]))
    W = bd(V)
    np.testing.assert_allclose(bd.inverse(W), V, rtol=1e-10, atol=1e-10 * np.abs(V).max())
    np.testing.assert_allclose(bd(2.5 * V), 2.5 * W, rtol=1e-13, atol=1e-13)
    np.testing.assert_allclose(bd(F[0]), F[-1], rtol=1e-12, atol=1e-12)


def test_jvp_vjp_are_the_selected_piece_and_its_transpose(system):
    Dh, F, R, bd, rng = system
    d = Dh.shape[1]
    V, T = rng.standard_normal((2, 30, d))
    P = np.array([ref.ref_reset_piece(Dh, F, R, o) for o in bd.orders(V)])
    scale = np.abs(P).max() * np.abs(T).max()
    np.testing.assert_allclose(bd.jvp(V, T), np.einsum("qij,qj->qi", P, T), atol=1e-12 * scale)
    np.testing.assert_allclose(bd.vjp(V, T), np.einsum("qji,qj->qi", P, T), atol=1e-12 * scale)
    np.testing.assert_allclose(bd.jvp(V, V), bd(V), atol=1e-12 * scale)


def _largest_jump(bd, u, v, steps=4001):
    """Largest |M(u + s v) - M(u + s' v)| between neighbouring s on [-1, 1], over the step
    times the largest piece norm along the line: <= 1 when M is continuous there."""
    s = np.linspace(-1.0, 1.0, steps)
    X = u + s[:, None] * v
    W = bd(X)
    lip = max(np.linalg.norm(bd.piece(o), 2) for o in np.unique(bd.orders(X), axis=0))
    return np.abs(np.diff(W, axis=0)).max() / (lip * (s[1] - s[0]) * np.abs(v).max())


def test_continuous_across_piece_boundaries_and_the_check_can_fail():
    rng = np.random.default_rng(7)
    Dh, F, R = ref.random_reset_system(rng, 3, 5)
    bd = BDerivative(Dh, F, resets=R)
    lines = [(rng.standard_normal(5), rng.standard_normal(5)) for _ in range(10)]
    crossings = sum(len(np.unique(bd.orders(u + np.linspace(-1, 1, 50)[:, None] * v),
                                  axis=0)) - 1 for u, v in lines)
    assert crossings >= 5  # the lines do cross piece boundaries
    assert max(_largest_jump(bd, u, v) for u, v in lines) <= 1.0 + 1e-6
    # the same measure on resets that do not commute, built without the check: a jump
    Dh, F, R = ref.random_reset_system(rng, 3, 5, compatible=False)
    bad = BDerivative(Dh, F, resets=R, reset_tol=1e300)
    assert max(_largest_jump(bad, u, v) for u, v in lines) > 10.0


@pytest.mark.parametrize("n, d", [(2, 4), (3, 5), (4, 7)])  # d - n >= 2: D_j can fail to commute
@pytest.mark.parametrize("kind", ["commute", "move"])
def test_existence_check_refuses_incompatible_resets(n, d, kind):
    rng = np.random.default_rng(n * d)
    for _ in range(5):
        Dh, F, R = ref.random_reset_system(rng, n, d, compatible=kind != "commute",
                                           moving=kind == "move")
        with pytest.raises(ValueError, match="no B-derivative") as info:
            BDerivative(Dh, F, resets=R)
        message = str(info.value)
        assert "region mask 0b" in message and "relative; tolerance 1e-09" in message
        if kind == "move":
            assert "moves the surface of event" in message
        else:
            assert "do not commute" in message
        Dh, F, R = ref.random_reset_system(rng, n, d)  # compatible: accepted
        BDerivative(Dh, F, resets=R)


@pytest.mark.parametrize("scale", [1e-8, 1e8])
def test_existence_check_tolerance_scales_with_the_entries(scale):
    rng = np.random.default_rng(9)
    for compatible in (True, False):  # Dh, F and the resets of scale 1e8 or 1e-8
        Dh, F, R = ref.random_reset_system(rng, 3, 5, compatible=compatible)
        if compatible:
            BDerivative(scale * Dh, F / scale, resets=scale * R)
        else:
            with pytest.raises(ValueError, match="do not commute"):
                BDerivative(scale * Dh, F / scale, resets=scale * R)


def test_one_event_is_the_classical_saltation_matrix_with_reset():
    rng = np.random.default_rng(3)
    d = 4
    dh = rng.standard_normal(d)
    f_minus = dh + 0.3 * rng.standard_normal(d)
    f_plus = dh + 0.3 * rng.standard_normal(d)
    Rj = np.eye(d) + 0.4 * rng.standard_normal((d, d))
    # Xi = R + (F+ - R F-) Dh^T / (Dh F-): the textbook saltation matrix with reset
    Xi = Rj + np.outer(f_plus - Rj @ f_minus, dh) / (dh @ f_minus)
    R = np.zeros((2, 1, d, d))
    R[0, 0] = Rj
    bd = BDerivative(dh[None], np.array([f_minus, f_plus]), resets=R)
    V = rng.standard_normal((50, d))
    np.testing.assert_allclose(bd(V), V @ Xi.T, rtol=1e-13, atol=1e-13)
    np.testing.assert_allclose(bd.piece([0]), Xi, rtol=1e-14, atol=1e-14)


def _velocity_stops(n, d, rng):
    """Position-level events h_k = q_k (positions q = x[:n], velocities x[n:2n], d >= 2n)
    whose impact sets velocity k to zero: R = I - e_{n+k} e_{n+k}^T (rank-one, singular)."""
    Dh = np.zeros((n, d))
    Dh[:, :n] = np.eye(n)
    F = np.empty((2**n, d))
    for b in range(2**n):
        F[b] = rng.uniform(0.5, 1.5, d)
    U = np.zeros((2**n, n, d, 1))
    for k in range(n):
        U[:, k, n + k, 0] = -1.0
    return Dh, F, LowRankResets(U, -U)


def test_low_rank_resets_equal_their_dense_form():
    rng = np.random.default_rng(11)
    n, d = 3, 7
    Dh, F, low = _velocity_stops(n, d, rng)
    dense = np.eye(d) + low.U @ low.V.transpose(0, 1, 3, 2)
    a, b = BDerivative(Dh, F, resets=low), BDerivative(Dh, F, resets=dense)
    assert isinstance(a.resets, LowRankResets) and a.resets.U.shape == (8, 3, 7, 1)
    V, T = rng.standard_normal((2, 100, d))
    for f in ("apply", "event_times"):
        for x, y in zip(np.atleast_1d(getattr(a, f)(V)), np.atleast_1d(getattr(b, f)(V)),
                        strict=True):
            np.testing.assert_allclose(x, y, rtol=1e-13, atol=1e-13)
    np.testing.assert_allclose(a.jvp(V, T), b.jvp(V, T), rtol=1e-13, atol=1e-13)
    np.testing.assert_allclose(a.vjp(V, T), b.vjp(V, T), rtol=1e-13, atol=1e-13)
    for order in ref.all_orders(n):
        np.testing.assert_allclose(a.piece(order), ref.ref_reset_piece(Dh, F, dense, order),
                                   rtol=1e-13, atol=1e-13)
    assert a.table_bytes < b.table_bytes
    # a stopped velocity is forgotten: no inverse, the rest works
    with pytest.raises(ValueError, match=r"R\[0, 0\] of event 0 .* is singular .* no inverse"):
        a.inverse(V)


def test_invertible_low_rank_inverse_by_woodbury():
    rng = np.random.default_rng(5)
    n, d = 2, 5
    Dh, F, low = _velocity_stops(n, d, rng)
    low = LowRankResets(0.7 * low.U, low.V)  # restitution: velocity k scaled by 0.3
    bd = BDerivative(Dh, F, resets=low)
    V = rng.standard_normal((300, d))
    np.testing.assert_allclose(bd.inverse(bd(V)), V, rtol=1e-12, atol=1e-12)
    again = pickle.loads(pickle.dumps(bd))
    assert np.array_equal(again.inverse(bd(V)), bd.inverse(bd(V)))
    assert np.array_equal(again.resets.U, bd.resets.U) and not again.resets.U.flags.writeable


def test_identity_resets_give_the_map_without_resets():
    rng = np.random.default_rng(2)
    Dh, F = ref.random_system(rng, 3, 4)
    R = np.broadcast_to(np.eye(4), (8, 3, 4, 4))
    V = rng.standard_normal((2000, 4))  # above PARALLEL_MIN_QUERIES: the task driver
    np.testing.assert_allclose(BDerivative(Dh, F, resets=R)(V), BDerivative(Dh, F)(V),
                               rtol=1e-12, atol=1e-12)


def test_results_do_not_depend_on_chunks_or_threads(system):
    Dh, F, R, bd, rng = system
    V = rng.standard_normal((3000, Dh.shape[1]))
    whole = bd(V)
    assert np.array_equal(whole, bd(V, chunk_size=7))
    assert np.array_equal(pickle.loads(pickle.dumps(bd))(V), whole)


def test_bad_resets_are_refused_with_their_name():
    rng = np.random.default_rng(1)
    Dh, F, R = ref.random_reset_system(rng, 2, 3)
    with pytest.raises(ValueError, match=r"resets must have shape \(2\*\*n, n, d, d\) = "
                                         r"\(4, 2, 3, 3\) .* got \(4, 2, 3\)"):
        BDerivative(Dh, F, resets=R[..., 0])
    bad = R.copy()
    bad[1, 1, 0, 2] = np.nan
    with pytest.raises(ValueError, match=r"resets must be finite, but resets\[1, 1, 0, 2\]"):
        BDerivative(Dh, F, resets=bad)
    unused = R.copy()
    unused[1, 0] = np.nan  # event 0 already happened in region 0b01: never read
    assert BDerivative(Dh, F, resets=unused).resets[1, 0].sum() == 0.0
    with pytest.raises(TypeError, match="resets must hold real numbers"):
        BDerivative(Dh, F, resets=R.astype(complex))
    with pytest.raises(ValueError, match=r"resets.V must have shape \(2\*\*n, n, d, r\)"):
        BDerivative(Dh, F, resets=LowRankResets(np.zeros((4, 2, 3, 1)), np.zeros((4, 2, 3, 2))))
    with pytest.raises(ValueError, match=r"reset tables for n=2 events in dimension d=3 "
                                         r"\(with the corner table\) take 1.3 KiB"):
        BDerivative(Dh, F, resets=R, memory_limit=1000)
    with pytest.raises(ValueError, match="reset_tol must be"):
        BDerivative(Dh, F, resets=R, reset_tol=-1.0)


def test_corner_models_with_resets_are_refused():
    from bderiv import StructuredCorners

    rng = np.random.default_rng(4)
    Dh, F, R = ref.random_reset_system(rng, 2, 3)
    model = StructuredCorners(F[0], F[[1, 2]] - F[0])
    with pytest.raises(TypeError, match="resets need a dense table"):
        BDerivative(Dh, model, resets=R)


@pytest.mark.parametrize("n, d", [(1, 1), (2, 2), (2, 4), (3, 3), (3, 5)])
def test_corner_points_and_the_triangulation_rebuild_the_map(n, d):
    rng = np.random.default_rng(31 * n + d)
    Dh, F, R = ref.random_reset_system(rng, n, d)
    bd = BDerivative(Dh, F, resets=R)
    pre, post = bd.corner_points()
    full = (1 << n) - 1
    np.testing.assert_allclose(pre[full], F[0], atol=1e-13)
    np.testing.assert_allclose(post[full], F[full], atol=1e-12)
    for S in range(1, full + 1):  # the two-time trajectory: S at time -1, the rest at 0
        w, times, _ = ref.ref_reset_flow(Dh, F, R, pre[S])
        inside = (S >> np.arange(n)) & 1 == 1
        np.testing.assert_allclose(times, np.where(inside, -1.0, 0.0), atol=1e-12)
        np.testing.assert_allclose(post[S], w, atol=1e-12 * np.abs(w).max())
    tri = bd.triangulation()
    V = rng.standard_normal((300, d))
    W = bd(V)
    np.testing.assert_allclose(tri(V), W, atol=1e-12 * np.abs(W).max())
    np.testing.assert_allclose(tri.inverse(W), V, atol=1e-10)
    if d == n:  # and the oracle's evaluation of the cones
        for q in range(5):
            np.testing.assert_allclose(
                ref.ref_tri_apply(tri.pre, tri.post, tri.simplices, tri.kernel, V[q]), W[q],
                atol=1e-12 * np.abs(W).max())


def test_singular_resets_have_no_triangulation():
    Dh, F, low = _velocity_stops(2, 4, np.random.default_rng(0))
    bd = BDerivative(Dh, F, resets=low)
    with pytest.raises(ValueError, match="is singular .* not a homeomorphism and has no "
                                         "triangulation"):
        bd.triangulation()


@pytest.mark.parametrize("scale_F, scale_Dh", [(1e155, 1.0), (1e300, 1.0), (1e-160, 1e160),
                                               (1e160, 1e-160)])
def test_the_inverse_of_a_table_at_the_ends_of_float64(scale_F, scale_Dh):
    """The map does not change when F is scaled, nor when Dh is scaled one way and F the
    other (mathematics.md, "Scale"); apply agreed, but the inverse's check multiplied
    |F| |Dh_k| (overflow, underflow) and refused with "the rate ... changes sign or
    vanishes" where every rate was 1.24 and up (a review). Oracle: tests/reference.py's
    map at unit scale, read back by the inverse."""
    rng = np.random.default_rng(5)
    Dh, F, R = ref.random_reset_system(rng, 2, 3)
    V = rng.standard_normal((4, 3))
    W = np.array([ref.ref_reset_flow(Dh, F, R, v)[0] for v in V])
    bd = BDerivative(Dh * scale_Dh, F * scale_F, resets=R)
    np.testing.assert_allclose(bd(V), W, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(bd.inverse(W), V, rtol=1e-12, atol=1e-12)
