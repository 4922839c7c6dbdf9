"""The driver called in slices of steps, so that a long stretch comes back to Python.

Numba's compiled code does not see Ctrl-C: the signal is handled when the driver returns.
:func:`drive` calls :func:`._integrate.drive_stretch` for about ``SLICE_SECONDS`` of steps at
a time (the steps a slice takes are learned from the calls so far), and goes on from where
it paused with the step size it had: the same steps as one call.
"""

from __future__ import annotations

import contextlib
import threading
import time
from typing import NamedTuple

import numpy as np

from ..._limits import FIRST_SLICE, SLICE_SECONDS
from ..._support._format import format_region
from ..._support._validate import check_record
from ._integrate import N_STEPS, PAUSED, drive_stretch

#: seconds per accepted step measured so far, per (model, length of the integrated vector)
_cost: dict = {}
#: the stop event of the batch whose run this thread makes (:func:`stopped_by`)
_batch = threading.local()


class Cancelled(Exception):
    """A run of a batch stopped at a slice's end because its batch stopped (Ctrl-C in the
    batch's calling thread, or a failed run)."""


@contextlib.contextmanager
def stopped_by(event):
    """The runs this thread makes in the block stop (:class:`Cancelled`) at the first
    :func:`cancel_point` after ``event`` is set: a thread of a batch cannot see Ctrl-C."""
    _batch.stop = event
    try:
        yield
    finally:
        _batch.stop = None


def cancel_point() -> None:
    """Raise :class:`Cancelled` if this thread's batch has stopped (:func:`stopped_by`)."""
    stop = getattr(_batch, "stop", None)
    if stop is not None and stop.is_set():
        raise Cancelled


class Driven(NamedTuple):
    """What the driver's calls of one stretch gave (see ``drive_stretch``): ``status``,
    ``t_end``, ``y_end``, ``ts`` (N,), ``ys`` (N, m), ``steps`` (S, 2), ``Fd``
    (S, 7, d), ``active`` (n,), ``roots`` (n,), ``counts`` (4,), ``bad`` (d,), ``t_bad``."""

    status: int
    t_end: float
    y_end: np.ndarray
    ts: np.ndarray
    ys: np.ndarray
    steps: np.ndarray
    Fd: np.ndarray
    active: np.ndarray
    roots: np.ndarray
    counts: np.ndarray
    bad: np.ndarray
    t_bad: float


def _interrupted(exc) -> None:
    """Raise the KeyboardInterrupt behind ``exc`` (a SystemError numba raised when the
    interrupt's handler ran while it built the results), if there is one."""
    seen = exc
    while seen is not None:
        if isinstance(seen, KeyboardInterrupt):
            raise KeyboardInterrupt from None
        seen = seen.__cause__ or seen.__context__


def slice_budget(key) -> int:
    """The accepted steps of about ``SLICE_SECONDS`` for ``key`` (model id, length of the
    integrated vector), as measured so far; ``FIRST_SLICE`` before any measurement."""
    per_step = _cost.get(key)
    return FIRST_SLICE if per_step is None else max(1, int(SLICE_SECONDS / per_step))


def measured(key, elapsed, steps) -> None:
    """Record that ``steps`` accepted steps took ``elapsed`` seconds for ``key``."""
    if steps:
        _cost[key] = elapsed / steps


def drive(model, jac_mode, variational, with_section, n_events, mask, d, t0, y0, t_final,
          rtol, atol, max_step, first_step, forced, on_side, dense, watch=None) -> Driven:
    """``drive_stretch`` with these arguments, in slices of steps (no validation);
    ``watch(t)``, if given, is told the time reached after each slice.

    The stretch's record (every accepted step's time and integrated vector, and with
    ``dense`` its dense output) grows with its steps: before each slice its projected size
    is held to what the process may still take (:func:`bderiv._support._validate.check_record`:
    a ValueError naming the record, never the model's MemoryError)."""
    key = (id(model), y0.size)
    parts, counts, held, start_t = [], None, 0, t0
    while True:
        budget = slice_budget(key)
        start = time.perf_counter()
        try:
            out = drive_stretch(model, jac_mode, variational, with_section, n_events, mask,
                                d, t0, y0, t_final, rtol, atol, max_step, first_step, forced,
                                on_side, budget, dense)
        except SystemError as exc:  # Ctrl-C seen while numba boxed the results
            _interrupted(exc)
            raise
        elapsed = time.perf_counter() - start
        status, t_end, y_end, ts, ys, steps, Fd, active, roots, part, bad, t_bad, h, _ = out
        measured(key, elapsed, part[N_STEPS])
        counts = part if counts is None else counts + part
        parts.append((ts, ys, steps, Fd) if not parts else (ts[1:], ys[1:], steps, Fd))
        if status != PAUSED:
            break
        cancel_point()
        if watch is not None:
            watch(t_end)
        # the next slice (about as many steps as this one; the driver's arrays double as
        # they fill) and the parts joined into one record at the end
        grown = sum(a.nbytes for a in parts[-1])
        held += grown
        check_record(held, held + 4 * grown, _stretch_record(mask, n_events, start_t, t_end,
                                                             counts[N_STEPS]),
                     "pass a shorter t_final and go on from the run's x_final, or a larger "
                     "rtol and atol (fewer steps)")
        t0, y0, first_step, forced, on_side = t_end, y_end, h, -1, False
    if len(parts) == 1:
        ts, ys, steps, Fd = parts[0]
    else:
        ts, ys, steps, Fd = (np.concatenate(p) for p in zip(*parts, strict=True))
    return Driven(status, t_end, y_end, ts, ys, steps, Fd, active, roots, counts, bad, t_bad)


def _stretch_record(mask, n, t0, t, steps) -> str:
    """The words naming a stretch's record in a refusal."""
    return (f"the record of the stretch of {format_region(mask, n)} "
            f"from t = {t0!r} (every accepted step's state and dense "
            f"output, kept to search for crossings inside the steps), {int(steps)} steps to "
            f"t = {t!r},")
