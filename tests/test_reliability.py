"""Reliability of the evaluation core (issue 9, items 1, 2, 3, 6, 8 and 9).

Each test reproduces a failure of the code before the engine core was rewritten (a wrong
fast path, ``out=`` aliasing its input, unwritten corners, overflow returned as inf/NaN,
an abort with numba's workqueue layer, Ctrl-C unseen for seconds) and checks what must
happen instead. Answers are checked against the oracle of ``reference.py`` with the
chain-scaled tolerance of ``chain_tolerance.py``. The last section holds a bug found by the
fuzz test (silent loss of accuracy with subnormal rates, now refused as underflow).
"""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap

import numba
import numpy as np
import pytest
from chain_tolerance import assert_matches_oracle
from fuzz_families import WAVY, own_rate_table, structured_corners
from reference import random_system, ref_apply, ref_corner_points, ref_inverse, tie_point

from bderiv import BDerivative, CornerFunction, StructuredCorners


def table_of(corners, n):
    """The (2**n, d) table of a function of (..., n) flags."""
    return corners(((np.arange(2**n)[:, None] >> np.arange(n)) & 1).astype(float))


def check_all_paths_agree(Dh, F, model=None, V=None):
    """The default map and the selection (``fast_paths=False``) agree with the oracle on
    ``apply``, ``inverse`` and ``event_times`` (``F``: the table, ``model``: what
    ``BDerivative`` gets, default ``F``); returns the default map."""
    given = F if model is None else model
    bd = BDerivative(Dh, given)
    assert_matches_oracle(bd, Dh, F, V)
    assert_matches_oracle(BDerivative(Dh, given, fast_paths=False), Dh, F, V)
    return bd


# ----------------------------------------------------------------------------------------
# item 1: a fast path only where it gives the selection's answer
# ----------------------------------------------------------------------------------------
def test_issue_repro_dense_own_rates():
    Dh = np.array([[1.0, 0, 0], [0, 1.0, 0]])
    F = np.array([[1, 0.01, 0], [20, 0.019, 0], [1, 20, 0], [20, 20, 1e10]])
    u = np.array([-1, -0.02, 0])
    bd = check_all_paths_agree(Dh, F, V=np.array([u, -u[[1, 0, 2]], [-1, -3, 2]]))
    # the selection by hand: event 0 at t = 1, then h_1 = -0.02 - 0.009 at rate 0.019
    np.testing.assert_allclose(bd(u), [-20, -20 * 0.029 / 0.019, -1e10 * 0.029 / 0.019],
                               rtol=1e-12)


def test_issue_repro_structured_linear():
    F0, A = np.array([1, 0.01, 0]), np.array([[0, 0.009, 1e10], [0, 1, 0]])
    none = np.empty((0, 2), dtype=np.int64)
    F = table_of(structured_corners(F0, A, none, np.empty((0, 3))), 2)
    V = np.array([[-1, -0.02, 0], [-0.02, -1, 0], [-1, -3, 2]])
    check_all_paths_agree(np.eye(2, 3), F, StructuredCorners(F0, A), V)


def adversarial_tables():
    """(name, Dh, exact table, table with a real dependence that a tolerance relative to
    the whole table, ``1e-12 max|F| |Dh[k]|``, hid). Two events; bit k of the row: event
    k happened; event 0's rate goes 1 -> 2 when it happens, event 1's 2 -> 1."""
    bits = ((np.arange(4)[:, None] >> np.arange(2)) & 1).astype(float)
    own = np.column_stack([1 + bits[:, 0], 2 - bits[:, 1]])
    out = []
    # one huge entry on a column no event sees; event 0's rate 1e-5 faster after event 1
    F = np.column_stack([own, np.where(bits[:, 0] * bits[:, 1], 1e8, 0.0)])
    G = F.copy()
    G[0b10, 0] *= 1 + 1e-5
    out.append(("huge entry", np.eye(2, 3), F, G))
    # tiny rates: event 0's are 1e-8 of event 1's; 1e-5 faster after event 1
    F = np.column_stack([1e-8 * own[:, 0], own[:, 1]])
    G = F.copy()
    G[0b10, 0] *= 1 + 1e-5
    out.append(("tiny rates", np.eye(2), F, G))
    # mixed scales: event 0's normal is 1e8 long, its column of F 1e-8
    Dh = np.array([[1e8, 0.0, 0.0], [0.0, 1.0, 0.0]])
    F = np.column_stack([1e-8 * own[:, 0], own[:, 1], 1 + bits @ [1.0, -0.5]])
    G = F.copy()
    G[0b10, 0] *= 1 + 1e-4
    out.append(("mixed scales", Dh, F, G))
    # own rates, additive but for 1e-5 in one entry, hidden by a huge constant column:
    # the linear path would be taken
    F = np.column_stack([own, bits @ [3.0, -1.0], np.full(4, 1e8)])
    G = F.copy()
    G[0b11, 2] += 1e-5
    out.append(("additive broken", np.eye(2, 4), F, G))
    return out


@pytest.mark.parametrize("name, Dh, exact, hidden", adversarial_tables(),
                         ids=[t[0] for t in adversarial_tables()])
def test_adversarial_fast_path_tables(name, Dh, exact, hidden):
    rng = np.random.default_rng(12)
    V = rng.standard_normal((40, Dh.shape[1])) * np.abs(exact).max(axis=0)
    V[:20, :2] = -np.abs(V[:20, :2])  # both events ahead: every order is met
    bd = check_all_paths_agree(Dh, hidden, V=V)
    if name != "additive broken":
        assert bd.fast_path is None
    else:  # own rates still hold; additivity does not
        assert bd.fast_path == "own-rates"
    # the exact table still gets its fast path: the detection is not merely switched off
    fast = check_all_paths_agree(Dh, exact, V=V)
    assert fast.fast_path is not None


# ----------------------------------------------------------------------------------------
# item 2: out= may be the input or overlap it, on every path
# ----------------------------------------------------------------------------------------
def alias_systems():
    rng = np.random.default_rng(21)
    Dh_g, F_g = random_system(rng, 3, 4)
    Dh_o, F_o = own_rate_table(rng, 3, 4, additive=False)
    Dh_l, F_l = own_rate_table(rng, 3, 4, additive=True)
    Dh_s = np.eye(3, 4) + 0.1 * rng.uniform(-1, 1, (3, 4))
    pairs = np.array([[0, 1], [1, 2]])
    general = StructuredCorners(np.ones(4), 0.2 * rng.uniform(-1, 1, (3, 4)), pairs,
                                0.1 * rng.uniform(-1, 1, (2, 4)))
    pinv = np.linalg.pinv(Dh_s)
    ker = np.eye(4) - pinv @ Dh_s
    F0, A = pinv @ np.ones(3), (pinv * [0.5, -0.3, 0.8]).T
    own = StructuredCorners(F0, A, pairs, rng.standard_normal((2, 4)) @ ker.T)
    return {
        "dense general": (Dh_g, F_g, None),
        "dense own-rates": (Dh_o, F_o, "own-rates"),
        "dense linear": (Dh_l, F_l, "linear"),
        "structured general": (Dh_s, general, None),
        "structured own-rates": (Dh_s, own, "own-rates"),
        "structured linear": (Dh_s, StructuredCorners(F0, A), "linear"),
        "corner function": (rng.uniform(0.2, 1.0, (3, 4)), WAVY, None),
    }


ALIAS = alias_systems()


def layouts(V):
    """(name, input, out) over one buffer: the same array, rows shifted either way, and
    entries shifted by one (an overlap that is not row-aligned)."""
    m, d = V.shape
    same = V.copy()
    yield "same", same, same
    down = np.empty((m + 1, d))
    down[:-1] = V
    yield "out one row after", down[:-1], down[1:]
    up = np.empty((m + 1, d))
    up[1:] = V
    yield "out one row before", up[1:], up[:-1]
    flat = np.empty(m * d + 1)
    flat[:-1] = V.ravel()
    yield "out one entry after", flat[:-1].reshape(m, d), flat[1:].reshape(m, d)


@pytest.mark.parametrize("path", list(ALIAS))
def test_out_aliasing_input(path):
    Dh, F, fast = ALIAS[path]
    bd = BDerivative(Dh, F)
    assert bd.fast_path == fast
    rng = np.random.default_rng(22)
    for m, chunk in ((7, 3), (3000, 1024)):  # serial and parallel kernels
        V = -np.abs(rng.standard_normal((m, Dh.shape[1])))
        for method in (bd.apply, bd.inverse):
            fresh = method(V.copy())
            for chunk_size in (None, chunk):
                for name, inp, out in layouts(V):
                    res = method(inp, out=out, chunk_size=chunk_size)
                    assert res is out
                    np.testing.assert_array_equal(
                        out, fresh, err_msg=f"{method.__name__}, {name}, m={m}, "
                                            f"chunk_size={chunk_size}")


# ----------------------------------------------------------------------------------------
# item 3: a corner function that leaves entries unwritten or writes non-finite ones
# ----------------------------------------------------------------------------------------
@numba.njit
def patchy(happened, out):
    """Fine everywhere but in region 0b10 (event 1 alone), where the last entry is left
    unwritten (d = 2), NaN (d = 3) or inf (d = 4)."""
    d = out.shape[0]
    for i in range(d - 1):
        out[i] = 1.0 + 0.5 * happened[i % 2]
    if happened[1] == 1 and happened[0] == 0:
        if d == 3:
            out[d - 1] = np.nan
        elif d == 4:
            out[d - 1] = np.inf
    else:
        out[d - 1] = 1.0


def patchy_table(d):
    F = np.ones((4, d))
    for mask in range(4):
        for i in range(d - 1):
            F[mask, i] = 1.0 + 0.5 * ((mask >> (i % 2)) & 1)
    F[0b10, -1] = np.nan  # never read on the chains that are compared
    return F


@pytest.mark.parametrize("d, what", [(2, "unwritten"), (3, "NaN"), (4, "inf")])
def test_corner_function_with_bad_entries(d, what):
    Dh = np.eye(2, d)
    bd = BDerivative(Dh, CornerFunction(patchy))
    good = np.zeros((3, d))
    good[:, :2] = [[-1, -3], [-0.5, -2], [0, -1]]  # event 0 first: region 0b10 unseen
    assert_matches_oracle(bd, Dh, patchy_table(d), good)
    bad = good.copy()
    bad[1, :2] = [-3, -1]  # event 1 first: region 0b10
    region = r"non-finite.*region mask 0b10 .*V\[1\]"
    for _ in range(5):  # deterministic, whatever memory the scratch arrays get
        junk = np.full((1000, d), -np.inf)
        with pytest.raises(ValueError, match=region):
            bd(bad)
        del junk
        with pytest.raises(ValueError, match=region):
            bd.event_times(bad)
    # the inverse leaves the full region through 0b10 when event 0 happened last
    W = np.zeros((2, d))
    W[:, :2] = [[-1, -3], [-3, -1]]
    np.testing.assert_allclose(bd.inverse(W[0]), ref_inverse(Dh, patchy_table(d), W[0]))
    with pytest.raises(ValueError, match=r"non-finite.*region mask 0b10 .*W\[1\] \(inverse"):
        bd.inverse(W)
    big = np.tile(good[0], (3000, 1))
    big[1234, :2] = [-3, -1]
    with pytest.raises(ValueError, match=r"non-finite.*region mask 0b10 .*V\[1234\]"):
        bd(big)  # the parallel kernel


# ----------------------------------------------------------------------------------------
# item 6: results that overflow are refused, naming the row
# ----------------------------------------------------------------------------------------
def test_overflowing_results_are_refused():
    Dh = np.array([[1.0, 0.0]])
    slow_after = BDerivative(Dh, np.array([[1.0, 0.0], [1e-10, 0.0]]))
    W = np.array([[1.0, 2.0], [3.0, 4.0], [1e300, 0.0]])
    with pytest.raises(ValueError, match=r"W\[2\].*overflow"):
        slow_after.inverse(W)
    np.testing.assert_allclose(slow_after.inverse(W[:2]),
                               [ref_inverse(Dh, slow_after.F, w) for w in W[:2]])
    big_jump = BDerivative(Dh, np.array([[1.0, 1e8], [1.0, 0.0]]))
    with pytest.raises(ValueError, match=r"V\[1\].*overflow"):
        big_jump(np.array([[-1.0, 0.0], [-1e301, 0.0]]))
    with pytest.raises(ValueError, match=r"V\[1\].*overflow"):
        big_jump(np.array([[-1.0, 0.0], [-1e301, 0.0]]), chunk_size=1)
    slow = BDerivative(Dh, np.array([[1e-10, 0.0], [1e-10, 0.0]]))
    with pytest.raises(ValueError, match=r"V\[0\].*overflow"):
        slow.event_times(np.array([[-1e300, 0.0]]))
    model = BDerivative(Dh, StructuredCorners([1.0, 1e8], [[0.0, -1e8]]))
    with pytest.raises(ValueError, match=r"V\[0\].*overflow"):
        model(np.array([[-1e301, 0.0]]))


def test_overflowing_times_of_both_signs_are_refused():
    """Event times +inf and -inf in one row: refused like any overflow (no NaN warning)."""
    bd = BDerivative(np.eye(2), np.full((4, 2), 2.0**-600))
    with pytest.raises(ValueError, match=r"V\[0\].*overflow"):
        bd.event_times(np.array([[-1e300, 1e300]]))


def test_overflowing_rates_are_scaled_at_construction():
    """Rates of 1e400 (once refused): M is invariant under Dh -> s Dh, F -> c F, so the
    tables are scaled by powers of two at build and the map is that of the scaled-down
    tables, by the oracle."""
    Dh = np.array([[1e200, 0.0]])
    F = np.array([[1e200, 0.0], [2e200, 1.0]])
    V = np.array([[-1.0, -2.0], [-3.0, 0.5]])
    assert_matches_oracle(BDerivative(Dh, F), Dh / 1e200, F / 1e200, V, times=False)


def test_huge_event_normals():
    """Dh ~ 1e160 and F ~ 1e-160: the rates are 1, and so is the map (it is invariant
    under Dh -> s Dh, F -> F / s). The row norms of Dh (for the grazing test) must not
    overflow: unscaled, every rate was called grazing relative to inf (found by the fuzz)."""
    Dh = np.array([[1e160, 0.0], [0.0, 1e160]])
    F = np.array([[1.0, 1.0], [2.0, 1.0], [1.0, 2.0], [2.0, 2.0]]) * 1e-160
    bd = BDerivative(Dh, F)
    V = np.array([[-1.0, -2.0]])
    assert_matches_oracle(bd, Dh / 1e160, F * 1e160, V, times=False)  # times scale


# ----------------------------------------------------------------------------------------
# items 8 and 9: threads with numba's workqueue layer; Ctrl-C during a long call
# ----------------------------------------------------------------------------------------
def run_python(code: str, timeout: float, **env) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", textwrap.dedent(code)], capture_output=True,
                          text=True, timeout=timeout, env={**os.environ, **env})


def test_two_threads_with_the_workqueue_layer():
    """Two Python threads calling one map with large batches (the parallel kernels) under
    the workqueue layer: the old code aborted the process (SIGABRT)."""
    code = """
        import threading
        import numba
        import numpy as np
        from bderiv import BDerivative, StructuredCorners

        rng = np.random.default_rng(0)
        Dh = np.eye(4) + 0.2 * rng.uniform(-1, 1, (4, 4))
        F = rng.uniform(0.5, 1.5, (16, 4)) @ np.linalg.inv(Dh).T   # rates in (0.5, 1.5)*4
        maps = [BDerivative(Dh, F), BDerivative(np.eye(4), StructuredCorners(np.ones(4),
                                                                             np.eye(4)))]
        V = rng.standard_normal((100_000, 4))
        expected = [bd(V) for bd in maps]
        assert numba.threading_layer() == "workqueue", numba.threading_layer()
        errors, same = [], []

        def work():
            try:
                for _ in range(3):
                    for bd, want in zip(maps, expected):
                        same.append(np.array_equal(bd(V), want))
                        same.append(np.array_equal(bd.inverse(want), bd.inverse(want)))
            except BaseException as exc:
                errors.append(repr(exc))

        threads = [threading.Thread(target=work) for _ in range(2)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        assert not errors, errors
        assert len(same) == 24 and all(same), same
        print("ok")
    """
    proc = run_python(code, timeout=240, NUMBA_THREADING_LAYER="workqueue")
    assert proc.returncode == 0 and proc.stdout.strip() == "ok", (
        f"exit status {proc.returncode}\n{proc.stdout}\n{proc.stderr[-3000:]}"
    )


@pytest.mark.skipif(sys.platform == "win32", reason="POSIX signals")
def test_ctrl_c_during_a_long_call():
    """SIGINT half a second into a call that would take >= 5 s raises KeyboardInterrupt
    within a second or two (the batch is cut into launches; the old code saw the
    interrupt only when the whole kernel ended)."""
    code = """
        import os, signal, subprocess, time
        import numpy as np
        from bderiv import BDerivative, StructuredCorners

        # as an interactive session: a background job (and its children) ignores SIGINT
        signal.signal(signal.SIGINT, signal.default_int_handler)
        rng = np.random.default_rng(1)
        n, d = 32, 8
        Dh = np.abs(rng.standard_normal((n, d))) + 0.5
        pairs = np.array([(i, (i + 1) % n) for i in range(n)])
        model = StructuredCorners(np.ones(d), 0.01 * rng.standard_normal((n, d)), pairs,
                                  0.01 * rng.standard_normal((n, d)))
        bd = BDerivative(Dh, model)
        probe = rng.standard_normal((1 << 16, d))
        bd(probe[:2048])
        t0 = time.perf_counter()
        bd(probe)
        per_query = (time.perf_counter() - t0) / probe.shape[0]
        m = min(int(6.0 / per_query), 1 << 23)
        V = np.resize(probe, (m, d))
        # a separate process sends SIGINT: a thread of ours would wait for the GIL
        subprocess.Popen(["sh", "-c", f"sleep 0.5; kill -INT {os.getpid()}"])
        t0 = time.perf_counter()
        try:
            bd(V)
            print("finished", time.perf_counter() - t0, m * per_query)
        except KeyboardInterrupt:
            print("interrupted", time.perf_counter() - t0 - 0.5, m * per_query)
    """
    proc = run_python(code, timeout=120)
    assert proc.returncode == 0, proc.stderr[-3000:]
    outcome, latency, full = proc.stdout.split()
    assert float(full) >= 5.0, proc.stdout  # the call would have lasted >= 5 s
    assert outcome == "interrupted", proc.stdout
    assert float(latency) < 1.5, f"KeyboardInterrupt {float(latency):.2f} s after SIGINT"


# ----------------------------------------------------------------------------------------
# found by the fuzz test: silent loss of accuracy near the bottom of the float range
# ----------------------------------------------------------------------------------------
def test_underflowing_rates():
    """Dh and F scaled by 2**-520 and 2**-540 (exact, normal numbers): the rates are
    subnormal (~1e-320) and keep a few digits only (the answer was off by ~1e-4, silently).
    M is invariant under this scaling, so the answer must be the unscaled one, or a clear
    ValueError naming the underflow."""
    Dh, F = random_system(np.random.default_rng(3), 3, 3)
    V = np.random.default_rng(4).standard_normal((5, 3))
    try:
        bd = BDerivative(np.ldexp(Dh, -520), np.ldexp(F, -540))
        bd(V)
    except ValueError as exc:
        assert "underflow" in str(exc), str(exc)
        return
    assert_matches_oracle(bd, Dh, F, V, times=False)  # times scale by 2**540


# ----------------------------------------------------------------------------------------
# "Also / grazing": what the transversality tolerance accepts is accurate
# ----------------------------------------------------------------------------------------
def longdouble_error(bd, Dh, F, V):
    """Largest error of ``bd(V)`` against the oracle run in long double (11 more bits on
    x86: it resolves float64 rounding), relative to the largest |entry| of the answer."""
    got = bd(V)
    worst = 0.0
    for u, w in zip(np.atleast_2d(V), np.atleast_2d(got), strict=True):
        ref = ref_apply(Dh, F, u, dtype=np.longdouble)
        worst = max(worst, float(np.abs(w - ref).max() / np.abs(ref).max()))
    return worst


#: a region where the flow nearly stops (|F| = 4e-14) among regions of size 1: its rates
#: pass the per-region test (relative to its own |F|), and the tie u = (-1, -1, 0) leaves
#: a gap of rounding size that the slow region stretches 2.5e13 times.
SLOW_DH = np.eye(2, 3)
SLOW_F = np.array([[1, 1, 0], [4e-14, 4e-14, 0], [1, 1, 0], [1, 1, 0.0]])


LONG_DOUBLE = pytest.mark.skipif(np.finfo(np.longdouble).nmant <= 52,
                                 reason="np.longdouble is float64 here: no finer oracle")


def test_a_region_where_the_flow_nearly_stops_is_refused():
    with pytest.raises(ValueError, match=(
            r"ill-conditioned event times: the rate of event 1 is G\[0, 1\] = 1 in region "
            r"mask 0b00 but G\[1, 1\] = 4e-14 in region mask 0b01 .* 2\.5e\+13 times slower, "
            r"more than 1 / transversality_tol = 1e\+09")):
        BDerivative(SLOW_DH, SLOW_F)
    # why: evaluated in float64 at the tie, the selection (here the oracle's) is off by
    # ~1e-3 (the issue's 0.3 %), which is rounding noise stretched 2.5e13 times
    if np.finfo(np.longdouble).nmant > 52:  # a finer oracle exists on this platform
        u = np.array([-1.0, -1.0, 0.0])
        noise = (ref_apply(SLOW_DH, SLOW_F, u)
                 - ref_apply(SLOW_DH, SLOW_F, u, dtype=np.longdouble))
        assert np.abs(noise).max() > 1e-4


def test_one_event_slowing_down_step_by_step_is_refused():
    """Two successive slow-downs by 1e5 each (whole regions, so the per-region test
    passes) would pass a test of neighbouring regions, but compound to 1e10 for event 2
    on the chain (0, 1, 2)."""
    Dh = np.eye(3)
    F = np.ones((8, 3))
    F[0b001] = 1e-5
    F[0b011] = 1e-10
    with pytest.raises(ValueError, match=r"rate of event 2 .* 1e\+10 times slower"):
        BDerivative(Dh, F)
    BDerivative(Dh, F, transversality_tol=1e-11)  # a caller may accept it


@LONG_DOUBLE
@pytest.mark.parametrize("slow", [1e3, 1e6, 1e8])
def test_accepted_slow_regions_keep_ties_accurate(slow):
    """The documented guarantee: with every event's rates within a factor ``s`` over the
    regions where it is pending, M(u) is computed to about n eps s of its scale, ties
    included (random systems with one region slowed down by ``s``, queries on the
    boundaries between pieces, where the stretched gaps are of rounding size)."""
    rng = np.random.default_rng(int(np.log10(slow)))
    n = 4
    worst = 0.0
    for _ in range(5):
        Dh, F = random_system(rng, n, n)
        F[rng.integers(1, 2**n - 1)] /= slow
        bd = BDerivative(Dh, F)
        U = ref_corner_points(Dh, F)[0]
        V = [tie_point(U, rng.permutation(n), int(rng.integers(1, n)), rng)[0]
             for _ in range(20)]
        worst = max(worst, longdouble_error(bd, Dh, F, np.array(V)) / bd.rate_spread)
    assert worst < n * np.finfo(float).eps * 100
