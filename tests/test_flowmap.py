"""FlowBDerivative: composition, inverse, pieces, final time, batches, pickling, validation.

Expected values come from the stages themselves, composed by hand: ``manual`` applies the
linear stages and the jumps' own maps one after the other, ``manual_piece`` multiplies the
linear stages with the jumps' ``piece`` matrices.
"""

from __future__ import annotations

import pickle

import hypothesis.extra.numpy as hnp
import hypothesis.strategies as st
import numpy as np
import pytest
from hypothesis import given

from bderiv import BDerivative, examples
from bderiv.analysis.flowmap import FlowBDerivative


def random_bd(rng, n, d):
    Dh = rng.standard_normal((n, d))
    F0 = Dh.T @ np.ones(n) / n  # a direction every event crosses upward
    F0 = F0 / np.min(Dh @ F0)
    F = F0 + 0.3 * rng.standard_normal((1 << n, d))
    while np.any(F @ Dh.T <= 0.1):
        F = F0 + 0.3 * rng.standard_normal((1 << n, d))
    return BDerivative(Dh, F)


@pytest.fixture
def composed():
    rng = np.random.default_rng(0)
    d = 4
    linear = [np.eye(d) + 0.3 * rng.standard_normal((d, d)) for _ in range(3)]
    jumps = [random_bd(rng, 3, d), random_bd(rng, 2, d)]
    ff = rng.standard_normal(d)
    return FlowBDerivative(linear, jumps, final_field=ff, group_events=[(0, 2, 3), (1, 4)])


def manual(fb, v):
    w = fb.linear[0] @ v
    for i, bd in enumerate(fb.jumps):
        w = fb.linear[i + 1] @ bd(w)
    return w


def manual_piece(fb, orders):
    P = fb.linear[0]
    for i, (bd, order) in enumerate(zip(fb.jumps, orders, strict=True)):
        P = fb.linear[i + 1] @ bd.piece(order) @ P
    return P


def test_composition_matches_manual(composed):
    V = np.random.default_rng(1).standard_normal((7, 4))
    out = composed(V)
    for v, o in zip(V, out, strict=True):
        np.testing.assert_allclose(o, manual(composed, v), rtol=1e-13, atol=1e-13)
    assert composed.n_groups == 2 and not composed.is_linear and composed.dim == 4
    assert "groups=[3, 2]" in repr(composed)


def test_batch_shapes(composed):
    V = np.random.default_rng(2).standard_normal((3, 5, 4))
    out = composed(V)
    assert out.shape == (3, 5, 4)
    np.testing.assert_allclose(out[1, 2], manual(composed, V[1, 2]), rtol=1e-13, atol=1e-13)
    assert composed(V[0, 0]).shape == (4,)
    v32 = V[2, 3].astype(np.float32)
    np.testing.assert_allclose(
        composed(v32), manual(composed, v32.astype(np.float64)), rtol=1e-13, atol=1e-13
    )
    Vt = np.asfortranarray(V[0].T).T  # non-contiguous
    np.testing.assert_allclose(composed(Vt), out[0], rtol=1e-14)
    ro = V.copy()
    ro.setflags(write=False)
    np.testing.assert_array_equal(composed(ro), out)


def test_piece_of_each_vector_orders(composed):
    V = np.random.default_rng(3).standard_normal((30, 4))
    orders = composed.orders(V)
    assert [o.shape for o in orders] == [(30, 3), (30, 2)]
    seen = set()
    for i, v in enumerate(V):
        P = manual_piece(composed, [orders[0][i], orders[1][i]])
        np.testing.assert_allclose(P @ v, manual(composed, v), rtol=1e-10, atol=1e-12)
        np.testing.assert_allclose(composed.piece([orders[0][i], orders[1][i]]), P, rtol=1e-13)
        seen.add((tuple(orders[0][i]), tuple(orders[1][i])))
    assert len(seen) > 3


def test_apply_orders_is_apply_and_orders_in_one_pass(composed):
    """The same bits as ``D(V)`` and ``D.orders(V)``, and the pieces' products (written
    out) agree with the images."""
    V = np.random.default_rng(13).standard_normal((40, 4))
    W, orders = composed.apply_orders(V)
    np.testing.assert_array_equal(W, composed(V))
    for got, want in zip(orders, composed.orders(V), strict=True):
        np.testing.assert_array_equal(got, want)
    for i, v in enumerate(V):
        P = manual_piece(composed, [orders[0][i], orders[1][i]])
        np.testing.assert_allclose(P @ v, W[i], rtol=1e-10, atol=1e-12)
    with pytest.raises(ValueError, match="V must"):
        composed.apply_orders(V[:, :3])


def test_event_times_are_the_jumps_event_times(composed):
    V = np.random.default_rng(3).standard_normal((6, 5, 4))
    pairs = composed.event_times(V)
    assert len(pairs) == composed.n_groups
    W = V @ composed.linear[0].T  # the vectors entering the first group
    times, order = composed.jumps[0].event_times(W)
    # the stages' products are the package's kernel, not BLAS: equal to rounding
    np.testing.assert_allclose(pairs[0][0], times, rtol=1e-12, atol=1e-12)
    np.testing.assert_array_equal(pairs[0][1], order)
    W = composed.jumps[0](W) @ composed.linear[1].T
    times, order = composed.jumps[1].event_times(W)
    np.testing.assert_allclose(pairs[1][0], times, rtol=1e-12, atol=1e-12)
    assert pairs[1][1].shape == (6, 5, 2) and pairs[1][1].dtype == np.int64
    np.testing.assert_array_equal(composed.orders(V)[1], pairs[1][1])


def test_positive_homogeneity_and_continuity(composed):
    rng = np.random.default_rng(4)
    V = rng.standard_normal((20, 4))
    np.testing.assert_allclose(composed(2.5 * V), 2.5 * composed(V), rtol=1e-12)
    dV = 1e-9 * rng.standard_normal((20, 4))
    assert np.abs(composed(V + dV) - composed(V)).max() < 1e-7


def test_final_time(composed):
    V = np.random.default_rng(5).standard_normal((6, 4))
    dt = np.linspace(-1, 1, 6)
    ff = composed.final_field
    expected = np.array([manual(composed, v) for v in V]) + dt[:, None] * ff
    np.testing.assert_allclose(composed(V, dt=dt), expected, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(
        composed(V, dt=0.5), expected - dt[:, None] * ff + 0.5 * ff, rtol=1e-12, atol=1e-12
    )
    chunked = composed(V, dt=dt, chunk_size=4)  # dt follows the rows of each chunk
    np.testing.assert_allclose(chunked, expected, rtol=1e-12, atol=1e-12)
    grid = composed(V.reshape(2, 3, 4), dt=dt[:3])  # broadcast over the leading shape
    np.testing.assert_allclose(
        grid, np.array([manual(composed, v) for v in V]).reshape(2, 3, 4)
        + np.tile(dt[:3], 2).reshape(2, 3, 1) * ff, rtol=1e-12, atol=1e-12
    )
    orders = composed.orders(V[0])
    P = composed.piece(orders, with_time=True)
    assert P.shape == (4, 5)
    np.testing.assert_allclose(P[:, 4], ff)
    np.testing.assert_allclose(P @ np.append(V[0], 0.3), expected[0] - dt[0] * ff + 0.3 * ff,
                               rtol=1e-10)


@pytest.mark.parametrize(
    ("dt", "error", "match"),
    [
        (np.ones(5), ValueError,
         r"dt must be a scalar or have a shape that broadcasts to the leading shape \(6,\) "
         r"of V, got shape \(5,\)"),
        ("0.1", TypeError, "dt must hold real numbers"),
        (np.array([0.1, np.inf, 0, 0, 0, 0]), ValueError, "dt must be finite, got inf"),
    ],
)
def test_bad_dt(composed, dt, error, match):
    with pytest.raises(error, match=match):
        composed(np.ones((6, 4)), dt=dt)


def test_inverse(composed):
    rng = np.random.default_rng(9)
    V = rng.standard_normal((40, 4))
    np.testing.assert_allclose(composed.inverse(composed(V)), V, rtol=1e-12, atol=1e-12)
    W = rng.standard_normal((2, 20, 4))
    np.testing.assert_allclose(composed(composed.inverse(W)), W, rtol=1e-12, atol=1e-12)
    # against the stages' inverses applied by hand, in reverse order
    w = W[1, 3]
    v = np.linalg.solve(composed.linear[2], w)
    v = np.linalg.solve(composed.linear[1], composed.jumps[1].inverse(v))
    v = np.linalg.solve(composed.linear[0], composed.jumps[0].inverse(v))
    np.testing.assert_allclose(composed.inverse(w), v, rtol=1e-12, atol=1e-12)
    with pytest.raises(ValueError, match=r"W must have shape \(\.\.\., 4\)"):
        composed.inverse(np.ones(3))
    with pytest.raises(ValueError, match="W must be finite"):
        composed.inverse(np.array([1.0, np.nan, 0.0, 0.0]))


def test_inverse_of_a_singular_stage_is_refused():
    rng = np.random.default_rng(7)  # random_bd(rng, 2, 3) terminates for this seed
    singular = np.array([[1.0, 2.0, 0.0], [2.0, 4.0, 0.0], [0.0, 0.0, 1.0]])
    fb = FlowBDerivative([np.eye(3), singular], [random_bd(rng, 2, 3)])
    V = rng.standard_normal((3, 3))
    fb(V)  # the forward map is fine
    with pytest.raises(
        ValueError,
        match=r"not invertible: its linear stage linear\[1\] is singular to working precision",
    ):
        fb.inverse(V)


def test_out_chunks_and_progress(composed):
    V = np.random.default_rng(11).standard_normal((10, 4))
    expected = np.array([manual(composed, v) for v in V])
    out = np.empty((10, 4))
    assert composed(V, out=out) is out
    np.testing.assert_allclose(out, expected, rtol=1e-12, atol=1e-12)
    seen = []
    res = composed(V, chunk_size=4, progress=lambda done, total: seen.append((done, total)))
    assert seen == [(4, 10), (8, 10), (10, 10)]
    np.testing.assert_allclose(res, expected, rtol=1e-12, atol=1e-12)
    alias = V.copy()
    composed(alias, out=alias)  # out may be V itself
    np.testing.assert_allclose(alias, expected, rtol=1e-12, atol=1e-12)
    back = composed.inverse(expected, chunk_size=3)
    np.testing.assert_allclose(back, V, rtol=1e-12, atol=1e-12)
    with pytest.raises(ValueError, match=r"out must have shape \(10, 4\)"):
        composed(V, out=np.empty((10, 3)))


def test_dask(composed):
    da = pytest.importorskip("dask.array")
    V = np.random.default_rng(12).standard_normal((50, 4))
    lazy = composed(da.from_array(V, chunks=(20, 4)), dt=0.25)
    expected = np.array([manual(composed, v) for v in V]) + 0.25 * composed.final_field
    np.testing.assert_allclose(lazy.compute(), expected, rtol=1e-12, atol=1e-12)
    images = expected - 0.25 * composed.final_field
    back = composed.inverse(da.from_array(images, chunks=(20, 4)))
    np.testing.assert_allclose(back.compute(), V, rtol=1e-12, atol=1e-12)
    with pytest.raises(ValueError, match="dt must be a scalar when V is a dask array"):
        composed(da.from_array(V, chunks=(20, 4)), dt=np.ones(50))


def test_final_time_matches_simulation():
    ex = examples.chair()
    s = ex.system
    fb = s.flow_bderivative(ex.x0, ex.t_final)
    dt = 1e-6
    a = s.simulate(ex.x0, ex.t_final, rtol=1e-12, atol=1e-13).x_final
    b = s.simulate(ex.x0, ex.t_final + dt, rtol=1e-12, atol=1e-13).x_final
    np.testing.assert_allclose((b - a) / dt, fb(np.zeros(6), dt=1.0), rtol=1e-4, atol=1e-4)


def test_pickle(composed):
    V = np.random.default_rng(6).standard_normal((5, 4))
    composed.inverse(V)  # the stage inverses travel too
    clone = pickle.loads(pickle.dumps(composed))
    np.testing.assert_array_equal(clone(V), composed(V))
    np.testing.assert_array_equal(clone.inverse(V), composed.inverse(V))
    np.testing.assert_array_equal(clone.final_field, composed.final_field)
    assert clone.group_events == composed.group_events
    assert not clone.linear[0].flags.writeable and not clone.final_field.flags.writeable


def test_stages_read_only(composed):
    with pytest.raises(ValueError):
        composed.linear[0][0, 0] = 1.0
    with pytest.raises(ValueError):
        composed.final_field[0] = 1.0


def test_validation():
    rng = np.random.default_rng(7)
    bd = random_bd(rng, 2, 3)
    eye = np.eye(3)
    with pytest.raises(ValueError, match=r"need len\(jumps\) \+ 1 = 2 linear stages, got 1"):
        FlowBDerivative([eye], [bd])
    with pytest.raises(TypeError, match=r"jumps\[0\] must be a BDerivative, got ndarray"):
        FlowBDerivative([eye, eye], [eye])
    with pytest.raises(ValueError, match="jumps\\[0\\] has dimension 3 but the stages have 2"):
        FlowBDerivative([np.eye(2), np.eye(2)], [bd])
    with pytest.raises(ValueError, match=r"linear\[1\] must have shape \(3, 3\), got \(2, 2\)"):
        FlowBDerivative([eye, np.eye(2)], [bd])
    with pytest.raises(ValueError, match="linear\\[0\\] must be finite"):
        FlowBDerivative([np.full((3, 3), np.nan), eye], [bd])
    with pytest.raises(ValueError, match="group_events has 2 groups but there are 1 jumps"):
        FlowBDerivative([eye, eye], [bd], group_events=[(0,), (1,)])
    fb = FlowBDerivative([eye, eye], [bd])
    with pytest.raises(ValueError, match=r"orders must be given: groups \[0\]"):
        fb.piece()
    with pytest.raises(ValueError, match=r"need one event order per group \(1 groups\), got 2"):
        fb.piece([[0, 1], [1, 0]])
    with pytest.raises(ValueError, match="order must be a permutation"):
        fb.piece([[0, 0]])
    with pytest.raises(ValueError, match="no final_field"):
        fb(np.ones(3), dt=1.0)
    with pytest.raises(ValueError, match="no final_field"):
        fb.piece([[0, 1]], with_time=True)
    with pytest.raises(ValueError, match=r"V must have shape \(\.\.\., 3\)"):
        fb(np.ones(4))
    with pytest.raises(ValueError, match="V must be finite"):
        fb(np.array([1.0, np.nan, 0.0]))
    with pytest.raises(ValueError, match="dt must be finite"):
        FlowBDerivative([eye], [], final_field=np.ones(3))(np.ones(3), dt=np.nan)


def test_linear_map_without_groups():
    M = np.arange(9.0).reshape(3, 3)
    fb = FlowBDerivative([M], [])
    assert fb.is_linear
    V = np.random.default_rng(8).standard_normal((4, 3))
    np.testing.assert_allclose(fb(V), V @ M.T)
    np.testing.assert_array_equal(fb.piece(), M)
    assert fb.orders(V) == [] and fb.event_times(V) == []
    with pytest.raises(ValueError, match=r"linear\[0\] is singular"):
        fb.inverse(V)
    M = M + np.eye(3)
    np.testing.assert_allclose(FlowBDerivative([M], []).inverse(V), np.linalg.solve(M, V.T).T,
                               rtol=1e-12, atol=1e-12)


@given(
    hnp.arrays(
        np.float64,
        (4,),
        elements=st.floats(-10, 10, allow_nan=False, allow_infinity=False),
    ),
    st.floats(0.01, 100),
)
def test_invariants_hypothesis(v, scale):
    fb = _COMPOSED
    out = fb(v)
    np.testing.assert_allclose(fb(scale * v), scale * out, rtol=1e-9, atol=1e-9)
    P = fb.piece(fb.orders(v))
    np.testing.assert_allclose(P @ v, out, rtol=1e-8, atol=1e-8 * (1 + np.abs(out).max()))


def _make_composed():
    rng = np.random.default_rng(0)
    d = 4
    linear = [np.eye(d) + 0.3 * rng.standard_normal((d, d)) for _ in range(3)]
    return FlowBDerivative(linear, [random_bd(rng, 3, d), random_bd(rng, 2, d)])


_COMPOSED = _make_composed()


def test_triangulation_of_a_flow_map_with_one_group(composed):
    """The fan of the group's map carried by the stages rebuilds D (the chair: d > n)."""
    ex = examples.chair()
    D = ex.system.flow_bderivative(ex.x0, ex.t_final)
    tri = D.triangulation()
    V = np.random.default_rng(9).standard_normal((200, D.dim))
    W = D(V)
    np.testing.assert_allclose(tri.apply(V), W, rtol=0, atol=1e-10 * np.abs(W).max())
    np.testing.assert_allclose(tri.inverse(W), V, rtol=0, atol=1e-9 * np.abs(V).max())
    with pytest.raises(ValueError, match=r"meets 2 event groups; a triangulation"):
        composed.triangulation()


def test_orders_of_subnormal_vectors_are_given():
    """The falsifying example of test_invariants_hypothesis: event times of 5e-324 vectors
    underflow, their orders do not (orders(c v) = orders(v))."""
    v = np.full(4, 5e-324)
    orders = _COMPOSED.orders(v)
    assert [o.tolist() for o in orders] == [o.tolist() for o in _COMPOSED.orders(v * 2.0**1000)]
