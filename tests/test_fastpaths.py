"""Fast paths (own rates, linear) and chunked evaluation against the general kernel and
the oracle."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from reference import (
    assert_maps_close,
    random_system,
    ref_apply,
    ref_event_times,
    ref_inverse,
    ref_piece,
)

from bderiv import BDerivative
from bderiv.geometry.corners import StructuredCorners


def own_rate_table(rng, n, d, additive=False):
    """A dense table whose rate G[mask, k] depends only on bit k of mask.

    F[mask] = pinv(Dh) r(mask) + K z(mask), with r(mask)[k] = before[k] or after[k] by bit
    k and z(mask) any kernel component (additive in the bits when ``additive``).
    """
    Dh = np.eye(n, d) + 0.3 * rng.uniform(-1, 1, (n, d))
    before = rng.uniform(0.5, 2.0, n)
    after = rng.uniform(0.5, 2.0, n)
    K = np.eye(d) - np.linalg.pinv(Dh) @ Dh
    masks = np.arange(2**n)
    bits = ((masks[:, None] >> np.arange(n)) & 1).astype(float)
    rates = before + bits * (after - before)
    if additive:
        z = rng.standard_normal(d) + bits @ rng.standard_normal((n, d))
    else:
        z = rng.standard_normal((2**n, d))
    F = rates @ np.linalg.pinv(Dh).T + z @ K.T
    return Dh, F


@pytest.mark.parametrize("n, d", [(1, 1), (2, 3), (4, 4), (5, 7), (7, 7)])
@pytest.mark.parametrize("additive", [False, True])
def test_dense_fast_paths(n, d, additive):
    rng = np.random.default_rng(10 * n + d + additive)
    Dh, F = own_rate_table(rng, n, d, additive)
    fast = BDerivative(Dh, F)
    general = BDerivative(Dh, F, fast_paths=False)
    # with d == n there is no kernel part: own rates alone make the corners additive
    assert fast.fast_path == ("linear" if additive or d == n else "own-rates")
    assert general.fast_path is None
    V = rng.standard_normal((300, d)) * rng.uniform(0.1, 10, (300, 1))
    W = fast(V)
    assert_maps_close(Dh, F, V, W, general(V))
    assert_maps_close(Dh, F, V[:15], W[:15], [ref_apply(Dh, F, u) for u in V[:15]])
    assert_maps_close(Dh, F, V[:15], fast.inverse(V[:15]), [ref_inverse(Dh, F, u) for u in V[:15]])
    assert_maps_close(Dh, F, V, fast.inverse(W), V)
    times, order = fast.event_times(V)
    tg, og = general.event_times(V)
    np.testing.assert_allclose(times, tg, rtol=1e-12, atol=1e-12)
    np.testing.assert_array_equal(order, og)
    for u, t in zip(V[:10], times[:10], strict=True):
        np.testing.assert_allclose(t, ref_event_times(Dh, F, u)[0], rtol=1e-12, atol=1e-12)


def test_linear_path_formula_and_single_piece():
    """Own rates + additive corners: every piece is I + A^T diag(1/G[0]) Dh and
    M(u) = u - A^T t with t the event times (checked against the general kernel)."""
    rng = np.random.default_rng(0)
    n, d = 4, 6
    Dh, F = own_rate_table(rng, n, d, additive=True)
    A = F[1 << np.arange(n)] - F[0]
    G0 = Dh @ F[0]
    M = np.eye(d) + A.T @ (Dh / G0[:, None])
    for order in itertools.permutations(range(n)):
        np.testing.assert_allclose(ref_piece(Dh, F, order), M, atol=1e-12)
    general = BDerivative(Dh, F, fast_paths=False)
    V = rng.standard_normal((200, d))
    t, _ = general.event_times(V)
    np.testing.assert_allclose(general(V), V - t @ A, atol=1e-12)
    np.testing.assert_allclose(general(V), V @ M.T, atol=1e-12)
    np.testing.assert_allclose(BDerivative(Dh, F)(V), V @ M.T, atol=1e-12)


def test_fast_path_not_taken_when_rates_depend_on_other_events():
    rng = np.random.default_rng(1)
    Dh, F = random_system(rng, 4, 4)
    assert BDerivative(Dh, F).fast_path is None
    Dh, F = own_rate_table(rng, 4, 5, additive=True)
    F2 = F.copy()
    F2[0b0110] += 1e-6 * Dh[0]  # event 0's rate now depends on events 1 and 2, slightly
    assert BDerivative(Dh, F2).fast_path is None
    F3 = F.copy()
    F3[0b0110] += 1e-3 * np.linalg.svd(Dh)[2][-1]  # kernel direction: rates unchanged
    assert BDerivative(Dh, F3).fast_path == "own-rates"  # ... but not additive


@pytest.mark.parametrize("structured, d, A1", [
    (False, 2.5e-9, (3.9e-12, 0.0)), (True, 1e-8, (1 - 1e-8 + 1.5e-12, 1.0))],
    ids=["dense", "structured"])
def test_a_rate_change_far_below_its_rounding_scale_but_not_the_rate_is_no_fast_path(
        structured, d, A1):
    """Near grazing (event 0's rate d, 1e-9 to 1e-8 of its rounding scale |F| |Dh|),
    event 1 changes that rate by 0.16 % (dense) or 0.015 % (structured): below 1e-12 of
    the scale, which let the fast paths ignore it and move event 0's time by as much. The
    change is held to the rate it changes too. Oracle: tests/reference.py."""
    Dh = np.array([[1.0, -(1 - d)], [0.0, 1.0]])
    F0, A = np.array([1.0, 1.0]), np.array([[d, 0.0], A1])
    F = np.array([F0, F0 + A[0], F0 + A[1], F0 + A[0] + A[1]])
    bd = BDerivative(Dh, StructuredCorners(F0, A) if structured else F)
    assert bd.fast_path is None
    V = np.array([[-d, 1.0], [d, -1.0], [-2 * d, 1.0]])
    exact = np.array([ref_apply(Dh, F, v, dtype=np.longdouble) for v in V], dtype=float)
    # within the table's own conditioning, relative to each row's size
    assert (np.abs(bd(V) - exact).max(axis=1) < 1e-6 * np.abs(exact).max(axis=1)).all()


def test_additive_without_own_rates_is_general_and_correct():
    rng = np.random.default_rng(2)
    n = 5
    Dh = np.eye(n)
    model = StructuredCorners(np.ones(n), 0.15 * rng.uniform(-1, 1, (n, n)))
    bd = BDerivative(Dh, model.table())
    assert bd.fast_path is None  # additive, but rates change with other events
    V = rng.standard_normal((30, n))
    assert_maps_close(Dh, model.table(), V, bd(V), [ref_apply(Dh, model.table(), u) for u in V])


@pytest.mark.parametrize("with_pairs", [False, True])
def test_structured_fast_paths(with_pairs):
    """Own rates in a structured model: A[k] moves only h_k's rate; pair jumps lie in
    ker Dh (d > n). With pairs the corners are not additive: own-rates path."""
    rng = np.random.default_rng(3)
    n, d = 6, 9
    Dh = np.eye(n, d) + 0.2 * rng.uniform(-1, 1, (n, d))
    pinv = np.linalg.pinv(Dh)
    K = np.eye(d) - pinv @ Dh
    F0 = pinv @ rng.uniform(0.5, 2, n) + K @ rng.standard_normal(d)
    A = (pinv * rng.uniform(-0.4, 1.0, n)).T + rng.standard_normal((n, d)) @ K.T
    if with_pairs:
        pairs = np.array([[0, 1], [2, 5], [1, 4], [3, 4]])
        B = rng.standard_normal((4, d)) @ K.T
        model = StructuredCorners(F0, A, pairs, B)
    else:
        model = StructuredCorners(F0, A)
    F = model.table()
    fast = BDerivative(Dh, model)
    assert fast.fast_path == ("own-rates" if with_pairs else "linear")
    assert BDerivative(Dh, F).fast_path == fast.fast_path
    general = BDerivative(Dh, model, fast_paths=False)
    V = rng.standard_normal((1500, d))  # large enough for the parallel kernels
    W = fast(V)
    assert_maps_close(Dh, F, V, W, general(V))
    assert_maps_close(Dh, F, V, W, BDerivative(Dh, F, fast_paths=False)(V))
    assert_maps_close(Dh, F, V[:10], W[:10], [ref_apply(Dh, F, u) for u in V[:10]])
    assert_maps_close(Dh, F, V, fast.inverse(W), V)
    assert_maps_close(Dh, F, V, fast.inverse(V), general.inverse(V))
    tf, of = fast.event_times(V)
    tg, og = general.event_times(V)
    np.testing.assert_allclose(tf, tg, rtol=1e-12, atol=1e-12)
    np.testing.assert_array_equal(of, og)
    np.testing.assert_allclose(fast.piece(of[0]), ref_piece(Dh, F, of[0]), atol=1e-12)


def test_fast_paths_serial_and_parallel_bitwise_equal():
    rng = np.random.default_rng(4)
    for additive in (False, True):
        Dh, F = own_rate_table(rng, 5, 6, additive)
        bd = BDerivative(Dh, F)
        V = rng.standard_normal((4096, 6))
        big = bd(V)
        np.testing.assert_array_equal(big, np.vstack([bd(V[i : i + 512])
                                                      for i in range(0, 4096, 512)]))


def test_sort_of_many_events_is_stable():
    """n > INSERTION_SORT_MAX uses argsort; ties keep the smaller event first."""
    n = 40
    Dh = np.eye(n)
    model = StructuredCorners(np.ones(n), 0.5 * np.eye(n))
    bd = BDerivative(Dh, model)
    assert bd.fast_path == "linear"
    u = -np.repeat(np.arange(n // 2, dtype=float), 2)  # every time twice
    times, order = bd.event_times(u)
    np.testing.assert_array_equal(order, np.argsort(-u, kind="stable"))
    np.testing.assert_array_equal(times, -u)


# ----------------------------------------------------------------------------------------
# chunked evaluation
# ----------------------------------------------------------------------------------------
@pytest.fixture
def system():
    rng = np.random.default_rng(5)
    Dh, F = random_system(rng, 4, 5)
    return BDerivative(Dh, F), rng


def test_chunked_memmap_to_memmap(system, tmp_path):
    bd, rng = system
    m = 5003
    V = np.lib.format.open_memmap(tmp_path / "V.npy", mode="w+", dtype=np.float64,
                                  shape=(m, 5))
    V[:] = rng.standard_normal((m, 5))
    V.flush()
    V = np.load(tmp_path / "V.npy", mmap_mode="r")
    out = np.lib.format.open_memmap(tmp_path / "W.npy", mode="w+", dtype=np.float64,
                                    shape=(m, 5))
    calls = []
    res = bd.apply(V, out=out, chunk_size=1000, progress=lambda done, total:
                   calls.append((done, total)))
    assert res is out
    assert calls == [(1000, m), (2000, m), (3000, m), (4000, m), (5000, m), (m, m)]
    out.flush()
    del out
    W = np.load(tmp_path / "W.npy")
    np.testing.assert_array_equal(W, bd(np.asarray(V)))  # bitwise: chunking changes nothing
    back = bd.inverse(np.load(tmp_path / "W.npy", mmap_mode="r"), chunk_size=777)
    np.testing.assert_allclose(back, V, atol=1e-12)


def test_chunked_float32_memmap_with_leading_shape(system, tmp_path):
    bd, rng = system
    path = tmp_path / "V32.dat"
    V = np.memmap(path, dtype=np.float32, mode="w+", shape=(3, 700, 5))
    V[:] = rng.standard_normal((3, 700, 5))
    V.flush()
    V = np.memmap(path, dtype=np.float32, mode="r", shape=(3, 700, 5))
    res = bd(V)  # a memmap input is chunked by default
    assert res.shape == (3, 700, 5)
    np.testing.assert_array_equal(res, bd(np.array(V, dtype=np.float64)))


def test_progress_default_chunk_and_validation(system):
    bd, rng = system
    V = rng.standard_normal((10, 5))
    calls = []
    bd.apply(V, progress=lambda d, t: calls.append((d, t)))
    assert calls == [(10, 10)]
    calls.clear()
    bd.inverse(np.empty((0, 5)), progress=lambda d, t: calls.append((d, t)))
    assert calls == [(0, 0)]
    with pytest.raises(ValueError, match="chunk_size must be an integer >= 1"):
        bd.apply(V, chunk_size=0)
    with pytest.raises(TypeError, match="chunk_size must be an integer"):
        bd.apply(V, chunk_size=2.5)
    with pytest.raises(ValueError, match=r"V must have shape \(\.\.\., 5\)"):
        bd.apply(np.ones((3, 4)), chunk_size=2)
    bad = V.copy()
    bad[7, 1] = np.nan
    with pytest.raises(ValueError, match=r"V must be finite, but vector V\[7\] = "):
        bd.apply(bad, chunk_size=3)
    with pytest.raises(ValueError, match=r"out must have shape \(10, 5\)"):
        bd.apply(V, out=np.empty((10, 4)), chunk_size=3)
