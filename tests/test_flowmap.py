"""FlowBDerivative: composition, pieces, final time, batches, pickling, validation."""

from __future__ import annotations

import pickle

import hypothesis.extra.numpy as hnp
import hypothesis.strategies as st
import numpy as np
import pytest
from hypothesis import given

from bderiv import BDerivative, examples
from bderiv.flowmap import FlowBDerivative


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
    np.testing.assert_allclose(out[1, 2], composed(V[1, 2]), rtol=1e-14)
    assert composed(V[0, 0]).shape == (4,)
    np.testing.assert_allclose(composed(V.astype(np.float32)), composed(V.astype(np.float32)))
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
        P = composed.piece([orders[0][i], orders[1][i]])
        np.testing.assert_allclose(P @ v, composed(v), rtol=1e-10, atol=1e-12)
        seen.add((tuple(orders[0][i]), tuple(orders[1][i])))
    assert len(seen) > 3
    times = composed.event_times(V)
    assert times[0][0].shape == (30, 3)


def test_positive_homogeneity_and_continuity(composed):
    rng = np.random.default_rng(4)
    V = rng.standard_normal((20, 4))
    np.testing.assert_allclose(composed(2.5 * V), 2.5 * composed(V), rtol=1e-12)
    dV = 1e-9 * rng.standard_normal((20, 4))
    assert np.abs(composed(V + dV) - composed(V)).max() < 1e-7


def test_final_time(composed):
    V = np.random.default_rng(5).standard_normal((6, 4))
    dt = np.linspace(-1, 1, 6)
    np.testing.assert_allclose(
        composed(V, dt=dt), composed(V) + dt[:, None] * composed.final_field
    )
    np.testing.assert_allclose(composed(V, dt=0.5), composed(V) + 0.5 * composed.final_field)
    orders = composed.orders(V[0])
    P = composed.piece(orders, with_time=True)
    assert P.shape == (4, 5)
    np.testing.assert_allclose(P @ np.append(V[0], 0.3), composed(V[0], dt=0.3), rtol=1e-10)


def test_final_time_matches_simulation():
    ex = examples.chair()
    s = ex.system
    fb = s.flow_bderivative(ex.x0, ex.t_final)
    dt = 1e-6
    a = s.simulate(ex.x0, ex.t_final, rtol=1e-12, atol=1e-13).x_final
    b = s.simulate(ex.x0, ex.t_final + dt, rtol=1e-12, atol=1e-13).x_final
    np.testing.assert_allclose((b - a) / dt, fb(np.zeros(6), dt=1.0), rtol=1e-4, atol=1e-4)


def test_pickle(composed):
    clone = pickle.loads(pickle.dumps(composed))
    V = np.random.default_rng(6).standard_normal((5, 4))
    np.testing.assert_array_equal(clone(V), composed(V))
    np.testing.assert_array_equal(clone.final_field, composed.final_field)
    assert clone.group_events == composed.group_events


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
    assert fb.orders(V) == []


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
