"""The on-disk cache of the compiled kernels: checked, and never fatal.

Numba keeps compiled code in an index file and data files (pickles) per function, in
``__pycache__`` beside the sources or under ``NUMBA_CACHE_DIR``. Read as numba reads them,
a truncated or garbled file raises ``UnpicklingError``/``EOFError`` from every first call in
every process, and a flipped bit inside the machine code may crash the process. Here:

- :class:`CheckedCache` (every cached kernel of bderiv, by :func:`harden`) treats a cache
  entry that fails to load as absent: the kernel is compiled again and the entry
  rewritten; the logger ``bderiv`` warns once per folder, naming it and the first damaged
  entry (a log message, not a Python warning: the call itself succeeds).
- its data files carry the sha256 of their content (:class:`CheckedCacheFile`, suffixes
  ``.bdi`` / ``.bdc`` so that plain numba never reads them), checked before anything is
  unpickled: damaged machine code is never run.
- :class:`DriverCache` keys a task driver (a closure over its block) by the sources of
  ``_kernels`` (see its docstring).

``FunctionCache`` and ``IndexDataCacheFile`` are numba internals: if they change, the
kernels fall back to numba's own cache (or none), never fail to import.
"""

from __future__ import annotations

import contextlib
import hashlib
import logging
import os
import pickle
import sys

try:
    import resource
except ImportError:  # not on Windows: no address-space limit to check
    resource = None

import numba
from numba.core.caching import FunctionCache, IndexDataCacheFile
from numba.core.dispatcher import Dispatcher

log = logging.getLogger("bderiv")


class CheckedCacheFile(IndexDataCacheFile):
    """Numba's index and data files, each data file led by the sha256 of the rest."""

    def __init__(self, cache_path, filename_base, source_stamp):
        super().__init__(cache_path, filename_base, source_stamp)
        self._index_name = f"{filename_base}.bdi"
        self._index_path = os.path.join(self._cache_path, self._index_name)
        self._data_name_pattern = f"{filename_base}.{{number:d}}.bdc"

    def _load_data(self, name):
        with open(self._data_path(name), "rb") as f:
            data = f.read()
        digest, payload = data[:32], data[32:]
        if hashlib.sha256(payload).digest() != digest:
            raise ValueError(f"{name} does not match the sha256 digest it was written with")
        return pickle.loads(payload)

    def _save_data(self, name, data):
        payload = self._dump(data)
        with self._open_for_write(self._data_path(name)) as f:
            f.write(hashlib.sha256(payload).digest() + payload)


class CheckedCache(FunctionCache):
    """A function's cache whose failures are misses: compiled again, never raised."""

    def __init__(self, py_func, parallel: bool = False):
        super().__init__(py_func)
        self._parallel = parallel
        old = self._cache_file
        self._cache_file = CheckedCacheFile(old._cache_path, _base(old), old._source_stamp)

    def load_overload(self, sig, target_context):
        # the first parallel kernel starts the threads, and the OpenMP runtime exits the
        # process when it cannot create them: asked before the first one is loaded
        threads = self._parallel and not _THREADS_CHECKED
        try:
            data = super().load_overload(sig, target_context)
        except OSError as exc:  # unreadable (permissions, I/O): a miss, not damage
            log.debug("bderiv: kernel cache not read (%s: %s)", type(exc).__name__, exc)
            data = None
        except Exception as exc:  # noqa: BLE001 - whatever a damaged file raises (also a
            self._discard(exc)  # MemoryError: a garbled pickle may claim any length)
            data = None
        if data is None:  # numba compiles next: LLVM aborts the process when out of memory
            check_address_space(COMPILE_BYTES, f"compiling the kernel "
                                f"{self._py_func.__qualname__} (its first use here)")
        if threads:
            check_address_space(thread_bytes(), f"starting {numba.config.NUMBA_NUM_THREADS} "
                                f"threads for the parallel kernels")
            _threads_checked()
        return data

    def save_overload(self, sig, data):
        try:
            super().save_overload(sig, data)
        except Exception as exc:  # noqa: BLE001 - a cache that cannot be written is no cache
            log.debug("bderiv: not cached (%s: %s)", type(exc).__name__, exc)

    def _discard(self, exc: Exception) -> None:
        """Remove the index of a damaged entry (the next save writes a fresh one); warn
        once per folder, list every entry at DEBUG."""
        index = self._cache_file._index_path
        with contextlib.suppress(OSError):
            os.unlink(index)
        what = (f"{type(exc).__name__}: {exc} in the entry of {self._py_func.__qualname__}, "
                f"{os.path.basename(index)}")
        if self._cache_path in _WARNED:
            log.debug("bderiv: damaged kernel cache entry (%s), compiled again", what)
            return
        _WARNED.add(self._cache_path)
        log.warning(
            "bderiv: the compiled-kernel cache in %s is damaged (%s); the kernels whose "
            "entries fail to load are compiled again and their entries rewritten (the "
            "logger 'bderiv' lists them at DEBUG). If this repeats, check the disk or "
            "delete that folder (NUMBA_CACHE_DIR, else __pycache__ beside the sources).",
            self._cache_path, what)


#: cache folders already warned about in this process
_WARNED: set = set()


#: address space a kernel's compilation may take (LLVM; measured 50 to 70 MiB for the
#: drivers of a small dense map), with a margin
COMPILE_BYTES = 128 << 20
#: address space a thread takes besides its stack (guard page, TLS, the runtime's own
#: structures; glibc's malloc arena of a thread is reserved only when it fits)
THREAD_EXTRA_BYTES = 2 << 20


def thread_bytes() -> int:
    """Address space the parallel kernels' threads take: a stack (``RLIMIT_STACK``, the
    default pthread stack) and :data:`THREAD_EXTRA_BYTES` each."""
    stack = resource.getrlimit(resource.RLIMIT_STACK)[0] if resource else -1
    if stack <= 0 or stack == getattr(resource, "RLIM_INFINITY", -1):
        stack = 8 << 20
    return numba.config.NUMBA_NUM_THREADS * (stack + THREAD_EXTRA_BYTES)


#: whether the threads' address space was checked in this process (before the first
#: parallel kernel of bderiv ran)
_THREADS_CHECKED = False


def _threads_checked() -> None:
    global _THREADS_CHECKED
    _THREADS_CHECKED = True


def check_address_space(need: int, what: str) -> None:
    """Raise ``MemoryError`` when ``need`` more bytes of address space exceed ``RLIMIT_AS``.

    LLVM (a compilation) and the OpenMP runtime (starting threads) abort the whole process
    when an allocation fails under ``ulimit -v``; checked here first, the caller gets an
    exception that names the limit. Nothing is checked without a limit, or where the
    address space in use cannot be read (``/proc/self/statm``).
    """
    if resource is None:
        return
    limit = resource.getrlimit(resource.RLIMIT_AS)[0]
    if limit in (resource.RLIM_INFINITY, -1):
        return
    try:
        with open("/proc/self/statm") as fh:
            used = int(fh.read().split()[0]) * os.sysconf("SC_PAGE_SIZE")
    except (OSError, ValueError, IndexError):
        return
    if used + need > limit:
        mib = 1 << 20
        raise MemoryError(
            f"{what} needs about {need // mib} MiB of address space, but the address-space "
            f"limit (RLIMIT_AS, ulimit -v) of {limit // mib} MiB leaves "
            f"{max(limit - used, 0) // mib} MiB; raise the limit (or run once without it: "
            f"compiled kernels are cached on disk for later processes)"
        )


def _base(cache_file: IndexDataCacheFile) -> str:
    """The file name base numba chose (its index file's name without ``.nbi``)."""
    return cache_file._index_name[: -len(".nbi")]


class DriverCache(CheckedCache):
    """The on-disk cache of a driver, keyed by the sources of the kernel package.

    Numba keys the cache of a closure by the pickle of what it closes over; a dispatcher
    pickles with per-process ids (its own and those of every jitted function it calls), so
    a driver closing over a block would miss the cache in every process and grow its
    index. This key is the signature and a digest of every source file of ``_kernels``:
    found again by every process, and invalidated by any edit of a block or of anything
    it calls (numba itself watches only the driver's own file).
    """

    def __init__(self, py_func, key: str, parallel: bool = False):
        super().__init__(py_func, parallel)
        self._key = key

    def _index_key(self, sig, codegen):
        return (sig, codegen.magic_tuple(), (self._key,))


def harden(dispatcher, cache=None):
    """Give ``dispatcher`` a :class:`CheckedCache` (or ``cache``); returns it.

    Left as it is when numba's internals differ from what this module knows.
    """
    try:
        parallel = bool(dispatcher.targetoptions.get("parallel"))
        dispatcher._cache = CheckedCache(dispatcher.py_func, parallel) if cache is None else cache
    except Exception:  # another numba: its own cache stays  # noqa: BLE001
        pass
    return dispatcher


def harden_all() -> None:
    """Harden every cached kernel defined at the top level of an imported bderiv module.

    Called when the package is imported and when a driver is made (kernel modules make
    theirs at import), so modules imported later are covered too. Idempotent and cheap.
    """
    for name, module in list(sys.modules.items()):
        if name.split(".")[0] != "bderiv" or module is None:
            continue
        for value in list(vars(module).values()):
            if isinstance(value, Dispatcher) and type(value._cache) is FunctionCache:
                harden(value)
