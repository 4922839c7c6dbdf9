"""The on-disk cache of the compiled kernels: keyed by numba, checked, never fatal.

Keys. Numba caches a function by its own file: an index per function, named by its module,
qualified name and first line, stamped with the sha256 of the function's source file, and
keyed by signature, target and the hash of its bytecode and closure. A function compiled
into another (a block into its driver, a step into its block) is not watched: after an
edit of ``selection.py`` a driver of ``dense.py`` would load the old steps from the cache.
:func:`keyed` therefore caches a function under a qualified name that ends with a digest of
every source file its compiled code comes from (:func:`sources_digest`), so an edit of any
of them names new cache files, which numba then fills by its own means; the functions
below the cached ones are compiled uncached (in the process that needs them, only when
the cached one is missing). Drivers are plain functions without closures (numba could not
key a closure over dispatchers: they pickle with per-process ids), bound to their block
by their globals (``_drivers.batch``).

Damage. Read as numba reads them, a truncated or garbled file raises
``UnpicklingError``/``EOFError`` from every first call in every process, and a flipped bit
inside the machine code may crash the process. :func:`harden` (every cached kernel of
bderiv: :func:`keyed`, and :func:`harden_all` at import) gives a kernel's cache a
:class:`CheckedCacheFile`: an entry that fails to load is a miss (compiled again, the entry
rewritten; the logger ``bderiv`` warns once per folder, naming it and the first damaged
entry), and index and data files carry the sha256 of their content, checked before
anything is unpickled, so damaged machine code is never run (suffixes ``.bdi``/``.bdc``:
plain numba never reads them; an index without the digest, an earlier bderiv's, is a
miss). Each data file also holds the source stamp and key it was saved under (signature,
CPU, bytecode), checked when it is loaded: two processes that save two keys of one kernel
at once both take the first free file name, and the index of one can end up naming the
other's data file; that entry is then a miss, compiled again, never the other
signature's or another CPU's code. This is the one guarantee that needs numba internals:
numba reads its files in ``numba.core.caching.IndexDataCacheFile``, with no public hook,
so the checked file subclasses it (``_load_index``, ``_save_index``, ``_load_data``,
``_save_data``, ``load``, ``save``, ``_data_name``, ``_index_path``,
``_data_name_pattern``, ``_version``, ``_source_stamp``) and is put in place as the
``_cache_file`` of the dispatcher's cache. If numba changes these,
:func:`harden` leaves numba's own files (kernels still cache, without the check) and
``tests/test_faults.py`` fails; nothing else here depends on them.

A user's own ``cache=True`` functions keep numba's plain files (bderiv does not change how
the user's dispatchers cache): when their compilation fails, :func:`damaged_entry` loads
the entry again (numba's ``Cache.load_overload``) to tell a damaged file from a typing
error, and the caller raises an error naming the folder and the files.

Address space. A miss is followed by a compilation (LLVM), and the first parallel kernel
starts the threads (OpenMP); both abort the process when memory runs out under
``ulimit -v``, so a checked file asks :func:`check_address_space` first.
"""

from __future__ import annotations

import contextlib
import hashlib
import io
import itertools
import logging
import os
import pathlib
import pickle
import sys
import types

try:
    import resource
except ImportError:  # not on Windows: no address-space limit to check
    resource = None

import numba
from numba import njit
from numba.core.caching import IndexDataCacheFile
from numba.core.dispatcher import Dispatcher

from .._limits import COMPILE_BYTES, THREAD_EXTRA_BYTES

if numba.config.DISABLE_JIT:  # njit would give plain functions: every kernel call fails
    raise ImportError(
        "bderiv needs numba's compiler, and NUMBA_DISABLE_JIT is set (numba.config."
        "DISABLE_JIT): its kernels and compiled integrator do not run as plain Python. "
        "Unset NUMBA_DISABLE_JIT; to step through your own model's functions in Python, "
        "pass them to bderiv undecorated (plain Python functions run on scipy's solve_ivp)")

log = logging.getLogger("bderiv")

#: hex digits of a sources digest in a cached function's qualified name
KEY_DIGITS = 16


def sources_digest(folder, *files, skip=()) -> str:
    """The first :data:`KEY_DIGITS` hex digits of the sha256 of the ``*.py`` files of
    ``folder`` (names and contents, in name order; ``None``: no folder) but those named in
    ``skip`` (files that hold no compiled code and that no compiled code reads), then of
    ``files`` (the modules outside ``folder`` whose values are compiled in:
    ``bderiv._numerics``)."""
    h = hashlib.sha256()
    listed = (sorted(p for p in pathlib.Path(folder).glob("*.py") if p.name not in skip)
              if folder is not None else [])
    for path in [*listed, *map(pathlib.Path, files)]:
        h.update(path.name.encode() + b"\0" + path.read_bytes())
    return h.hexdigest()[:KEY_DIGITS]


def keyed(fn, key: str, name: str | None = None, namespace: dict | None = None, **options):
    """``njit(cache=True, **options)`` of ``fn``, cached under the qualified name
    ``f"{name or fn.__qualname__}.k{key}"`` (``key``: a :func:`sources_digest` of every
    file its compiled code comes from), and :func:`harden`-ed.

    ``namespace``: the globals ``fn``'s code runs with (a copy of ``fn`` is compiled; its
    ``__name__`` entry names the module), so one function's code can be bound to several
    callees, each a plain function numba caches on its own. A closure is keyed by numba
    by the pickle of the values it holds: plain values only (a dispatcher pickles with ids
    that are new in every process: it would be compiled again in every process).
    """
    glob = fn.__globals__ if namespace is None else namespace
    func = types.FunctionType(fn.__code__, glob, fn.__name__, fn.__defaults__, fn.__closure__)
    func.__qualname__ = f"{name or fn.__qualname__}.k{key}"
    func.__doc__ = fn.__doc__
    return harden(njit(cache=True, **options)(func))


def checked_njit(**options):
    """The decorator ``njit(cache=True, **options)``, its dispatcher :func:`harden`-ed where it
    is defined: for a cached kernel outside ``_kernels`` whose compiled code comes from its
    own file only (numba's own key then suffices), in a module that may be imported after
    :func:`harden_all` ran."""

    def decorate(fn):
        return harden(njit(cache=True, **options)(fn))

    return decorate


def rekey(dispatcher, key: str):
    """Cache a module-level ``njit(cache=True)`` kernel under ``key`` as :func:`keyed`
    does (its qualified name gets ``.k{key}``; numba's ``enable_caching`` makes its
    cache again under that name), :func:`harden`-ed; returns it. For kernels decorated
    before the key was known (a package keys its own at import)."""
    dispatcher.py_func.__qualname__ = f"{dispatcher.py_func.__qualname__}.k{key}"
    dispatcher.enable_caching()
    return harden(dispatcher)


def rekey_modules(modules, key: str) -> None:
    """:func:`rekey` every cached kernel defined at the top level of ``modules`` that has
    not compiled yet and is not keyed by ``key`` already (those compiled at import keep
    their names: they call nothing of another file)."""
    for module in modules:
        for value in list(vars(module).values()):
            if (isinstance(value, Dispatcher) and value.py_func.__module__ == module.__name__
                    and value.stats.cache_path is not None and not value.signatures
                    and not value.py_func.__qualname__.endswith(f".k{key}")):
                rekey(value, key)


class CheckedCacheFile(IndexDataCacheFile):
    """Numba's index and data files, each data file led by the sha256 of the rest; an entry
    that fails to load is a miss (see the module docstring)."""

    def __init__(self, plain: IndexDataCacheFile, qualname: str, parallel: bool):
        base = plain._index_name[: -len(".nbi")]
        super().__init__(plain._cache_path, base, plain._source_stamp)
        self._index_name = f"{base}.bdi"
        self._index_path = os.path.join(self._cache_path, self._index_name)
        self._data_name_pattern = f"{base}.{{number:d}}.bdc"
        self._qualname, self._parallel = qualname, parallel

    def load(self, key):
        # the first parallel kernel starts the threads, and the OpenMP runtime exits the
        # process when it cannot create them: asked before the first one is loaded
        threads = self._parallel and not _THREADS_CHECKED
        try:
            data = self._load_entry(key)
        except OSError as exc:  # unreadable (permissions, I/O): a miss, not damage
            log.debug("bderiv: kernel cache not read (%s: %s)", type(exc).__name__, exc)
            data = None
        except Exception as exc:  # noqa: BLE001 - whatever a damaged file raises (also a
            self._discard(exc)  # MemoryError: a garbled pickle may claim any length)
            data = None
        if data is None:  # numba compiles next: LLVM aborts the process when out of memory
            check_address_space(COMPILE_BYTES, f"compiling the kernel {self._qualname} "
                                f"(its first use here)")
        if threads:
            check_address_space(thread_bytes(), f"starting {numba.config.NUMBA_NUM_THREADS} "
                                f"threads for the parallel kernels")
            _threads_checked()
        return data

    def _load_entry(self, key):
        """numba's ``load``, the source stamp and key saved with the data checked: another
        key's data (two saves at once that took one file name), an earlier source's (read
        between a save's index and its data) or an earlier bderiv's is a miss."""
        name = self._load_index().get(key)
        if name is None:
            return None
        try:
            entry = self._load_data(name)
        except FileNotFoundError:  # removed while the index still names it
            return None
        if not (isinstance(entry, tuple) and len(entry) == 3
                and entry[:2] == (self._source_stamp, key)):
            log.debug("bderiv: %s holds another entry of %s; compiled again", name,
                      self._qualname)
            return None
        return entry[2]

    def save(self, key, data):
        """numba's ``save`` (the index names the entry's data file, the first free name),
        the source stamp and key saved with the data."""
        try:
            overloads = self._load_index()
            name = overloads.get(key)
            if name is None:
                taken = set(overloads.values())
                name = next(n for n in map(self._data_name, itertools.count(1))
                            if n not in taken)
                overloads[key] = name
                self._save_index(overloads)
            self._save_data(name, (self._source_stamp, key, data))
        except Exception as exc:  # noqa: BLE001 - a cache that cannot be written is no cache
            log.debug("bderiv: not cached (%s: %s)", type(exc).__name__, exc)

    def _load_index(self):
        try:
            with open(self._index_path, "rb") as f:
                data = f.read()
        except FileNotFoundError:
            return {}
        if not data.startswith(INDEX_MAGIC):  # an earlier bderiv's index: a miss
            return {}
        payload = data[len(INDEX_MAGIC) + 32:]
        if hashlib.sha256(payload).digest() != data[len(INDEX_MAGIC):len(INDEX_MAGIC) + 32]:
            raise ValueError(f"{self._index_name} does not match the sha256 digest it was "
                             f"written with")
        stream = io.BytesIO(payload)  # numba's index: its version, then (stamp, overloads)
        if pickle.load(stream) != self._version:
            return {}
        stamp, overloads = pickle.loads(stream.read())
        _debug("[cache] index loaded from %r", self._index_path)
        return overloads if stamp == self._source_stamp else {}  # stale: compiled again

    def _save_index(self, overloads):
        payload = (pickle.dumps(self._version, protocol=-1)
                   + self._dump((self._source_stamp, overloads)))
        with self._open_for_write(self._index_path) as f:
            f.write(INDEX_MAGIC + hashlib.sha256(payload).digest() + payload)
        _debug("[cache] index saved to %r", self._index_path)

    def _load_data(self, name):
        with open(self._data_path(name), "rb") as f:
            data = f.read()
        digest, payload = data[:32], data[32:]
        if hashlib.sha256(payload).digest() != digest:
            raise ValueError(f"{name} does not match the sha256 digest it was written with")
        entry = pickle.loads(payload)
        _debug("[cache] data loaded from %r", self._data_path(name))
        return entry

    def _save_data(self, name, data):
        payload = self._dump(data)
        with self._open_for_write(self._data_path(name)) as f:
            f.write(hashlib.sha256(payload).digest() + payload)
        _debug("[cache] data saved to %r", self._data_path(name))

    def _discard(self, exc: Exception) -> None:
        """Remove the index of a damaged entry (the next save writes a fresh one); warn
        once per folder, list every entry at DEBUG."""
        with contextlib.suppress(OSError):
            os.unlink(self._index_path)
        what = (f"{type(exc).__name__}: {exc} in the entry of {self._qualname}, "
                f"{self._index_name}")
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


def _debug(message: str, path: str) -> None:
    """numba's line for ``NUMBA_DEBUG_CACHE``, printed from the methods of numba's that
    :class:`CheckedCacheFile` replaces."""
    if numba.core.config.DEBUG_CACHE:
        print(message % (path,))


#: how a checked index file starts; the sha256 of the rest follows, then numba's index
INDEX_MAGIC = b"bderiv-index-sha256-keyed\n"

#: cache folders already warned about in this process
_WARNED: set = set()


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


def harden(dispatcher):
    """Give a cached ``dispatcher`` a :class:`CheckedCacheFile` (see the module docstring);
    returns it. Left as it is when uncached, or when numba's internals differ."""
    try:
        cache = dispatcher._cache
        if type(cache._cache_file) is IndexDataCacheFile:
            parallel = bool(dispatcher.targetoptions.get("parallel"))
            cache._cache_file = CheckedCacheFile(cache._cache_file,
                                                 dispatcher.py_func.__qualname__, parallel)
    except AttributeError:  # uncached (numba's NullCache), or another numba
        pass
    return dispatcher


def hardened(dispatcher) -> bool:
    """Whether ``dispatcher``'s cache reads and writes :class:`CheckedCacheFile` files."""
    return isinstance(getattr(getattr(dispatcher, "_cache", None), "_cache_file", None),
                      CheckedCacheFile)


def damaged_entry(dispatcher, signature) -> str | None:
    """Why numba's disk cache of a user's ``dispatcher`` cannot be loaded for
    ``signature`` (the argument types, as numba's ``compile`` takes them), or None.

    A user's ``cache=True`` function reads numba's plain files (not bderiv's checked
    ones): a damaged entry makes every compilation raise (``UnpicklingError``,
    ``EOFError``, ...) in every later process. Called when a compilation failed, this
    loads the entry again to tell such damage from a typing error, and names the folder,
    the files and how to clear them.
    """
    cache = getattr(dispatcher, "_cache", None)
    index = getattr(getattr(cache, "_cache_file", None), "_index_path", None)
    if index is None:  # not cached (numba's NullCache)
        return None
    try:
        cache.load_overload(signature, dispatcher.targetctx)
    except Exception as exc:  # noqa: BLE001 - whatever a damaged file raises
        folder, name = os.path.split(index)
        base = name[: -len(os.path.splitext(name)[1])]
        data = os.path.splitext(name)[1].replace("i", "c")
        return (f"its numba disk cache (cache=True) cannot be loaded "
                f"({type(exc).__name__}: {exc}): its files in {folder} "
                f"({name} and {base}.*{data}) are damaged; delete them (or that folder: "
                f"NUMBA_CACHE_DIR, else the __pycache__ beside the function's source) and "
                f"numba compiles the function again")
    return None


def harden_all() -> None:
    """:func:`harden` every kernel defined at the top level of an imported bderiv module.

    Called when the package is imported and when a driver is made, so modules imported
    later are covered too. Idempotent and cheap.
    """
    for name, module in list(sys.modules.items()):
        if name.split(".")[0] != "bderiv" or module is None:
            continue
        for value in list(vars(module).values()):
            if isinstance(value, Dispatcher):
                harden(value)
