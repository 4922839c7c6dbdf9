"""The structured kernel's lockstep groups: each query's result depends on nothing but the
query (not its neighbours in a group, a short tail group, the split of the batch or the
thread count), agrees with the oracle, and resolves ties as documented."""

from __future__ import annotations

import numpy as np
import pytest
from reference import assert_maps_close, ref_apply, ref_event_times, ref_inverse
from test_corners import structured_system

from bderiv import BDerivative
from bderiv._kernels.structured_chains import GROUP, LOCK
from bderiv.geometry.corners import StructuredCorners

#: 11 events and 13 coordinates: both axes padded inside the kernel
N, D = 11, 13


def _system(seed, coupling=0.9):
    """A structured model whose orders change with the query (strong coupling, pairs)."""
    return structured_system(np.random.default_rng(seed), N, D, 9, coupling=coupling)


def _rows_alone(fn, V):
    """fn on each row of V by itself (a group of one query)."""
    return np.array([fn(v) for v in V])


def test_groups_mix_orders_and_each_row_is_computed_alone():
    """A batch of one full group, one full lockstep and a short tail (3 queries), whose
    lockstep groups hold different orders: every row equals the row computed alone and
    in reversed position, bit for bit, and the oracle."""
    Dh, model = _system(1)
    bd = BDerivative(Dh, model)
    assert bd.fast_path is None
    m = GROUP + LOCK + 3
    rng = np.random.default_rng(2)
    V = rng.standard_normal((m, D)) * rng.uniform(0.1, 10, (m, 1))
    times, order = bd.event_times(V)
    for q0 in range(0, m, LOCK):  # the groups really mix orders
        assert len({tuple(o) for o in order[q0:q0 + LOCK]}) > 1
    F = model.table()
    for fn in (bd.apply, bd.inverse):
        W = fn(V)
        np.testing.assert_array_equal(W, _rows_alone(fn, V))
        np.testing.assert_array_equal(W[::-1], fn(V[::-1].copy()))
    np.testing.assert_array_equal(order, _rows_alone(lambda v: bd.event_times(v)[1], V))
    np.testing.assert_array_equal(times, _rows_alone(lambda v: bd.event_times(v)[0], V))
    assert_maps_close(Dh, F, V, bd(V), [ref_apply(Dh, F, u) for u in V])
    assert_maps_close(Dh, F, V, bd.inverse(V), [ref_inverse(Dh, F, u) for u in V])
    for u, t, o in zip(V, times, order, strict=True):
        t_ref, o_ref = ref_event_times(Dh, F, u)
        np.testing.assert_array_equal(o, o_ref)
        np.testing.assert_allclose(t, t_ref, rtol=1e-9, atol=1e-12)


def test_any_split_of_a_parallel_batch_gives_the_same_bits():
    """Chunks of odd sizes shift every query to another lane, group and task."""
    Dh, model = _system(3)
    bd = BDerivative(Dh, model)
    V = np.random.default_rng(4).standard_normal((3000, D))
    whole = bd(V)
    cuts = np.cumsum([1, 3, 5, 37, 2, 611, 1200])
    parts = np.split(V, cuts)
    np.testing.assert_array_equal(whole, np.vstack([bd(P) for P in parts]))
    np.testing.assert_array_equal(bd.inverse(whole),
                                  np.vstack([bd.inverse(P) for P in np.split(whole, cuts)]))


def _twins(seed):
    """The model of ``_system`` with events 7 and 10 copies of events 2 and 3 (same row of
    Dh, hence the same value and rate in every region): every query ties them."""
    Dh, model = _system(seed, coupling=0.4)
    Dh = Dh.copy()
    Dh[7], Dh[10] = Dh[2], Dh[3]
    return Dh, model


def test_exact_ties_go_to_the_smaller_event_both_ways():
    Dh, model = _twins(5)
    bd = BDerivative(Dh, model)
    F = model.table()
    V = np.random.default_rng(6).standard_normal((GROUP + 5, D))
    times, order = bd.event_times(V)
    pos = np.argsort(order, axis=1)
    assert (pos[:, 2] < pos[:, 7]).all() and (pos[:, 3] < pos[:, 10]).all()
    np.testing.assert_allclose(times[:, 7], times[:, 2], rtol=1e-12)
    # the oracle's products (BLAS) may round the twins apart: compare up to twins
    twin = np.array([0, 1, 2, 3, 4, 5, 6, 2, 8, 9, 3])
    for u, o in zip(V, order, strict=True):
        np.testing.assert_array_equal(twin[o], twin[ref_event_times(Dh, F, u)[1]])
    assert_maps_close(Dh, F, V, bd(V), [ref_apply(Dh, F, u) for u in V])
    assert_maps_close(Dh, F, V, bd.inverse(V), [ref_inverse(Dh, F, u) for u in V])
    # the origin ties every event at t = 0: the order is 0, 1, ..., n - 1
    times, order = bd.event_times(np.zeros((3, D)))
    np.testing.assert_array_equal(order, np.tile(np.arange(N), (3, 1)))
    assert not times.any()
    np.testing.assert_array_equal(bd(np.zeros(D)), np.zeros(D))


def test_near_ties_give_the_oracle_map():
    """Twins one ulp apart: which one the kernel selects first is decided by rounding,
    but M is continuous across the tie, so the map is the oracle's either way."""
    Dh, model = _twins(7)
    Dh[7] = np.nextafter(Dh[7], np.inf)
    bd = BDerivative(Dh, model)
    F = model.table()
    V = np.random.default_rng(8).standard_normal((2 * LOCK + 1, D))
    assert_maps_close(Dh, F, V, bd(V), [ref_apply(Dh, F, u) for u in V])
    assert_maps_close(Dh, F, V, bd.inverse(V), [ref_inverse(Dh, F, u) for u in V])


def _weak_pair():
    """Three events; region 0b011 has rate -0.2 for event 2 (the kernel checks rates)."""
    A = np.zeros((3, 3))
    A[0, 2], A[1, 2], A[2, 2] = -0.7, -0.6, 1.0
    return np.eye(3), StructuredCorners(np.ones(3), A, [[0, 1]], [[0.0, 0.0, 0.1]])


def test_a_stopped_lane_is_named_and_leaves_its_neighbours_alone():
    """Query 5 of 7 (lane 1 of the second lockstep group) meets the bad region; the
    others do not. The error names it with the rate at the point where it stopped."""
    Dh, model = _weak_pair()
    bd = BDerivative(Dh, model)
    assert bd.transversality == "per-query"
    good = np.array([-5.0, -1.0, -2.0])  # event 2 happens before event 0: never 0b011
    V = np.tile(good, (7, 1)) * np.arange(1, 8)[:, None]
    V[5] = [-1.0, -2.0, -10.0]  # visits 0b011
    for call, name in ((bd, "V"), (lambda X: bd.event_times(X), "V"), (bd.inverse, "W")):
        with pytest.raises(ValueError, match=rf"{name}\[5\].*event 2 has rate -0.2 <= 0 in "
                                             rf"region mask 0b011"):
            call(V)
    rest = np.delete(V, 5, axis=0)
    W = bd(rest)
    np.testing.assert_array_equal(W, _rows_alone(bd, rest))
    F = model.table()
    assert_maps_close(Dh, F, rest, W, [ref_apply(Dh, F, u) for u in rest])
