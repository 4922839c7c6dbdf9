"""Every kernel variant (``tests/variants.py``: each representation at its test sizes, each
operation) against ``tests/reference.py``, and the invariants every variant keeps: a query
gives the same bits alone (the serial driver) and in a parallel batch, and the tangent
maps are the transposes of each other and agree with the map itself (``jvp(V, V) = M(V)``,
positive homogeneity)."""

from __future__ import annotations

import functools

import numpy as np
import pytest
from variants import OPERATIONS, REPRESENTATIONS, cases

import bderiv

#: queries per batch: enough for the parallel driver (``_core.PARALLEL_MIN_QUERIES``)
QUERIES = 1500
#: every STRIDE-th query is checked against the oracle; the first ALONE are run alone too
STRIDE, ALONE = 50, 40


@functools.cache
def system(rep, n, d):
    return REPRESENTATIONS[rep].build(bderiv, n, d, seed=7)


def queries(n, d):
    rng = np.random.default_rng(100 * n + d)
    return rng.standard_normal((QUERIES, d)), rng.standard_normal((QUERIES, d))


@pytest.mark.parametrize("op", list(OPERATIONS))
@pytest.mark.parametrize("rep, n, d", cases())
def test_every_variant_matches_the_oracle(rep, n, d, op):
    s, (V, T) = system(rep, n, d), queries(n, d)
    operation = OPERATIONS[op]
    batch = operation.run(s.bd, V, T)
    alone = operation.run(s.bd, V[:ALONE], T[:ALONE])
    for q in range(ALONE):
        for a, b in zip(np.atleast_1d(operation.row(alone, q)),
                        np.atleast_1d(operation.row(batch, q)), strict=True):
            np.testing.assert_array_equal(a, b, err_msg=f"query {q} alone and in a batch")
    for q in range(0, QUERIES, STRIDE):
        operation.check(s, V[q], T[q], operation.row(batch, q))


@pytest.mark.parametrize("rep, n, d", cases())
def test_tangent_maps_are_transposes_and_agree_with_the_map(rep, n, d):
    s, (V, T) = system(rep, n, d), queries(n, d)
    W = np.random.default_rng(3).standard_normal(V.shape)
    J, Jt = s.bd.jvp(V, T), s.bd.vjp(V, W)
    # <W, M T> == <M^T W, T> row by row
    lhs, rhs = np.einsum("ij,ij->i", W, J), np.einsum("ij,ij->i", Jt, T)
    size = np.abs(W) @ np.abs(J).max(axis=0) + np.abs(Jt) @ np.abs(T).max(axis=0)
    assert np.all(np.abs(lhs - rhs) <= 1e-12 * size)
    # positive homogeneity: the piece a query selects maps it to M(V)
    np.testing.assert_allclose(s.bd.jvp(V, V), s.bd(V), rtol=1e-11,
                               atol=1e-11 * np.abs(V).max())
