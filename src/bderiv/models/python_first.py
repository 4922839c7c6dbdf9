"""Python first: a new model's numba functions run on their Python code until that has
taken a second, then compiled (docs/design.md, "Python first").

Compiling a model's functions takes 1.5 to 2.5 s (the chair's, for float and complex
input): more than a first answer needs when it is small (0.05 s on the same functions'
Python code). Under ``BDERIV_INTEGRATOR=auto`` a model whose numba functions are not
compiled on this machine yet (:func:`starts_in_python`) runs on their Python code
(``py_func``, what numba compiles; numba runs the same under ``NUMBA_DISABLE_JIT``) until
its runs have taken :data:`bderiv._limits.PYTHON_FIRST_SECONDS`, the ski rental's rule:
work that would not pay for the compilation never waits for it, work that would is
compiled after at most that second. The second is the field's, shared by every model of it
(a sweep's), and is charged the runs' wall time without the thread's own numba compilations
(a library kernel's first, which on an empty cache took the whole second of the chair's
first answer): :class:`PythonTime`. :class:`~bderiv.models.calls.ModelCalls` switches its
evaluations; :func:`bderiv.models.integrate.run.run` makes a run again compiled when it
ends by :class:`~bderiv.models.readiness.PythonTierEnded`.

No library does this for numba functions: numba compiles at the first call, and its
``NUMBA_DISABLE_JIT`` is one switch for a whole process (bderiv's own kernels need
compiling).
"""

from __future__ import annotations

import contextlib
import threading
import time
import weakref

import numpy as np
from numba.core import event as numba_event

from .. import _limits
from .compiled import is_compiled
from .readiness import PythonTierEnded, compiling_in_this_process, machine_has, policy

#: the time left to a field's Python code, shared by every model of that field (a sweep's
#: models): ``{field dispatcher: [seconds]}``
_LEFT = weakref.WeakKeyDictionary()
#: seconds each thread has spent in numba's compilations (the outermost ones), by thread
#: id: a run on Python code is charged its time without its own thread's compilations
_COMPILING = {}


class _CompileClock(numba_event.Listener):
    """Adds the time of each outermost numba compilation to its thread's entry of
    :data:`_COMPILING` (numba compiles under one lock: one compilation at a time)."""

    def __init__(self):
        self.depth, self.start = 0, 0.0

    def on_start(self, event):
        self.depth += 1
        if self.depth == 1:
            self.start = time.perf_counter()

    def on_end(self, event):
        self.depth = max(self.depth - 1, 0)
        if self.depth == 0:
            thread = threading.get_ident()
            _COMPILING[thread] = _COMPILING.get(thread, 0.0) + time.perf_counter() - self.start


numba_event.register("numba:compile", _CompileClock())


def starts_in_python(functions) -> bool:
    """Whether a model's runs start on its numba functions' Python code: under
    ``BDERIV_INTEGRATOR=auto`` (the default), when none of its dispatchers is compiled in
    this process or kept in numba's disk cache for this machine (``cache=True``: it loads
    in milliseconds): a model just written or edited, or a machine's first use of one,
    whose compilation would take seconds before the first answer. Never in the process
    that compiles the integrator (its runs are what compiles it)."""
    dispatchers = [f for f in functions if is_compiled(f)]
    return policy() == "auto" and bool(dispatchers) and not compiling_in_this_process() \
        and not any(machine_has(f) for f in dispatchers)


class PythonTime:
    """The time a model's runs may still spend on its field's Python code: ``left``, a
    one-element list shared by the models of ``field`` (``[0.0]`` for a model that runs
    compiled: ``field`` None). A run is its thread's (``threading.local``): another
    thread's call outside a run is neither charged nor raised as a run's end."""

    def __init__(self, field):
        self.left = [0.0] if field is None else \
            _LEFT.setdefault(field, [_limits.PYTHON_FIRST_SECONDS])
        self._here = threading.local()

    def budgeted(self, fn, outside):
        """``fn`` (a function's Python code) raising
        :class:`~bderiv.models.readiness.PythonTierEnded`, in a run, at a call once the run
        has spent the time left, or when ``fn`` raises (the cause; a ``ValueError`` is the
        run's own, raised on purpose, and complex input refused is left to the complex
        step's fallback); outside a run, what ``fn`` raises goes to ``outside(exc, args)``,
        whose value is the call's."""

        def call(*args):
            in_run = getattr(self._here, "start", None) is not None
            if in_run and self.spent() > self.left[0]:
                raise PythonTierEnded
            try:
                out = fn(*args)
            except ValueError:  # raised on purpose (a guard, a check): as compiled
                raise
            except Exception as exc:  # noqa: BLE001 - the compiled function decides
                if any(np.iscomplexobj(a) for a in args):
                    raise  # complex input refused: the complex step's fallback decides
                if in_run:
                    raise PythonTierEnded from exc
                return outside(exc, args)
            if out is None or as_compiled_returns(out):
                return out
            # another type than the compiled path takes (float32, ints, a list, a view):
            # the compiled function decides, which refuses it by name from the first run
            # on, not after the model's Python second
            other = NotAsCompiled(f"{fn.__name__} returned {_kind(out)}")
            if in_run:
                raise PythonTierEnded from other
            return outside(other, args)

        call.__wrapped__ = fn
        return call

    @contextlib.contextmanager
    def run(self):
        """A run on the Python code: yields whether it is the thread's outermost (a run
        within a run keeps the outer one's clock); the time it took is taken from
        ``left`` at its end, whatever the end."""
        here = self._here
        outer = getattr(here, "start", None), getattr(here, "compiling", 0.0)
        here.start = time.perf_counter()
        here.compiling = _COMPILING.get(threading.get_ident(), 0.0)
        try:
            yield outer[0] is None
        finally:
            self.left[0] -= self.spent()
            here.start, here.compiling = outer

    def spent(self) -> float:
        """The seconds this thread's run has taken, its numba compilations left out."""
        here = self._here
        return time.perf_counter() - here.start - (
            _COMPILING.get(threading.get_ident(), 0.0) - here.compiling)


class NotAsCompiled(TypeError):
    """A numba function's Python code returned another type than the compiled path takes
    (:func:`as_compiled_returns`): its compiled version decides."""


def _kind(out) -> str:
    if isinstance(out, np.ndarray):
        layout = "C-contiguous" if out.flags.c_contiguous else "non-contiguous"
        return f"a {layout} {out.dtype} array"
    return f"a {type(out).__name__}"


def as_compiled_returns(out) -> bool:
    """Whether ``out`` is of the type the compiled path takes from a model's function: a
    C-contiguous float64 array (complex128 under the complex step)."""
    return (type(out) is np.ndarray and out.dtype in (np.float64, np.complex128)
            and out.flags.c_contiguous)
