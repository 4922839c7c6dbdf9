"""The shortcuts of a small build give what the full checks give, bit for bit.

A compiled ``flow_bderivative`` takes milliseconds, so the fixed cost of building each event
group's map counts (issue 19). These shortcuts must never change a result or a refusal: the
screen that spares the transversality test its row norms accepts only tables the full test
accepts; the assembly's ``BDerivative._from_checked`` builds the map ``BDerivative`` builds;
the mask tables the assembly makes are those of their definitions.
"""

from __future__ import annotations

import pickle

import numpy as np
import pytest
from reference import random_reset_system, random_system

from bderiv import BDerivative
from bderiv._limits import TABLE_BAND
from bderiv._support import _tables
from bderiv.analysis.assembly import spread_masks
from bderiv.analysis.system import HybridSystem
from bderiv.engine._engines.dense import table_exponents

TINY = np.finfo(np.float64).tiny


def full_test_accepts(G, F, Dh, tol, happened=None) -> bool:
    """The transversality test of ``find_transversality_violation`` written out: a rate
    is refused when not above ``tol |F[mask]| |Dh[k]|`` (the norms as ``row_norms`` gives
    them), below the normal range, or not finite; with ``happened`` only pending rates
    must pass the first two."""
    with np.errstate(over="ignore", invalid="ignore"):
        scale = _tables.row_norms(F)[:, None] * _tables.row_norms(Dh)
        bad = (G <= tol * scale) | (G < TINY)
    if happened is not None:
        bad &= ~happened
    return not (bad | ~np.isfinite(G)).any()


def adversarial_block(rng, rows, n, d):
    """(G, F, Dh, tol): entries from subnormal to near overflow, and rates placed at the
    full test's threshold (a few ulps either side), at TINY, 0, inf or NaN."""
    exps = rng.integers(-320, 287, size=2)
    F = rng.standard_normal((rows, d)) * 10.0 ** rng.integers(exps[0], exps[0] + 20,
                                                              size=(rows, 1))
    Dh = rng.standard_normal((n, d)) * 10.0 ** rng.integers(exps[1], exps[1] + 20, size=(n, 1))
    F[rng.random(rows) < 0.1] = 0.0
    if rng.random() < 0.3:  # flat rows, one magnitude each: the norms at the bound's edge
        F = np.sign(F) * np.abs(F).max(axis=1, keepdims=True)
        Dh = np.sign(Dh) * np.abs(Dh).max(axis=1, keepdims=True)
    tol = float(rng.choice([0.0, 1e-9, 1e-3, 0.4, 7.0, 1e300]))
    with np.errstate(all="ignore"):
        edge = tol * _tables.row_norms(F)[:, None] * _tables.row_norms(Dh)
        G = edge * (1.0 + rng.integers(-4, 5, size=(rows, n)) * np.finfo(float).eps)
        G = np.where(rng.random((rows, n)) < 0.5, G * 10.0 ** rng.uniform(0, 12, (rows, n)), G)
    special = rng.random((rows, n))
    G[special < 0.02] = TINY
    G[(special >= 0.02) & (special < 0.03)] = np.inf
    G[(special >= 0.03) & (special < 0.04)] = np.nan
    G[(special >= 0.04) & (special < 0.05)] = 0.0
    return G, F, Dh, tol


def test_the_transversality_screen_accepts_only_what_the_full_test_accepts():
    rng = np.random.default_rng(19)
    passed = 0
    for case in range(3000):
        n, d = int(rng.integers(1, 5)), int(rng.choice([1, 2, 3, 8, 33]))
        rows = 1 << n
        G, F, Dh, tol = adversarial_block(rng, rows, n, d)
        happened = _tables.mask_bits(np.arange(rows), n) != 0 if case % 3 == 0 else None
        for maxima in (_tables.table_maxima(Dh, F), None):
            dh_big, f_big = maxima if maxima else _tables.table_maxima(Dh, F)
            if _tables._clearly_transversal(G, d, f_big, dh_big, tol, happened):
                passed += 1
                assert full_test_accepts(G, F, Dh, tol, happened), (case, tol)
    assert passed > 100  # the screen is exercised, not only refused


def test_the_screen_spares_the_row_norms_of_a_transversal_table(monkeypatch):
    Dh, F = random_system(np.random.default_rng(1), 3, 8)
    expected = pickle.dumps(BDerivative(Dh, F)(np.ones((4, 8))))

    def refused(A):
        raise AssertionError("row norms taken")

    monkeypatch.setattr(_tables, "row_norms", refused)
    assert pickle.dumps(BDerivative(Dh, F)(np.ones((4, 8)))) == expected
    F[3] = -F[3]  # a violated rate: the full test runs and names it
    monkeypatch.undo()
    with pytest.raises(ValueError, match="transversality violated"):
        BDerivative(Dh, F)


def test_table_exponents_are_those_of_np_frexp():
    rng = np.random.default_rng(4)
    for scale in (5e-324, 1e-310, 1e-200, 1e-20, 1.0, 3e19, 1e200, 1.7e308):
        with np.errstate(all="ignore"):  # beyond the range: the largest finite entries
            Dh = np.nan_to_num(rng.standard_normal((3, 5)) * scale
                               * np.array([[1.0], [1e-30], [0.0]]))
            F = np.nan_to_num(rng.standard_normal((8, 5)) * scale)
        dh = np.frexp(np.abs(Dh).max(axis=1))[1].astype(np.int64)
        dh[np.abs(dh) <= TABLE_BAND] = 0
        f = int(np.frexp(np.abs(F).max())[1])
        got_dh, got_f = table_exponents(*_tables.table_maxima(Dh, F))
        assert got_dh.dtype == np.int64
        np.testing.assert_array_equal(got_dh, dh)
        assert got_f == (f if abs(f) > TABLE_BAND else 0)


def test_block_bits_are_the_mask_bits_and_shared_read_only():
    for n in (1, 4, _tables.SHARED_BITS_N, _tables.SHARED_BITS_N + 1):
        rows = slice(0, 1 << n)
        bits = _tables.block_bits(rows, n)
        np.testing.assert_array_equal(bits, [[(m >> k) & 1 for k in range(n)]
                                             for m in range(1 << n)])
        if n <= _tables.SHARED_BITS_N:
            assert _tables.block_bits(rows, n) is bits and not bits.flags.writeable
    part = slice(3, 7)
    np.testing.assert_array_equal(_tables.block_bits(part, 3),
                                  [[(m >> k) & 1 for k in range(3)] for m in range(3, 7)])


@pytest.mark.parametrize("mask_before", [0, 0b1011, 0b110001])
def test_spread_masks_flip_the_bits_of_the_events_of_each_local_mask(mask_before):
    events = (4, 0, 3, 1)
    glob = spread_masks(events, mask_before)
    assert glob.dtype == np.int64
    for local, mask in enumerate(glob.tolist()):
        flips = sum(1 << k for j, k in enumerate(events) if local >> j & 1)
        assert mask == mask_before ^ flips


def _bits(bd, V):
    return [bd.Dh.tobytes(), bd.F.tobytes(), bd.rates.tobytes(), bd._engine.R.tobytes(),
            repr(bd.rate_spread), bd.fast_path, bd.transversality, bd(V).tobytes(),
            bd.inverse(bd(V)).tobytes()]


@pytest.mark.parametrize("kind", ["random", "linear", "own-rates"])
def test_from_checked_builds_the_map_of_the_constructor(kind):
    rng = np.random.default_rng(7)
    Dh, F = random_system(rng, 3, 6)
    if kind != "random":  # additive corners with own rates (F[mask] = F0 + sum A[k])
        P = np.linalg.pinv(Dh)
        bits = _tables.mask_bits(np.arange(8), 3)
        F = P @ np.ones(3) + bits @ (P * rng.uniform(0.5, 2.0, 3)).T
        if kind == "own-rates":  # a pair term the rates do not see
            F += bits.prod(axis=1)[:, None] * ((np.eye(6) - P @ Dh) @ rng.standard_normal(6))
    V = rng.standard_normal((16, 6))
    public = BDerivative(Dh, F)
    assert public.fast_path == (None if kind == "random" else kind)
    private = BDerivative._from_checked(Dh.copy(), F)
    assert _bits(private, V) == _bits(public, V)
    assert not private.Dh.flags.writeable


def test_from_checked_with_resets_builds_the_map_of_the_constructor():
    rng = np.random.default_rng(3)
    Dh, F, R = random_reset_system(rng, 2, 4)
    V = rng.standard_normal((16, 4))
    public = BDerivative(Dh, F, resets=R, reset_tol=1e-9)
    private = BDerivative._from_checked(Dh.copy(), F, resets=R, reset_tol=1e-9)
    assert _bits(private, V) == _bits(public, V)
    np.testing.assert_array_equal(private.resets, public.resets)


@pytest.mark.parametrize("defect", ["violated", "grazing", "spread", "pending"])
def test_from_checked_refuses_what_the_constructor_refuses(defect):
    Dh, F, R = random_reset_system(np.random.default_rng(5), 2, 4)
    resets = {"resets": R, "reset_tol": 1e-9} if defect == "pending" else {}
    if defect == "violated":
        F[0b10] = -F[0b10]
    elif defect == "grazing":  # F[0b10] . Dh[0] = 1e-12 |F[0b10]| |Dh[0]|, far below 1e-9
        F[0b10] -= (F[0b10] @ Dh[0] - 1e-12 * np.linalg.norm(F[0b10])
                    * np.linalg.norm(Dh[0])) / (Dh[0] @ Dh[0]) * Dh[0]
    elif defect == "spread":
        F[0b01] *= 1e10
    else:  # with resets only pending rates count: event 1 pending in region 0b01
        F[0b01] = -F[0b01]
    with pytest.raises(ValueError) as public:
        BDerivative(Dh, F, **resets)
    with pytest.raises(ValueError) as private:
        BDerivative._from_checked(Dh.copy(), F, **resets)
    expected = {"violated": "transversality violated", "grazing": "grazing rate",
                "spread": "ill-conditioned event times", "pending": "transversality violated"}
    assert expected[defect] in str(public.value)
    assert str(private.value) == str(public.value)


def test_corners_at_is_sample_corners_at_a_checked_state():
    system = HybridSystem(lambda x, m: x * (1.0 + m), lambda x: x[:2], n_events=2, dim=3)
    x = np.array([0.5, -1.0, 2.0])
    masks = np.array([3, 0, 2], dtype=np.int64)
    np.testing.assert_array_equal(system.calls.corners_at(x, masks),
                                  system.calls.sample_corners(x, masks))
    np.testing.assert_array_equal(system.calls.corners_at(x, masks),
                                  [x * (1.0 + m) for m in masks.tolist()])


def test_a_map_on_a_fast_path_never_builds_the_selection_tables():
    rng = np.random.default_rng(8)
    Dh, F = random_system(rng, 3, 6)
    P = np.linalg.pinv(Dh)
    bits = _tables.mask_bits(np.arange(8), 3)
    F = P @ np.ones(3) + bits @ (P * rng.uniform(0.5, 2.0, 3)).T
    F += bits.prod(axis=1)[:, None] * ((np.eye(6) - P @ Dh) @ rng.standard_normal(6))
    fast, slow = BDerivative(Dh, F), BDerivative(Dh, F, fast_paths=False)
    assert fast.fast_path == "own-rates"
    V = rng.standard_normal((16, 6))
    np.testing.assert_allclose(fast(V), slow(V), rtol=1e-12, atol=1e-12)
    fast.event_times(V), fast.inverse(V)
    assert "_selection_tables" not in fast._engine.__dict__  # built for slow's queries only
    assert "_selection_tables" in slow._engine.__dict__
    again = pickle.loads(pickle.dumps(slow))
    assert again(V).tobytes() == slow(V).tobytes()
