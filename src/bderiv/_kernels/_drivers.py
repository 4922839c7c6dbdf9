"""The drivers that run a block over a batch of queries (:class:`Batch`).

A *block* is an njit function ``block(tables, V, outs, start, stop, inverse)`` that
computes queries ``V[start:stop]`` of one corner representation (``tables``: a named tuple
of its arrays, one class per representation, defined beside the blocks that read it and
built once by its engine) and writes the rows ``start:stop`` of the arrays in the tuple
``outs``. The arrays of ``outs`` are the per-query ones (row q belongs to ``V[q]``), cut
with ``V`` into launches; ``outs[0]`` is the result whose non-finite rows are counted, and
a block may read a later one as a second per-query input (the tangent vectors of
jvp/vjp). :func:`batch` turns a block into a :class:`Batch`: a serial driver with the block
inlined, and the parallel driver all blocks share, whose tasks call the serial one through
a trampoline's address (each block's code is compiled once, in its serial driver). Every query is
computed by the same serial code whatever the driver, the thread count or the split into
tasks and launches, so results are bitwise independent of all three.

Launches of parallel kernels are serialised while numba's threading layer is not known to
be thread-safe (:func:`serialised`).
"""

from __future__ import annotations

import hashlib
import threading
import time
from typing import NamedTuple

import numba
from numba import njit, parallel_chunksize, prange
from numba.core import cgutils, errors
from numba.extending import intrinsic

from .._limits import LAUNCH_SECONDS, PARALLEL_MIN_QUERIES, sized_by_time
from .._numerics import TASK_QUERIES
from ._cache import harden_all, keyed
from ._core import JIT, SOURCES, cached, frozen_tables, read_only
from ._pointer import call_at, call_at_or

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


# The serial driver's code. ``block``, ``bind`` and ``statics`` are no names of this
# module: :class:`Batch` runs this code with globals of its own, one namespace per block,
# so each serial driver is a plain function without a closure that numba caches by its own
# means.
def _serial(tables, V, outs, start, stop, inverse):
    block(bind(tables, statics), V, outs, start, stop, inverse)  # noqa: F821
    return nonfinite_rows(outs[0], start, stop)  # while the rows are in cache


@intrinsic
def _run_at(typingctx, address, args):
    """``f(*args) -> int64`` called at ``address``: the address of a function compiled for
    the types of ``args`` (numba's call of a compiled function, its exceptions propagated,
    through a pointer): the parallel driver from its launcher, a serial driver from its
    trampoline. Typed from ``args`` alone, so that one caller serves every callee of those
    types; :func:`_address_of` checks that the function at the address returns an int64."""
    if not isinstance(args, numba.types.BaseTuple):
        raise errors.TypingError(f"_run_at: the arguments as a tuple, got {args}")
    argtypes = tuple(args.types)

    def codegen(context, builder, sig, llargs):
        values = cgutils.unpack_tuple(builder, llargs[1], len(argtypes))
        return call_at(context, builder, llargs[0], numba.int64, argtypes, values)

    return numba.int64(address, args), codegen


@intrinsic
def _pack(typingctx, args):
    """The address of a copy of the tuple ``args`` in the caller's stack frame, valid while
    the caller runs (the arrays in it are the caller's references: it holds them)."""
    if not isinstance(args, numba.types.BaseTuple):
        raise errors.TypingError(f"_pack: a tuple, got {args}")

    def codegen(context, builder, sig, llargs):
        slot = cgutils.alloca_once_value(builder, llargs[0])
        return builder.ptrtoint(slot, context.get_value_type(numba.int64))

    return numba.int64(args), codegen


def _unowned(context, builder, kind, value):
    """``value`` with each array's owner (its meminfo and parent) set to null, as numba's
    parallel loops pass arrays to their threads: the threads' reference counting is then
    a no-op, not atomic operations of every thread on the same counters (which took a
    third of the speed on two threads)."""
    if isinstance(kind, numba.types.Array):
        array = context.make_array(kind)(context, builder, value=value)
        array.meminfo = cgutils.get_null_value(array.meminfo.type)
        array.parent = cgutils.get_null_value(array.parent.type)
        return array._getvalue()
    if isinstance(kind, numba.types.BaseTuple):
        for i, item in enumerate(kind.types):
            member = _unowned(context, builder, item, builder.extract_value(value, i))
            value = builder.insert_value(value, member, i)
        return value
    if isinstance(kind, (numba.types.Number, numba.types.Boolean)):
        return value
    raise errors.TypingError(f"_unpack: arrays, numbers and tuples of them, got {kind}")


@intrinsic
def _unpack(typingctx, address, kind):
    """The tuple :func:`_pack` stored at ``address``, its arrays without an owner (the
    packing caller holds them while it runs); ``kind``: its type, a global of the caller."""
    if not isinstance(kind, numba.types.TypeRef):
        raise errors.TypingError(f"_unpack: the tuple's type as a global, got {kind}")
    packed = kind.instance_type

    def codegen(context, builder, sig, llargs):
        pointer = builder.inttoptr(llargs[0], context.get_value_type(packed).as_pointer())
        return _unowned(context, builder, packed, builder.load(pointer))

    return packed(address, kind), codegen


#: what a task adds to the parallel driver's count when its serial driver raised: the
#: count is then negative (a launch has at most 2**20 rows, so at most 2**12 tasks)
FAILED = -(1 << 40)


@intrinsic
def _try_at(typingctx, address, args):
    """:func:`_run_at`, giving :data:`FAILED` where the function raises (the exception is
    dropped: ``_kernels/_pointer.call_at_or``)."""
    if not isinstance(args, numba.types.BaseTuple):
        raise errors.TypingError(f"_try_at: the arguments as a tuple, got {args}")
    argtypes = tuple(args.types)

    def codegen(context, builder, sig, llargs):
        values = cgutils.unpack_tuple(builder, llargs[1], len(argtypes))
        return call_at_or(context, builder, llargs[0], numba.int64, argtypes, values, FAILED)

    return numba.int64(address, args), codegen


def _tasks(m, packed, trampoline):
    bad = 0
    for task in prange((m + TASK_QUERIES - 1) // TASK_QUERIES):
        start = task * TASK_QUERIES
        stop = min(start + TASK_QUERIES, m)
        bad += _try_at(trampoline, (packed, start, stop))
    return bad


#: the parallel driver of every block (:class:`Batch`), compiled once: its arguments are
#: int64 (the rows, the address of the launch's packed arguments, the address of the
#: trampoline that unpacks them for the serial driver), whatever the block and the types
_TASKS = keyed(_tasks, SOURCES, "_tasks", parallel=True, **JIT)

#: what :data:`_TASKS` is compiled for
_TASKS_ARGS = (numba.int64, numba.int64, numba.int64)


def _launch(tables, V, outs, inverse, serial, trampoline, tasks):
    return _run_at(tasks, (V.shape[0], _pack((tables, V, outs, inverse, serial)), trampoline))


#: the launcher: packs the launch's arguments and runs :data:`_TASKS` at ``tasks`` on them
#: (a few lines compiled per type of tables and outputs, where the parallel driver itself
#: would be compiled again per type)
_LAUNCH = keyed(_launch, SOURCES, "_launch", **JIT)


# The trampoline's code: ``PACKED`` is no name of this module (:func:`_trampoline` runs it
# with globals of its own, one per type of the packed arguments).
def _trampoline_code(packed, start, stop):
    tables, V, outs, inverse, serial = _unpack(packed, PACKED)  # noqa: F821
    return _run_at(serial, (tables, V, outs, start, stop, inverse))


#: the trampolines made so far: packed type -> (dispatcher, address); each is kept for
#: the process's life, since the drivers keep its address
TRAMPOLINES: dict = {}
_TRAMPOLINES_LOCK = threading.Lock()


def _trampoline(packed_type) -> int:
    """The address of the trampoline for arguments of ``packed_type`` (the tuple of
    :func:`_launch`'s ``tables, V, outs, inverse, serial``): it unpacks them and calls the
    serial driver on its task's rows. Cached on disk under the type's digest; made once
    per type and process, under a lock (two threads' dispatchers for one type: the one
    not kept would be freed under its address)."""
    with _TRAMPOLINES_LOCK:
        if packed_type not in TRAMPOLINES:
            digest = hashlib.sha256(str(packed_type).encode()).hexdigest()[:16]
            trampoline = keyed(_trampoline_code, SOURCES, f"_trampoline_{digest}",
                               dict(globals(), PACKED=packed_type), **JIT)
            TRAMPOLINES[packed_type] = trampoline, _address_of(trampoline, _TASKS_ARGS)
        return TRAMPOLINES[packed_type][1]


def _check_packable(kind, block: str) -> None:
    """A TypeError unless the launch's arguments are arrays, numbers, booleans and tuples
    of them, what :func:`_unpack` hands the threads without an owner (another value
    numba counts references of would be freed under them)."""
    if isinstance(kind, numba.types.BaseTuple):
        for item in kind.types:
            _check_packable(item, block)
    elif not isinstance(kind, (numba.types.Array, numba.types.Number, numba.types.Boolean)):
        raise TypeError(f"the parallel driver of {block}: its tables and outputs must be "
                        f"arrays, numbers and tuples of them, got a {kind}")


def _address_of(dispatcher, argtypes) -> int:
    """The address of ``dispatcher`` compiled (or loaded) for ``argtypes``, which must
    return an int64 (what :func:`_run_at` calls)."""
    dispatcher.compile(argtypes)
    compiled = dispatcher.overloads[argtypes]
    if compiled.signature.return_type != numba.int64:
        raise TypeError(f"{dispatcher.py_func.__qualname__} returns "
                        f"{compiled.signature.return_type}, not int64")
    return compiled.library.get_pointer_to_function(compiled.fndesc.llvm_func_name)


_TASKS_AT: list = []


def _tasks_address() -> int:
    """The address of :data:`_TASKS` (compiled, or loaded, at the first parallel launch)."""
    if not _TASKS_AT:
        _TASKS_AT.append(_address_of(_TASKS, _TASKS_ARGS))
    return _TASKS_AT[0]


class Batch:
    """Serial and parallel drivers of one block; call ``batch(tables, V, outs, inverse)``.

    The serial driver runs the block on rows ``start:stop`` and counts the non-finite
    ones; the block is inlined into it (numba's ``inline="always"``: its code is compiled
    there only, once). The parallel driver (one for all blocks and types, :data:`_TASKS`,
    started by the launcher :data:`_LAUNCH`) runs the serial one on each task's rows
    through a trampoline, both called through their addresses (:meth:`_address`): numba
    would otherwise link the serial driver's code into its caller and optimise and
    generate it again there. A task whose serial driver raised counts :data:`FAILED`, and
    the launch's rows then run on the serial driver, which raises the error here.

    ``statics``: a named tuple of ``_simd.static`` values compiled into the serial driver;
    the block then gets ``(tables, statics)`` in place of ``tables``. They are constants
    of the driver, not arguments: a type of our own in an argument would send every call
    through Python's typeof (docs/benchmarks.md, "Kernel design choices, measured").

    The serial driver is cached on disk under the block's qualified name, the statics'
    sizes and :data:`SOURCES` (a block that calls a user's function calls it through an
    address, as :mod:`.function` does, so that it is cached too).
    """

    def __init__(self, block, statics: NamedTuple | None = None):
        inlined = njit(inline="always", **JIT)(block.py_func)
        namespace = dict(globals(), block=inlined, statics=statics,
                         bind=_alone if statics is None else _paired)
        sizes = "" if statics is None else "_" + "_".join(str(len(s)) for s in statics)
        name = f"{block.py_func.__module__.rsplit('.', 1)[-1]}.{block.__name__}{sizes}"
        serial = keyed(_serial, SOURCES, f"{name}.serial", namespace, **JIT)
        harden_all()  # the kernels of the modules imported so far
        self.block, self.serial = block, serial
        self._addresses = {}

    def _address(self, tables, V, outs, inverse) -> tuple[int, int]:
        """The addresses of the serial driver compiled for the types the parallel one calls
        it with, and of the trampoline for them (each compiled, or loaded from the disk
        cache, the first time)."""
        typeof = self.serial.typeof_pyval
        kinds = (typeof(tables), typeof(V), typeof(outs))
        addresses = self._addresses.get(kinds)
        if addresses is None:
            serial = _address_of(self.serial, (*kinds, numba.int64, numba.int64,
                                               numba.boolean))
            # the type of the tuple _launch packs: (tables, V, outs, bool, address)
            packed = typeof((tables, V, outs, True, serial))
            _check_packable(packed, self.block.__name__)
            addresses = self._addresses[kinds] = serial, _trampoline(packed)
        return addresses

    def __call__(self, tables, V, outs, inverse: bool = False, launch: int = 1 << 16,
                 timed: bool = False) -> int:
        """Run the block on every row of ``V``; ``launch``: queries per kernel launch (with
        ``timed``, at most: the block's cost per query is not known, as where it calls a
        user's function, so the first launch takes ``PARALLEL_MIN_QUERIES`` and each next
        one as many as the last ran in ``LAUNCH_SECONDS``: Ctrl-C is seen between them).

        Returns the number of rows of ``outs[0]`` with a non-finite entry (an overflow, or a
        query that a model's kernel stopped and left unwritten). ``tables`` and ``V`` are
        run read-only (:func:`frozen_tables`, :func:`read_only`). Every row is computed by
        the same serial code, so the launches never change the bits.
        """
        tables, V = frozen_tables(tables), read_only(V)
        m = V.shape[0]
        if m < PARALLEL_MIN_QUERIES:
            return self.serial(tables, V, outs, 0, m, inverse)
        bad, start, size = 0, 0, min(launch, PARALLEL_MIN_QUERIES) if timed else launch
        while start < m:
            stop = min(start + size, m)
            part = tuple(o[start:stop] for o in outs)
            began = time.perf_counter() if timed else 0.0
            bad += self._launch(tables, V[start:stop], part, inverse)
            if timed:  # (a first launch that compiled is short and soon outgrown)
                size = sized_by_time(stop - start, time.perf_counter() - began,
                                     LAUNCH_SECONDS, PARALLEL_MIN_QUERIES, launch)
            start = stop
        return bad

    def _launch(self, tables, V, outs, inverse) -> int:
        serial, trampoline = self._address(tables, V, outs, inverse)
        bad = self._tasks_at(tables, V, outs, bool(inverse), serial, trampoline)
        if bad >= 0:
            return bad
        # a task's serial driver raised (a user's corner function): the tasks report it
        # by :data:`FAILED`, since numba's parallel loop loses an exception raised on a
        # worker thread; the serial driver, run on the launch's rows here, raises it as it
        # is (or, if it does not raise again, computes every row)
        return self.serial(tables, V, outs, 0, V.shape[0], inverse)

    def _tasks_at(self, tables, V, outs, inverse, serial, trampoline) -> int:
        # dynamic schedule, one task at a time (set outside the jit: inside it, numba could
        # not cache the function)
        tasks = _tasks_address()
        if _SAFE_LAYER[0]:
            with parallel_chunksize(1):
                return _LAUNCH(tables, V, outs, inverse, serial, trampoline, tasks)
        with _LAUNCH_LOCK, parallel_chunksize(1):
            bad = _LAUNCH(tables, V, outs, inverse, serial, trampoline, tasks)
            _note_layer()
        return bad


def batch(block, statics: NamedTuple | None = None) -> Batch:
    """The :class:`Batch` of an njit ``block``."""
    return Batch(block, statics)


# ----------------------------------------------------------------------------------------
# the drivers' count of bad rows
# ----------------------------------------------------------------------------------------
@cached
def nonfinite_rows(a, start, stop):
    """How many of the rows ``a[start:stop]`` hold a NaN or an infinity."""
    bad = 0
    for q in range(start, stop):
        s = 0.0
        for i in range(a.shape[1]):
            s += a[q, i] * 0.0  # 0 for a finite entry, NaN for inf or NaN
        bad += s != s
    return bad
