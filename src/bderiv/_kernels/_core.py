"""What every kernel shares: jit options, the disk cache's key (:data:`SOURCES`,
:func:`cached`), the kernels' choice (:data:`PLAIN`), read-only inputs and the size of a
launch; the drivers that run a block over a batch are in :mod:`._drivers`, the shared
arithmetic steps in :mod:`.steps`.

No validation here: callers pass C-contiguous arrays of consistent shapes. What a kernel
only reads (queries, tables, tangents) it gets read-only (:func:`read_only`,
:func:`frozen_tables`, applied by the drivers and the Python wrappers): a writeable and a
read-only array are two numba types, and each would compile the kernel once more. Likewise
a constant passed to an njit function that is not inlined is a literal type (``False``,
``0``), another compilation of the callee and of what it calls: the blocks pass
``np.bool_(False)``, ``np.int64(0)`` instead.
"""

from __future__ import annotations

import os
import pathlib
import warnings

import numpy as np

from .. import _numerics
from .._limits import LAUNCH_WORK
from ._cache import keyed, sources_digest

# error_model="numpy": a division by zero gives inf instead of a Python exception path, so
# LLVM vectorises the loops that divide (rates are positive where it matters: checked
# when tables are built, or per region by the model kernels). Not cached by itself: the
# kernels called from Python and the steps several kernels call are :func:`cached`, the
# drivers keyed, under a key that covers everything compiled into them (see ``_cache``);
# the blocks and the inlined helpers compile into them.
JIT = {"error_model": "numpy"}

#: the digest of this package's sources and of the numbers compiled into them
#: (``bderiv._numerics``) that names every cached kernel (``_cache.keyed``)
SOURCES = sources_digest(pathlib.Path(__file__).parent, _numerics.__file__)


def cached(fn=None, *, parallel: bool = False):
    """A kernel called from Python, or a step several kernels call (a process compiling a
    new kernel then loads it, where it would compile it again): ``njit(parallel=parallel,
    **JIT)``, cached on disk under :data:`SOURCES`. ``@cached`` or
    ``@cached(parallel=True)``."""
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
