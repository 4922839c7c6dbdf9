"""What every kernel shares: jit options, the one task driver, and the common steps.

A *block* is an njit function ``block(tables, V, outs, start, stop, inverse)`` that
computes queries ``V[start:stop]`` of one corner representation (``tables``: a named tuple
of its arrays, one class per representation, defined beside the blocks that read it and
built once by its engine) and writes the rows ``start:stop`` of the arrays in the tuple
``outs``. The
arrays of ``outs`` are the per-query ones (row q belongs to ``V[q]``), cut with ``V`` into
launches; ``outs[0]`` is the result whose non-finite rows are counted, and a block may read
a later one as a second per-query input (the tangent vectors of jvp/vjp).
:func:`batch` turns a block into a :class:`Batch`: a serial and a parallel driver around
it. Every query is computed by the same serial code whatever the driver, the thread count
or the split into tasks and launches, so results are bitwise independent of all three.

No validation here: callers pass C-contiguous arrays of consistent shapes. What a kernel
only reads (queries, tables, tangents) it gets read-only (:func:`read_only`,
:func:`frozen_tables`, applied by :class:`Batch` and the Python wrappers): a writeable and a
read-only array are two numba types, and each would compile the kernel once more.
"""

from __future__ import annotations

import math
import os
import pathlib
import threading
import types
import warnings
from typing import NamedTuple

import numba
import numpy as np
from numba import njit, parallel_chunksize, prange

from .. import _numerics
from .._limits import LAUNCH_WORK, PARALLEL_MIN_QUERIES
from .._numerics import INSERTION_SORT_MAX, QUERY_BAND, TASK_QUERIES
from ._cache import harden_all, keyed, sources_digest
from ._simd import bits_float, float_bits

# error_model="numpy": a division by zero gives inf instead of a Python exception path, so
# LLVM vectorises the loops that divide (rates are positive where it matters: checked
# when tables are built, or per region by the model kernels). Not cached: only the
# functions called from Python are (:func:`cached`, the drivers), under a key that
# covers everything compiled into them (see ``_cache``).
JIT = {"error_model": "numpy"}

#: the digest of this package's sources and of the numbers compiled into them
#: (``bderiv._numerics``) that names every cached kernel (``_cache.keyed``)
SOURCES = sources_digest(pathlib.Path(__file__).parent, _numerics.__file__)


def cached(fn=None, *, parallel: bool = False):
    """A kernel called from Python: ``njit(parallel=parallel, **JIT)``, cached on disk
    under :data:`SOURCES`. ``@cached`` or ``@cached(parallel=True)``."""
    if fn is None:
        return lambda f: keyed(f, SOURCES, parallel=parallel, **JIT)
    return keyed(fn, SOURCES, parallel=parallel, **JIT)

#: ``BDERIV_KERNELS=plain`` (read at import) runs the scalar dense kernels instead of the
#: explicit-vector ones (``_simd``): a path any numba target compiles, tested in CI.
_KERNELS = os.environ.get("BDERIV_KERNELS", "").strip().lower()
PLAIN = _KERNELS == "plain"
if _KERNELS not in ("", "plain", "simd"):
    warnings.warn(f"BDERIV_KERNELS={_KERNELS!r} is not 'plain' or 'simd'; using the "
                  f"default (simd) kernels", RuntimeWarning, stacklevel=1)


def read_only(a: np.ndarray) -> np.ndarray:
    """``a`` read-only (a view when it is writeable): the one form in which kernels get the
    arrays they only read, so that each compiles once, not once per writeability."""
    if a.flags.writeable:
        a = a.view()
        a.flags.writeable = False
    return a


def frozen_tables(tables):
    """A named tuple of tables with every array :func:`read_only` (itself when it is)."""
    if not any(isinstance(x, np.ndarray) and x.flags.writeable for x in tables):
        return tables
    return type(tables)(*(read_only(x) if isinstance(x, np.ndarray) else x for x in tables))


def launch_queries(n: int, d: int) -> int:
    """Queries per launch for n events in dimension d (between 2**14 and 2**20)."""
    return min(max(LAUNCH_WORK // (n * (n + d)), 1 << 14), 1 << 20)


#: numba's ``workqueue`` threading layer (its fallback without OpenMP or TBB) aborts the
#: process when two Python threads launch parallel kernels at once; launches are
#: serialised while the layer in use is not known to be thread-safe.
_LAUNCH_LOCK = threading.Lock()
_SAFE_LAYER = [False]


def _note_layer() -> None:
    try:
        _SAFE_LAYER[0] = numba.threading_layer() in ("tbb", "omp")
    except ValueError:  # no parallel kernel has run yet
        pass


def serialised(kernel, *args):
    """``kernel(*args)`` for a parallel kernel outside a :class:`Batch`, under the launch
    lock while the threading layer is not known to be thread-safe."""
    if _SAFE_LAYER[0]:
        return kernel(*args)
    with _LAUNCH_LOCK:
        result = kernel(*args)
        _note_layer()
    return result


@njit(inline="always", **JIT)
def _alone(tables, statics):
    """What a block without static values gets: its tables."""
    return tables


@njit(inline="always", **JIT)
def _paired(tables, statics):
    """What a block compiled for static values gets: ``(tables, statics)``."""
    return tables, statics


# The code of the drivers. ``block``, ``bind`` and ``statics`` are no names of this module:
# :class:`Batch` runs this code with globals of its own, one namespace per block, so each
# driver is a plain function without a closure that numba caches by its own means.
def _serial(tables, V, outs, inverse):
    m = V.shape[0]
    start = m - m  # 0 as an int64, as :func:`_tasks` passes it: a literal 0 would compile
    # the block (and its steps) a second time, for the literal
    block(bind(tables, statics), V, outs, start, m, inverse)  # noqa: F821
    return nonfinite_rows(outs[0], start, m)


def _tasks(tables, V, outs, inverse):
    m = V.shape[0]
    bad = 0
    for task in prange((m + TASK_QUERIES - 1) // TASK_QUERIES):
        start = task * TASK_QUERIES
        stop = min(start + TASK_QUERIES, m)
        block(bind(tables, statics), V, outs, start, stop, inverse)  # noqa: F821
        bad += nonfinite_rows(outs[0], start, stop)  # while the rows are in cache
    return bad


class Batch:
    """Serial and parallel drivers of one block; call ``batch(tables, V, outs, inverse)``.

    ``statics``: a named tuple of ``_simd.static`` values compiled into the drivers; the
    block then gets ``(tables, statics)`` in place of ``tables``. They are constants of
    the drivers, not arguments: numba's parallel loops take no nested tuples, and a type
    of our own in an argument would send every call through Python's typeof
    (docs/benchmarks.md, "Kernel design choices, measured").

    The drivers are cached on disk (``cache=True``) under the block's qualified name, the
    statics' sizes and :data:`SOURCES`; ``cache=False`` for blocks that call a user's
    function (a closure: numba cannot key it across processes).
    """

    def __init__(self, block, cache: bool = True, statics: NamedTuple | None = None):
        namespace = dict(globals(), block=block, statics=statics,
                         bind=_alone if statics is None else _paired)
        if cache:
            sizes = "" if statics is None else "_" + "_".join(str(len(s)) for s in statics)
            name = f"{block.py_func.__module__.rsplit('.', 1)[-1]}.{block.__name__}{sizes}"
            serial = keyed(_serial, SOURCES, f"{name}.serial", namespace, **JIT)
            tasks = keyed(_tasks, SOURCES, f"{name}.tasks", namespace, parallel=True, **JIT)
            harden_all()  # the kernels of the modules imported so far
        else:
            serial = njit(**JIT)(_bound(_serial, namespace))
            tasks = njit(parallel=True, **JIT)(_bound(_tasks, namespace))
        self.block, self.serial, self.tasks = block, serial, tasks

    def __call__(self, tables, V, outs, inverse: bool = False, launch: int = 1 << 16) -> int:
        """Run the block on every row of ``V``; ``launch``: queries per kernel launch.

        Returns the number of rows of ``outs[0]`` with a non-finite entry (an overflow, or a
        query that a model's kernel stopped and left unwritten). ``tables`` and ``V`` are
        run read-only (:func:`frozen_tables`, :func:`read_only`).
        """
        tables, V = frozen_tables(tables), read_only(V)
        m = V.shape[0]
        if m < PARALLEL_MIN_QUERIES:
            return self.serial(tables, V, outs, inverse)
        bad = 0
        for start in range(0, m, launch):
            stop = min(start + launch, m)
            part = tuple(o[start:stop] for o in outs)
            bad += self._launch(tables, V[start:stop], part, inverse)
        return bad

    def _launch(self, tables, V, outs, inverse) -> int:
        # dynamic schedule, one task at a time (set outside the jit: inside it, numba could
        # not cache the function)
        if _SAFE_LAYER[0]:
            with parallel_chunksize(1):
                return self.tasks(tables, V, outs, inverse)
        with _LAUNCH_LOCK, parallel_chunksize(1):
            bad = self.tasks(tables, V, outs, inverse)
            _note_layer()
        return bad


def _bound(fn, namespace):
    """A copy of ``fn`` whose code runs with ``namespace`` as its globals."""
    return types.FunctionType(fn.__code__, namespace, fn.__name__, fn.__defaults__)


def batch(block, cache: bool = True, statics: NamedTuple | None = None) -> Batch:
    """The :class:`Batch` of an njit ``block``."""
    return Batch(block, cache, statics)


# ----------------------------------------------------------------------------------------
# steps shared by the representations
# ----------------------------------------------------------------------------------------
@njit(**JIT)
def nonfinite_rows(a, start, stop):
    """How many of the rows ``a[start:stop]`` hold a NaN or an infinity."""
    bad = 0
    for q in range(start, stop):
        s = 0.0
        for i in range(a.shape[1]):
            s += a[q, i] * 0.0  # 0 for a finite entry, NaN for inf or NaN
        bad += s != s
    return bad


@njit(inline="always", **JIT)
def row_exponent(V, q, d):
    """e with ``max_i |V[q, i]|`` in [2**(e - 1), 2**e) (0 for a zero row), as
    ``math.frexp`` gives it: the query ``2**-e V[q]`` has its largest entry in [0.5, 1)
    (see :mod:`.scaling`). Read from the bits of a normal float (a libm call per query
    cost the lane kernels half their time)."""
    big = 0.0
    for i in range(d):
        big = max(big, abs(V[q, i]))
    biased = (float_bits(big) >> 52) & 0x7FF
    if biased == 0:  # 0 or subnormal
        return math.frexp(big)[1]
    return biased - 1022


@njit(inline="always", **JIT)
def query_exponent(V, q, d):
    """:func:`row_exponent`, or 0 for a row within the query band (``QUERY_BAND``): such
    a row runs as given, which gives the scaled row's bits, scaled."""
    e = row_exponent(V, q, d)
    return 0 if -QUERY_BAND <= e <= QUERY_BAND else e


@njit(inline="always", **JIT)
def _pow2(k):
    """2.0**k for -1022 <= k <= 1023, from its bits."""
    return bits_float((k + 1023) << 52)


@njit(inline="always", **JIT)
def factors(e):
    """Two floats whose product is 2**e, for |e| <= 2044: ``(2**e, 1)`` when 2**e is a
    normal float (one multiplication rounds once, into the subnormals too), else two
    halves (the first product is exact, the second rounds only into the subnormals)."""
    if -1022 <= e <= 1023:
        return _pow2(e), 1.0
    return _pow2(e // 2), _pow2(e - e // 2)


@njit(**JIT)
def impacts(DhT, u, g):
    """g = Dh @ u from DhT = Dh.T (d, n), as axpys over the rows of DhT (vectorises)."""
    d, n = DhT.shape
    for k in range(n):
        g[k] = 0.0
    for i in range(d):
        ui = u[i]
        for k in range(n):
            g[k] += DhT[i, k] * ui


@njit(**JIT)
def own_rate_times(DhT, rate, u, tev):
    """tev[k] = -(Dh u)_k / rate[k]: the event times when no pending rate ever changes."""
    impacts(DhT, u, tev)
    for k in range(tev.shape[0]):
        tev[k] = -tev[k] / rate[k]


@njit(**JIT)
def insertion_order(t, order):
    """order = stable argsort of t (ties keep the smaller event first), by insertion: the
    order of up to a few dozen events (:data:`INSERTION_SORT_MAX`; a dense table's n <= 40)."""
    n = t.shape[0]
    for k in range(n):
        order[k] = k
    # the bound i >= 0 lets LLVM drop the negative-index test of order[i] (a bound passed
    # in, as merge_order's runs have, cost 10-20 % at n = 2..16)
    for j in range(1, n):
        k = order[j]
        v = t[k]
        i = j - 1
        while i >= 0 and t[order[i]] > v:
            order[i + 1] = order[i]
            i -= 1
        order[i + 1] = k


@njit(**JIT)
def merge_order(t, order):
    """order = stable argsort of t (ties keep the smaller event first) for more than
    :data:`INSERTION_SORT_MAX` events: runs of that length by insertion, merged pairwise,
    bottom up (``np.argsort``'s merge sort compiled into the kernels cost seconds of
    compile time each)."""
    n = t.shape[0]
    for k in range(n):
        order[k] = k
    run = INSERTION_SORT_MAX
    for lo in range(0, n, run):
        for j in range(lo + 1, min(lo + run, n)):
            k = order[j]
            v = t[k]
            i = j - 1
            while i >= lo and t[order[i]] > v:
                order[i + 1] = order[i]
                i -= 1
            order[i + 1] = k
    src, dst = order, np.empty(n, dtype=np.int64)
    moved = False
    while run < n:
        for lo in range(0, n, 2 * run):
            mid, hi = min(lo + run, n), min(lo + 2 * run, n)
            i, j = lo, mid
            for o in range(lo, hi):  # the left run first on ties: stable
                if j >= hi or (i < mid and not t[src[i]] > t[src[j]]):
                    dst[o] = src[i]
                    i += 1
                else:
                    dst[o] = src[j]
                    j += 1
        src, dst = dst, src
        moved = not moved
        run *= 2
    if moved:  # the last pass wrote the scratch
        for k in range(n):
            order[k] = src[k]


class OwnRateTables(NamedTuple):
    """The own-rates fast path's event times (any representation)."""

    #: (d, n) the transposed event Jacobian
    DhT: np.ndarray
    #: (n,) the rates of the region the chains start from
    rate: np.ndarray


class LinearTables(NamedTuple):
    """The linear fast path, and the linear stages of a flow map."""

    #: (d, d) M transposed (forwards)
    MT: np.ndarray
    #: (d, d) M^-1 transposed (backwards)
    MinvT: np.ndarray


class ChainCornerTables(NamedTuple):
    """Tangents along chains found beforehand (:func:`_saltations_block`)."""

    #: (n, d) the event Jacobian
    Dh: np.ndarray
    #: (m, n + 1, d): C[q, j] the corner of the region before the (j+1)-th event of query q
    C: np.ndarray
    #: (m, n) int64: the order of each query's chain
    orders: np.ndarray


@njit(**JIT)
def _own_times_block(tables, V, outs, start, stop, inverse):
    """Event times and orders from own rates (any representation's own-rates fast path),
    for up to :data:`INSERTION_SORT_MAX` events."""
    times, orders = outs
    for q in range(start, stop):
        own_rate_times(tables.DhT, tables.rate, V[q], times[q])
        insertion_order(times[q], orders[q])


@njit(**JIT)
def _own_times_many_block(tables, V, outs, start, stop, inverse):
    """:func:`_own_times_block` for more events (a kernel of its own: the merge sort is
    compiled only where it runs)."""
    times, orders = outs
    for q in range(start, stop):
        own_rate_times(tables.DhT, tables.rate, V[q], times[q])
        merge_order(times[q], orders[q])


@njit(**JIT)
def _linear_block(tables, V, outs, start, stop, inverse):
    """out[q] = M @ V[q] (:class:`LinearTables`), as axpys (vectorises), on V[q] scaled by
    a power of two (:func:`query_exponent`: no product under- or overflows unless the
    result does)."""
    MT = tables.MinvT if inverse else tables.MT
    out = outs[0]
    d = MT.shape[0]
    for q in range(start, stop):
        e = query_exponent(V, q, d)
        a, b = factors(-e)
        for r in range(d):
            out[q, r] = 0.0
        for c in range(d):
            vc = V[q, c] * a * b
            for r in range(d):
                out[q, r] += MT[c, r] * vc
        if e != 0:
            a, b = factors(e)
            for r in range(d):
                out[q, r] = out[q, r] * a * b


@njit(**JIT)
def write_times(order, times, q0, pn, order_out, times_out):
    """Rows q0.. of the outputs of ``event_times`` from a group's steps: ``order[p, j]``
    the j-th event of query q0 + p and ``times[p, j]`` its time."""
    for p in range(pn):
        for j in range(order.shape[1]):
            order_out[q0 + p, j] = order[p, j]
            times_out[q0 + p, order[p, j]] = times[p, j]



#: times and orders of an own-rates fast path: :class:`OwnRateTables`, outs (times,
#: orders); ``own_times`` for up to :data:`INSERTION_SORT_MAX` events, ``own_times_many``
#: above (the engine picks by n).
own_times = batch(_own_times_block)
own_times_many = batch(_own_times_many_block)
#: the linear fast path: :class:`LinearTables`, outs (out,).
linear = batch(_linear_block)


@cached
def piece_from_corners(Dh, Fc, order, out):
    """Linear piece S_n ... S_1 of one order (mathematics.md section 4) into ``out`` (d, d).

    ``Fc[j]`` is the corner of the region before the (j+1)-th event (``Fc[n]`` after the
    last). S_j = I + (Fc[j] - Fc[j-1]) Dh[k_j]^T / rate, rate = Dh[k_j] . Fc[j-1]; applied
    to the running product as M += outer(jump, Dh[k_j] @ M / rate).
    """
    n, d = Dh.shape
    out[:, :] = 0.0
    for i in range(d):
        out[i, i] = 1.0
    row = np.empty(d)
    for j in range(n):
        k = order[j]
        rate = 0.0
        for i in range(d):
            rate += Dh[k, i] * Fc[j, i]
        for c in range(d):
            s = 0.0
            for i in range(d):
                s += Dh[k, i] * out[i, c]
            row[c] = s / rate
        for r in range(d):
            jump = Fc[j + 1, r] - Fc[j, r]
            for c in range(d):
                out[r, c] += jump * row[c]


# ----------------------------------------------------------------------------------------
# tangent maps: one saltation factor at a time, along a query's chain
# ----------------------------------------------------------------------------------------
@njit(**JIT)
def saltation_step(y, Dh, k, Fc, before, after, rate, transpose):
    """y <- S y, or S^T y when ``transpose``, in place (mathematics.md section 4).

    S = I + (Fc[after] - Fc[before]) Dh[k]^T / rate, the factor of event k leaving the
    region whose corner is ``Fc[before]`` (``rate`` = Dh[k] . Fc[before] > 0). O(d).
    """
    d = y.shape[0]
    c = 0.0
    if transpose:  # S^T y = y + Dh[k] (jump . y) / rate
        for i in range(d):
            c += (Fc[after, i] - Fc[before, i]) * y[i]
        c /= rate
        for i in range(d):
            y[i] += c * Dh[k, i]
    else:  # S y = y + jump (Dh[k] . y) / rate
        for i in range(d):
            c += Dh[k, i] * y[i]
        c /= rate
        for i in range(d):
            y[i] += c * (Fc[after, i] - Fc[before, i])


@njit(**JIT)
def _saltations_block(tables, V, outs, start, stop, transpose):
    """out[q] = M_sigma T[q] (or M_sigma^T T[q]) from the corners along each chain
    (:class:`ChainCornerTables`); ``outs = (out, T)``. The transpose runs the factors
    backwards: M^T = S_1^T ... S_n^T.
    """
    Dh, C, orders = tables.Dh, tables.C, tables.orders
    out, T = outs
    n, d = Dh.shape
    for q in range(start, stop):
        y = out[q]
        for i in range(d):
            y[i] = T[q, i]
        Cq = C[q]
        for s in range(n):
            j = n - 1 - s if transpose else s
            k = orders[q, j]
            rate = 0.0
            for i in range(d):
                rate += Dh[k, i] * Cq[j, i]
            saltation_step(y, Dh, k, Cq, j, j + 1, rate, transpose)


#: tangents from chain corners: :class:`ChainCornerTables`, outs (out, T).
saltations = batch(_saltations_block)
