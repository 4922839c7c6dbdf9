"""Where a command's time goes: phases timed apart, and numba's compilation within them.

The first run on a new machine compiles the kernels (or loads them from numba's on-disk
cache), inside whichever call first needs them. :class:`Phases` times each phase of a
command and, through numba's event API (``numba.core.event``), the time spent holding
numba's compiler lock (compiling, or loading a cached compilation) during it, so that a
report can say once where the time went and give the timings without the compilation.
"""

from __future__ import annotations

import time
from contextlib import contextmanager

from numba.core import event


class _CompileClock(event.Listener):
    """Wall time spent holding numba's compiler lock (outermost acquisitions only: the
    lock is re-entrant, nested compilations would otherwise count twice)."""

    def __init__(self):
        self.seconds, self._depth, self._start = 0.0, 0, 0.0

    def on_start(self, ev):
        if self._depth == 0:
            self._start = time.perf_counter()
        self._depth += 1

    def on_end(self, ev):
        self._depth -= 1
        if self._depth == 0:
            self.seconds += time.perf_counter() - self._start


class Phases:
    """Seconds per named phase, and the compilation each includes.

    ``seconds[name]`` is a phase's wall time, ``compiling[name]`` the part of it spent
    compiling or loading cached kernels; :meth:`without_compiling` the rest.

    Examples
    --------
    >>> phases = Phases()
    >>> with phases("sleeping"):
    ...     time.sleep(0.01)
    >>> list(phases.seconds), phases.seconds["sleeping"] >= 0.01, phases.compiling
    (['sleeping'], True, {'sleeping': 0.0})
    """

    def __init__(self):
        self.seconds: dict[str, float] = {}
        self.compiling: dict[str, float] = {}
        self._clock = _CompileClock()

    def without_compiling(self, name: str) -> float:
        """Seconds of phase ``name`` not spent compiling."""
        return self.seconds[name] - self.compiling[name]

    @contextmanager
    def __call__(self, name: str):
        t0, c0 = time.perf_counter(), self._clock.seconds
        with event.install_listener("numba:compiler_lock", self._clock):
            try:
                yield
            finally:
                self.seconds[name] = self.seconds.get(name, 0.0) + time.perf_counter() - t0
                self.compiling[name] = (self.compiling.get(name, 0.0)
                                        + self._clock.seconds - c0)
