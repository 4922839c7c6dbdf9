"""Positive homogeneity at the ends of the float64 range (issue 27, item 1).

M is positively homogeneous, ``M(c v) = c M(v)``, and so are its event times; its pieces
depend only on ratios, so scaling a row of Dh or the whole table F by a positive factor
changes nothing. The oracle of every test below is ``tests/reference.py`` run on a
mid-range version of the system, scaled by the exact powers of two that relate the two;
homogeneity itself is asserted bit for bit (a power-of-two scaling is exact in floating
point wherever the scaled answer is a normal float).
"""

from __future__ import annotations

import numpy as np
import pytest
import reference as ref
from fuzz_families import structured_corners

from bderiv import BDerivative, StructuredCorners

# the issue's system: Dh = 1e160 I, F = 1e51 [[1, 1], [1, 3], [3, 1], [2, 2]]
ISSUE_F = np.array([[1.0, 1], [1, 3], [3, 1], [2, 2]])


def test_the_issues_tiny_vector_moves():
    """``bd(v)`` for |v| ~ 1e-300 was v itself (event times ~1e-351 underflowed, so every
    event happened at once); it is the oracle's answer at a mid-range scale, scaled."""
    bd = BDerivative(1e160 * np.eye(2), 1e51 * ISSUE_F)
    v = np.array([-1.2345678e-300, -2.3456789e-300])
    want = np.ldexp(ref.ref_apply(np.eye(2), ISSUE_F, np.ldexp(v, 1000)), -1000)
    np.testing.assert_allclose(bd(v), want, rtol=1e-14)
    np.testing.assert_allclose(want, [-2.83950597e-300, -3.20987633e-300], rtol=1e-8)
    np.testing.assert_allclose(bd.inverse(want), v, rtol=1e-14)
    times, order = ref.ref_event_times(np.eye(2), ISSUE_F, np.ldexp(v, 1000))
    np.testing.assert_array_equal(bd.orders(v), order)
    # the times themselves (~1e-351) are below float64: refused, naming the query
    with pytest.raises(ValueError, match=r"time of event 0 for V\[0\] underflows float64"):
        bd.event_times(v)
    # at 2**600 v they are ~1e-171: the oracle's, scaled (times Dh / (F . Dh))
    t600, _ = bd.event_times(np.ldexp(v, 600))
    np.testing.assert_allclose(t600, np.ldexp(times, -400) * 1e160 / 1e211, rtol=1e-14)


def test_overflowing_event_times_are_refused_while_the_map_answers():
    """Rates ~1e-300 and a vector ~1e100: times ~1e400 are beyond float64, M(v) is not."""
    F = np.ldexp(ISSUE_F, -1000)
    bd = BDerivative(np.eye(2), F)
    v = np.array([-1e100, -2e100])
    np.testing.assert_allclose(bd(v), ref.ref_apply(np.eye(2), ISSUE_F, v), rtol=1e-14)
    with pytest.raises(ValueError, match=r"time of event 0 for V\[0\] overflows float64"):
        bd.event_times(v)
    np.testing.assert_array_equal(bd.orders(v), [0, 1])


def _maps(rng):
    """(name, bd, mid-range oracle of M as a function of one vector, d) for every engine:
    the general selection, the own-rates and linear fast paths, a structured model, a
    corner function and resets."""
    from fuzz_families import WAVY, own_rate_table, wavy_corners

    out = []
    Dh, F = ref.random_system(rng, 4, 5)
    out.append(("dense", BDerivative(Dh, F), lambda v, Dh=Dh, F=F: ref.ref_apply(Dh, F, v)))
    for additive in (False, True):
        Do, Fo = own_rate_table(rng, 3, 4, additive)
        bd = BDerivative(Do, Fo)
        assert bd.fast_path == ("linear" if additive else "own-rates")
        out.append((bd.fast_path, bd, lambda v, Dh=Do, F=Fo: ref.ref_apply(Dh, F, v)))
    Ds = np.abs(rng.standard_normal((4, 5))) + 0.5
    F0, A = np.ones(5), 0.2 * rng.standard_normal((4, 5))
    pairs, B = np.array([[0, 1]]), 0.1 * rng.standard_normal((1, 5))
    corners = structured_corners(F0, A, pairs, B)
    out.append(("structured", BDerivative(Ds, StructuredCorners(F0, A, pairs, B)),
                lambda v, Ds=Ds: ref.ref_apply(Ds, corners, v)))
    Dw = rng.uniform(0.1, 1.0, (3, 4))
    out.append(("function", BDerivative(Dw, WAVY),
                lambda v, Dw=Dw: ref.ref_apply(Dw, wavy_corners(4), v)))
    Dr, Fr, R = ref.random_reset_system(rng, 2, 4)
    out.append(("resets", BDerivative(Dr, Fr, resets=R),
                lambda v, Dh=Dr, F=Fr, R=R: ref.ref_reset_flow(Dh, F, R, v)[0]))
    return out


@pytest.mark.parametrize("k", [-1060, -900, -600, -200, 300, 700, 1000])
def test_homogeneity_over_powers_of_two_on_every_engine(k):
    """At 2**k the answers are 2**k the mid-range ones, bit for bit (apply, inverse,
    event times and orders, jvp in both arguments, vjp), and the mid-range answers are
    the oracle's."""
    rng = np.random.default_rng(27)
    for name, bd, oracle in _maps(rng):
        d = bd.dim
        V = rng.standard_normal((40, d))
        T = rng.standard_normal((40, d))
        W = bd(V)
        want = np.array([oracle(v) for v in V])
        np.testing.assert_allclose(W, want, rtol=1e-10, atol=1e-12 * np.abs(want).max(),
                                   err_msg=name)
        Vk, Tk = np.ldexp(V, k), np.ldexp(T, k)
        # the scaling of the inputs is exact, unless they fall in the subnormals
        exact = (np.ldexp(Vk, -k) == V).all(axis=1) & (np.ldexp(Tk, -k) == T).all(axis=1)
        assert exact.all() or k < -1000
        np.testing.assert_array_equal(bd(Vk)[exact], np.ldexp(W, k)[exact], err_msg=name)
        np.testing.assert_array_equal(bd.inverse(np.ldexp(W, k))[exact],
                                      np.ldexp(bd.inverse(W), k)[exact], err_msg=name)
        np.testing.assert_array_equal(bd.orders(Vk), bd.orders(V), err_msg=name)
        J = bd.jvp(V, T)
        np.testing.assert_array_equal(bd.jvp(Vk, T), J, err_msg=name)
        np.testing.assert_array_equal(bd.jvp(V, Tk)[exact], np.ldexp(J, k)[exact],
                                      err_msg=name)
        np.testing.assert_array_equal(bd.vjp(V, Tk)[exact],
                                      np.ldexp(bd.vjp(V, T), k)[exact], err_msg=name)
        times = bd.event_times(V)[0]
        if -600 <= k <= 300:  # times of V are ~1e-3..1e3: 2**k of them stay normal
            np.testing.assert_array_equal(bd.event_times(Vk)[0], np.ldexp(times, k),
                                          err_msg=name)


@pytest.mark.parametrize(("row_exp", "f_exp"), [(600, 400), (-700, 650), (-500, -500),
                                                 (900, -900)])
def test_tables_beyond_the_band_are_scaled_at_build(row_exp, f_exp):
    """Rows of Dh and the table F at 2**+-500..900 (rates up to 2**1300, beyond float64,
    or down to 2**-1000): the map is the mid-range one, the times 2**-f_exp of it, and
    the attributes stay in the caller's units."""
    rng = np.random.default_rng(abs(row_exp - f_exp))
    Dh, F = ref.random_system(rng, 3, 4)
    rows = row_exp + rng.integers(-40, 41, 3)
    Dh_s, F_s = np.ldexp(Dh, rows[:, None]), np.ldexp(F, f_exp)
    bd = BDerivative(Dh_s, F_s)
    V = rng.standard_normal((30, 4))
    want = np.array([ref.ref_apply(Dh, F, v) for v in V])
    ref.assert_maps_close(Dh, F, V, bd(V), want)
    ref.assert_maps_close(Dh, F, want, bd.inverse(want), V)
    times = np.array([ref.ref_event_times(Dh, F, v)[0] for v in V])
    np.testing.assert_allclose(bd.event_times(V)[0], np.ldexp(times, -f_exp), rtol=1e-11)
    np.testing.assert_array_equal(bd.F, F_s)
    np.testing.assert_array_equal(bd.Dh, Dh_s)
    with np.errstate(over="ignore", under="ignore"):
        G = np.ldexp(F @ Dh.T, f_exp + rows[None, :])
    np.testing.assert_allclose(bd.rates, G, rtol=1e-14)  # inf where beyond float64
    pre, post = bd.corner_points()
    rpre, rpost = ref.ref_corner_points(Dh, F)
    np.testing.assert_allclose(np.ldexp(pre, -f_exp), rpre, atol=1e-12 * np.abs(rpre).max())
    np.testing.assert_allclose(np.ldexp(post, -f_exp), rpost, atol=1e-12 * np.abs(rpost).max())
    np.testing.assert_allclose(bd.piece([2, 0, 1]), ref.ref_piece(Dh, F, [2, 0, 1]),
                               atol=1e-12 * np.abs(ref.ref_piece(Dh, F, [2, 0, 1])).max())


def test_tables_within_the_band_keep_their_records():
    """A table within 2**+-64 is not copied: F and rates are views of the records."""
    rng = np.random.default_rng(3)
    Dh, F = ref.random_system(rng, 3, 4)
    bd = BDerivative(Dh * 1e15, F * 1e-15)
    assert np.shares_memory(bd.F, bd._engine.R) and np.shares_memory(bd.rates, bd._engine.R)


def test_issue_fuzz_homogeneity_dense_and_structured():
    """The issue's fuzz in small: random dense and structured systems with entries over
    1e-150..1e150 (rows of Dh, F, the model's corners), queries at 2**-1000..2**900.
    Every answer whose value is a normal float is 2**k times the mid-range answer (bit for
    bit) and nothing is refused; the mid-range answers are the oracle's."""
    rng = np.random.default_rng(2611)
    checked = 0
    for case in range(30):
        n, d = int(rng.integers(1, 5)), int(rng.integers(4, 7))
        Dh, F = ref.random_system(rng, n, d)
        rows = rng.integers(-500, 500, n)
        if case % 2:  # rates near 1 in every region: transversal
            e = np.ones(d) / np.sqrt(d)
            Dh = e + 0.3 * rng.uniform(-1, 1, (n, d)) / np.sqrt(d)
            F0, A = e, 0.1 * rng.standard_normal((n, d)) / n
            corners = structured_corners(F0, A, np.empty((0, 2), np.int64), np.empty((0, d)))
            bd = BDerivative(np.ldexp(Dh, rows[:, None]), StructuredCorners(F0, A))
            oracle = lambda v, Dh=Dh, c=corners: ref.ref_apply(Dh, c, v)  # noqa: E731
        else:
            bd = BDerivative(np.ldexp(Dh, rows[:, None]), np.ldexp(F, rng.integers(-500, 500)))
            oracle = lambda v, Dh=Dh, F=F: ref.ref_apply(Dh, F, v)  # noqa: E731
        V = rng.standard_normal((20, d))
        W = bd(V)
        want = np.array([oracle(v) for v in V])
        np.testing.assert_allclose(W, want, rtol=1e-9, atol=1e-12 * np.abs(want).max())
        for k in rng.integers(-1000, 901, 6):
            Wk = np.ldexp(W, k)
            normal = (np.abs(Wk) >= np.finfo(float).tiny).all(axis=1) & np.isfinite(Wk).all(
                axis=1) & (np.ldexp(np.ldexp(V, k), -k) == V).all(axis=1)
            got = np.array([bd(v) if ok else np.zeros(d)
                            for v, ok in zip(np.ldexp(V, k), normal, strict=True)])
            np.testing.assert_array_equal(got[normal], Wk[normal])
            checked += int(normal.sum())
    assert checked > 1000



def test_small_batches_scale_serially_with_the_same_bits():
    """A batch below ``SERIAL_ENTRIES`` runs the serial loops (no parallel launch: 11-16 ms
    each under load), with the parallel kernels' bits: scaled rows, exponents, the rows
    beyond the band and the overflow count, on rows from 5e-324 to 1.7e308; the oracle of
    the scaling is NumPy's frexp/ldexp."""
    from bderiv._kernels import _core, _drivers, scaling
    from bderiv._numerics import QUERY_BAND

    rng = np.random.default_rng(4)
    R = (rng.standard_normal((300, 7)) * 10.0 ** rng.integers(-300, 300, (300, 1))
         * 10.0 ** rng.integers(-20, 1, (300, 7)))
    R[:3] = [[0.0] * 7, [5e-324, 0, 0, 0, 0, 0, -5e-324], [1.7e308, 1e-300, 4e-320, 0, 1, 2, 3]]
    assert R.size < scaling.SERIAL_ENTRIES
    R = _core.read_only(R)  # as the public functions pass it (one compilation each)
    outs = {}
    for name, scale, unscale, band in (
            ("serial", scaling._scale_rows_serial, scaling._unscale_rows_serial,
             scaling._outside_band_serial),
            ("parallel", scaling._scale_rows, scaling._unscale_rows, scaling._outside_band)):
        U, exps = np.empty_like(R), np.empty(R.shape[0], np.int64)
        _drivers.serialised(scale, R, U, exps)
        band_exps = np.empty_like(exps)
        beyond = _drivers.serialised(band, R, band_exps)
        back = U.copy()
        bad = _drivers.serialised(unscale, back, exps, 300)  # overflows the rows beyond 2**724
        outs[name] = (U, exps, band_exps, beyond, back, bad)
    serial, parallel = outs["serial"], outs["parallel"]
    for s, p in zip(serial, parallel, strict=True):
        np.testing.assert_array_equal(s, p)
    U, exps, _, beyond, _, bad = serial
    np.testing.assert_array_equal(U, np.ldexp(R, -np.frexp(np.abs(R).max(axis=1))[1][:, None]))
    assert beyond == int(np.sum(np.abs(exps) > QUERY_BAND)) > 0
    with np.errstate(over="ignore"):
        overflows = ~np.isfinite(np.ldexp(U, (exps + 300)[:, None])).all(axis=1)
    assert bad == int(np.sum(overflows)) > 0
    # the public functions take the serial loops for this batch (same bits again)
    U2, exps2 = np.empty_like(R), np.empty(R.shape[0], np.int64)
    scaling.scale_rows(R, U2, exps2)
    np.testing.assert_array_equal(U2, U)
