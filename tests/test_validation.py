"""Bad input gives a clear ValueError/TypeError saying what was expected and what came."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from reference import random_system, ref_apply

from bderiv import BDerivative
from bderiv._support._validate import all_finite, check_state
from bderiv._support._validate_ints import check_int

DH2 = np.eye(2)
F2 = np.array([[1.0, 1.0], [2.0, 1.0], [1.0, 3.0], [2.0, 2.0]])


@pytest.fixture
def bd3():
    rng = np.random.default_rng(0)
    return BDerivative(*random_system(rng, 2, 3))


# --------------------------------------------------------------------------------------
# Constructor: shapes
# --------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("Dh", "F", "match"),
    [
        (np.ones(2), F2, r"Dh must be a 2-D array, got 1-D"),
        (np.ones((1, 2, 2)), F2, r"Dh must be a 2-D array, got 3-D with shape \(1, 2, 2\)"),
        (5.0, F2, r"Dh must be a 2-D array, got 0-D"),
        (DH2, np.ones(8), r"F must be a 2-D array, got 1-D"),
        (DH2, np.ones((4, 2, 1)), r"F must be a 2-D array, got 3-D"),
        (DH2, np.ones((4, 3)), r"F must have shape \(any, 2\), got \(4, 3\).*expected 2, got 3"),
        (DH2, np.ones((3, 2)), r"F must have 2\*\*n = 4 rows.*n=2.*got 3 rows"),
        (DH2, np.ones((2, 2)), r"F must have 2\*\*n = 4 rows.*got 2 rows"),
        (np.ones((3, 2)), np.ones((4, 2)), r"F must have 2\*\*n = 8 rows.*got 4 rows"),
        (np.ones((0, 2)), np.ones((1, 2)), r"at least one event.*got \(0, 2\)"),
        (np.ones((2, 0)), np.ones((4, 0)), r"at least one event and one dimension.*\(2, 0\)"),
    ],
)
def test_bad_shapes(Dh, F, match):
    with pytest.raises(ValueError, match=match):
        BDerivative(Dh, F)


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_non_finite_tables(bad):
    Dh = DH2.copy()
    Dh[1, 0] = bad
    with pytest.raises(ValueError, match=r"Dh must be finite, but Dh\[1, 0\] = "):
        BDerivative(Dh, F2)
    F = F2.copy()
    F[2, 1] = bad
    with pytest.raises(ValueError, match=r"F must be finite, but F\[2, 1\] = "):
        BDerivative(DH2, F)


@pytest.mark.parametrize(
    ("dtype", "word"),
    [(np.complex128, "complex"), (bool, "bool"), (object, "object"), (str, "string")],
)
def test_non_real_dtypes(dtype, word):
    match = rf"must hold real numbers.*{word}"
    with pytest.raises(TypeError, match=rf"Dh {match}"):
        BDerivative(DH2.astype(dtype), F2)
    with pytest.raises(TypeError, match=rf"F {match}"):
        BDerivative(DH2, F2.astype(dtype))


def test_non_real_query_dtypes(bd3):
    V = np.ones((2, 3))
    for dtype, word in [
        (np.complex128, "complex"),
        (bool, "bool"),
        (object, "object"),
        (str, "string"),
    ]:
        for method, name in [(bd3, "V"), (bd3.inverse, "W"), (bd3.event_times, "V")]:
            with pytest.raises(TypeError, match=rf"{name} must hold real numbers.*{word}"):
                method(V.astype(dtype))


# --------------------------------------------------------------------------------------
# Constructor: transversality
# --------------------------------------------------------------------------------------
def test_transversality_violation_names_mask_and_event():
    F = F2.copy()
    F[0b10] = [-1.0, 3.0]  # after event 1 only, h_0 decreases: G[0b10, 0] = -1
    with pytest.raises(
        ValueError, match=r"transversality violated at event 0 in region mask 0b10.*-1"
    ):
        BDerivative(DH2, F)


def test_zero_rate_is_a_violation():
    F = F2.copy()
    F[0b01, 1] = 0.0  # after event 0, h_1 does not move
    with pytest.raises(ValueError, match=r"transversality violated at event 1 .*mask 0b01"):
        BDerivative(DH2, F)


def test_a_row_of_zeros_is_named_not_called_an_underflow():
    """A zero row of Dh, or a zero corner F[mask], was "underflows float64: |F| |Dh| =
    1e-320 ...; rescale the state or time units", which no rescaling mends (a review)."""
    F = np.abs(F2) + 0.5
    with pytest.raises(ValueError, match=r"transversality fails at event 0 .*: Dh\[0\] is a "
                                         r"row of zeros: event 0's surface has no normal"):
        BDerivative(np.array([[0.0, 0.0], [0.0, 1.0]]), F)
    F[0] = 0.0
    with pytest.raises(ValueError, match=r"F\[0\] is a row of zeros: the flow stands still"):
        BDerivative(np.eye(2), F)


def test_violation_mask_bit_string_has_n_bits():
    n = 4
    Dh = np.eye(n)
    F = np.ones((2**n, n))
    F[0b0101, 3] = -2.0
    with pytest.raises(ValueError, match=r"event 3 in region mask 0b0101\b"):
        BDerivative(Dh, F)


def test_grazing_rate():
    F = F2.copy()
    F[0b01, 1] = 1e-12  # positive but 1e-12 of |F[0b01]| |Dh[1]| ~ 2
    with pytest.raises(ValueError, match=r"grazing rate at event 1 in region mask 0b01"):
        BDerivative(DH2, F)
    # the tolerance is relative to the table's scale: the same table scaled is refused too
    with pytest.raises(ValueError, match=r"grazing"):
        BDerivative(1e6 * DH2, 1e6 * F)
    # and a caller can loosen it
    BDerivative(DH2, F, transversality_tol=1e-13)


def test_grazing_is_relative_not_absolute():
    # tiny but well-proportioned tables are fine
    bd = BDerivative(1e-150 * DH2, 1e-150 * F2)
    assert bd.n_events == 2


@pytest.mark.parametrize("tol", [-1.0, np.nan, np.inf])
def test_bad_transversality_tol(tol):
    with pytest.raises(ValueError, match=r"transversality_tol must be a finite number >= 0"):
        BDerivative(DH2, F2, transversality_tol=tol)


@pytest.mark.parametrize("tol", ["1e-9", None, True])
def test_transversality_tol_of_the_wrong_type(tol):
    with pytest.raises(TypeError, match=r"transversality_tol must be a real number, got"):
        BDerivative(DH2, F2, transversality_tol=tol)


@pytest.mark.parametrize("limit, exc", [("1e9", TypeError), (-5, ValueError),
                                        (1.5, ValueError), (np.nan, ValueError)])
def test_bad_memory_limit(limit, exc):
    with pytest.raises(exc, match="memory_limit must be"):
        BDerivative(DH2, F2, memory_limit=limit)


# --------------------------------------------------------------------------------------
# Memory
# --------------------------------------------------------------------------------------
def test_table_too_large_for_memory_is_refused_before_allocating():
    # n = 40 events: F would need 2**40 rows; only Dh is given, a small F is never read
    Dh = np.eye(40)
    with pytest.raises(ValueError, match=r"n=40 events.*2\*\*40 rows.*TiB.*memory limit"):
        BDerivative(Dh, np.ones((2, 40)), memory_limit=16 << 30)


def test_memory_limit_argument():
    rng = np.random.default_rng(1)
    Dh, F = random_system(rng, 10, 10)
    # one record per region: -1/G, G and F, n and d each padded to 16, float64
    need = 2**10 * (16 + 16 + 16) * 8
    with pytest.raises(ValueError, match=r"2\*\*10 rows, 384\.0 KiB.*memory limit of 1000 B"):
        BDerivative(Dh, F, memory_limit=1000)
    with pytest.raises(ValueError, match=r"384\.0 KiB"):
        BDerivative(Dh, F, memory_limit=need - 1)
    assert BDerivative(Dh, F, memory_limit=need).table_bytes == need


# --------------------------------------------------------------------------------------
# Queries
# --------------------------------------------------------------------------------------
@pytest.mark.parametrize("shape", [(4,), (2,), (5, 2), (5, 4), (2, 3, 1), ()])
def test_query_wrong_dimension(bd3, shape):
    V = np.ones(shape)
    got = "a scalar" if shape == () else rf"shape \({shape[0]},"
    for method, name in [(bd3, "V"), (bd3.apply, "V"), (bd3.inverse, "W"), (bd3.event_times, "V")]:
        with pytest.raises(ValueError, match=rf"{name} must have shape \(\.\.\., 3\).*got {got}"):
            method(V)


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_non_finite_query_names_first_bad_row(bd3, bad):
    V = np.ones((6, 3))
    V[4, 0] = bad
    V[2, 1] = bad
    for method, name in [(bd3, "V"), (bd3.inverse, "W"), (bd3.event_times, "V")]:
        with pytest.raises(ValueError, match=rf"{name} must be finite.*{name}\[2\] = "):
            method(V)
    V3 = np.ones((2, 3, 3))
    V3[1, 2, 0] = bad
    with pytest.raises(ValueError, match=r"V must be finite.*V\[1, 2\] = "):
        bd3(V3)
    with pytest.raises(ValueError, match=r"V must be finite, but V = \[ *1\. +nan +1\.\] is not"):
        bd3(np.array([1.0, np.nan, 1.0]))


def test_bad_out(bd3):
    V = np.ones((4, 3))
    with pytest.raises(ValueError, match=r"out must have shape \(4, 3\), got \(3, 4\)"):
        bd3.apply(V, out=np.empty((3, 4)))
    with pytest.raises(ValueError, match=r"out must be a writeable C-contiguous float64.*float32"):
        bd3.apply(V, out=np.empty((4, 3), dtype=np.float32))
    with pytest.raises(ValueError, match=r"contiguous=False"):
        bd3.apply(V, out=np.empty((4, 6))[:, ::2])
    with pytest.raises(TypeError, match=r"out must be a numpy array, got list"):
        bd3.inverse(V, out=[[0.0] * 3] * 4)


# --------------------------------------------------------------------------------------
# Pieces and orders
# --------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    "order", [[0, 0, 1], [0, 1], [0, 1, 2, 3], [0, 1, 3], [-1, 0, 1], [[0, 1, 2]], []]
)
def test_piece_order_not_a_permutation(order):
    bd = BDerivative(np.eye(3), np.ones((8, 3)))
    with pytest.raises(ValueError, match=r"order must be a permutation of 0\.\.2.*got"):
        bd.piece(order)


@pytest.mark.parametrize("order", [[0.5, 1, 2], ["0", "1", "2"], [0j, 1, 2]])
def test_piece_order_not_integers(order):
    bd = BDerivative(np.eye(3), np.ones((8, 3)))
    with pytest.raises(TypeError, match=r"order must be a sequence of integers"):
        bd.piece(order)


def test_pieces_bad_limit(bd3):
    with pytest.raises(ValueError, match=r"max_pieces must be an integer >= 1, got 0"):
        bd3.pieces(max_pieces=0)
    with pytest.raises(TypeError, match=r"max_pieces must be an integer >= 1, got float 2.0"):
        bd3.pieces(max_pieces=2.0)


def test_pieces_refusal_message():
    bd = BDerivative(np.eye(5), np.ones((32, 5)))
    with pytest.raises(ValueError, match=r"5! = 120 pieces, more than max_pieces=100"):
        bd.pieces(max_pieces=100)


# --------------------------------------------------------------------------------------
# Corner points / triangulation need full row rank
# --------------------------------------------------------------------------------------
def test_rank_deficient_refuses_corner_points_and_triangulation():
    rng = np.random.default_rng(2)
    bd = BDerivative(*random_system(rng, 4, 2))
    assert not bd.full_rank
    with pytest.raises(ValueError, match=r"corner points need Dh of full row rank n=4.*rank"):
        bd.corner_points()
    with pytest.raises(ValueError, match=r"triangulation need Dh of full row rank n=4"):
        bd.triangulation()
    # everything else still works
    V = rng.standard_normal((5, 2))
    bd.inverse(bd(V))
    bd.event_times(V)
    bd.piece([3, 1, 0, 2])


def test_parallel_rows_are_rank_deficient():
    Dh = np.array([[1.0, 0.5], [2.0, 1.0]])  # h_1 = 2 h_0: one surface, two events
    bd = BDerivative(Dh, np.ones((4, 2)))
    assert not bd.full_rank
    with pytest.raises(ValueError, match=r"full row rank"):
        bd.corner_points()


def test_triangulation_max_pieces():
    bd = BDerivative(np.eye(4), np.ones((16, 4)))
    with pytest.raises(ValueError, match=r"2 \* 4! = 48 simplices.*max_pieces=10"):
        bd.triangulation(max_pieces=10)


# --------------------------------------------------------------------------------------
# Rates at the ends of the float64 range; sizes of corner models
# --------------------------------------------------------------------------------------
@pytest.mark.parametrize("scale", [1e200, 1e-200, 1e-150])
def test_rates_beyond_float64_are_scaled_not_refused(scale):
    # the rates F Dh^T (1e400, 1e-400) are not representable, but M is invariant under
    # Dh -> s Dh and F -> c F (s, c > 0: every event time scales by 1 / (s c) and the jumps
    # t (F[a] - F[b]) do not change), so the tables are scaled at build (mathematics.md
    # section 3, "Scale") and the map is that of (DH2, F2), by the plain oracle
    V = np.array([[-1.0, -2.0], [-3.0, -1.0], [0.5, -0.2]])
    bd = BDerivative(DH2 * scale, F2 * scale)
    expected = np.array([ref_apply(DH2, F2, v) for v in V])
    np.testing.assert_allclose(bd(V), expected, rtol=1e-14, atol=1e-15)
    np.testing.assert_allclose(bd.inverse(expected), V, rtol=1e-14, atol=1e-15)


def test_overflowing_results_are_refused_not_returned():
    bd = BDerivative(np.array([[1.0, 0.0]]), np.array([[1.0, 0.0], [3.0, 0.0]]))
    with pytest.raises(ValueError, match=r"result for V\[1\] overflowed .*positively homogeneous"):
        bd([[1.0, 1.0], [-1.7e308, 1e308]])
    with pytest.raises(ValueError, match=r"result for V\[2\] overflowed"):
        bd([[1.0, 1.0], [2.0, 1.0], [-1.7e308, 1e308]], chunk_size=2)
    np.testing.assert_allclose(bd([-1.7e300, 1e300]), [-5.1e300, 1e300])


def test_corner_model_tables_are_checked_against_memory_first():
    """n = 20, d = 4000: the dense table would take 31 GiB; refused before allocating."""
    from bderiv import StructuredCorners

    n, d = 20, 4000
    model = StructuredCorners(np.ones(d), np.hstack([0.01 * np.eye(n), np.zeros((n, d - n))]))
    bd = BDerivative(np.hstack([np.eye(n), np.zeros((n, d - n))]), model)
    with pytest.raises(ValueError, match=r"dense table\) take 31.\d GiB, more than the memory"):
        bd.to_dense()
    with pytest.raises(ValueError, match=r"corner points .* more than the memory limit"):
        bd.corner_points()
    with pytest.raises(ValueError, match=r"triangulation .* more than the memory limit"):
        bd.triangulation(max_pieces=10**30)
    # 4 region records of 8 (-1/G) + 8 (G) + 8 (F) float64
    with pytest.raises(ValueError, match=r"take 768 B, more than the memory limit of 64 B"):
        BDerivative(np.eye(2), StructuredCorners(np.ones(2), np.eye(2))).to_dense(
            memory_limit=64)


def test_model_triangulation_counts_pieces_before_building_a_table():
    from bderiv import StructuredCorners

    bd = BDerivative(np.eye(12), StructuredCorners(np.ones(12), 0.01 * np.eye(12)))
    with pytest.raises(ValueError, match=r"12! = 479001600 pieces, more than max_pieces"):
        bd.triangulation()


# --------------------------------------------------------------------------------------
# Flags: True or False only (a truthy string such as "no" would silently mean True)
# --------------------------------------------------------------------------------------
def _flag_calls():
    from bderiv import FlowBDerivative, HybridSystem, examples

    def hybrid(flag):
        return HybridSystem(lambda x, m: x, lambda x: x, n_events=1, dim=1,
                            check_jacobians=flag)

    return {
        "fast_paths": lambda flag: BDerivative(DH2, F2, fast_paths=flag),
        "with_time": lambda flag: FlowBDerivative([np.eye(2)], []).piece(with_time=flag),
        "check_jacobians": hybrid,
        "extended": lambda flag: examples.network(2, extended=flag),
    }


@pytest.mark.parametrize("name", ["fast_paths", "with_time", "check_jacobians", "extended"])
@pytest.mark.parametrize("bad", ["no", "False", 1, 0.0, None, [True]])
def test_flags_refuse_anything_but_bools(name, bad):
    call = _flag_calls()[name]
    with pytest.raises(TypeError, match=rf"{name} must be True or False, got "
                                        rf"{type(bad).__name__} "):
        call(bad)
    call(False), call(np.bool_(False))  # the bools themselves are taken


def test_fast_paths_false_means_no_fast_path():
    V = np.random.default_rng(1).standard_normal((50, 2))
    slow, fast = BDerivative(DH2, F2, fast_paths=False), BDerivative(DH2, F2)
    assert slow._fast_paths is False and fast._fast_paths is True
    expected = np.array([ref_apply(DH2, F2, v) for v in V])
    np.testing.assert_allclose(slow(V), expected, rtol=1e-13, atol=1e-13)


# --------------------------------------------------------------------------------------
# The finiteness test every check uses (a sum where it can), against NumPy's element-wise one
# --------------------------------------------------------------------------------------
#: values whose sums overflow, cancel to NaN, or stay finite next to a non-finite entry
_EDGES = st.sampled_from([np.inf, -np.inf, np.nan, 1.7e308, -1.7e308, 0.0, -0.0, 5e-324])


@given(st.integers(1, 40), st.lists(st.tuples(st.integers(0, 39), _EDGES), max_size=4),
       st.integers(0, 2**32 - 1))
def test_all_finite_is_numpys_elementwise_test(size, edges, seed):
    """Sizes on both sides of the Python sum's limit (32), with infinities of both signs
    (whose sum is NaN), NaNs, and values whose sum overflows among finite ones."""
    arr = np.random.default_rng(seed).standard_normal(size)
    for i, value in edges:
        arr[i % size] = value
    for a in (arr, arr.reshape(1, -1), arr[::2], np.full(5000, arr[0])):
        assert all_finite(a) == bool(np.isfinite(a).all()), a


@pytest.mark.parametrize("value, kwargs, error, message", [
    (True, {"low": 0}, TypeError, "n must be an integer >= 0, got bool True"),
    (3.0, {"low": 0}, TypeError, "n must be an integer >= 0, got float 3.0"),
    (np.int64(0), {"low": 1, "high": 4}, ValueError, r"n must be an integer in \[1, 4\], got 0"),
    (5, {"high": 4}, ValueError, "n must be an integer <= 4, got 5"),
    (4, {"low": 0, "high": 3, "span": "in [0, 4)", "meaning": "an index"}, ValueError,
     r"n must be an integer in \[0, 4\) \(an index\), got 4"),
])
def test_one_integer_check_names_the_range_and_what_came(value, kwargs, error, message):
    with pytest.raises(error, match=f"^{message}$"):
        check_int(value, "n", **kwargs)


def test_one_integer_check_takes_numpy_integers_as_ints():
    got = check_int(np.uint8(3), "n", low=0, high=3)
    assert got == 3 and type(got) is int


@pytest.mark.parametrize("x, message", [
    (1.0, r"x must have shape \(2,\) \(a point\), got a scalar"),
    ([1.0, [2.0, 3.0]], r"x must have shape \(2,\) \(a point\), got a ragged nest "
                        r"\[1.0, \[2.0, 3.0\]\]"),
    (np.zeros((1, 2)), r"x must have shape \(2,\) \(a point\), got shape \(1, 2\)"),
    ([1.0, np.inf], r"x must be finite, but x\[1\] = inf; got \[1.0, inf\]"),
])
def test_one_state_check_names_the_shape_its_meaning_and_what_came(x, message):
    with pytest.raises(ValueError, match=f"^{message}$"):
        check_state(x, 2, "x", meaning="a point")


def test_a_large_array_with_one_bad_entry_gets_a_short_message():
    """The entry that is not finite is named, the array shown by its ends and its count:
    a state of 200,000 or a 1500 x 1500 covariance gave messages of 1 and 11 MB."""
    from bderiv.estimate._checks import check_matrix

    x = np.ones(200_000)
    x[7] = np.inf
    with pytest.raises(ValueError, match=r"x\[7\] = inf; got \[1.0, .*, inf, \.\.\., "
                                         r".*\] \(200000 entries\)$") as err:
        check_state(x, x.size)
    assert len(str(err.value)) < 300
    P = np.ones((1500, 1500))
    P[5, 5] = np.nan
    with pytest.raises(ValueError, match=r"P must be finite, but P\[5, 5\] = nan") as err:
        check_matrix(P, "P", (1500, 1500))
    assert len(str(err.value)) < 300


def test_one_state_check_returns_a_contiguous_float64_copy():
    x = np.arange(4)[::2]
    got = check_state(x, 2)
    assert got.dtype == np.float64 and got.flags.c_contiguous and got.flags.writeable
    y = np.array([1.0, 2.0])
    assert check_state(y, 2) is not y
