"""Exact power-of-two scaling of queries, so that every chain runs mid-range.

M is positively homogeneous, ``M(c v) = c M(v)``, and so are the event times; scaling by a
power of two is exact in floating point (away from overflow and the subnormals). A query
``v`` is run as ``2**-e v`` with ``e`` the binary exponent of its largest entry (largest
entry in [0.5, 1)), and the result is scaled back by ``2**e``: queries whose chain was
representable give the same bits as before, and queries near the ends of the float64
range (event times that would underflow or overflow) give the answer of a mid-range one.
A factor ``2**e`` with ``|e|`` up to 2098 is applied as two representable factors
(``steps.factors``). The lane, plain, own-rates and linear kernels of dense tables scale
each query as they load it (``steps.row_exponent``); the other engines scale a batch with
:func:`scale_rows` and :func:`unscale_rows`, which launch their parallel kernels through
``_drivers.serialised`` (numba's workqueue layer aborts on concurrent launches). A batch of
fewer than :data:`SERIAL_ENTRIES` entries runs serially instead: the same rows in the same
order, so the same bits, without a launch that costs more than the work.
"""

from __future__ import annotations

from numba import njit, prange

from .._limits import SERIAL_ENTRIES
from .._numerics import QUERY_BAND
from ._core import JIT, cached, read_only
from ._drivers import serialised
from .steps import factors, row_exponent


def _small(A):
    return A.shape[0] * A.shape[1] < SERIAL_ENTRIES


def scale_rows(V, out, exps):
    """``out[q] = 2**-e V[q]`` and ``exps[q] = e`` (:func:`row_exponent`), on all threads
    (serially for a small batch)."""
    V = read_only(V)
    if _small(V):
        return _scale_rows_serial(V, out, exps)
    return serialised(_scale_rows, V, out, exps)


def unscale_rows(out, exps, shift):
    """``out[q] *= 2**(exps[q] + shift)`` in place; returns the number of rows that are no
    longer finite (an overflowing result)."""
    if _small(out):
        return _unscale_rows_serial(out, exps, shift)
    return serialised(_unscale_rows, out, exps, shift)


def outside_band(V, exps):
    """``exps[q]``: the :func:`row_exponent` of each row (read only); returns how many
    rows are beyond ``_numerics.QUERY_BAND`` (those need :func:`scale_rows`)."""
    V = read_only(V)
    if _small(V):
        return _outside_band_serial(V, exps)
    return serialised(_outside_band, V, exps)


# Each operation is one row's function (inlined) and two loops over the rows: parallel
# (prange) and serial. Two loops and not one Python function compiled twice: numba's
# cache does not tell compilations of one function with different options apart. The loops
# are called from Python: cached under the sources' digest (``_core.cached``).


@njit(inline="always", **JIT)
def _scale_row(V, out, exps, q):
    e = row_exponent(V, q, V.shape[1])
    exps[q] = e
    a, b = factors(-e)
    for i in range(V.shape[1]):
        out[q, i] = V[q, i] * a * b


@njit(inline="always", **JIT)
def _unscale_row(out, exps, shift, q):
    """Scales row q back; 1 if it is no longer finite, else 0."""
    a, b = factors(exps[q] + shift)
    s = 0.0
    for i in range(out.shape[1]):
        out[q, i] = out[q, i] * a * b
        s += out[q, i] * 0.0
    return 1 if s != s else 0


@njit(inline="always", **JIT)
def _band_row(V, exps, q):
    """Row q's exponent into exps; 1 if it is beyond the band, else 0."""
    e = row_exponent(V, q, V.shape[1])
    exps[q] = e
    return 1 if (e < -QUERY_BAND) | (e > QUERY_BAND) else 0


@cached(parallel=True)
def _scale_rows(V, out, exps):
    for q in prange(V.shape[0]):
        _scale_row(V, out, exps, q)


@cached
def _scale_rows_serial(V, out, exps):
    for q in range(V.shape[0]):
        _scale_row(V, out, exps, q)


@cached(parallel=True)
def _unscale_rows(out, exps, shift):
    bad = 0
    for q in prange(out.shape[0]):
        bad += _unscale_row(out, exps, shift, q)
    return bad


@cached
def _unscale_rows_serial(out, exps, shift):
    bad = 0
    for q in range(out.shape[0]):
        bad += _unscale_row(out, exps, shift, q)
    return bad


@cached(parallel=True)
def _outside_band(V, exps):
    bad = 0
    for q in prange(V.shape[0]):
        bad += _band_row(V, exps, q)
    return bad


@cached
def _outside_band_serial(V, exps):
    bad = 0
    for q in range(V.shape[0]):
        bad += _band_row(V, exps, q)
    return bad
