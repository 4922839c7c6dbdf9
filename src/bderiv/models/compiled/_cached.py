"""The on-disk cache of the integrator's kernels, keyed by every source file of the package.

Numba invalidates a cached function when its own file changes, not when a function it
calls (and compiled into it) does: after an edit of ``_rhs.py`` the driver and the steps
would load the old right-hand side from the cache. Every kernel here is therefore cached
under a name that ends with a digest of ``compiled/``'s sources (but
:data:`PYTHON_ONLY`) and of
``bderiv._numerics`` (whose numbers are compiled in; ``bderiv._limits``, Python-only
defaults, keys nothing) and of ``bderiv._kernels._pointer`` (the driver's call), by
numba's own cache, in bderiv's checked cache files (:func:`bderiv._kernels._cache.rekey`:
a damaged entry is compiled again, never run).
"""

from __future__ import annotations

import pathlib
import sys
import threading

from ... import _numerics
from ..._kernels import _pointer
from ..._kernels._cache import checked_njit, rekey_modules, sources_digest

#: the files of ``compiled/`` that hold no compiled code and that no compiled code reads
#: (the model's Python face, its checks, notices and slices): out of the key, so that
#: editing them compiles nothing again (``tests/test_numerics.py`` checks both)
PYTHON_ONLY = ("__init__.py", "_checks.py", "_notice.py", "_slices.py", "model.py",
               "stretch.py")

#: the functions of :func:`eager` not compiled yet, with their signatures
_PENDING: list = []
_PENDING_LOCK = threading.Lock()


def eager(signature):
    """``njit(signature, cache=True)`` through bderiv's checked cache files
    (:func:`bderiv._kernels._cache.checked_njit`: numba's plain ``.nbi``/``.nbc`` files are
    never read, so a damaged entry is compiled again, never run: a flipped bit in a plain
    ``.nbc`` aborted every later ``import bderiv``), compiled for ``signature`` alone by
    :func:`compile_eager`, before the first model is bound for the compiled integrator:
    not at import, where these placeholders and the binder took 0.66 s of a fresh
    machine's first answer, which runs on scipy while the integrator compiles. Its
    compilation is then closed (other argument types are refused), as with a signature
    given to ``njit``."""

    def decorate(fn):
        dispatcher = checked_njit()(fn)
        _PENDING.append((dispatcher, signature))
        return dispatcher

    return decorate


def compile_eager() -> None:
    """Compile the functions of :func:`eager` (once; loaded from the disk cache where it
    holds them)."""
    if not _PENDING:
        return
    with _PENDING_LOCK:
        while _PENDING:
            dispatcher, signature = _PENDING[0]
            dispatcher.compile(signature)
            dispatcher.disable_compile()
            _PENDING.pop(0)


def sources_key() -> str:
    """The digest of ``compiled/``'s sources (but :data:`PYTHON_ONLY`), of
    ``bderiv._numerics`` and of the pointer call compiled into the run
    (``bderiv._kernels._pointer``)."""
    return sources_digest(pathlib.Path(__file__).parent, _numerics.__file__,
                          _pointer.__file__, skip=PYTHON_ONLY)


def key_all_kernels() -> None:
    """Give every lazily compiled, cached kernel of ``bderiv.models.compiled`` the sources key.

    (Those of :func:`eager` too: they compile later, under that key.)
    """
    rekey_modules([module for name, module in list(sys.modules.items())
                   if name.startswith(__package__ + ".") and module is not None],
                  sources_key())
