"""BDerivative against the NumPy oracle of tests/reference.py and the checks of
mathematics.md section 8."""

from __future__ import annotations

import math
import pickle

import numba
import numpy as np
import pytest
import scipy.linalg
from hypothesis import assume, given
from hypothesis import strategies as st
from numpy.testing import assert_allclose, assert_array_equal
from reference import (
    RTOL,
    all_orders,
    assert_maps_close,
    chain,
    overtaking_system,
    query_scale,
    random_system,
    ref_apply,
    ref_corner_points,
    ref_det,
    ref_event_times,
    ref_first_order_order,
    ref_inverse,
    ref_piece,
    ref_qp_apply,
    relabel,
    tie_point,
)

from bderiv import BDerivative

KINDS = ["square", "tall", "wide"]  # d = n, d > n, n > d (rank-deficient Dh)


def make_dims(kind, n, rng):
    if kind == "square":
        return n, n
    if kind == "tall":
        return n, n + int(rng.integers(1, 4))
    n = max(n, 2)
    return n, int(rng.integers(1, n))


@st.composite
def systems(draw, kinds=KINDS, n_max=8):
    """(rng, Dh, F, V): a random transversal system and queries of assorted scales."""
    seed = draw(st.integers(0, 2**32 - 1))
    kind = draw(st.sampled_from(kinds))
    n = draw(st.integers(1, n_max))
    dh_scale = 10.0 ** draw(st.integers(-3, 3))
    f_scale = 10.0 ** draw(st.integers(-3, 3))
    m = draw(st.integers(1, 12))
    rng = np.random.default_rng(seed)
    n, d = make_dims(kind, n, rng)
    Dh, F = random_system(rng, n, d, dh_scale=dh_scale, f_scale=f_scale)
    V = rng.standard_normal((m, d)) * 10.0 ** rng.uniform(-3, 3, (m, 1))
    return rng, Dh, F, V


def ties_forced(Dh):
    """d = 1 with n > 1: all event surfaces coincide, every query has tied event times."""
    n, d = Dh.shape
    return d == 1 and n > 1


# --------------------------------------------------------------------------------------
# Hand-computed cases
# --------------------------------------------------------------------------------------
def test_math_md_worked_example():
    # mathematics.md section 3: Dh = I, F all ones except F[0b001] = (1, 0.1, 1), u = (-1, -2, -3).
    # t0 = 1; x = u + 1 (F[0] - F[1]) = (-1, -1.1, -3), rates after event 0 are (., 0.1, 1):
    # event 1 would need 1.1 / 0.1 = 11, event 2 needs 3 -> event 2 at t = 3, back to the
    # all-ones field: x_1 = -1.1 + 3 (0.1 - 1) = -3.8 -> t1 = 3.8. Order (0, 2, 1).
    Dh = np.eye(3)
    F = np.ones((8, 3))
    F[0b001] = [1.0, 0.1, 1.0]
    bd = BDerivative(Dh, F)
    u = np.array([-1.0, -2.0, -3.0])
    assert_allclose(bd(u), [-1.0, -3.8, -3.0], rtol=1e-14)
    times, order = bd.event_times(u)
    assert_allclose(times, [1.0, 3.8, 3.0], rtol=1e-14)
    assert_array_equal(order, [0, 2, 1])
    # the first-order order (0, 1, 2) is the wrong piece: it would give (-1, -11, -3)
    assert_allclose(bd.piece([0, 1, 2]) @ u, [-1.0, -11.0, -3.0], rtol=1e-13)
    assert_allclose(bd.piece([0, 2, 1]) @ u, [-1.0, -3.8, -3.0], rtol=1e-13)
    assert_allclose(bd.inverse([-1.0, -3.8, -3.0]), u, rtol=1e-14)


def test_hand_computed_2d():
    # Dh = I (h_0 = x, h_1 = y), F[00] = (1, 1), F[01] = (2, 1), F[10] = (1, 3), F[11] = (2, 2).
    # u = (-1, -2): x(t) = (-1 + t, -2 + t) hits x = 0 at t = 1 at (0, -1); then F[01] = (2, 1)
    #   reaches y = 0 at t = 2 at (2, 0); then F[11]: (2, 0) + (t - 2)(2, 2) = (-2, -4) + t F[11],
    #   so M(u) = (-2, -4), times (1, 2), order (0, 1).
    # u = (-3, -1): y = 0 at t = 1 at (-2, 0); then F[10] = (1, 3) reaches x = 0 at t = 3 at
    #   (0, 6); then (0, 6) + (t - 3)(2, 2) = (-6, 0) + t F[11]: M(u) = (-6, 0), times (3, 1).
    # Pieces (section 4, G = F since Dh = I):
    #   (0, 1): S1 = I + (1, 0) e0^T / 1 = diag(2, 1), S2 = I + (0, 1) e1^T / 1 = diag(1, 2),
    #           M = diag(2, 2), det 4 = (2/1)(2/1);
    #   (1, 0): S1 = I + (0, 2) e1^T / 1 = diag(1, 3),
    #           S2 = I + (1, -1) e0^T / 1 = [[2, 0], [-1, 1]], M = [[2, 0], [-1, 3]],
    #           det 6 = (3/1)(2/1).
    # Tie u = (-1, -1): both pieces give (-2, -2). u = F[00] = (1, 1) -> (2, 2) = F[11].
    # Corner point S = 0b01: Dh x = (G[01, 0], 0) = (2, 0): W = (2, 0),
    #   U = W - F[01] + F[00] = (1, 0).
    Dh = np.eye(2)
    F = np.array([[1.0, 1.0], [2.0, 1.0], [1.0, 3.0], [2.0, 2.0]])
    bd = BDerivative(Dh, F)
    V = np.array([[-1.0, -2.0], [-3.0, -1.0], [-1.0, -1.0], [1.0, 1.0], [1.0, 0.0]])
    expected = np.array([[-2.0, -4.0], [-6.0, 0.0], [-2.0, -2.0], [2.0, 2.0], [2.0, 0.0]])
    assert_allclose(bd(V), expected, rtol=1e-15, atol=1e-15)
    assert_allclose(bd.inverse(expected), V, rtol=1e-15, atol=1e-15)
    times, order = bd.event_times(V[:2])
    assert_allclose(times, [[1.0, 2.0], [3.0, 1.0]], rtol=1e-15)
    assert_array_equal(order, [[0, 1], [1, 0]])
    assert_allclose(bd.piece([0, 1]), [[2.0, 0.0], [0.0, 2.0]], rtol=1e-15)
    assert_allclose(bd.piece([1, 0]), [[2.0, 0.0], [-1.0, 3.0]], rtol=1e-15, atol=1e-15)
    U, W = bd.corner_points()
    assert_allclose(U[0b01], [1.0, 0.0], atol=1e-15)
    assert_allclose(W[0b01], [2.0, 0.0], atol=1e-15)


@given(seed=st.integers(0, 2**32 - 1), d=st.integers(1, 6))
def test_single_event_is_classical_saltation_matrix(seed, d):
    rng = np.random.default_rng(seed)
    Dh, F = random_system(rng, 1, d)
    dh, f0, f1 = Dh[0], F[0], F[1]
    S = np.eye(d) + np.outer(f1 - f0, dh) / (dh @ f0)  # written out, not via reference.py
    bd = BDerivative(Dh, F)
    assert_allclose(bd.piece([0]), S, rtol=1e-12, atol=1e-12 * np.abs(S).max())
    V = rng.standard_normal((7, d))
    assert_maps_close(Dh, F, V, bd(V), V @ S.T)
    times, order = bd.event_times(V)
    assert_allclose(times[:, 0], -(V @ dh) / (dh @ f0), rtol=1e-12)
    assert_array_equal(order, np.zeros((7, 1), dtype=np.int64))


@given(seed=st.integers(0, 2**32 - 1), n=st.integers(1, 6), extra=st.integers(0, 2))
def test_continuous_field_is_identity(seed, n, extra):
    rng = np.random.default_rng(seed)
    d = n + extra
    Dh, F = random_system(rng, n, d)
    F[:] = F[0]  # the same field in every region
    bd = BDerivative(Dh, F)
    V = rng.standard_normal((9, d))
    assert_allclose(bd(V), V, rtol=1e-12, atol=1e-12)
    assert_allclose(bd.inverse(V), V, rtol=1e-12, atol=1e-12)
    for order in all_orders(n)[:6]:
        assert_allclose(bd.piece(order), np.eye(d), atol=1e-12)


# --------------------------------------------------------------------------------------
# The true order, not the first-order one
# --------------------------------------------------------------------------------------
@pytest.mark.parametrize("n", range(3, 9))
@pytest.mark.parametrize("extra", [0, 2])
def test_overtaking_follows_true_order(n, extra):
    Dh, F, u, order, w, times = overtaking_system(n, n + extra)
    # a random rotation of state space and a relabelling of the events change nothing
    rng = np.random.default_rng(100 * n + extra)
    R = np.linalg.qr(rng.standard_normal((n + extra,) * 2))[0]
    perm = rng.permutation(n)
    Dh2, F2 = relabel(Dh @ R.T, F @ R.T, perm)
    inv_perm = np.argsort(perm)  # old label -> new label
    for Dh_, F_, u_, w_, order_, times_ in [
        (Dh, F, u, w, order, times),
        (Dh2, F2, R @ u, R @ w, inv_perm[order], times[perm]),
    ]:
        assert not np.array_equal(ref_first_order_order(Dh_, F_, u_), order_)
        bd = BDerivative(Dh_, F_)
        assert_allclose(bd(u_), w_, rtol=1e-12, atol=1e-12)
        t, o = bd.event_times(u_)
        assert_array_equal(o, order_)
        assert_allclose(t, times_, rtol=1e-12)
        assert_allclose(bd.inverse(w_), u_, rtol=1e-12, atol=1e-12)


@given(systems())
def test_random_systems_often_overtake(case):
    """The random systems exercise the re-read of the rates: across a batch of queries,
    some event orders differ from the first-order ones, and the engine follows the oracle."""
    rng, Dh, F, _ = case
    d = Dh.shape[1]
    V = rng.standard_normal((40, d))
    bd = BDerivative(Dh, F)
    _, order = bd.event_times(V)
    ref_orders = np.array([ref_event_times(Dh, F, u)[1] for u in V])
    if not ties_forced(Dh):
        assert_array_equal(order, ref_orders)
    assert_maps_close(Dh, F, V, bd(V), [ref_apply(Dh, F, u) for u in V])


def test_overtaking_is_common_in_random_systems():
    """Guard on the generator: its systems must make the first-order shortcut fail often."""
    rng = np.random.default_rng(7)
    differ = total = 0
    for n in range(3, 8):
        Dh, F = random_system(rng, n, n)
        for u in rng.standard_normal((30, n)):
            total += 1
            differ += not np.array_equal(
                ref_event_times(Dh, F, u)[1], ref_first_order_order(Dh, F, u)
            )
    assert differ >= 0.15 * total


# --------------------------------------------------------------------------------------
# Three independent evaluations agree; inverse round trip (mathematics.md section 8, first bullet)
# --------------------------------------------------------------------------------------
@given(systems())
def test_apply_matches_oracles(case):
    _, Dh, F, V = case
    n, d = Dh.shape
    bd = BDerivative(Dh, F)
    out = bd(V)
    assert out.shape == V.shape and out.dtype == np.float64
    assert_maps_close(Dh, F, V, out, [ref_apply(Dh, F, u) for u in V])
    for i, u in enumerate(V):
        _, order = ref_event_times(Dh, F, u)
        # the piece of u's own order, from the oracle's saltation product and the engine's
        assert_maps_close(Dh, F, u, out[i], ref_piece(Dh, F, order) @ u)
        assert_maps_close(Dh, F, u, out[i], bd.piece(order) @ u)
        if n <= d:
            assert_maps_close(Dh, F, u, out[i], ref_qp_apply(Dh, F, u))


@given(systems())
def test_event_times_match_oracle(case):
    _, Dh, F, V = case
    bd = BDerivative(Dh, F)
    times, order = bd.event_times(V)
    assert times.shape == V.shape[:1] + (Dh.shape[0],) and times.dtype == np.float64
    assert order.shape == times.shape and order.dtype == np.int64
    for i, u in enumerate(V):
        ref_t, ref_o = ref_event_times(Dh, F, u)
        # times are an O(n)-step forward substitution: same scale argument as for M(u)
        scale = query_scale(Dh, F, u) / np.abs(F).max()
        assert np.abs(times[i] - ref_t).max() <= RTOL * scale
        assert_array_equal(np.sort(order[i]), np.arange(Dh.shape[0]))
        assert np.all(np.diff(times[i][order[i]]) >= -RTOL * scale)  # order sorts the times
        if not ties_forced(Dh):
            assert_array_equal(order[i], ref_o)


@given(systems())
def test_inverse_round_trip_and_oracle(case):
    _, Dh, F, V = case
    bd = BDerivative(Dh, F)
    W = bd(V)
    assert_maps_close(Dh, F, V, bd.inverse(W), V)
    assert_maps_close(Dh, F, V, bd.inverse(W), [ref_inverse(Dh, F, w) for w in W])
    # and the other way round: M(M^-1(w)) = w, scaled by the size of M^-1(w)'s terms
    Winv = bd.inverse(V)
    assert_maps_close(Dh, F, Winv, bd(Winv), V)


# --------------------------------------------------------------------------------------
# Pieces and determinants
# --------------------------------------------------------------------------------------
@given(systems())
def test_piece_matches_saltation_product_and_determinant(case):
    rng, Dh, F, _ = case
    n = Dh.shape[0]
    bd = BDerivative(Dh, F)
    for _ in range(4):
        order = rng.permutation(n)
        M = bd.piece(order)
        ref = ref_piece(Dh, F, order)
        assert M.shape == (Dh.shape[1],) * 2 and M.dtype == np.float64
        # products of n rank-one updates: entries are sums of terms bounded by |ref| entries
        assert_allclose(M, ref, rtol=1e-9, atol=1e-9 * np.abs(ref).max())
        # det from the rates vs LU determinant of the oracle's and the engine's matrices
        det = ref_det(Dh, F, order)
        assert det > 0
        assert_allclose(np.linalg.det(ref), det, rtol=1e-8)
        assert_allclose(np.linalg.det(M), det, rtol=1e-8)
        # piece accepts lists and tuples too
        assert_array_equal(bd.piece(tuple(int(k) for k in order)), M)


@pytest.mark.parametrize("n", [1, 2, 3, 4])
def test_pieces_enumerates_all_orders(n):
    rng = np.random.default_rng(n)
    Dh, F = random_system(rng, n, n + 1)
    bd = BDerivative(Dh, F)
    seen = set()
    for order, M in bd.pieces():
        assert order.dtype.kind == "i"
        seen.add(tuple(int(k) for k in order))
        ref = ref_piece(Dh, F, order)
        assert_allclose(M, ref, rtol=1e-9, atol=1e-9 * np.abs(ref).max())
    assert seen == {tuple(int(k) for k in o) for o in all_orders(n)}
    assert len(seen) == math.factorial(n)


def test_pieces_refuses_above_limit():
    rng = np.random.default_rng(0)
    Dh, F = random_system(rng, 4, 4)
    bd = BDerivative(Dh, F)
    with pytest.raises(ValueError, match=r"24.*23|23.*24"):
        next(iter(bd.pieces(max_pieces=23)))
    assert len(list(bd.pieces(max_pieces=24))) == 24


# --------------------------------------------------------------------------------------
# Structural properties (mathematics.md section 8, second and third bullets)
# --------------------------------------------------------------------------------------
@given(systems(), st.sampled_from([1e-3, 0.5, 1.0, 3.0, 1e4]))
def test_positive_homogeneity(case, s):
    _, Dh, F, V = case
    bd = BDerivative(Dh, F)
    assert_maps_close(Dh, F, s * V, bd(s * V), s * bd(V))
    assert_maps_close(Dh, F, s * V, bd.inverse(s * V), s * bd.inverse(V))
    t1, o1 = bd.event_times(V)
    ts, os_ = bd.event_times(s * V)
    assert_allclose(ts, s * t1, rtol=1e-9, atol=1e-9 * s * np.abs(t1).max())
    if not ties_forced(Dh):
        assert_array_equal(os_, o1)


@given(systems(kinds=["square", "tall"]), st.data())
def test_continuity_across_piece_boundaries(case, data):
    rng, Dh, F, _ = case
    n = Dh.shape[0]
    assume(n >= 2)
    bd = BDerivative(Dh, F)
    U, _ = ref_corner_points(Dh, F)
    order = rng.permutation(n)
    j = data.draw(st.integers(1, n - 1))
    u, swapped = tie_point(U, order, j, rng)  # events order[j-1], order[j] tie at u
    expected = ref_piece(Dh, F, order) @ u
    for value in (
        ref_piece(Dh, F, swapped) @ u,
        bd.piece(order) @ u,
        bd.piece(swapped) @ u,
        bd(u),
        ref_apply(Dh, F, u),
    ):
        assert_maps_close(Dh, F, u, value, expected, rtol=1e-8)
    # and just off the boundary, on either side, the map moves by at most
    # max(|M_sigma|, |M_sigma'|) times the step (both pieces are Lipschitz with their norm)
    step = 1e-7 * np.linalg.norm(u)
    lip = max(np.linalg.norm(ref_piece(Dh, F, o), 2) for o in (order, swapped))
    for sign in (1, -1):
        z = rng.standard_normal(u.shape)
        v = u + sign * step * z / np.linalg.norm(z)
        lip_v = max(lip, np.linalg.norm(ref_piece(Dh, F, ref_event_times(Dh, F, v)[1]), 2))
        assert np.linalg.norm(bd(v) - bd(u)) <= 1.5 * lip_v * step + RTOL * query_scale(Dh, F, u)


def test_ties_give_the_same_result():
    rng = np.random.default_rng(3)
    for n in (2, 3, 5):
        Dh = np.eye(n)
        F = np.exp(rng.uniform(-1, 1, (2**n, n)))  # positive entries: G = F > 0
        bd = BDerivative(Dh, F)
        # u = -F[0]: every event happens at t = 1 and ties persist (after the first event
        # each other g_j becomes -G[B, j]); every piece maps it to -F[full]
        for order in all_orders(n)[:24]:
            assert_allclose(ref_piece(Dh, F, order) @ -F[0], -F[-1], rtol=1e-12)
        assert_allclose(bd(-F[0]), -F[-1], rtol=1e-12)
        # u whose events 0 and 1 tie first (times -u_k / F[0, k] equal to 1), the rest later
        u = -F[0] * np.r_[1.0, 1.0, rng.uniform(1.5, 3.0, n - 2)]
        _, order = ref_event_times(Dh, F, u)
        swapped = order.copy()
        swapped[:2] = swapped[1::-1]
        expected = ref_piece(Dh, F, order) @ u
        assert_allclose(ref_piece(Dh, F, swapped) @ u, expected, rtol=1e-12)
        assert_allclose(bd(u), expected, rtol=1e-12)
        assert_allclose(bd.inverse(expected), u, rtol=1e-12)


@given(systems(kinds=["tall"]))
def test_identity_on_kernel(case):
    rng, Dh, F, V = case
    bd = BDerivative(Dh, F)
    K = scipy.linalg.null_space(Dh)
    Z = rng.standard_normal((V.shape[0], K.shape[1])) @ K.T
    scale = np.abs(Z).max()
    assert_allclose(bd(Z), Z, rtol=1e-12, atol=1e-12 * scale)
    assert_allclose(bd.inverse(Z), Z, rtol=1e-12, atol=1e-12 * scale)
    # translation along the kernel commutes with M (the kernel part never enters Dh x)
    assert_maps_close(Dh, F, V, bd(V + Z), bd(V) + Z)


@given(systems())
def test_flow_direction_maps_to_flow_direction(case):
    _, Dh, F, _ = case
    bd = BDerivative(Dh, F)
    V = np.array([F[0], -F[0], 2.5 * F[0]])
    W = np.array([F[-1], -F[-1], 2.5 * F[-1]])
    assert_maps_close(Dh, F, V, bd(V), W)
    assert_maps_close(Dh, F, V, bd.inverse(W), V)


@given(systems(), st.data())
def test_relabelling_events_changes_nothing(case, data):
    rng, Dh, F, V = case
    n = Dh.shape[0]
    perm = np.array(data.draw(st.permutations(range(n))))
    Dh2, F2 = relabel(Dh, F, perm)
    bd, bd2 = BDerivative(Dh, F), BDerivative(Dh2, F2)
    assert_maps_close(Dh, F, V, bd2(V), bd(V))
    assert_maps_close(Dh, F, V, bd2.inverse(V), bd.inverse(V))
    t, o = bd.event_times(V)
    t2, o2 = bd2.event_times(V)
    assert_allclose(t2, t[:, perm], rtol=1e-9, atol=1e-9 * np.abs(t).max())
    if not ties_forced(Dh):
        assert_array_equal(o2, np.argsort(perm)[o])  # old labels -> new labels
    order = rng.permutation(n)
    M = bd.piece(order)
    assert_allclose(bd2.piece(np.argsort(perm)[order]), M, rtol=1e-9, atol=1e-9 * np.abs(M).max())


def test_attributes():
    rng = np.random.default_rng(11)
    Dh, F = random_system(rng, 3, 5)
    bd = BDerivative(Dh, F)
    assert (bd.n_events, bd.dim) == (3, 5)
    assert bd.full_rank
    for name, ref in [("Dh", Dh), ("F", F), ("rates", F @ Dh.T)]:
        arr = getattr(bd, name)
        assert arr.dtype == np.float64 and not arr.flags.writeable
        assert_allclose(arr, ref, rtol=1e-15)
        with pytest.raises(ValueError):
            arr[0, 0] = 1.0
    Dh_w, F_w = random_system(rng, 4, 2)
    assert not BDerivative(Dh_w, F_w).full_rank


def test_constructor_copies_its_inputs():
    rng = np.random.default_rng(12)
    Dh, F = random_system(rng, 2, 2)
    bd = BDerivative(Dh, F)
    V = rng.standard_normal((5, 2))
    before = bd(V)
    Dh[:] = 7.0
    F[:] = 3.0
    assert_array_equal(bd(V), before)


# --------------------------------------------------------------------------------------
# Shapes, batches, out=
# --------------------------------------------------------------------------------------
@pytest.mark.parametrize("lead", [(), (4,), (2, 3), (0,), (3, 0), (1, 1, 2)])
def test_batch_shapes(lead):
    rng = np.random.default_rng(5)
    Dh, F = random_system(rng, 3, 4)
    bd = BDerivative(Dh, F)
    V = rng.standard_normal(lead + (4,))
    for result in (bd(V), bd.apply(V), bd.inverse(V)):
        assert result.shape == lead + (4,) and result.dtype == np.float64
    times, order = bd.event_times(V)
    assert times.shape == lead + (3,) and times.dtype == np.float64
    assert order.shape == lead + (3,) and order.dtype == np.int64
    flat = V.reshape(-1, 4)
    expected = np.array([ref_apply(Dh, F, u) for u in flat]).reshape(lead + (4,))
    assert_maps_close(Dh, F, flat, bd(V), expected)


def test_list_input():
    bd = BDerivative(np.eye(2), [[1.0, 1.0], [2.0, 1.0], [1.0, 3.0], [2.0, 2.0]])
    assert_allclose(bd([-1.0, -2.0]), [-2.0, -4.0], rtol=1e-15)
    assert_allclose(bd([[-1, -2], [-3, -1]]), [[-2.0, -4.0], [-6.0, 0.0]], atol=1e-15)


def test_out_argument():
    rng = np.random.default_rng(6)
    Dh, F = random_system(rng, 3, 3)
    bd = BDerivative(Dh, F)
    V = rng.standard_normal((10, 3))
    out = np.empty((10, 3))
    assert bd.apply(V, out=out) is out
    assert_array_equal(out, bd(V))
    out2 = np.empty((10, 3))
    assert bd.inverse(V, out=out2) is out2
    assert_array_equal(out2, bd.inverse(V))


# --------------------------------------------------------------------------------------
# Bitwise reproducibility
# --------------------------------------------------------------------------------------
def _batch_system(seed=8, n=6, d=7, m=3000):
    rng = np.random.default_rng(seed)
    Dh, F = random_system(rng, n, d)
    return BDerivative(Dh, F), rng.standard_normal((m, d))


def test_bitwise_independent_of_batch_split():
    bd, V = _batch_system()
    W, Winv = bd(V), bd.inverse(V)
    times, order = bd.event_times(V)
    for i in [0, 1, 17, 1500, len(V) - 1]:
        assert_array_equal(bd(V[i : i + 1])[0], W[i])
        assert_array_equal(bd(V[i]), W[i])
        assert_array_equal(bd.inverse(V[i : i + 1])[0], Winv[i])
        t1, o1 = bd.event_times(V[i : i + 1])
        assert_array_equal(t1[0], times[i])
        assert_array_equal(o1[0], order[i])
    assert_array_equal(np.concatenate([bd(V[:1000]), bd(V[1000:])]), W)


def test_bitwise_independent_of_thread_count():
    if numba.config.NUMBA_NUM_THREADS < 2:
        pytest.skip("numba has a single thread")
    bd, V = _batch_system()
    saved = numba.get_num_threads()
    try:
        results = {}
        for threads in (1, 2):
            numba.set_num_threads(threads)
            results[threads] = (bd(V), bd.inverse(V), *bd.event_times(V))
    finally:
        numba.set_num_threads(saved)
    for a, b in zip(results[1], results[2], strict=True):
        assert_array_equal(a, b)


# --------------------------------------------------------------------------------------
# Input flavours: float32, integer, read-only, non-contiguous; pickling
# --------------------------------------------------------------------------------------
def _flavours(A):
    """(label, variant) pairs of A holding the same values (cast where the dtype changes)."""
    ro = A.copy()
    ro.setflags(write=False)
    wide = np.zeros(A.shape[:-1] + (2 * A.shape[-1],))
    wide[..., ::2] = A
    return [
        ("float32", A.astype(np.float32)),
        ("int64", np.round(A * 100).astype(np.int64)),
        ("int32", np.round(A * 100).astype(np.int32)),
        ("read-only", ro),
        ("strided", wide[..., ::2]),
        ("fortran", np.asfortranarray(A)),
    ]


def test_query_flavours_give_float64_answer():
    rng = np.random.default_rng(9)
    Dh, F = random_system(rng, 4, 5)
    bd = BDerivative(Dh, F)
    V = rng.standard_normal((50, 5))
    for label, Vx in _flavours(V):
        V64 = np.array(Vx, dtype=np.float64)
        assert_array_equal(bd(Vx), bd(V64), err_msg=label)
        assert bd(Vx).dtype == np.float64
        assert_array_equal(bd.inverse(Vx), bd.inverse(V64), err_msg=label)
        for a, b in zip(bd.event_times(Vx), bd.event_times(V64), strict=True):
            assert_array_equal(a, b, err_msg=label)
    # negative strides
    assert_array_equal(bd(V[::-1]), bd(V)[::-1])
    # the read-only input is left alone
    ro = V.copy()
    ro.setflags(write=False)
    bd(ro)
    assert_array_equal(ro, V)


def test_table_flavours_give_float64_answer():
    rng = np.random.default_rng(10)
    Dh, F = random_system(rng, 3, 4)
    F = np.abs(F) + 0.5  # keep integer-rounded tables transversal
    Dh = np.abs(Dh) + 0.5
    V = rng.standard_normal((20, 4))
    for (label, Dx), (_, Fx) in zip(_flavours(Dh), _flavours(F), strict=True):
        ref = BDerivative(np.array(Dx, dtype=np.float64), np.array(Fx, dtype=np.float64))
        bd = BDerivative(Dx, Fx)
        assert bd.Dh.dtype == bd.F.dtype == np.float64
        assert_array_equal(bd(V), ref(V), err_msg=label)


def test_pickle_round_trip():
    rng = np.random.default_rng(13)
    Dh, F = random_system(rng, 3, 4)
    bd = BDerivative(Dh, F)
    V = rng.standard_normal((30, 4))
    bd2 = pickle.loads(pickle.dumps(bd))
    assert (bd2.n_events, bd2.dim) == (3, 4)
    assert_array_equal(bd2.Dh, bd.Dh)
    assert_array_equal(bd2.F, bd.F)
    assert_array_equal(bd2(V), bd(V))
    assert_array_equal(bd2.inverse(V), bd.inverse(V))
    assert_array_equal(bd2.piece([2, 0, 1]), bd.piece([2, 0, 1]))


def test_chain_helper():
    # guard on the oracle's own helper used everywhere above
    assert chain([2, 0, 1]) == [0, 0b100, 0b101, 0b111]
