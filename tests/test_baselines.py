"""The shared benchmark baselines (``bderiv.engine._baselines``) against the oracle and by hand."""

from __future__ import annotations

import time

import numpy as np
import pytest
import reference

from bderiv.engine import _baselines
from bderiv.engine._baselines import (
    benchmark_system,
    best_time,
    blas_operands,
    blas_yardstick,
    numpy_apply,
    random_system,
    useful_flops,
)

SIZES = [(1, 1), (2, 3), (3, 3), (4, 2), (5, 8)]


def test_benchmark_system_is_the_one_the_suite_measured():
    """The dense suite drew its systems from default_rng(1000 n + d) (docs/benchmarks.md)."""
    for n, d in [(2, 2), (4, 8), (8, 8)]:
        for got, want in zip(benchmark_system(n, d),
                             reference.random_system(np.random.default_rng(1000 * n + d), n, d),
                             strict=True):
            np.testing.assert_array_equal(got, want)


@pytest.mark.parametrize(("n", "d"), SIZES)
def test_random_system_keeps_its_promises(n, d):
    spread, dh_scale, f_scale = 0.8, 2.0, 0.5
    Dh, F = random_system(np.random.default_rng(n + d), n, d, spread=spread,
                          dh_scale=dh_scale, f_scale=f_scale, max_cond=100.0)
    assert Dh.shape == (n, d) and F.shape == (2**n, d)
    G = F @ Dh.T
    # G[m, k] = dh_scale f_scale c_m (1 + a_k . b_m) with c_m >= exp(-1.5), |a|, |b| <= spread
    assert G.min() >= dh_scale * f_scale * np.exp(-1.5) * (1 - spread**2) * (1 - 1e-12)
    if n <= d:
        assert np.linalg.cond(Dh) <= 100.0
    else:
        assert np.linalg.matrix_rank(Dh) == d


def test_random_system_refuses_a_spread_outside_0_1():
    with pytest.raises(ValueError, match=r"spread must be in \[0, 1\) .*got 1.0"):
        random_system(np.random.default_rng(0), 2, 2, spread=1.0)


@pytest.mark.parametrize(("n", "d", "m", "chunk"), [(1, 1, 5, 4096), (3, 3, 50, 7),
                                                    (4, 6, 64, 16), (5, 5, 1, 3)])
def test_numpy_apply_matches_the_oracle(n, d, m, chunk):
    """Forward and inverse, chunks that do not divide m: row for row the per-query oracle."""
    Dh, F = random_system(np.random.default_rng(10 * n + d), n, d)
    V = np.random.default_rng(1).standard_normal((m, d))
    W = numpy_apply(Dh, F, F @ Dh.T, V, chunk=chunk)
    want = np.array([reference.ref_apply(Dh, F, v) for v in V])
    reference.assert_maps_close(Dh, F, V, W, want)
    back = numpy_apply(Dh, F, F @ Dh.T, want, inverse=True, chunk=chunk)
    want_back = np.array([reference.ref_inverse(Dh, F, w) for w in want])
    np.testing.assert_allclose(back, want_back, rtol=1e-9, atol=1e-9 * np.abs(V).max())
    np.testing.assert_allclose(back, V, rtol=1e-8, atol=1e-8 * np.abs(V).max())


def test_numpy_apply_on_the_overtaking_example():
    """mathematics.md section 3: event 1 is overtaken; M(u) has -3.8 in component 1, not -2."""
    Dh, F, u, _, w, _ = reference.overtaking_system(4)
    np.testing.assert_allclose(numpy_apply(Dh, F, F @ Dh.T, u[None])[0], w, rtol=1e-14)


def test_useful_flops_by_hand():
    assert useful_flops(3, 5) == 9 + 30


def test_blas_operands_have_the_flops_of_the_queries():
    A, B, flops = blas_operands(8, 16, 10**5)
    N = A.shape[0]
    assert A.shape == B.shape == (N, N) and flops == 2 * N**3
    want = 10**5 * useful_flops(8, 16)
    assert abs(flops - want) <= 2 * 3 * (N + 1) ** 2  # N rounded: 2 N^3 within one step
    C = np.empty_like(A)
    assert blas_yardstick(A, B, C) is C
    np.testing.assert_allclose(C, A @ B)


def test_best_time_keeps_the_best_run_and_warms_up():
    calls = []

    def fn():
        calls.append(None)
        time.sleep(0.5 if len(calls) == 2 else 0.005)  # the first timed run is slow

    t = best_time(fn, 3)
    assert len(calls) == 4  # one warm-up, three timed
    assert 0.005 <= t.wall < 0.25  # not the slow run (margin for a loaded machine)
    assert t.cpu < t.wall  # sleeping takes no CPU time
    calls.clear()
    best_time(fn, 2, warmup=False)
    assert len(calls) == 2


def test_blas_setting_names_the_environment(monkeypatch):
    monkeypatch.setenv("OPENBLAS_NUM_THREADS", "1")
    assert "OPENBLAS_NUM_THREADS=1" in _baselines.blas_setting()
