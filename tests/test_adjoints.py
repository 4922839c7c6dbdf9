"""Per-direction linearisation: ``jvp``, ``vjp`` and ``piece_matrices`` (issue 11).

Oracles: the pieces of ``reference.py`` (saltation products of the order the oracle's
selection finds for each vector), the dot-product identity, and finite differences of the
simulated flow of the examples. Every representation's jvp and vjp against the oracle's
pieces, with the dot-product identity and ``jvp(V, V) = M(V)``: ``tests/test_variants.py``.
"""

from __future__ import annotations

import numpy as np
import pytest
from reference import random_system, ref_event_times, ref_piece

from bderiv import BDerivative, FlowBDerivative, StructuredCorners, examples


def structured_normals(rng, n, d):
    """Event normals around a unit vector e and the pre-event field 1.5 e (rates > 0)."""
    e = rng.standard_normal(d)
    e /= np.linalg.norm(e)
    return e + 0.4 * rng.uniform(-1, 1, (n, d)) / np.sqrt(d), 1.5 * e


def test_a_tie_takes_the_smaller_events_piece():
    """u = (-1, -1): both events at t = 1, a boundary between the pieces (0, 1) and (1, 0),
    which differ. The selection takes event 0 first, and so do jvp, vjp, piece_matrices."""
    Dh = np.eye(2)
    F = np.array([[1.0, 1.0], [2.0, 0.5], [0.5, 3.0], [1.5, 2.0]])
    bd = BDerivative(Dh, F)
    u = np.array([-1.0, -1.0])
    assert bd.orders(u).tolist() == [0, 1]
    first, second = ref_piece(Dh, F, [0, 1]), ref_piece(Dh, F, [1, 0])
    assert np.abs(first - second).max() >= 0.5  # the two linearisations really differ
    t = np.array([0.3, -0.7])
    np.testing.assert_allclose(bd.jvp(u, t), first @ t, rtol=1e-14)
    np.testing.assert_allclose(bd.vjp(u, t), first.T @ t, rtol=1e-14)
    np.testing.assert_allclose(bd.piece_matrices(u), first, rtol=1e-14)
    # both pieces agree on u itself (M is continuous)
    np.testing.assert_allclose(first @ u, second @ u, rtol=1e-14)


def test_piece_matrices_shapes_and_consistency():
    rng = np.random.default_rng(2)
    Dh, F = random_system(rng, 3, 4)
    bd = BDerivative(Dh, F)
    V = rng.standard_normal((2, 5, 4))
    P = bd.piece_matrices(V)
    assert P.shape == (2, 5, 4, 4)
    orders = bd.orders(V)
    for idx in np.ndindex(2, 5):
        np.testing.assert_allclose(P[idx], bd.piece(orders[idx]), rtol=1e-12, atol=1e-12)
    assert bd.piece_matrices(V[0, 0]).shape == (4, 4)
    # the result (12.2 MiB), the rows' copy and scaled copy (2 x 3.05 MiB) and the
    # temporaries of building the result (3x 12.2 MiB)
    with pytest.raises(ValueError, match=r"piece matrices of 100000 vectors in dimension 4 "
                                         r"take 54\.9 MiB, more than the memory limit"):
        bd.piece_matrices(np.ones((100000, 4)), memory_limit=1 << 20)


def test_shapes_out_chunks_and_errors():
    rng = np.random.default_rng(3)
    Dh, F = random_system(rng, 3, 3)
    bd = BDerivative(Dh, F)
    V, T = rng.standard_normal((2, 7, 3)), rng.standard_normal((2, 7, 3))
    J = bd.jvp(V, T)
    assert J.shape == (2, 7, 3)
    np.testing.assert_array_equal(bd.jvp(V[1, 2], T[1, 2]), J[1, 2])
    np.testing.assert_array_equal(bd.jvp(V, T, chunk_size=3), J)  # bitwise
    for alias in ("V", "T"):
        Vc, Tc = V.copy(), T.copy()
        res = bd.jvp(Vc, Tc, out=Vc if alias == "V" else Tc)
        np.testing.assert_array_equal(res, J)
    with pytest.raises(ValueError, match=r"V and T must have the same shape, got \(2, 7, 3\) "
                                         r"and \(7, 3\)"):
        bd.jvp(V, T[0])
    with pytest.raises(ValueError, match=r"W must have shape \(\.\.\., 3\)"):
        bd.vjp(V, np.ones((2, 7, 2)))
    bad = T.copy()
    bad[1, 4, 0] = np.nan
    with pytest.raises(ValueError, match=r"T\[1, 4\]"):
        bd.jvp(V, bad)
    da = pytest.importorskip("dask.array")
    with pytest.raises(TypeError, match="jvp/vjp take NumPy arrays"):
        bd.vjp(da.from_array(V), T)


def test_many_events_structured_model():
    """n = 40 (no table): the generic path (orders, corners along them, factors) against
    the piece of the selection's order, and the dot-product identity."""
    rng = np.random.default_rng(4)
    n = d = 40
    Dh, F0 = structured_normals(rng, n, d)
    A = 0.02 * rng.standard_normal((n, d))
    model = StructuredCorners(F0, A, np.array([(0, 1), (5, 9)]),
                              0.1 * rng.standard_normal((2, d)))
    bd = BDerivative(Dh, model)
    V, T = rng.standard_normal((50, d)), rng.standard_normal((50, d))
    J, Jt = bd.jvp(V, T), bd.vjp(V, T)
    orders = bd.orders(V)
    for q in (0, 17, 49):
        P = bd.piece(orders[q])
        np.testing.assert_allclose(J[q], P @ T[q], rtol=1e-10, atol=1e-10)
        np.testing.assert_allclose(Jt[q], P.T @ T[q], rtol=1e-10, atol=1e-10)


# ----------------------------------------------------------------------------------------
# flow maps
# ----------------------------------------------------------------------------------------
def test_flow_jvp_vjp_against_its_pieces():
    rng = np.random.default_rng(6)
    d = 4
    jumps = [BDerivative(*random_system(rng, 2, d)), BDerivative(*random_system(rng, 3, d))]
    linear = [np.eye(d) + 0.3 * rng.standard_normal((d, d)) for _ in range(3)]
    D = FlowBDerivative(linear, jumps)
    V, T, W = (rng.standard_normal((400, d)) for _ in range(3))
    J, Jt = D.jvp(V, T), D.vjp(V, W)
    orders = D.orders(V)
    for q in range(0, 400, 23):
        P = D.piece([o[q] for o in orders])
        np.testing.assert_allclose(J[q], P @ T[q], rtol=1e-12, atol=1e-12 * np.abs(P).max())
        np.testing.assert_allclose(Jt[q], P.T @ W[q], rtol=1e-12, atol=1e-12 * np.abs(P).max())
    np.testing.assert_allclose(D.jvp(V, V), D(V), rtol=1e-12, atol=1e-12)
    P = D.piece_matrices(V[:30])
    np.testing.assert_allclose(np.einsum("qij,qj->qi", P, T[:30]), J[:30], rtol=1e-12,
                               atol=1e-12)


@pytest.mark.parametrize("make", [examples.chair, examples.table], ids=["chair", "table"])
def test_gradient_of_a_terminal_cost_against_simulation(make):
    """d/ds c(Phi(T, x0 + s v)) at s = 0+ is grad c . D(v) = vjp(v, grad c) . v; compared
    with one-sided differences of the simulated cost c(x) = sum(sin(x)) + |x|^2 / 2."""
    ex = make()
    D = ex.system.flow_bderivative(ex.x0, ex.t_final)
    x_final = D.x_final
    grad = np.cos(x_final) + x_final
    V = np.random.default_rng(7).standard_normal((6, D.dim))
    G = D.vjp(V, np.broadcast_to(grad, V.shape))
    predicted = np.einsum("ij,ij->i", G, V)
    eps = 1e-6
    moved = x_final + eps * ex.system.flow_fd(ex.x0, ex.t_final, V, eps)
    cost = np.sin(moved).sum(axis=1) + 0.5 * (moved**2).sum(axis=1)
    base = np.sin(x_final).sum() + 0.5 * (x_final**2).sum()
    np.testing.assert_allclose((cost - base) / eps, predicted, rtol=1e-3,
                               atol=1e-3 * np.abs(predicted).max())


# ----------------------------------------------------------------------------------------
# found by review: extreme scales, fast-path ties, several vector blocks
# ----------------------------------------------------------------------------------------
@pytest.mark.parametrize("scale", [1e300, 1e-300, 2.0**-1060])
def test_the_piece_does_not_depend_on_the_directions_scale(scale):
    """Dh v near the ends of float64 overflowed (underflowed) the event times, and the
    selection picked a wrong piece, silently; the piece depends on the direction only."""
    Dh = np.diag([1e10, 1e-10])
    F = 1e10 * np.array([[1, 1], [2, 0.5], [0.5, 3], [1.5, 2]])
    bd = BDerivative(Dh, F)
    v, t = np.array([-1.0, -2.0]), np.array([0.3, -0.7])
    P = ref_piece(Dh, F, [0, 1])
    np.testing.assert_allclose(bd.jvp(scale * v, t), P @ t, rtol=1e-14)
    np.testing.assert_allclose(bd.vjp(scale * v, t), P.T @ t, rtol=1e-14)
    np.testing.assert_allclose(bd.piece_matrices(scale * v), P, rtol=1e-14)


def test_own_rates_tie_uses_the_piece_orders_names():
    """Own rates (a fast path) and a three-way exact tie: jvp/vjp/piece_matrices take the
    piece of ``orders(v)`` (the fast path's sort), not a chain recomputed differently."""
    F = np.array([[1, 3, 1, 3, -3], [3, 3, 1, -2, -3], [1, 3, 1, 2, 2], [3, 3, 1, 3, 1],
                  [1, 3, 2, -1, -1], [3, 3, 2, 3, 2], [1, 3, 2, -2, -1], [3, 3, 2, -2, -1]],
                 float)
    bd = BDerivative(np.eye(3, 5), F, transversality_tol=0)
    assert bd.fast_path == "own-rates"
    v = np.array([-2, -6, -2, -4, -6]) / 3.0
    P = bd.piece(bd.orders(v))
    np.testing.assert_allclose(bd.piece_matrices(v), P, rtol=1e-14, atol=1e-14)
    t = np.arange(5.0)
    np.testing.assert_allclose(bd.vjp(v, t), P.T @ t, rtol=1e-13)


@pytest.mark.parametrize("n, d", [(9, 17), (17, 9)])
def test_several_vector_blocks(n, d):
    """n or d beyond one 8-wide block: the lane kernels' loops over blocks."""
    rng = np.random.default_rng(n * d)
    Dh, F = random_system(rng, n, d)
    bd = BDerivative(Dh, F)
    V, T = rng.standard_normal((40, d)), rng.standard_normal((40, d))
    J, Jt = bd.jvp(V, T), bd.vjp(V, T)
    for q in range(0, 40, 7):
        P = ref_piece(Dh, F, ref_event_times(Dh, F, V[q])[1])
        scale = np.abs(P).max() * np.abs(T[q]).max()
        np.testing.assert_allclose(J[q], P @ T[q], rtol=0, atol=1e-11 * scale)
        np.testing.assert_allclose(Jt[q], P.T @ T[q], rtol=0, atol=1e-11 * scale)


def test_an_overflowing_tangent_names_the_tangent_row():
    """The directions are scaled before the selection, so only the tangent (or co-vector)
    can overflow the result: the error names its row, through a flow map's groups too."""
    Dh = np.eye(2)
    F = np.array([[1.0, 1.0], [2.0, 1.0], [1.0, 3.0], [2.0, 2.0]])
    bd = BDerivative(Dh, F)
    V = np.ones((4, 2))
    T = np.ones((4, 2))
    T[2] = 1e308
    with pytest.raises(ValueError, match=r"the result for T\[2\] overflowed"):
        bd.jvp(V, T)
    with pytest.raises(ValueError, match=r"the result for W\[2\] overflowed"):
        bd.vjp(V, T)
    D = FlowBDerivative([np.eye(2), 2.0 * np.eye(2)], [bd])
    T[[2, 3]] = T[[3, 2]]  # row 3: in the second chunk of two rows
    with pytest.raises(ValueError, match=r"event group 0 .*the result for T\[3\] overflowed"):
        D.jvp(V, T, chunk_size=2)


def test_unit_scale_is_ldexp_of_the_row_exponent():
    """The directions' scaling (one compiled pass) is exactly NumPy's frexp/ldexp, down into
    the subnormals and up from them."""
    from bderiv.engine._linearise import unit_scale

    rng = np.random.default_rng(9)
    R = (rng.standard_normal((20000, 5)) * 10.0 ** rng.integers(-290, 300, (20000, 1))
         * 10.0 ** rng.integers(-30, 1, (20000, 5)))
    R[:3] = [[0.0] * 5, [5e-324, 0, 0, 0, -5e-324], [1.7e308, 1e-300, 4e-320, 0, 1]]
    expected = np.ldexp(R, -np.frexp(np.abs(R).max(axis=1))[1][:, None])
    np.testing.assert_array_equal(unit_scale(R), expected)
    assert np.all((np.abs(expected).max(axis=1) >= 0.5)[3:])
