"""Blocks for corners computed by a user's njit function ``func`` (tables: a
:class:`FunctionTables`).

``func(happened, out)`` writes the corner of the region ``happened`` (uint8 flags,
``happened[k] = 1`` iff event k happened) into ``out`` (d,); it is evaluated on the n + 1
regions of each query's chain and the rates are recomputed as ``Dh @ F[region]``.

The blocks call ``func`` through an address (:func:`entry`: ``func`` compiled behind a
one-line wrapper of a fixed signature), so they are compiled once and cached on disk like
the other blocks, and a new corner function compiles only itself and its wrapper. Called
directly (numba's first-class function, or a closure per function), the function was part
of the blocks' signature: numba compiled the chain and both drivers again for every
function and process and could not cache them (design.md, "Corner functions through
their address, the lanes' position width").
"""

from __future__ import annotations

import functools
from types import FunctionType
from typing import NamedTuple

import numpy as np
from numba import carray, njit, types
from numba.core import errors
from numba.extending import intrinsic

from .._limits import COMPILE_BYTES
from ._cache import check_address_space
from ._core import JIT, cached
from ._drivers import batch
from ._pointer import call_at
from .selection import advance, earliest, pending_times, retire
from .steps import impacts

#: status of a query whose chain met a corner with a non-finite (or unwritten) entry.
NON_FINITE = -2

#: the types ``func`` is compiled for: ``happened`` and ``out``, C-contiguous, writeable
HAPPENED = types.Array(types.uint8, 1, "C")
OUT = types.Array(types.float64, 1, "C")
#: the types of the wrapper the kernels call (:func:`entry`)
_ENTRY_ARGS = (types.CPointer(types.uint8), types.CPointer(types.float64), types.int64,
               types.int64)


class FunctionTables(NamedTuple):
    """What the blocks read: the event Jacobian and where the corner function is."""

    #: (d, n) the transposed event Jacobian
    DhT: np.ndarray
    #: (1,) int64: the address of the function's :func:`entry`
    at: np.ndarray


def _entry(happened, out, n, d):
    """The wrapper's code (:func:`entry` gives it ``func`` and ``carray`` as globals)."""
    func(carray(happened, n), carray(out, d))  # noqa: F821


@functools.lru_cache(maxsize=64)
def entry(func):
    """``(wrapper, address)``: ``func`` compiled for ``(happened, out)`` (:data:`HAPPENED`,
    :data:`OUT`) and called by an njit wrapper of raw pointers and sizes,
    ``wrapper(happened_data, out_data, n, d)``, and the wrapper's address, which the
    kernels call (:func:`_call`). The address is valid while ``wrapper`` lives: hold it as
    long as the address is used. Raises numba's error (naming ``func``) if ``func`` cannot
    be compiled so, and ``MemoryError`` where the address space left is too small to
    compile (LLVM would abort the process).

    Pointers and not arrays: numba passes an array as seven values and counts references
    to its owner around the call, and a view made for the call (``out[i]``) is a new
    reference; the corner of a region then cost 14 ns against 6 ns inlined (n = d = 8),
    with the rows' pointers 5 ns. The wrapper's globals name ``func``'s module, not this
    one: it is the user's code, compiled per process (not cached), not a kernel of the
    package."""
    name = getattr(func, "__name__", repr(func))
    check_address_space(COMPILE_BYTES, f"compiling the corner function {name}")
    func.compile((HAPPENED, OUT))
    module = getattr(getattr(func, "py_func", None), "__module__", None) or "__main__"
    namespace = {"func": func, "carray": carray, "__name__": module}
    wrapper = njit(**JIT)(FunctionType(_entry.__code__, namespace, f"{name}_entry"))
    wrapper.compile(_ENTRY_ARGS)
    compiled = wrapper.overloads[_ENTRY_ARGS]
    return wrapper, compiled.library.get_pointer_to_function(compiled.fndesc.llvm_func_name)


def tables(Dh: np.ndarray, address: int) -> FunctionTables:
    """The :class:`FunctionTables` of ``Dh`` (n, d) and an :func:`entry` address."""
    return FunctionTables(np.ascontiguousarray(Dh.T, dtype=np.float64),
                          np.array([address], dtype=np.int64))


def _rows(a, index, name, dtype):
    """Refuse (numba's ``TypingError``) what :func:`_call` cannot pass: ``a`` must be a
    writeable C-contiguous array of ``dtype`` with 1 or 2 dimensions, ``index`` an integer,
    the literal 0 for a 1-D ``a``."""
    if (not isinstance(a, types.Array) or a.layout != "C" or a.ndim not in (1, 2)
            or not a.mutable or a.dtype != dtype):
        raise errors.TypingError(f"_call: {name} must be a writeable C-contiguous {dtype} "
                                 f"array of 1 or 2 dimensions, got {a}")
    if not isinstance(index, types.Integer) or (
            a.ndim == 1 and getattr(index, "literal_value", None) != 0):
        raise errors.TypingError(f"_call: the row of {name} must be an integer (the "
                                 f"literal 0 for a 1-D array), got {index}")


@intrinsic
def _call(typingctx, at, happened, i, out, j):
    """``func(happened[i], out[j])`` (``happened`` and ``out`` 2-D) or ``func(happened,
    out)`` (1-D, ``i`` and ``j`` the literal 0) for the function whose :func:`entry` is at
    ``at``; an exception it raises propagates. Rows by pointer: no array views made for the
    call; like numba's own indexing, the rows are not bounds-checked."""
    if at != types.int64:
        raise errors.TypingError(f"_call: the address must be an int64, got {at}")
    _rows(happened, i, "happened", types.uint8), _rows(out, j, "out", types.float64)

    def row(context, builder, arytype, value, index):
        a = context.make_array(arytype)(context, builder, value)
        size = builder.extract_value(a.shape, arytype.ndim - 1)
        if arytype.ndim == 1:
            return a.data, size
        return builder.gep(a.data, [builder.mul(index, size)]), size

    def codegen(context, builder, sig, args):
        index_i = context.cast(builder, args[2], i, types.int64)
        index_j = context.cast(builder, args[4], j, types.int64)
        h, n = row(context, builder, happened, args[1], index_i)
        o, d = row(context, builder, out, args[3], index_j)
        call_at(context, builder, args[0], types.none, _ENTRY_ARGS, (h, o, n, d))
        return context.get_dummy_value()

    return types.none(at, happened, i, out, j), codegen


@cached
def _region(at, DhT, hap, C, c, R):
    """C[c] = F[hap] and R[c] = Dh @ F[hap]; returns -1, NON_FINITE when ``func`` left an
    entry unwritten or non-finite (the row is NaN-filled before the call), or the first
    event whose rate is <= 0."""
    f, r = C[c], R[c]
    f[:] = np.nan
    _call(at, hap, 0, C, c)
    for i in range(f.shape[0]):
        if not np.isfinite(f[i]):
            return NON_FINITE
    impacts(DhT, f, r)
    for k in range(r.shape[0]):
        if not r[k] > 0.0:
            return k
    return -1


@cached
def chain(at, DhT, u, inverse, x, g, tau, R, C, hap, tev, order):
    """One query; x = M(u) (or M^-1(u)), ``tev[k]`` the time of event k, ``order``.

    The steps of :mod:`.selection` on row 0 of ``g`` and ``tau`` (1, n), with the rates
    and corners of the current and the next region in the rows of ``R`` (2, n) and ``C``
    (2, d), taken in turn; on switching, the position moves by t (F[before] - F[after]).
    Returns -1, or (the chain stops there, ``hap`` its region) the event whose rate is
    <= 0 or NON_FINITE.
    """
    d, n = DhT.shape
    impacts(DhT, u, g[0])
    for k in range(n):
        hap[k] = 1 if inverse else 0
    for i in range(d):
        x[i] = u[i]
    now = np.int64(0)  # not a literal: _region compiles once for both rows
    bad = _region(at, DhT, hap, C, now, R)
    if bad != -1:
        return bad
    for j in range(n):
        pending_times(g, 0, R, now, tau)
        kb, best = earliest(tau, 0, inverse)
        retire(g, 0, kb, inverse)
        hap[kb] = 0 if inverse else 1
        tev[kb] = best
        order[n - 1 - j if inverse else j] = kb
        bad = _region(at, DhT, hap, C, 1 - now, R)
        if bad != -1:
            return bad
        for i in range(d):
            x[i] += best * (C[now, i] - C[1 - now, i])
        advance(g, 0, best, R, now, 1 - now)
        now = 1 - now
    return -1


@cached
def _scratch(n, d):
    """x, g, tau, R, C, hap, tev, order: the per-query work arrays of :func:`chain`."""
    return (np.empty(d), np.empty((1, n)), np.empty((1, n)), np.empty((2, n)),
            np.empty((2, d)), np.zeros(n, dtype=np.uint8), np.empty(n),
            np.empty(n, dtype=np.int64))


@njit(**JIT)
def _apply_block(tables, V, outs, start, stop, inverse):
    DhT, at = tables.DhT, tables.at[0]
    out, status = outs
    d, n = DhT.shape
    x, g, tau, R, C, hap, tev, order = _scratch(n, d)
    for q in range(start, stop):
        status[q] = chain(at, DhT, V[q], inverse, x, g, tau, R, C, hap, tev, order)
        for i in range(d):
            out[q, i] = x[i]


@njit(**JIT)
def _times_block(tables, V, outs, start, stop, inverse):
    DhT, at = tables.DhT, tables.at[0]
    times, orders, status = outs
    d, n = DhT.shape
    x, g, tau, R, C, hap, _, _ = _scratch(n, d)
    for q in range(start, stop):
        status[q] = chain(at, DhT, V[q], np.bool_(False), x, g, tau, R, C, hap, times[q],
                          orders[q])


#: M(V) or M^-1(V): outs (out, status).
apply = batch(_apply_block)
#: event times and orders: outs (times, orders, status).
event_times = batch(_times_block)


@cached
def diagnose(at, DhT, u, inverse, hap, r):
    """Re-run one query; returns the bad event (or -1), ``hap`` and ``r`` at that point."""
    d, n = DhT.shape
    x, g, tau, R, C, _, tev, order = _scratch(n, d)
    bad = chain(at, DhT, u, inverse, x, g, tau, R, C, hap, tev, order)
    if bad >= 0:  # rates of the region where the chain stopped
        _region(at, DhT, hap, C, np.int64(0), R)
        for k in range(n):
            r[k] = R[0, k]
    return bad


@cached
def _corners(at, happened, out):
    for i in range(happened.shape[0]):
        _call(at, happened, i, out, i)


def corners(func, happened: np.ndarray, out: np.ndarray) -> None:
    """out[i] = F[happened[i]] for each row of 0/1 flags (tables, chains, checks):
    ``happened`` (m, n) of 0/1 (``func`` gets a private uint8 copy: it may write it) and
    ``out`` (m, d), a writeable C-contiguous float64 array."""
    if not (isinstance(out, np.ndarray) and out.dtype == np.float64 and out.ndim == 2
            and out.flags.c_contiguous and out.flags.writeable):
        raise TypeError(f"out must be a writeable C-contiguous float64 array (m, d), got "
                        f"{type(out).__name__} {getattr(out, 'dtype', '')} "
                        f"{getattr(out, 'shape', '')}")
    wrapper, at = entry(func)  # wrapper held while its address is in use
    _corners(at, np.array(happened, dtype=np.uint8, order="C", ndmin=2), out)
