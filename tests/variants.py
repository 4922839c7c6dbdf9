"""The kernel variants, listed once: what builds a case of each representation, and what
each operation computes and is checked against (the way numbagg lists its functions).

``tests/test_variants.py`` runs every operation of every representation at its test sizes
against ``tests/reference.py``; ``benchmarks/ab.py`` times every one at its benchmark
sizes. A new kernel variant is tested and benchmarked by adding one line to
:data:`REPRESENTATIONS` (a new way to give the corners) or to :data:`OPERATIONS` (a new
kernel of every representation).

A builder ``build(package, n, d, seed)`` takes the package to build with (``bderiv``, or
the other checkout of ``benchmarks/ab.py``) and returns a :class:`System`: the map and
what the oracle needs, the dense table of its corners and its resets.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

import numpy as np
from fuzz_families import own_rate_table, structured_corners
from reference import (
    assert_maps_close,
    random_reset_system,
    ref_apply,
    ref_event_times,
    ref_inverse,
    ref_piece,
    ref_reset_flow,
    ref_reset_piece,
)

from bderiv.engine._baselines import benchmark_system


class System(NamedTuple):
    """A map and its oracle's data."""

    #: the map (a ``BDerivative`` of the package it was built with)
    bd: object
    #: (n, d) the event Jacobian
    Dh: np.ndarray
    #: (2**n, d) the corners as a dense table
    F: np.ndarray
    #: (2**n, n, d, d) the resets, or None
    R: np.ndarray | None = None


def _regions(n):
    return ((np.arange(2**n)[:, None] >> np.arange(n)) & 1).astype(float)


def dense(package, n, d, seed=0):
    """A dense table (``_baselines.benchmark_system``), no fast path: the lane kernels up
    to d = 64, the plain kernels beyond."""
    Dh, F = benchmark_system(n, d, seed)
    return System(package.BDerivative(Dh, F, fast_paths=False), Dh, F)


def own_rates(package, n, d, seed=0, additive=False):
    """A dense table whose rates change only with their own event: the own-rates fast
    path (``additive``: the linear one)."""
    Dh, F = own_rate_table(np.random.default_rng(seed), n, d, additive)
    bd = package.BDerivative(Dh, F)
    assert bd.fast_path == ("linear" if additive else "own-rates"), bd.fast_path
    return System(bd, Dh, F)


def linear(package, n, d, seed=0):
    """The linear fast path (every corner additive in its events' bits)."""
    return own_rates(package, n, d, seed, additive=True)


def structured(package, n, d, seed=0):
    """Structured corners like a multi-contact system (``benchmarks/test_bench_corners``'s
    contact system, two pairs per event): transversal by construction, with orders that
    change along the chains."""
    rng = np.random.default_rng(seed)
    Dh = np.eye(n, d) + 0.3 / n * rng.uniform(-1, 1, (n, d))
    F0 = np.linalg.lstsq(Dh, np.ones(n), rcond=None)[0]
    A = 0.4 / n * rng.uniform(-1, 1, (n, d))
    i = rng.integers(0, n, n)
    pairs = np.stack([i, (i + rng.integers(1, max(n, 2), n)) % n], axis=1)
    pairs = pairs[pairs[:, 0] != pairs[:, 1]]
    B = 0.2 / n * rng.uniform(-1, 1, (len(pairs), d))
    model = package.StructuredCorners(F0, A, pairs, B)
    F = structured_corners(F0, A, pairs, B)(_regions(n)) if n <= 16 else None
    return System(package.BDerivative(Dh, model, fast_paths=False), Dh, F)


def function(package, n, d, seed=0):
    """A corner function (an njit function reading a dense table): the function kernels."""
    from numba import njit

    Dh, F = benchmark_system(n, d, seed)

    @njit
    def corners(happened, out):
        b = 0
        for k in range(happened.shape[0]):
            b |= np.int64(happened[k]) << k
        for i in range(out.shape[0]):
            out[i] = F[b, i]

    return System(package.BDerivative(Dh, package.CornerFunction(corners), fast_paths=False),
                  Dh, F)


def resets(package, n, d, seed=0):
    """A dense table with resets that commute and keep the surfaces
    (``reference.random_reset_system``): the reset kernels."""
    Dh, F, R = random_reset_system(np.random.default_rng(seed), n, d)
    return System(package.BDerivative(Dh, F, resets=R), Dh, F, R)


class Representation(NamedTuple):
    """One way to give the corners, and the sizes it is run at."""

    #: ``build(package, n, d, seed) -> System``
    build: Callable
    #: (n, d) of the tests
    tests: tuple
    #: benchmark case name -> (n, d, queries)
    bench: dict


#: every representation's kernels (the lanes are the dense default up to d = 64; the plain
#: blocks run beyond, and everywhere under ``BDERIV_KERNELS=plain``)
REPRESENTATIONS = {
    "lanes": Representation(dense, ((3, 3), (4, 4), (2, 5), (5, 3), (9, 17)),
                            {"dense8": (8, 8, 10**6), "dense16": (16, 16, 10**6),
                             "dense20": (20, 20, 2 * 10**5)}),
    "plain": Representation(dense, ((3, 66),), {"plain8": (8, 72, 2 * 10**5)}),
    "own-rates": Representation(own_rates, ((4, 5),), {"own8": (8, 9, 10**6)}),
    "linear": Representation(linear, ((4, 5),), {"linear8": (8, 8, 10**6)}),
    "structured": Representation(structured, ((4, 6), (7, 9)),
                                 {"structured128": (128, 128, 1 << 15)}),
    "function": Representation(function, ((3, 4),), {"function8": (8, 8, 1 << 16)}),
    "resets": Representation(resets, ((3, 5), (4, 6)), {"resets6": (6, 8, 1 << 17)}),
}


# ----------------------------------------------------------------------------------------
# operations: what each runs, and its oracle for one query
# ----------------------------------------------------------------------------------------
def _forward(s: System, v):
    """(M(v), times, order) by the oracle."""
    if s.R is not None:
        return ref_reset_flow(s.Dh, s.F, s.R, v)
    times, order = ref_event_times(s.Dh, s.F, v)
    return ref_apply(s.Dh, s.F, v), times, order


def _piece(s: System, v):
    order = _forward(s, v)[2]
    return (ref_piece(s.Dh, s.F, order) if s.R is None
            else ref_reset_piece(s.Dh, s.F, s.R, order))


def check_apply(s: System, v, t, got):
    assert_maps_close(s.Dh, s.F, v[None], got[None], _forward(s, v)[0][None])


def check_inverse(s: System, w, t, got):
    """The oracle's M maps the result back onto the query (and, without resets, the
    oracle's inverse gives it)."""
    if s.R is None:
        assert_maps_close(s.Dh, s.F, w[None], got[None], ref_inverse(s.Dh, s.F, w)[None])
    assert_maps_close(s.Dh, s.F, got[None], w[None], _forward(s, got)[0][None])


def check_times(s: System, v, t, got):
    times, order = got
    _, ref_times, ref_order = _forward(s, v)
    np.testing.assert_array_equal(order, ref_order)
    np.testing.assert_allclose(times, ref_times, rtol=1e-9,
                               atol=1e-9 * np.abs(ref_times).max())


def check_jvp(s: System, v, t, got):
    P = _piece(s, v)
    np.testing.assert_allclose(got, P @ t, rtol=0, atol=1e-12 * np.abs(P).max() * np.abs(t).max())


def check_vjp(s: System, v, t, got):
    P = _piece(s, v)
    np.testing.assert_allclose(got, P.T @ t, rtol=0,
                               atol=1e-12 * np.abs(P).max() * np.abs(t).max())


class Operation(NamedTuple):
    """One kernel of every representation."""

    #: ``run(bd, V, T)``: the batch result (V the queries, T tangent rows of the same shape)
    run: Callable
    #: ``check(system, v, t, result)`` for one query against ``tests/reference.py``
    check: Callable
    #: rows of the result of one query (``result[q]``, or a tuple of arrays)
    row: Callable = lambda result, q: result[q]


OPERATIONS = {
    "apply": Operation(lambda bd, V, T: bd(V), check_apply),
    "inverse": Operation(lambda bd, V, T: bd.inverse(V), check_inverse),
    "times": Operation(lambda bd, V, T: bd.event_times(V), check_times,
                       lambda result, q: (result[0][q], result[1][q])),
    "jvp": Operation(lambda bd, V, T: bd.jvp(V, T), check_jvp),
    "vjp": Operation(lambda bd, V, T: bd.vjp(V, T), check_vjp),
}


def cases():
    """(representation name, n, d) of every test size, for ``pytest.mark.parametrize``."""
    return [(name, n, d) for name, rep in REPRESENTATIONS.items() for n, d in rep.tests]


def bench_cases():
    """Benchmark case name -> (representation name, n, d, queries)."""
    return {case: (name, *size) for name, rep in REPRESENTATIONS.items()
            for case, size in rep.bench.items()}
