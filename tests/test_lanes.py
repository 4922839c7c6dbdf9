"""The lane kernels of dense tables (``_kernels/lanes.py``): every vector width they are
compiled for against the oracle, the prefetching variant bitwise equal to the other, a
query's answer independent of the lockstep group it shares, and tables wider than the
lanes (d > ``lanes.MAX_D``) on the plain blocks."""

from __future__ import annotations

import numpy as np
import pytest
from chain_tolerance import assert_matches_oracle, chain_scale, excess, oracle, table_corners
from reference import RTOL, random_system

from bderiv import BDerivative
from bderiv._kernels import _core, _simd, dense, lanes

pytestmark = pytest.mark.skipif(_core.PLAIN, reason="BDERIV_KERNELS=plain: no lane kernels")


@pytest.mark.parametrize("n, d", [(1, 1), (3, 9), (8, 8), (8, 1),
                                  pytest.param(9, 16, marks=pytest.mark.slow), (12, 7),
                                  (17, 3), (5, 37), (5, 64)])  # (9, 16): in the slow set
def test_every_width_matches_the_oracle(n, d):
    """h in 8, 16 and 24 lanes, x in 8 to 64 lanes, d below, at and above a multiple of 8
    (the masked loads and stores of a row; (5, 37): those of the sums after a chain that
    records its steps, d > 32)."""
    rng = np.random.default_rng(100 * n + d)
    Dh, F = random_system(rng, n, d)
    bd = BDerivative(Dh, F, fast_paths=False)
    wh, wx = 8 * (-(-n // 8)), 8 * (-(-d // 8))
    assert bd._engine._lane_kernels in (lanes.kernels(wh, wx, 0), lanes.kernels(wh, wx, 1))
    V = rng.standard_normal((37 if n < 12 else 11, d))  # a tail group of 5 (or 3)
    assert_matches_oracle(bd, Dh, F, V)


@pytest.mark.parametrize("n, d", [(2, 2), (5, 7), (8, 8), (11, 13)])
def test_rounding_stays_within_n_eps_of_the_chain(n, d):
    """The bound of docs/mathematics.md ("How the kernels round"): against the oracle (the
    virtual-position loop in NumPy), apply, inverse and the event times agree within
    n eps of the size of what their chains sum (``chain_tolerance.chain_scale``); the
    tolerance of the other tests is RTOL = 1e-9 of it, this one is 4 n eps."""
    rng = np.random.default_rng(n * d)
    Dh, F = random_system(rng, n, d)
    bd = BDerivative(Dh, F, fast_paths=False)
    V = rng.standard_normal((400, d))
    x, t, o = oracle(Dh, F, V)
    S, S_back, dt, _ = chain_scale(Dh, table_corners(F), V, t, o)
    bound = 4 * n * np.finfo(float).eps / RTOL  # in units of RTOL * scale
    assert excess(bd(V), x, S).max() <= bound
    assert excess(bd.inverse(x), V, S_back).max() <= bound
    assert excess(bd.event_times(V)[0], t, np.abs(t) + dt).max() <= bound


def test_the_prefetching_variant_gives_the_same_bits(monkeypatch):
    """``far`` (records beyond the caches) only adds prefetches: forced on a small table
    it must not change a bit of any answer."""
    rng = np.random.default_rng(7)
    Dh, F = random_system(rng, 6, 10)
    near = BDerivative(Dh, F, fast_paths=False)
    monkeypatch.setattr("bderiv.engine._engines.dense.FAR_BYTES", 0)
    far = BDerivative(Dh, F, fast_paths=False)
    assert near._engine._lane_kernels == lanes.kernels(8, 16, 0)
    assert far._engine._lane_kernels == lanes.kernels(8, 16, 1)
    V = rng.standard_normal((3001, 10))
    np.testing.assert_array_equal(far(V), near(V))
    np.testing.assert_array_equal(far.inverse(V), near.inverse(V))
    for a, b in zip(far.event_times(V), near.event_times(V), strict=True):
        np.testing.assert_array_equal(a, b)
    T = rng.standard_normal((3001, 10))
    np.testing.assert_array_equal(far.jvp(V, T), near.jvp(V, T))
    np.testing.assert_array_equal(far.vjp(V, T), near.vjp(V, T))


def test_chains_that_record_their_steps_share_drivers_across_position_widths():
    """Event times, and apply when the position is too wide to carry (d > 32), record
    the steps and never read the position's width: one driver per ``wh`` and ``far``
    serves every ``wx``; the tangents, which carry a vector of d, do not share."""
    a8, t8, g8 = lanes.kernels(8, 8, 0)
    a16, t16, g16 = lanes.kernels(8, 16, 0)
    a40, t40, g40 = lanes.kernels(8, 40, 0)
    a64, t64, g64 = lanes.kernels(8, 64, 0)
    assert t8 is t16 is t40 is t64
    assert a40 is a64 and a8 is not a16 and a16 is not a40
    assert len({g8, g16, g40, g64}) == 4
    assert lanes.kernels(16, 8, 0)[1] is not t8 and lanes.kernels(8, 8, 1)[1] is not t8


def test_a_query_does_not_depend_on_its_lockstep_group():
    """Eight queries run in lockstep (and a short group repeats its last query): each row
    alone gives the bits it gets in any group, whatever its neighbours' orders."""
    rng = np.random.default_rng(3)
    Dh, F = random_system(rng, 7, 7)
    bd = BDerivative(Dh, F, fast_paths=False)
    V = rng.standard_normal((29, 7))
    orders = bd.event_times(V)[1]
    assert len({tuple(o) for o in orders}) > 20  # neighbours really differ
    together, back = bd(V), bd.inverse(V)
    for q in range(len(V)):
        np.testing.assert_array_equal(bd(V[q:q + 1])[0], together[q])
        np.testing.assert_array_equal(bd(V[q:q + 3])[0], together[q])
        np.testing.assert_array_equal(bd.inverse(V[q:q + 1])[0], back[q])


def test_tables_wider_than_the_lanes_run_the_plain_blocks():
    rng = np.random.default_rng(11)
    Dh, F = random_system(rng, 3, lanes.MAX_D + 1)
    bd = BDerivative(Dh, F, fast_paths=False)
    assert bd._engine._lanes is None
    assert_matches_oracle(bd, Dh, F, rng.standard_normal((20, lanes.MAX_D + 1)))


def test_static_values_are_checked():
    with pytest.raises(ValueError, match="non-negative int, got -1"):
        _simd.static(-1)
    with pytest.raises(ValueError, match="non-negative int, got 2.5"):
        _simd.static(2.5)


def test_the_tables_stay_on_numbas_fast_dispatch():
    """Every argument tuple numba's dispatcher receives must have a type fingerprint, else
    each call goes through Python's typeof (one query took 38 us instead of 5 us); the
    static values are compiled into the drivers instead."""
    from numba._dispatcher import compute_fingerprint

    rng = np.random.default_rng(1)
    for n, d in [(3, 4), (9, 70)]:
        eng = BDerivative(*random_system(rng, n, d), fast_paths=False)._engine
        for tables in (eng._lanes, eng._plain):
            if tables is not None:
                assert compute_fingerprint(tables)


def test_wide_positions_are_summed_after_the_chain():
    """d > 32 (``lanes.WIDE_X``): apply sums the jumps after the chain instead of carrying
    the position in registers; it meets the same rounding bound as the register path."""
    rng = np.random.default_rng(40)
    Dh, F = random_system(rng, 6, 40)
    bd = BDerivative(Dh, F, fast_paths=False)
    assert bd._engine._lanes is not None and lanes.WIDE_X < 40  # the lane blocks run
    V = rng.standard_normal((203, 40))
    x, t, o = oracle(Dh, F, V)
    S, S_back, _, _ = chain_scale(Dh, table_corners(F), V, t, o)
    bound = 4 * 6 * np.finfo(float).eps / RTOL
    assert excess(bd(V), x, S).max() <= bound
    assert excess(bd.inverse(x), V, S_back).max() <= bound


def _plain(e, V, T):
    """apply, inverse, (times, orders), jvp, vjp of the scalar chain (``dense.py``: the
    steps of ``selection.py``, what ``BDERIV_KERNELS=plain`` runs) on an engine's tables."""
    m, n = V.shape[0], e.n
    res = [np.empty_like(V), np.empty_like(V), np.empty((m, n)), np.empty((m, n), np.int64),
           np.empty_like(V), np.empty_like(V)]
    dense.apply(e._plain, V, (res[0],), False)
    dense.apply(e._plain, V, (res[1],), True)
    dense.event_times(e._plain, V, (res[2], res[3]))
    T = _core.read_only(T)  # as the engines pass it: one signature of the driver
    dense.tangents(e._plain, V, (res[4], T), False)
    dense.tangents(e._plain, V, (res[5], T), True)
    return res


def _tangent_scales(e, orders, T):
    """``|S_n| ... |S_1| |T|`` and ``|S_1|^T ... |S_n|^T |T|`` row by row: the sizes the
    saltation factors (mathematics.md section 4) sum along each order."""
    d = e.d
    fwd, back = np.abs(T).copy(), np.abs(T).copy()
    for q, order in enumerate(orders):
        factors, before = [], 0
        for k in order:
            after = before | (1 << int(k))
            factors.append(np.abs(np.eye(d) + np.outer(e.F[after] - e.F[before], e.Dh[k])
                                  / e.G[before, k]))
            before = after
        for S in factors:
            fwd[q] = S @ fwd[q]
        for S in factors[::-1]:
            back[q] = S.T @ back[q]
    return fwd, back


@pytest.mark.parametrize("n, d", [(3, 3), (8, 8), (9, 17), (6, 40)])
def test_the_lanes_agree_with_the_scalar_chain(n, d):
    """The lanes select with their own arithmetic (a stored ``-1 / G`` in actual
    coordinates, fused updates, tree sums: the module docstring gives what the scalar
    chain's arithmetic costs them). Against the scalar chain on the same tables: the same
    event orders exactly, apply, inverse and the times within 4 n eps of their chains'
    scales (the bound they meet against the oracle), jvp and vjp within 4 n (d + 2) eps of
    the sizes their factors sum."""
    rng = np.random.default_rng(500 + n * d)
    Dh, F = random_system(rng, n, d)
    e = BDerivative(Dh, F, fast_paths=False)._engine
    assert e._lanes is not None
    # T read-only, as the engine passes it (a writeable T would compile the tangent
    # drivers once more)
    V, T = rng.standard_normal((300, d)), _core.read_only(rng.standard_normal((300, d)))
    x, back, t, o, jvp, vjp = _plain(e, V, T)
    lanes_apply, lanes_back = np.empty_like(V), np.empty_like(V)
    e._lane_kernels[0](e._lanes, V, (lanes_apply,), False)
    e._lane_kernels[0](e._lanes, V, (lanes_back,), True)
    lanes_t, lanes_o = np.empty_like(t), np.empty_like(o)
    e._lane_kernels[1](e._lanes, V, (lanes_t, lanes_o))
    lanes_jvp, lanes_vjp = np.empty_like(V), np.empty_like(V)
    e._lane_kernels[2](e._lanes, V, (lanes_jvp, T), False)
    e._lane_kernels[2](e._lanes, V, (lanes_vjp, T), True)
    np.testing.assert_array_equal(lanes_o, o)
    S, _, dt, _ = chain_scale(e.Dh, table_corners(e.F), V, t, o)
    t_back, o_back = np.empty_like(t), np.empty_like(o)
    dense.event_times(e._plain, back, (t_back, o_back))
    # the scale of M^-1(V): the chain of M^-1(V), summed back from V
    S_back = chain_scale(e.Dh, table_corners(e.F), back, t_back, o_back)[1]
    eps = np.finfo(float).eps
    bound = 4 * n * eps / RTOL  # in units of RTOL * scale
    assert excess(lanes_apply, x, S).max() <= bound
    assert excess(lanes_back, back, S_back).max() <= bound
    assert excess(lanes_t, t, np.abs(t) + dt).max() <= bound
    fwd, bwd = _tangent_scales(e, o, T)
    assert excess(lanes_jvp, jvp, fwd).max() <= 4 * n * (d + 2) * eps / RTOL
    assert excess(lanes_vjp, vjp, bwd).max() <= 4 * n * (d + 2) * eps / RTOL


def test_the_lanes_agree_with_the_scalar_chain_at_ties():
    """Queries whose first two events tie exactly (and d = 1, where every time ties): the
    lanes' product ``h * (-1 / G)`` can break a tie of ``-g / G`` the other way, so the
    orders may differ there; the map is continuous across ties, and apply and inverse
    agree with the scalar chain within 4 n eps of the scales of both orders."""
    rng = np.random.default_rng(8)
    for n, d in [(3, 3), (5, 5), (4, 1)]:
        Dh = np.eye(n, d) if d > 1 else np.ones((n, 1))
        F = np.exp(rng.uniform(-1, 1, (2**n, d)))  # positive: every rate > 0
        e = BDerivative(Dh, F, fast_paths=False)._engine
        assert e._lanes is not None
        U = -F[0] * np.concatenate([np.ones((40, min(2, d))),
                                    rng.uniform(1.5, 3.0, (40, d - min(2, d)))], axis=1)
        U *= rng.uniform(0.5, 2.0, (40, 1))
        x, back, t, o = _plain(e, U, U)[:4]
        lanes_apply, lanes_back = np.empty_like(U), np.empty_like(U)
        e._lane_kernels[0](e._lanes, U, (lanes_apply,), False)
        e._lane_kernels[0](e._lanes, U, (lanes_back,), True)
        S = chain_scale(e.Dh, table_corners(e.F), U, t, o)[0]
        t_back, o_back = np.empty_like(t), np.empty_like(o)
        dense.event_times(e._plain, back, (t_back, o_back))
        S_back = chain_scale(e.Dh, table_corners(e.F), back, t_back, o_back)[1]
        bound = 4 * n * np.finfo(float).eps / RTOL
        assert excess(lanes_apply, x, S).max() <= bound
        assert excess(lanes_back, back, S_back).max() <= bound


def test_queries_beyond_the_band_rerun_on_the_same_apply_driver():
    """A group with event values beyond ``QUERY_BAND`` comes back NaN from the checked
    apply and runs again scaled into the band, through the same compiled driver (the flag
    ``check`` is in the tables, not compiled in: one apply per width pair). Scaled by a
    power of two, a row whose largest entry is in [0.5, 1) gives its answer's bits scaled."""
    rng = np.random.default_rng(11)
    Dh, F = random_system(rng, 5, 6)
    bd = BDerivative(Dh, F, fast_paths=False)
    apply, times, tangents = bd._engine._lane_kernels
    assert bd._engine._lanes.dims[lanes.CHECK] == 1
    assert lanes.unchecked(bd._engine._lanes).dims[lanes.CHECK] == 0
    V = rng.standard_normal((20, 6))
    V /= 2.0 ** np.ceil(np.log2(np.abs(V).max(axis=1, keepdims=True) * 1.0000001))
    np.testing.assert_array_equal(bd(V * 2.0**600), bd(V) * 2.0**600)
    np.testing.assert_array_equal(bd.inverse(V * 2.0**-600), bd.inverse(V) * 2.0**-600)
