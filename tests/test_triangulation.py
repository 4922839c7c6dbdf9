"""The triangulation (corner points, simplices, kernel) rebuilds the same PL map."""

from __future__ import annotations

import math
import pickle

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from numpy.testing import assert_allclose, assert_array_equal
from reference import (
    all_orders,
    assert_maps_close,
    chain,
    random_system,
    ref_apply,
    ref_corner_points,
    ref_inverse,
    ref_tri_apply,
)

from bderiv import BDerivative, Triangulation


@st.composite
def full_rank_systems(draw, n_max=4):
    seed = draw(st.integers(0, 2**32 - 1))
    n = draw(st.integers(1, n_max))
    d = n + draw(st.integers(0, 2))
    dh_scale = 10.0 ** draw(st.integers(-2, 2))
    f_scale = 10.0 ** draw(st.integers(-2, 2))
    rng = np.random.default_rng(seed)
    Dh, F = random_system(rng, n, d, dh_scale=dh_scale, f_scale=f_scale)
    return rng, Dh, F


def expected_simplices(n):
    """[0, B_1, ..., B_{n-1}, full] and [0, B_1, ..., B_{n-1}, 2**n] for every order."""
    full = 2**n - 1
    out = set()
    for order in all_orders(n):
        inner = chain(order)[1:n]
        out.add((0, *inner, full))
        out.add((0, *inner, full + 1))
    return out


@given(full_rank_systems())
def test_corner_points(case):
    rng, Dh, F = case
    n, d = Dh.shape
    bd = BDerivative(Dh, F)
    U, W = bd.corner_points()  # pre, post
    assert U.shape == W.shape == (2**n, d)
    G = F @ Dh.T
    scale = np.abs(F).max()
    # mathematics.md section 5 defining equations: Dh W[S] = 1_S * G[S], U[S] - W[S] = F[0] - F[S]
    bits = (np.arange(2**n)[:, None] >> np.arange(n)) & 1
    assert_allclose(W @ Dh.T, bits * G, atol=1e-10 * np.abs(G).max())
    assert_allclose(U - W, F[0] - F, atol=1e-12 * scale)
    assert_allclose(U[0], 0, atol=1e-12 * scale)
    # U[full] = F[0], W[full] = F[full] up to ker Dh (x_full is any solution of
    # Dh x = G[full] = Dh F[full]; mathematics.md's equalities hold exactly when d = n)
    Pr = np.eye(d) - np.linalg.pinv(Dh) @ Dh  # projector onto ker Dh
    assert_allclose((np.eye(d) - Pr) @ (U[-1] - F[0]), 0, atol=1e-10 * scale)
    assert_allclose((np.eye(d) - Pr) @ (W[-1] - F[-1]), 0, atol=1e-10 * scale)
    # M(U[S]) = W[S], by the oracle (for d > n the kernel part of x_S is free; it cancels)
    assert_maps_close(Dh, F, U, W, [ref_apply(Dh, F, u) for u in U])
    if d == n:  # then x_S is unique: the oracle's pinv gives the same points
        rU, rW = ref_corner_points(Dh, F)
        assert_allclose(U, rU, atol=1e-10 * scale)
        assert_allclose(W, rW, atol=1e-10 * scale)


@given(full_rank_systems())
def test_triangulation_structure(case):
    _, Dh, F = case
    n, d = Dh.shape
    bd = BDerivative(Dh, F)
    tri = bd.triangulation()
    U, W = bd.corner_points()  # pre, post
    assert tri.pre.shape == tri.post.shape == (2**n + 1, d)
    assert_allclose(tri.pre[: 2**n], U, rtol=1e-15)
    assert_allclose(tri.post[: 2**n], W, rtol=1e-15)
    assert_allclose(tri.pre[2**n], -F[0], rtol=1e-15)
    assert_allclose(tri.post[2**n], -F[-1], rtol=1e-15)
    assert tri.simplices.dtype == np.int64
    assert tri.simplices.shape == (2 * math.factorial(n), n + 1)
    assert {tuple(int(i) for i in s) for s in tri.simplices} == expected_simplices(n)
    assert tri.kernel.shape == (d, d - n)
    assert_allclose(tri.kernel.T @ tri.kernel, np.eye(d - n), atol=1e-12)
    assert_allclose(Dh @ tri.kernel, 0, atol=1e-12 * np.abs(Dh).max())


@given(full_rank_systems(), st.integers(1, 10))
def test_triangulation_rebuilds_the_map(case, m):
    rng, Dh, F = case
    d = Dh.shape[1]
    bd = BDerivative(Dh, F)
    tri = bd.triangulation()
    V = rng.standard_normal((m, d)) * 10.0 ** rng.uniform(-2, 2, (m, 1))
    # the cones of this fan can be thin (P ill-conditioned), so the barycentric solve
    # loses a few more digits than the forward substitution: 1e-7 of the query scale
    assert_maps_close(Dh, F, V, tri(V), bd(V), rtol=1e-7)
    # an evaluation of the triangulation's data written independently of the package
    independent = [ref_tri_apply(tri.pre, tri.post, tri.simplices, tri.kernel, v) for v in V]
    assert_maps_close(Dh, F, V, independent, [ref_apply(Dh, F, v) for v in V], rtol=1e-7)


def test_a_fan_that_does_not_cover_space_is_refused_at_the_rows_it_misses():
    """Two of the four cones of a two-event map, kept by hand: the rows in them map as
    the B-derivative does (tests/reference.py), a row in the missing cones is refused by
    its index (it was extrapolated from the nearest cone, 47 % off, silently), forward
    and back."""
    rng = np.random.default_rng(3)
    Dh = rng.standard_normal((2, 2))
    F = rng.uniform(0.5, 1.5, (4, 2)) @ np.linalg.pinv(Dh).T
    tri = BDerivative(Dh, F).triangulation()
    half = Triangulation(tri.pre, tri.post, tri.simplices[[0, 3]], tri.kernel)
    V = rng.standard_normal((400, 2))
    inside = [v for v in V if _in_cone(tri.pre[tri.simplices[0, 1:]], v)
              or _in_cone(tri.pre[tri.simplices[3, 1:]], v)]
    outside = next(i for i, v in enumerate(V) if not any(
        _in_cone(tri.pre[tri.simplices[c, 1:]], v) for c in (0, 3)))
    assert_allclose(half(np.array(inside)), [ref_apply(Dh, F, v) for v in inside],
                    rtol=1e-12, atol=1e-12)
    with pytest.raises(ValueError, match=rf"V\[{outside}\] lies in no cone of the "
                                         r"triangulation's pre fan"):
        half(V)
    with pytest.raises(ValueError, match=r"W\[0\] lies in no cone of the triangulation's "
                                         r"post fan"):
        half.inverse(tri(V[[outside]]))


def test_a_fan_too_flat_for_float64_says_so_and_the_map_still_evaluates():
    """Rates over eight decades (n = d = 5): a cone of the fan is numerically flat. The
    refusal said a "field 'simplices'" was degenerate, as for a damaged file; it now says
    the map's fan is too ill-conditioned, and the map evaluates (tests/reference.py)."""
    rng = np.random.default_rng(0)
    Dh = rng.standard_normal((5, 5))
    F = np.exp(rng.uniform(np.log(1e-4), np.log(1e4), (32, 5))) @ np.linalg.pinv(Dh).T
    bd = BDerivative(Dh, F)
    with pytest.raises(ValueError, match=r"^this map's fan is too ill-conditioned to "
                                         r"triangulate in float64 .* the map itself "
                                         r"evaluates"):
        bd.triangulation()
    v = rng.standard_normal(5)
    assert_allclose(bd(v), ref_apply(Dh, F, v), rtol=1e-8, atol=1e-8 * np.abs(bd(v)).max())


def _in_cone(rays, v) -> bool:
    """Whether v is a nonnegative combination of the rays (rows), by a solve."""
    return bool((np.linalg.solve(np.asarray(rays).T, v) >= 0).all())


def test_triangulation_hand_case():
    # the 2-D case of test_bderivative.test_hand_computed_2d: M(-1, -2) = (-2, -4),
    # M(-3, -1) = (-6, 0), M(F[00]) = F[11], M(-F[00]) = -F[11]
    F = np.array([[1.0, 1.0], [2.0, 1.0], [1.0, 3.0], [2.0, 2.0]])
    tri = BDerivative(np.eye(2), F).triangulation()
    V = np.array([[-1.0, -2.0], [-3.0, -1.0], [1.0, 1.0], [-1.0, -1.0]])
    assert_allclose(tri(V), [[-2.0, -4.0], [-6.0, 0.0], [2.0, 2.0], [-2.0, -2.0]], atol=1e-14)
    assert tri.kernel.shape == (2, 0)


@pytest.mark.parametrize("lead", [(), (3,), (2, 2), (0,)])
def test_triangulation_batch_shapes(lead):
    rng = np.random.default_rng(4)
    Dh, F = random_system(rng, 2, 3)
    tri = BDerivative(Dh, F).triangulation()
    V = rng.standard_normal(lead + (3,))
    out = tri(V)
    assert out.shape == lead + (3,) and out.dtype == np.float64


def test_triangulation_rebuilt_from_its_data_and_pickled():
    rng = np.random.default_rng(5)
    Dh, F = random_system(rng, 3, 4)
    tri = BDerivative(Dh, F).triangulation()
    V = rng.standard_normal((25, 4))
    again = Triangulation(tri.pre, tri.post, tri.simplices, tri.kernel)
    assert_array_equal(again(V), tri(V))
    unpickled = pickle.loads(pickle.dumps(tri))
    assert_array_equal(unpickled(V), tri(V))
    assert_array_equal(unpickled.simplices, tri.simplices)


def test_triangulation_inputs_flavours():
    rng = np.random.default_rng(6)
    Dh, F = random_system(rng, 2, 2)
    tri = BDerivative(Dh, F).triangulation()
    V = rng.standard_normal((10, 2))
    ro = V.copy()
    ro.setflags(write=False)
    wide = np.zeros((10, 4))
    wide[:, ::2] = V
    for Vx in (ro, wide[:, ::2], np.asfortranarray(V)):
        assert_array_equal(tri(Vx), tri(V))
    assert_array_equal(tri(V.astype(np.float32)), tri(V.astype(np.float32).astype(float)))


@given(full_rank_systems(), st.integers(1, 10))
def test_triangulation_inverse(case, m):
    rng, Dh, F = case
    d = Dh.shape[1]
    tri = BDerivative(Dh, F).triangulation()
    V = rng.standard_normal((m, d)) * 10.0 ** rng.uniform(-2, 2, (m, 1))
    W = np.array([ref_apply(Dh, F, v) for v in V])
    # mathematics.md section 6: the post cones are a fan; the oracle inverts by running time
    # backwards
    assert_maps_close(Dh, F, V, tri.inverse(W), [ref_inverse(Dh, F, w) for w in W], rtol=1e-7)
    assert_maps_close(Dh, F, V, tri.inverse(tri(V)), V, rtol=1e-7)


def test_triangulation_inverse_hand_case():
    # test_triangulation_hand_case read backwards
    F = np.array([[1.0, 1.0], [2.0, 1.0], [1.0, 3.0], [2.0, 2.0]])
    tri = BDerivative(np.eye(2), F).triangulation()
    W = np.array([[-2.0, -4.0], [-6.0, 0.0], [2.0, 2.0], [-2.0, -2.0]])
    assert_allclose(tri.inverse(W), [[-1.0, -2.0], [-3.0, -1.0], [1.0, 1.0], [-1.0, -1.0]],
                    atol=1e-14)


@pytest.fixture(scope="module")
def tri_n3():
    rng = np.random.default_rng(7)
    Dh, F = random_system(rng, 3, 4)
    return BDerivative(Dh, F), rng.standard_normal((40, 4))


@pytest.mark.parametrize("method", ["apply", "inverse"])
def test_out_chunks_and_progress(tri_n3, method):
    bd, V = tri_n3
    fn = getattr(bd.triangulation(), method)
    want = fn(V)
    out = np.empty_like(V)
    assert fn(V, out=out) is out
    assert_array_equal(out, want)
    calls = []
    chunked = fn(V.reshape(8, 5, 4), chunk_size=7, progress=lambda *a: calls.append(a))
    assert_array_equal(chunked.reshape(V.shape), want)  # bit for bit, as BDerivative
    for size in (1, 3, 39):
        assert_array_equal(fn(V, chunk_size=size), want)
    assert calls == [(k, 40) for k in (7, 14, 21, 28, 35, 40)]
    alias = V.copy()
    assert fn(alias, out=alias) is alias  # out may be the input itself
    assert_array_equal(alias, want)


def test_triangulation_bad_queries():
    bd = BDerivative(np.eye(2), np.ones((4, 2)))
    tri = bd.triangulation()
    with pytest.raises(ValueError, match=r"must have shape \(\.\.\., 2\)"):
        tri(np.ones(3))
    with pytest.raises(ValueError, match=r"must be finite"):
        tri(np.array([1.0, np.nan]))
    # the messages are BDerivative's, word for word (one validation path, _batch.evaluate)
    for bad, kwargs in [
        (np.ones(3), {}),
        (np.array([[1.0, 2.0], [1.0, np.inf]]), {}),
        (np.ones((2, 2), dtype=complex), {}),
        ("abc", {}),
        (np.ones((3, 2)), {"out": np.empty((2, 2))}),
        (np.ones((3, 2)), {"out": np.empty((3, 2), dtype=np.float32)}),
        (np.ones((3, 2)), {"chunk_size": 0}),
    ]:
        for mine, theirs in ((tri.apply, bd.apply), (tri.inverse, bd.inverse)):
            with pytest.raises((ValueError, TypeError)) as got:
                mine(bad, **kwargs)
            with pytest.raises(type(got.value)) as want:
                theirs(bad, **kwargs)
            assert str(got.value) == str(want.value)
    V = np.ones((3, 4, 2))
    V[2, 1, 0] = np.nan  # row 9 of 12: chunk 4 of size 2; named by its index in V
    with pytest.raises(ValueError, match=r"must be finite, but vector V\[2, 1\] = \[nan  1\.\]"):
        tri(V, chunk_size=2)
    with pytest.raises(ValueError, match=r"the result for W\[1\] overflowed \(not finite\)"):
        tri.inverse([[1.0, 1.0], [1e308, -1e308]])  # finite, but the weights overflow


def test_triangulation_pickles_read_only(tri_n3):
    bd, V = tri_n3
    tri = bd.triangulation()
    clone = pickle.loads(pickle.dumps(tri))
    assert_array_equal(clone.inverse(V), tri.inverse(V))
    for a in (tri, clone):
        for name in ("pre", "post", "simplices", "kernel", "kernel_post"):
            assert not getattr(a, name).flags.writeable
    # a pickle made before kernel_post existed: the map is the identity on the kernel
    state = {k: v for k, v in tri.__dict__.items() if k != "kernel_post"}
    old = Triangulation.__new__(Triangulation)
    old.__setstate__(pickle.loads(pickle.dumps(state)))
    assert_array_equal(old.kernel_post, tri.kernel)
    assert not old.kernel_post.flags.writeable
    assert_array_equal(old(V), tri(V))


def test_direct_construction_is_checked():
    """Triangulation(pre, post, simplices, kernel) runs the checks of a loaded file."""
    tri = BDerivative(np.eye(2), np.array([[1.0, 1], [2, 1], [1, 3], [2, 2]])).triangulation()
    good = dict(pre=tri.pre, post=tri.post, simplices=tri.simplices, kernel=tri.kernel)
    with pytest.raises(TypeError, match=r"Triangulation: field 'simplices' must hold integers"):
        Triangulation(**good | {"simplices": tri.simplices.astype(float)})
    with pytest.raises(TypeError, match=r"field 'pre' must hold real numbers, got dtype compl"):
        Triangulation(**good | {"pre": tri.pre.astype(complex)})
    flat = tri.pre.copy()
    flat[3] = 2 * flat[1]  # U[0b11] on the ray of U[0b01]: the cones of both orders collapse
    with pytest.raises(ValueError, match=r"simplex 0 \[0, 1, 3\] spans less than R\^2 with "
                                         r"the pre vertices"):
        Triangulation(**good | {"pre": flat})
    with pytest.raises(ValueError, match=r"field 'post' must have shape \(5, 2\)"):
        Triangulation(**good | {"post": tri.post[:4]})


@pytest.mark.parametrize("n, d", [(2, 2), (3, 3), (2, 4), (3, 5)])
def test_composed_is_the_composition(n, d):
    """tri.composed(A, B)(v) = B bd(A v), and its inverse, on vectors of every cone."""
    rng = np.random.default_rng(10 * n + d)
    bd = BDerivative(*random_system(rng, n, d))
    A = np.eye(d) + 0.4 * rng.standard_normal((d, d))
    B = np.eye(d) + 0.4 * rng.standard_normal((d, d))
    tri = bd.triangulation().composed(A, B)
    V = rng.standard_normal((400, d))
    want = bd(V @ A.T) @ B.T
    # relative to the batch's scale: the fan solves with its cones' (d, d) matrices
    assert_allclose(tri(V), want, atol=1e-9 * np.abs(want).max())
    assert_allclose(tri.inverse(want), V, atol=1e-9 * np.abs(V).max())
    # the vertices: pre-event points pulled back by A, post-event points pushed by B
    assert_allclose(tri.pre @ A.T, bd.triangulation().pre, atol=1e-12)
    assert_allclose(tri.post, bd.triangulation().post @ B.T, atol=1e-12)
    assert (tri.n_events, tri.dim) == (n, d)


def test_composed_of_a_flow_map_by_hand():
    """One event group: the fan carried by the flow's linear stages is the flow map D."""
    from bderiv import examples

    ex = examples.chair()
    D = ex.system.flow_bderivative(ex.x0, ex.t_final)
    (L0, L1), (M,) = D.linear, D.jumps
    tri = M.triangulation().composed(L0, L1)
    V = np.random.default_rng(0).standard_normal((300, 6))
    W = D(V)
    assert_allclose(tri(V), W, atol=1e-10 * np.abs(W).max())
    assert_allclose(tri.inverse(W), V, atol=1e-10 * np.abs(V).max())


def test_composed_refuses_bad_matrices():
    tri = BDerivative(np.eye(2), np.array([[1.0, 1], [2, 1], [1, 3], [2, 2]])).triangulation()
    with pytest.raises(ValueError, match=r"before must have shape \(2, 2\), got \(3, 3\)"):
        tri.composed(np.eye(3), np.eye(2))
    with pytest.raises(ValueError, match="after must be invertible.*condition number"):
        tri.composed(np.eye(2), [[1.0, 2.0], [2.0, 4.0]])
    with pytest.raises(ValueError, match="before must be finite"):
        tri.composed([[np.nan, 0.0], [0.0, 1.0]], np.eye(2))
    with pytest.raises(TypeError, match="after"):
        tri.composed(np.eye(2), [["a", "b"], ["c", "d"]])


def _one_cone_at_a_time(tri, rows):
    """Triangulation.apply as it was written before the cones went in blocks: each cone's
    weights in turn, the first cone kept on a tie."""
    n = tri.simplices.shape[1] - 1
    best_weight, res = np.full(rows.shape[0], -np.inf), np.full(rows.shape, np.nan)
    for simplex in tri.simplices:
        P = np.hstack([tri.pre[simplex[1:]].T, tri.kernel])
        Q = np.hstack([tri.post[simplex[1:]].T, tri.kernel_post])
        weights = np.einsum("ij,mj->mi", np.linalg.inv(P), rows)
        lam = weights[:, :n]
        min_weight = lam.min(axis=1) / (np.abs(lam).max(axis=1) + 1e-300)
        better = min_weight > best_weight
        best_weight[better] = min_weight[better]
        res[better] = np.einsum("ij,mj->mi", Q, weights[better])
    return res


@pytest.mark.parametrize("block", [1, 7 * 6, 1 << 20])  # 1 and 7 cones of 6 rows at once
def test_cones_in_blocks_give_the_bits_of_one_cone_at_a_time(monkeypatch, block):
    """On vectors inside cones, on their shared faces (a tie: the first cone wins) and on
    their rays, over block boundaries."""
    from bderiv.geometry import triangulation

    rng = np.random.default_rng(5)
    Dh, F = random_system(rng, 4, 6)
    tri = BDerivative(Dh, F).triangulation()
    rows = np.vstack([rng.standard_normal((3, 6)), tri.pre[tri.simplices[9, 2]],
                      tri.pre[tri.simplices[9, 1]] + tri.pre[tri.simplices[9, 2]],
                      tri.pre[tri.simplices[-1, 3]]])
    monkeypatch.setattr(triangulation, "FAN_BLOCK", block)
    assert_array_equal(tri(rows), _one_cone_at_a_time(tri, rows))
