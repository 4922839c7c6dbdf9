"""Exact power-of-two scaling of queries, so that every chain runs mid-range.

M is positively homogeneous, ``M(c v) = c M(v)``, and so are the event times; scaling by a
power of two is exact in floating point (away from overflow and the subnormals). A query
``v`` is run as ``2**-e v`` with ``e`` the binary exponent of its largest entry (largest
entry in [0.5, 1)), and the result is scaled back by ``2**e``: queries whose chain was
representable give the same bits as before, and queries near the ends of the float64
range (event times that would underflow or overflow) give the answer of a mid-range one.
A factor ``2**e`` with ``|e|`` up to 2098 is applied as two representable factors
(``_core.factors``). The lane, plain, own-rates and linear kernels of dense tables scale
each query as they load it (``_core.row_exponent``); the other engines scale a batch with
:func:`scale_rows` and :func:`unscale_rows`, which launch their parallel kernels through
``_core.serialised`` (numba's workqueue layer aborts on concurrent launches).
"""

from __future__ import annotations

from numba import njit, prange

from ._core import QUERY_BAND, factors, row_exponent, serialised


def scale_rows(V, out, exps):
    """``out[q] = 2**-e V[q]`` and ``exps[q] = e`` (:func:`row_exponent`), on all threads."""
    return serialised(_scale_rows, V, out, exps)


def unscale_rows(out, exps, shift):
    """``out[q] *= 2**(exps[q] + shift)`` in place; returns the number of rows that are no
    longer finite (an overflowing result)."""
    return serialised(_unscale_rows, out, exps, shift)


def outside_band(V, exps):
    """``exps[q]``: the :func:`row_exponent` of each row (read only); returns how many
    rows are beyond ``_core.QUERY_BAND`` (those need :func:`scale_rows`)."""
    return serialised(_outside_band, V, exps)


@njit(parallel=True, cache=True, error_model="numpy")
def _scale_rows(V, out, exps):
    """``out[q] = 2**-e V[q]`` and ``exps[q] = e`` (:func:`row_exponent`), on all threads."""
    d = V.shape[1]
    for q in prange(V.shape[0]):
        e = row_exponent(V, q, d)
        exps[q] = e
        a, b = factors(-e)
        for i in range(d):
            out[q, i] = V[q, i] * a * b


@njit(parallel=True, cache=True, error_model="numpy")
def _unscale_rows(out, exps, shift):
    """``out[q] *= 2**(exps[q] + shift)`` in place; returns the number of rows that are no
    longer finite (an overflowing result)."""
    d = out.shape[1]
    bad = 0
    for q in prange(out.shape[0]):
        a, b = factors(exps[q] + shift)
        s = 0.0
        for i in range(d):
            out[q, i] = out[q, i] * a * b
            s += out[q, i] * 0.0
        bad += s != s
    return bad


@njit(parallel=True, cache=True, error_model="numpy")
def _outside_band(V, exps):
    """``exps[q]``: the :func:`row_exponent` of each row (read only); returns how many
    rows are beyond ``_core.QUERY_BAND`` (those need :func:`scale_rows`)."""
    d = V.shape[1]
    bad = 0
    for q in prange(V.shape[0]):
        e = row_exponent(V, q, d)
        exps[q] = e
        bad += (e < -QUERY_BAND) | (e > QUERY_BAND)
    return bad
