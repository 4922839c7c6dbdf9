"""Corner models (StructuredCorners, CornerFunction) against dense tables and the oracle."""

from __future__ import annotations

import pickle

import numba
import numpy as np
import pytest
from reference import (
    assert_maps_close,
    overtaking_system,
    random_system,
    ref_apply,
    ref_event_times,
    ref_inverse,
    ref_piece,
)

from bderiv import BDerivative
from bderiv.geometry.corners import CornerFunction, StructuredCorners


def structured_system(rng, n, d=None, n_pairs=0, coupling=0.4, proved=True):
    """A transversal structured model with mask-dependent rates (orders change).

    Dh = [I + small, noise]; F0 has unit rates; the jumps A and B change every rate by at
    most ``coupling`` in total, so all rates stay >= 1 - coupling - small > 0 (proved).
    With ``proved=False`` one jump is made so negative that the lower bound fails while
    every reachable region stays transversal (needs pairs to compensate).
    """
    d = n if d is None else d
    Dh = np.zeros((n, d))
    Dh[:, :n] = np.eye(n) + 0.1 / n * rng.uniform(-1, 1, (n, n))
    if d > n:
        Dh[:, n:] = rng.uniform(-0.5, 0.5, (n, d - n))
    F0 = np.zeros(d)
    F0[:n] = 1.0
    F0 = np.linalg.lstsq(Dh, np.ones(n), rcond=None)[0] + 0.0 * F0  # Dh F0 = 1
    A = coupling / n * rng.uniform(-1, 1, (n, d))
    A += rng.uniform(-1, 1, (n, d)) @ (np.eye(d) - np.linalg.pinv(Dh) @ Dh)  # kernel part
    if n_pairs:
        i = rng.integers(0, n, n_pairs)
        j = (i + rng.integers(1, n, n_pairs)) % n
        pairs = np.stack([i, j], axis=1)
        B = coupling / (2 * n_pairs) * rng.uniform(-1, 1, (n_pairs, d))
        return Dh, StructuredCorners(F0, A, pairs, B)
    return Dh, StructuredCorners(F0, A)


# a corner function over a fixed random table, compiled once for the module
_RNG = np.random.default_rng(1234)
DH4, F4 = random_system(_RNG, 4, 5)
_F4 = F4.copy()


@numba.njit
def table_corners(happened, out):
    mask = 0
    for k in range(happened.shape[0]):
        if happened[k]:
            mask |= 1 << k
    for i in range(out.shape[0]):
        out[i] = _F4[mask, i]


TABLE_FUNC = CornerFunction(table_corners)


# ----------------------------------------------------------------------------------------
# structured corners
# ----------------------------------------------------------------------------------------
@pytest.mark.parametrize("n", [1, 2, 3, 5, 7])
@pytest.mark.parametrize("extra", [0, 2])
@pytest.mark.parametrize("n_pairs", [0, 4])
def test_structured_matches_dense_and_oracle(n, extra, n_pairs):
    rng = np.random.default_rng(100 * n + 10 * extra + n_pairs)
    n_pairs = n_pairs if n > 1 else 0
    Dh, model = structured_system(rng, n, n + extra, n_pairs)
    F = model.table()
    bd = BDerivative(Dh, model)
    dense = BDerivative(Dh, F, fast_paths=False)
    assert bd.model is model and bd.F is None and bd.table_bytes == 0
    V = rng.standard_normal((40, n + extra)) * rng.uniform(0.1, 10, (40, 1))
    W = bd(V)
    assert_maps_close(Dh, F, V, W, dense(V))
    assert_maps_close(Dh, F, V[:15], W[:15], [ref_apply(Dh, F, u) for u in V[:15]])
    assert_maps_close(Dh, F, V[:15], bd.inverse(V[:15]), [ref_inverse(Dh, F, u) for u in V[:15]])
    assert_maps_close(Dh, F, V, bd.inverse(W), V)
    times, order = bd.event_times(V)
    t_ref, o_ref = dense.event_times(V)
    np.testing.assert_allclose(times, t_ref, rtol=1e-9, atol=1e-12)
    np.testing.assert_array_equal(order, o_ref)
    for u, o in zip(V[:5], order[:5], strict=True):
        np.testing.assert_allclose(bd.piece(o), ref_piece(Dh, F, o), atol=1e-10)
        assert_maps_close(Dh, F, u, bd.piece(o) @ u, ref_apply(Dh, F, u))


def test_structured_orders_really_change():
    """The test systems are not secretly first-order: some orders differ from the sort."""
    rng = np.random.default_rng(5)
    Dh, model = structured_system(rng, 6, 6, 6, coupling=0.9)
    F = model.table()
    V = rng.standard_normal((2000, 6))
    _, order = BDerivative(Dh, model).event_times(V)
    first = np.argsort(-(V @ Dh.T) / (Dh @ model.F0), axis=1, kind="stable")
    assert (order != first).any(axis=1).sum() > 10
    assert_maps_close(Dh, F, V[:20], BDerivative(Dh, model)(V[:20]),
                      [ref_apply(Dh, F, u) for u in V[:20]])


def test_structured_serial_and_parallel_bitwise_equal():
    rng = np.random.default_rng(7)
    Dh, model = structured_system(rng, 9, 11, 12)
    bd = BDerivative(Dh, model)
    V = rng.standard_normal((3000, 11))
    big = bd(V)
    small = np.vstack([bd(V[i : i + 500]) for i in range(0, 3000, 500)])
    np.testing.assert_array_equal(big, small)
    np.testing.assert_array_equal(bd.inverse(big), np.vstack(
        [bd.inverse(big[i : i + 100]) for i in range(0, 3000, 100)]))


@pytest.mark.parametrize("n_pairs", [0, 256])
def test_structured_n128(n_pairs):
    """n = d = 128 events: no 2**n anything; round trip, identities, times and pieces."""
    rng = np.random.default_rng(128)
    n = 128
    Dh, model = structured_system(rng, n, n, n_pairs)
    bd = BDerivative(Dh, model)
    assert bd.transversality == "proved" and bd.fast_path is None
    V = rng.standard_normal((2000, n))
    W = bd(V)
    np.testing.assert_allclose(bd.inverse(W), V, atol=1e-10)
    # the per-query oracle, on the model's own corners (masks as Python integers)
    for u, w in zip(V[:3], W[:3], strict=True):
        np.testing.assert_allclose(w, ref_apply(Dh, model.corners, u), rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(bd.inverse(w), ref_inverse(Dh, model.corners, w),
                                   rtol=1e-9, atol=1e-9)
        t, o = bd.event_times(u)
        t_ref, o_ref = ref_event_times(Dh, model.corners, u)
        np.testing.assert_array_equal(o, o_ref)
        np.testing.assert_allclose(t, t_ref, rtol=1e-9, atol=1e-12)
    # M(F[0]) = F[full]; homogeneity
    full = model.F0 + model.A.sum(0) + model.B.sum(0)
    np.testing.assert_allclose(bd(model.F0), full, atol=1e-12)
    np.testing.assert_allclose(bd(3.0 * V[:10]), 3.0 * W[:10], atol=1e-10)
    times, order = bd.event_times(V[:50])
    assert (np.sort(order, axis=1) == np.arange(n)).all()
    sorted_t = np.take_along_axis(times, order, axis=1)
    assert (np.diff(sorted_t, axis=1) >= 0).all()
    # the piece of the query's own order reproduces it
    np.testing.assert_allclose(bd.piece(order[0]) @ V[0], W[0], atol=1e-9)
    with pytest.raises(ValueError, match="2\\*\\*128 rows"):
        bd.corner_points()
    with pytest.raises(ValueError, match="refused for n > 20"):
        bd.triangulation()


def test_structured_n128_fast_matches_general():
    rng = np.random.default_rng(3)
    n = 128
    Dh = np.eye(n) + 0.2 / n * rng.uniform(-1, 1, (n, n))
    A = rng.uniform(-0.4, 2.0, n)[:, None] * np.linalg.inv(Dh).T  # Dh[j] . A[k] = 0, j != k
    model = StructuredCorners(Dh.T @ np.linalg.solve(Dh @ Dh.T, np.ones(n)), A)
    fast, general = BDerivative(Dh, model), BDerivative(Dh, model, fast_paths=False)
    assert fast.fast_path == "linear" and general.fast_path is None
    V = rng.standard_normal((1500, n))
    np.testing.assert_allclose(fast(V), general(V), atol=1e-10)
    np.testing.assert_allclose(fast.inverse(V), general.inverse(V), atol=1e-10)
    tf, of = fast.event_times(V)
    tg, og = general.event_times(V)
    np.testing.assert_allclose(tf, tg, atol=1e-10)
    np.testing.assert_array_equal(of, og)
    # and the oracle: the selection on the model's own corners, query by query
    for u in V[:3]:
        np.testing.assert_allclose(fast(u), ref_apply(Dh, model.corners, u), atol=1e-10)
        t_ref, o_ref = ref_event_times(Dh, model.corners, u)
        np.testing.assert_allclose(fast.event_times(u)[0], t_ref, atol=1e-10)


def test_structured_pickles():
    rng = np.random.default_rng(2)
    Dh, model = structured_system(rng, 5, 6, 3)
    bd = BDerivative(Dh, model)
    V = rng.standard_normal((10, 6))
    np.testing.assert_array_equal(pickle.loads(pickle.dumps(bd))(V), bd(V))


def test_structured_small_triangulation_and_corner_points_via_table():
    rng = np.random.default_rng(4)
    Dh, model = structured_system(rng, 3, 3, 2)
    bd = BDerivative(Dh, model)
    dense = BDerivative(Dh, model.table())
    for a, b in zip(bd.corner_points(), dense.corner_points(), strict=True):
        np.testing.assert_array_equal(a, b)
    V = rng.standard_normal((20, 3))
    np.testing.assert_allclose(bd.triangulation()(V), bd(V), atol=1e-9)
    assert bd.to_dense().model is None


# ----------------------------------------------------------------------------------------
# transversality of models
# ----------------------------------------------------------------------------------------
def test_structured_violation_refused_at_construction():
    Dh = np.eye(3)
    A = np.zeros((3, 3))
    A[0, 2] = -0.7
    A[1, 2] = -0.6  # rate of event 2 after events 0 and 1: 1 - 1.3 < 0
    with pytest.raises(ValueError, match=r"transversality violated at event 2 in region mask "
                                         r"0b011"):
        BDerivative(Dh, StructuredCorners(np.ones(3), A))


def test_structured_violation_found_by_the_query():
    """With pairs the bound is only sufficient: a bad region is reported by the query
    whose chain meets it, naming the query, the event and the region."""
    Dh = np.eye(3)
    A = np.zeros((3, 3))
    A[0, 2] = -0.7
    A[1, 2] = -0.6  # without the pair, event 2's rate in region 0b011 is 1 - 1.3 < 0
    A[2, 2] = 1.0  # ... and 0.8 or more once event 2 has happened
    # a strong pair repairs region 0b011 (rate 0.2): the bound fails, every region is fine
    fine = BDerivative(Dh, StructuredCorners(np.ones(3), A, [[0, 1]], [[0.0, 0.0, 0.5]]))
    assert fine.transversality == "per-query"
    V = np.random.default_rng(0).standard_normal((50, 3))
    np.testing.assert_allclose(fine.inverse(fine(V)), V, atol=1e-12)
    # a weak pair leaves region 0b011 with rate -0.2
    bd = BDerivative(Dh, StructuredCorners(np.ones(3), A, [[0, 1]], [[0.0, 0.0, 0.1]]))
    V = np.array([[-1.0, -2.0, -10.0], [-5.0, -1.0, -2.0]])  # V[0] visits 0b011
    with pytest.raises(ValueError, match=r"V\[0\]: event 2 has rate -0.2 <= 0 in region mask "
                                         r"0b011"):
        bd(V)
    with pytest.raises(ValueError, match=r"V\[0\]: event 2 has rate"):
        bd.event_times(V)
    with pytest.raises(ValueError, match=r"W\[0\] \(inverse map\): event 2 has rate -0.2"):
        bd.inverse(V)
    with pytest.raises(ValueError, match=r"transversality violated on the chain of V\[0\]"):
        bd.apply(V, chunk_size=1)
    # in a batch of several leading axes the vector is named by its full index
    batch = np.tile(V[1], (2, 3, 1))
    batch[1, 2] = V[0]
    for kwargs in ({}, {"chunk_size": 4}):
        with pytest.raises(ValueError, match=r"on the chain of V\[1, 2\]: event 2 has rate"):
            bd(batch, **kwargs)
    with pytest.raises(ValueError, match=r"event 2 has rate -0.2"):
        bd.piece([0, 1, 2])
    bd(V[1])  # V[1] never visits 0b011 (event 2 happens before event 0)


def test_structured_violation_in_region_0_or_full():
    Dh = np.eye(2)
    with pytest.raises(ValueError, match="event 1 in region full"):
        BDerivative(Dh, StructuredCorners([1.0, 1.0], [[0, 0], [0, -3.0]], [[0, 1]],
                                          [[0.0, 0.0]]))


# ----------------------------------------------------------------------------------------
# corner functions
# ----------------------------------------------------------------------------------------
def test_corner_function_matches_dense_and_oracle():
    bd = BDerivative(DH4, TABLE_FUNC)
    dense = BDerivative(DH4, F4, fast_paths=False)
    rng = np.random.default_rng(11)
    V = rng.standard_normal((300, 5))
    W = bd(V)
    assert_maps_close(DH4, F4, V, W, dense(V))
    assert_maps_close(DH4, F4, V[:20], W[:20], [ref_apply(DH4, F4, u) for u in V[:20]])
    assert_maps_close(DH4, F4, V, bd.inverse(W), V)
    times, order = bd.event_times(V)
    for u, t, o in zip(V[:20], times[:20], order[:20], strict=True):
        t_ref, o_ref = ref_event_times(DH4, F4, u)
        np.testing.assert_allclose(t, t_ref, rtol=1e-12, atol=1e-12)
        np.testing.assert_array_equal(o, o_ref)
    np.testing.assert_allclose(bd.piece(order[0]), dense.piece(order[0]), atol=1e-12)
    np.testing.assert_array_equal(CornerFunction(table_corners, n_events=4, dim=5).table(), F4)
    np.testing.assert_allclose(bd.corner_points()[0], dense.corner_points()[0])


def test_corner_function_parallel_path():
    bd = BDerivative(DH4, TABLE_FUNC)
    V = np.random.default_rng(12).standard_normal((2500, 5))
    W = bd(V)
    np.testing.assert_array_equal(W[:100], bd(V[:100]))
    np.testing.assert_allclose(W, BDerivative(DH4, F4)(V), atol=1e-12)


def test_corner_function_overtaking():
    """The mathematics.md section 3 pitfall: the order is not the first-order sort."""
    Dh, F, u, order, w, times = overtaking_system(4)
    G = F.copy()

    @numba.njit
    def overtaking(happened, out):
        mask = 0
        for k in range(happened.shape[0]):
            if happened[k]:
                mask |= 1 << k
        for i in range(out.shape[0]):
            out[i] = G[mask, i]

    bd = BDerivative(Dh, CornerFunction(overtaking))
    np.testing.assert_allclose(bd(u), w, atol=1e-12)
    t, o = bd.event_times(u)
    np.testing.assert_array_equal(o, order)
    np.testing.assert_allclose(t, times, atol=1e-12)


def _additive(rng, n):
    """``(Dh, model, function)``: a structured model of n events in R^n without pairs and
    the corner function that adds its jumps, written out."""
    Dh, model = structured_system(rng, n, n, 0)
    F0, A = model.F0.copy(), model.A.copy()

    @numba.njit
    def additive(happened, out):
        out[:] = F0
        for k in range(happened.shape[0]):
            if happened[k]:
                out += A[k]

    return Dh, model, CornerFunction(additive)


def test_corner_function_beyond_62_events_matches_structured():
    """happened is an array: n = 70 > 62 works; same map as the structured model."""
    rng = np.random.default_rng(70)
    n = 70
    Dh, model, function = _additive(rng, n)
    bd = BDerivative(Dh, function)
    ref = BDerivative(Dh, model)
    V = rng.standard_normal((50, n))
    np.testing.assert_allclose(bd(V), ref(V), atol=1e-10)
    np.testing.assert_allclose(bd.inverse(V), ref.inverse(V), atol=1e-10)
    for u in V[:3]:  # and the per-query oracle on the model's corners
        np.testing.assert_allclose(bd(u), ref_apply(Dh, model.corners, u), atol=1e-10)
        np.testing.assert_allclose(bd.inverse(u), ref_inverse(Dh, model.corners, u),
                                   atol=1e-10)


def test_a_corner_function_that_raises_raises_the_same_in_a_large_batch():
    """An exception of the user's function inside the parallel driver, on whichever
    thread its task runs (numba loses one raised on a worker thread: the batch returned
    with the task's rows unwritten, and no error), makes the batch raise the function's
    own exception, as a small batch (the serial driver) does: one raising row among 3000,
    at the start, the middle and the end (the tasks of both threads)."""
    @numba.njit
    def undefined_after_1(happened, out):
        if happened[1] and not happened[0]:
            raise ValueError("region 0b10 is not modelled")
        out[0] = 1.0 + happened[0]
        out[1] = 1.0 + 0.5 * happened[1]

    bd = BDerivative(np.eye(2), CornerFunction(undefined_after_1))
    V = np.random.default_rng(3).standard_normal((6000, 2))
    raises = np.array([_raises(bd, v[None]) for v in V[:200]])
    assert raises.any() and not raises.all()
    bad, good = V[:200][raises][0], V[~np.concatenate((raises, np.ones(5800, bool)))]
    good = np.concatenate([good] * (3000 // len(good) + 1))[:3000]
    for at in (0, 1, 700, 1499, 1500, 2200, 2999):
        rows = good.copy()
        rows[at] = bad
        bd(good)  # no row raises; its buffers, freed, are what the next call's get
        with pytest.raises(ValueError, match="region 0b10 is not modelled") as info:
            bd(rows)
        assert info.value.__context__ is None  # no other error on the way


def _raises(bd, rows) -> bool:
    try:
        bd(rows)
    except ValueError:
        return True
    return False


def test_a_new_corner_function_compiles_only_itself():
    """The blocks call the function through an address (``_kernels/function.entry``):
    a second function adds no signature to the blocks' serial or parallel drivers or to
    ``corners``, only its own wrapper (one more ``entry``); both give their own corners."""
    from bderiv._kernels import _drivers
    from bderiv._kernels import function as kernels

    V = np.random.default_rng(5).standard_normal((2000, 5))  # the parallel driver too
    before = BDerivative(DH4, TABLE_FUNC)
    before(V), before.inverse(V), before.event_times(V), before.corner_points()
    drivers = (kernels.apply.serial, kernels.event_times.serial, _drivers._TASKS,
               _drivers._LAUNCH, kernels._corners)
    counts = [len(k.signatures) for k in drivers]
    assert min(counts) >= 1
    misses = kernels.entry.cache_info().misses

    @numba.njit
    def doubled(happened, out):
        table_corners(happened, out)
        for i in range(out.shape[0]):
            out[i] *= 2.0

    bd = BDerivative(DH4, CornerFunction(doubled))
    W = bd(V)
    back, (times, orders) = bd.inverse(W), bd.event_times(V)
    assert [len(k.signatures) for k in drivers] == counts
    assert kernels.entry.cache_info().misses == misses + 1
    # doubling every corner keeps the orders and halves the event times (M is unchanged)
    np.testing.assert_allclose(W, before(V), rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(back, V, rtol=1e-12, atol=1e-12)
    np.testing.assert_array_equal(orders, before.event_times(V)[1])
    np.testing.assert_allclose(times, before.event_times(V)[0] / 2, rtol=1e-12)
    np.testing.assert_array_equal(bd.corner_points()[1], 2 * before.corner_points()[1])


def test_a_corner_function_engine_pickles_and_links_its_function_again(monkeypatch):
    """The tables hold an address of this process: the engine drops it when pickled and
    links the function again when unpickled, and holds the wrapper behind the address as
    long as it lives (not the cache of ``entry``)."""
    import gc
    import weakref

    from bderiv._kernels import function as kernels

    bd = BDerivative(DH4, TABLE_FUNC)
    V = np.random.default_rng(6).standard_normal((30, 5))
    state = bd._engine.__getstate__()
    assert "_tables" not in state and "_entry" not in state
    linked, real = [], kernels.entry
    with monkeypatch.context() as m:
        m.setattr(kernels, "entry", lambda func: linked.append(func) or real(func))
        copy = pickle.loads(pickle.dumps(bd))
    assert len(linked) == 1  # linked again on unpickling
    wrapper, at = kernels.entry(copy._engine.func)
    assert copy._engine._entry is wrapper and copy._engine._tables.at[0] == at
    np.testing.assert_array_equal(copy(V), bd(V))
    held = weakref.ref(copy._engine._entry)
    del wrapper
    kernels.entry.cache_clear()
    gc.collect()
    assert held() is not None  # the engine holds it
    np.testing.assert_array_equal(copy(V), bd(V))
    np.testing.assert_array_equal(copy.event_times(V)[1], bd.event_times(V)[1])


def test_a_corner_function_gets_a_copy_of_the_regions_it_is_asked_for():
    """``func`` may write into ``happened``: the caller's array (read-only here) is not
    touched, and a read-only ``out`` is refused."""
    from bderiv._kernels import function as kernels

    @numba.njit
    def scribbles(happened, out):
        out[0] = 1.0 + happened[0]
        out[1] = 1.0
        happened[0] = 7

    h = np.array([[0, 1], [1, 0]], dtype=np.uint8)
    h.flags.writeable = False
    np.testing.assert_array_equal(CornerFunction(scribbles, n_events=2, dim=2).corners(h),
                                  [[1.0, 1.0], [2.0, 1.0]])
    np.testing.assert_array_equal(h, [[0, 1], [1, 0]])
    out = np.zeros((2, 2))
    out.flags.writeable = False
    with pytest.raises(TypeError, match="out must be a writeable C-contiguous float64"):
        kernels.corners(scribbles, h, out)


def test_corner_function_violation_and_errors():
    @numba.njit
    def bad(happened, out):
        out[0] = 1.0
        out[1] = 1.0 - 2.0 * happened[0] * (1 - happened[1])  # region 0b01: rate of 1 < 0

    bd = BDerivative(np.eye(2), CornerFunction(bad))
    bd([-2.0, -1.0])  # event 1 first: never visits 0b01
    with pytest.raises(ValueError, match=r"V\[1\]: event 1 has rate -1 <= 0 in region mask "
                                         r"0b01"):
        bd([[-2.0, -1.0], [-1.0, -2.0]])
    with pytest.raises(TypeError, match="must be a function"):
        CornerFunction(3)
    with pytest.raises(ValueError, match="finite values"):

        @numba.njit
        def nan(happened, out):
            out[:] = np.nan

        BDerivative(np.eye(2), CornerFunction(nan))
    with pytest.raises(TypeError, match="could not be called"):

        def wrong(happened):
            return happened

        BDerivative(np.eye(2), CornerFunction(wrong))
    assert "CornerFunction(bad)" in repr(CornerFunction(bad))


def test_python_function_is_compiled():
    def plain(happened, out):
        out[0] = 1.0 + happened[0]
        out[1] = 1.0

    bd = BDerivative(np.eye(2), CornerFunction(plain))
    np.testing.assert_allclose(bd([-1.0, -2.0]), [-2.0, -2.0])


# ----------------------------------------------------------------------------------------
# validation
# ----------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    "kwargs, exc, match",
    [
        (dict(F0=np.ones((2, 2)), A=np.ones((2, 2))), ValueError, r"F0 must have shape \(d,\)"),
        (dict(F0=[1j, 1], A=np.ones((2, 2))), TypeError, "F0 must hold real numbers"),
        (dict(F0=[np.nan, 1], A=np.ones((2, 2))), ValueError, "F0 must be finite"),
        (dict(F0=[1, 1], A=np.ones((2, 3))), ValueError, r"A must have shape \(any, 2\)"),
        (dict(F0=[1, 1], A=np.ones((0, 2))), ValueError, "at least one row"),
        (dict(F0=[1, 1], A=np.ones((2, 2)), pairs=[[0, 1]]), ValueError, "pass both or neither"),
        (dict(F0=[1, 1], A=np.ones((2, 2)), pairs=[[0, 2]], B=np.ones((1, 2))), ValueError,
         r"pairs must name events 0..1"),
        (dict(F0=[1, 1], A=np.ones((2, 2)), pairs=[[1, 1]], B=np.ones((1, 2))), ValueError,
         r"pairs\[0\] = \[1, 1\] joins an event with itself"),
        (dict(F0=[1, 1], A=np.ones((2, 2)), pairs=[[0.5, 1]], B=np.ones((1, 2))), TypeError,
         "pairs must hold integers"),
        (dict(F0=[1, 1], A=np.ones((2, 2)), pairs=[0, 1], B=np.ones((1, 2))), ValueError,
         r"pairs must have shape \(p, 2\)"),
        (dict(F0=[1, 1], A=np.ones((2, 2)), pairs=[[0, 1]], B=np.ones((2, 2))), ValueError,
         r"B must have shape \(1, 2\)"),
    ],
)
def test_structured_validation(kwargs, exc, match):
    with pytest.raises(exc, match=match):
        StructuredCorners(**kwargs)


def test_model_shape_mismatch():
    model = StructuredCorners(np.ones(3), np.zeros((2, 3)))
    with pytest.raises(ValueError, match=r"Dh has shape \(2, 4\).*n=2 events in dimension d=3"):
        BDerivative(np.ones((2, 4)), model)
    with pytest.raises(ValueError, match=r"shape \(3, 3\) \(n=3 events"):
        BDerivative(np.eye(3), model)
    assert repr(model) == "StructuredCorners(n_events=2, dim=3, pairs=0)"


def test_table_refused_for_large_n():
    model = StructuredCorners(np.ones(30), 0.01 * np.eye(30))
    with pytest.raises(ValueError, match=r"2\*\*30 rows"):
        model.table()
    bd = BDerivative(np.eye(30), model)
    with pytest.raises(ValueError, match="corner points of a corner model with n=30"):
        bd.corner_points()


# ----------------------------------------------------------------------------------------
# the corner-model protocol: a representation written by a user
# ----------------------------------------------------------------------------------------
class CountCorners:
    """Identical contacts: the field depends only on how many events have happened,
    ``F[mask] = F0 + C[popcount(mask)]`` (C[0] = 0). Implements the protocol only."""

    def __init__(self, F0, C):
        self.F0, self.C = np.asarray(F0, float), np.asarray(C, float)
        self.n_events, self.dim = self.C.shape[0] - 1, self.F0.shape[0]

    def corners(self, happened):
        count = np.asarray(happened).astype(np.int64).sum(axis=-1)
        return self.F0 + self.C[count]

    def corner_function(self):
        F0, C = self.F0, self.C

        @numba.njit
        def func(happened, out):
            count = 0
            for k in range(happened.shape[0]):
                count += happened[k]
            for i in range(out.shape[0]):
                out[i] = F0[i] + C[count, i]

        return func


def test_user_corner_model_follows_the_protocol():
    from bderiv.geometry.corners import CornerModel

    rng = np.random.default_rng(21)
    n, d = 5, 6
    Dh = np.hstack([np.eye(n), 0.1 * rng.standard_normal((n, d - n))])
    C = np.vstack([np.zeros(d), 0.3 * rng.uniform(-1, 1, (n, d))])
    model = CountCorners(np.ones(d), C)
    assert isinstance(model, CornerModel)
    bd = BDerivative(Dh, model)
    assert bd.model is model and bd.transversality == "per-query"
    V = rng.standard_normal((400, d))
    W = bd(V)
    for u, w in zip(V[:30], W[:30], strict=True):
        np.testing.assert_allclose(w, ref_apply(Dh, model.corners, u), rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(bd.inverse(W), V, atol=1e-10)
    # the same map as the dense table the protocol's corners() spells out
    F = model.corners((np.arange(1 << n)[:, None] >> np.arange(n)) & 1)
    np.testing.assert_allclose(W, BDerivative(Dh, F)(V), atol=1e-12)
    _, order = bd.event_times(V[:1])
    np.testing.assert_allclose(bd.piece(order[0]), ref_piece(Dh, F, order[0]), atol=1e-12)
    np.testing.assert_allclose(bd.to_dense().F, F)


def test_a_protocol_models_plain_python_function_is_compiled_as_corner_functions_are():
    """CornerFunction(plain function) compiled it; a protocol model's corner_function()
    returning one failed with "'function' object has no attribute 'compile'" (a
    review). Oracle: the dense table its corners() spell out."""

    def func(happened, out):
        out[0] = 1.0 + happened[0]
        out[1] = 1.0 + 0.5 * happened[1]

    class Plain:
        n_events, dim = 2, 2

        def corners(self, happened):
            h = np.asarray(happened, dtype=np.float64)
            return np.stack([1.0 + h[..., 0], 1.0 + 0.5 * h[..., 1]], axis=-1)

        def corner_function(self):
            return func

    Dh = np.array([[1.0, 0.2], [0.1, 1.0]])
    V = np.random.default_rng(3).standard_normal((50, 2))
    F = Plain().corners((np.arange(4)[:, None] >> np.arange(2)) & 1)
    np.testing.assert_allclose(BDerivative(Dh, Plain())(V), BDerivative(Dh, F)(V),
                               rtol=1e-13, atol=1e-13)


def test_incomplete_corner_model_is_refused():
    class OnlyCorners:
        n_events, dim = 2, 2

        def corners(self, happened):
            return np.ones(np.shape(happened)[:-1] + (2,))

    with pytest.raises(TypeError, match=r"lacks part of the protocol.*corner_function\(\)"):
        BDerivative(np.eye(2), OnlyCorners())


def test_a_corner_functions_launches_are_sized_by_their_time(monkeypatch):
    """A user's corner function runs n + 1 times per query at a cost no one knows before:
    the batch's first launch is PARALLEL_MIN_QUERIES queries and each next one is sized to
    LAUNCH_SECONDS from the last one's time (Ctrl-C is seen between launches; at n = 128 a
    launch of 2**14 queries held it for up to 20 s). The launches never change the bits."""
    from bderiv._kernels import _drivers
    from bderiv._limits import PARALLEL_MIN_QUERIES

    rng = np.random.default_rng(16)
    n = 16
    Dh, model, function = _additive(rng, n)
    bd = BDerivative(Dh, function)
    V = rng.standard_normal((20000, n))
    sizes, launch = [], _drivers.Batch._launch

    def counted(self, tables, V, outs, inverse):
        sizes.append(V.shape[0])
        return launch(self, tables, V, outs, inverse)

    monkeypatch.setattr(_drivers.Batch, "_launch", counted)
    whole = bd(V)  # launches as LAUNCH_SECONDS sizes them
    assert sizes[0] == PARALLEL_MIN_QUERIES and sum(sizes) == V.shape[0]
    sizes.clear()
    monkeypatch.setattr(_drivers, "LAUNCH_SECONDS", 1e-9)  # each at its smallest
    np.testing.assert_array_equal(bd(V), whole)
    assert sizes == [PARALLEL_MIN_QUERIES] * 19 + [V.shape[0] - 19 * PARALLEL_MIN_QUERIES]
    np.testing.assert_allclose(whole, BDerivative(Dh, model.table())(V), atol=1e-12)


@pytest.mark.parametrize("s_dh, s_f", [(1e200, 1e200), (1e-200, 1e-200), (1e-310, 1.0),
                                       (1.0, 1e-310)])
def test_structured_corners_at_the_ends_of_float64(s_dh, s_f):
    """The map does not change when Dh's rows or F are scaled (mathematics.md, "Scale").
    Structured corners with Dh and F of 1e200 each (rates 1e400) or 1e-200 each were
    refused as "transversality violated" (rate nan, rate 0), and subnormal corners gave a
    query "overflowed" (a review); the dense table of the same model was right. Their
    kernels' tables are now scaled by powers of two as a dense table's. Oracle:
    tests/reference.py's map at unit scale."""
    rng = np.random.default_rng(8)
    n, d = 4, 5
    Dh = np.hstack([np.eye(n), 0.1 * rng.standard_normal((n, d - n))])
    F0, A = np.ones(d), 0.3 * rng.uniform(-1, 1, (n, d))
    unit = StructuredCorners(F0, A)
    V, T = rng.standard_normal((12, d)), rng.standard_normal((12, d))
    scaled = StructuredCorners(F0 * s_f, A * s_f)
    bd = BDerivative(Dh * s_dh, scaled)
    W = np.array([ref_apply(Dh, unit.corners, v) for v in V])
    np.testing.assert_allclose(bd(V), W, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(bd.inverse(W), V, rtol=1e-12, atol=1e-12)
    ones = BDerivative(Dh, unit)
    np.testing.assert_allclose(bd.jvp(V, T), ones.jvp(V, T), rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(bd.vjp(V, T), ones.vjp(V, T), rtol=1e-12, atol=1e-12)
    if s_f >= 1e-300:  # times are 1 / s_f those at unit scale: within float64 here
        times, orders = bd.event_times(V)
        unit_times, unit_orders = ones.event_times(V)
        np.testing.assert_array_equal(orders, unit_orders)
        # (subnormal rows of Dh keep fewer digits: the times' small entries lose a few)
        np.testing.assert_allclose(times * s_f, unit_times, rtol=1e-10,
                                   atol=1e-12 * np.abs(unit_times).max())
    np.testing.assert_array_equal(bd.to_dense().F, scaled.table())  # the caller's units
