"""Many runs of one model: :func:`run_many` integrates a batch of start states, one run each.

The runs are independent: :func:`~bderiv.models.integrate.run.run` from each start state.
Each run is exactly the one ``simulate`` makes (the same trajectory, to the bit); what the
batch adds is one validation of the settings, a progress bar of the runs done, errors that
name the start state they came from, and, on a compiled model whose stops are decided in
compiled code (:func:`threaded`), runs side by side on threads.

Why Python threads and not a numba ``prange``: a run's output has a size known only at its
end (its samples, its event groups), and a stop the compiled run cannot decide (a peak to
search, a return across a surface, a refusal to word) is handed back to the Python stop
logic in the middle of the run. So each thread makes whole runs; the compiled run
(:func:`bderiv.models.compiled._run.run_stretches`) and the driver of a stretch the Python
loop takes (:func:`bderiv.models.compiled._integrate.drive_stretch`) are ``nogil``: the
threads' compiled stretches run on the cores at once, and take the GIL only for the Python
around them. The Python parts (a run's set-up and records, the stop logic of the stops
handed back) run one at a time: the gain is the share of compiled time.
A Python model, or a compiled one whose stops are all Python's (its event Jacobian not had
in compiled code, or a Python reset), runs its batch one run after the other: threads would
only take turns at the GIL.

Thread safety. The runs share the model's compiled functions, its struct and atol caches
(``CompiledModel``: built once, then read; two threads building an entry build equal ones),
its set of checked Jacobians (``ModelCalls._checked``: one ``add`` per check), the
measured cost of a slice of steps (``_slices._cost``: it sets where a run hands back, never
its bits) and numba's dispatchers (a compilation holds numba's lock). A run's ``StopCalls``
are its own, and it draws no bar of its own time (the batch's bar is the calling
thread's). The
numerical-Jacobian cost counters are not touched: such a model's event Jacobian is had in
compiled code, and a field Jacobian only with the variational equations, which ``simulate``
does not integrate. The first runs go alone, until one has checked the event Jacobian (a
complex step found wrong is replaced by a numerical one: the loop's first check decides),
the rest on threads. The bar of runs done and ``progress(done, total)`` are drawn and
called by the calling thread, as runs finish.

Errors: the error of the first failing run in the order of the start states, as the loop
raises it (runs are taken in that order: the earlier ones still going are waited for; no
later one starts). Ctrl-C stops the batch within a second: the calling thread waits in
short slices and raises, no thread takes another run, and a run going in a thread stops at
its next slice of steps or stretch (:class:`_Workers`).
"""

from __future__ import annotations

import queue
import threading
from dataclasses import dataclass

import numba
import numpy as np

from ..._limits import GROUP_HELD_BYTES, RUN_HELD_BYTES
from ..._support._format import format_state, note_more
from ..._support._progress import count_bar, resolve_progress
from ..._support._tables import human_bytes, mask_dtype
from ..._support._validate import (
    batch_size,
    check_memory,
    check_number,
    check_points,
    check_positive_int,
    check_record,
)
from ..compiled import Cancelled, stopped_by
from .options import check_options
from .run import STEPS, compiled_stops, run, stops_compile

__all__ = ["Trajectories", "check_states", "run_many", "threaded", "worker_count"]

#: seconds the calling thread waits for a run at a time (it sees Ctrl-C in between)
_POLL = 0.05
#: the words of a refusal of a batch that would not fit in memory: what to do instead
_INSTEAD = ("pass fewer start states at a time (the batch in chunks, one call each, keeping "
            "of each what you need), or t_eval=() to keep the final states and the events "
            "only (or fewer t_eval times)")


@dataclass(frozen=True, eq=False)
class Trajectories:
    """Result of :meth:`HybridSystem.simulate_many
    <bderiv.analysis.system.HybridSystem.simulate_many>`: one trajectory per start state.

    Attributes
    ----------
    trajectories : tuple of Trajectory
        The runs, in the order of the start states (row-major over the leading shape).
    x_final : ndarray, shape (..., d)
        The final states, in the shape of ``X0``.
    mask_final : ndarray of int64, shape (...)
        The final region masks (Python ints, dtype object, for a model of more than 63
        events).

    ``len``, iteration and indexing (``runs[i]``: a Trajectory) go over ``trajectories``.
    """

    trajectories: tuple
    x_final: np.ndarray
    mask_final: np.ndarray

    def __len__(self):
        return len(self.trajectories)

    def __iter__(self):
        return iter(self.trajectories)

    def __getitem__(self, i):
        return self.trajectories[i]


def check_states(X0, dim: int, record=STEPS) -> tuple[np.ndarray, tuple]:
    """Start states ``(..., d)`` as C-contiguous float64 rows ``(m, d)`` and the leading
    shape; a ValueError names what was expected and what came, or the first row that is
    not finite. First, from ``X0``'s shape alone (before any copy), a batch whose runs
    would take more than the process may is refused: at least :func:`run_bytes` of a run
    that meets no event and keeps, of ``record`` (``STEPS`` or the times ``t_eval``), the
    start and the end or the times asked for."""
    X0, m, copy = batch_size(X0, dim, "X0")
    samples = 2 if isinstance(record, str) else record.size
    per = _held_bytes(dim, 0, samples * (16 + 8 * dim))
    check_memory(copy + m * per, None,
                 f"the {m} runs of simulate_many (at least {human_bytes(per)} a run: its "
                 f"final state and {samples} samples; more with each event group it meets "
                 f"and each step it keeps) would", _INSTEAD)
    return check_points(X0, dim, "X0", meaning="start states of this system, one per row")


def run_bytes(traj) -> int:
    """About the bytes a run of a batch holds: its Trajectory's samples, event groups and
    final state, and the batch's slots for it (``RUN_HELD_BYTES``, ``GROUP_HELD_BYTES``)."""
    return _held_bytes(traj.x_final.size, len(traj.groups),
                       traj.t.nbytes + traj.x.nbytes + traj.masks.nbytes)


def _held_bytes(d: int, groups: int, samples: int) -> int:
    """A run's bytes (:func:`run_bytes`) of dimension ``d``: ``samples`` bytes of samples,
    ``groups`` event groups (each with two states), its final state in the Trajectory and
    in the batch's ``x_final``, its final mask and its two slots (a list, a tuple)."""
    return RUN_HELD_BYTES + groups * (GROUP_HELD_BYTES + 16 * d) + samples + 16 * d + 24


def threaded(system, section=None) -> bool:
    """Whether a batch of ``system`` runs on threads: its stops are decided in compiled
    code (:func:`.run.stops_compile`), so its runs spend their time in the compiled run,
    which releases the GIL."""
    return stops_compile(system)


def worker_count(m: int) -> int:
    """Threads for ``m`` runs: ``numba.config.NUMBA_NUM_THREADS`` (the cores, or the
    environment variable of that name), at most ``m``."""
    return max(1, min(m, numba.config.NUMBA_NUM_THREADS))


def run_many(system, X0, lead, t_final, *, options, max_groups,
             section=None, progress=None, record=STEPS) -> Trajectories:
    """:func:`~bderiv.models.integrate.run.run` from every row of ``X0``, on
    :func:`worker_count` threads when :func:`threaded` (else one after the other).

    Parameters
    ----------
    system : ModelCalls
        The model's checked calls (``HybridSystem.calls``).
    X0 : ndarray, shape (m, d)
        Checked start states (:func:`check_states`).
    lead : tuple
        The leading shape the results take (``m`` = its product).
    t_final, options, max_groups, section, record
        As for :func:`~bderiv.models.integrate.run.run` (checked here once; ``record``
        by the caller).
    progress : None, bool or callable ``progress(done, total)``
        None: a bar of the runs done once the batch has lasted a few seconds (on a
        terminal, as a simulation's); False: none; True: a tqdm bar from the start; a
        callable: called after each run (in the calling thread, as runs finish).

    Returns
    -------
    Trajectories

    Raises
    ------
    ValueError, RuntimeError
        As a run raises them, the message prefixed with the start state's index (the
        first failing run in the order of ``X0``).
    """
    t_final = check_number(t_final, "t_final")
    check_options(options)
    max_groups = check_positive_int(max_groups, "max_groups")
    m = X0.shape[0]

    def one(i):
        return run(system, X0[i].copy(), t_final, options=options, max_groups=max_groups,
                   section=section, record=record, bar=False)

    watch = None
    if progress is None:
        watch = count_bar(m, "simulate_many", "runs")
        report = watch
    else:
        tell = resolve_progress(progress, desc="simulate_many", unit="run")
        report = None if tell is None else (lambda done: tell(done, m))
    trajectories = [None] * m
    store = _Store(trajectories, report)

    def parallel(first):
        return worker_count(m - first) > 1 and threaded(system, section)

    try:
        first = 0
        # a new model's runs on its Python code one by one, until they are compiled
        while first < m and getattr(system, "python_first", False):
            first += _serial(one, range(first, first + 1), store, X0, lead)
        # runs alone until one has checked the event Jacobian (whose check may change how
        # the model computes it): the order of the loop of simulate
        while parallel(first) and not compiled_stops(system, section):
            first += _serial(one, range(first, first + 1), store, X0, lead)
        if parallel(first):
            _Workers(one, range(first, m), worker_count(m - first)).collect(store, X0, lead)
        else:
            _serial(one, range(first, m), store, X0, lead)
    finally:
        if watch is not None:
            watch.close()
    d = X0.shape[1]
    x_final = np.array([traj.x_final for traj in trajectories]).reshape(lead + (d,))
    masks = np.array([traj.mask_final for traj in trajectories],
                     dtype=mask_dtype(system.n_events))
    return Trajectories(tuple(trajectories), x_final, masks.reshape(lead))


def _named(exc, i, X0, lead):
    """A run's ValueError or RuntimeError again, its message prefixed with the start state
    (``exc`` itself for another exception)."""
    where = ", ".join(str(int(j)) for j in np.unravel_index(i, lead)) if lead else ""
    if type(exc) not in (ValueError, RuntimeError):  # a model's function's: a note more
        note_more(exc, f"in the run from X0[{where}] = {format_state(X0[i])}")
        return exc
    return type(exc)(f"the run from X0[{where}] = {X0[i]}: {exc}")


def _raise(exc, i, X0, lead):
    named = _named(exc, i, X0, lead)
    if named is exc:
        raise exc
    raise named from exc


class _Store:
    """Where the calling thread puts each run as it finishes: its slot of ``trajectories``,
    the report of the runs done, and the bytes the batch holds (:func:`run_bytes`), checked
    again whenever they have grown by half against the runs left at the mean so far, as a
    run's record is (:func:`bderiv._support._validate.check_record`): a batch of runs
    larger than measured up front (:func:`check_states`) is refused as it grows."""

    def __init__(self, trajectories, report):
        self.trajectories, self.report = trajectories, report
        self.done = self.held = self.next_check = 0

    def __call__(self, i, traj) -> None:
        self.trajectories[i] = traj
        self.done += 1
        self.held += run_bytes(traj)
        if self.held >= self.next_check:
            self.next_check = self.held + self.held // 2
            m, done = len(self.trajectories), self.done
            check_record(self.held, self.held * (m - done) // done,
                         f"simulate_many's batch ({done} of {m} runs done, about "
                         f"{human_bytes(self.held // done)} a run)", _INSTEAD)
        if self.report is not None:
            self.report(self.done)


def _serial(one, indices, store, X0, lead) -> int:
    """The runs of ``indices`` one after the other in this thread; the number done."""
    for i in indices:
        try:
            traj = one(i)
        except Exception as exc:  # named (ours) or noted (a model's function's)
            _raise(exc, i, X0, lead)
        store(i, traj)
    return len(indices)


class _Workers:
    """The runs of ``indices``, taken in order by ``count`` threads.

    Each thread takes the next index until none is left or the batch stops, and puts
    ``(i, trajectory, exception)`` on a queue the calling thread reads (:meth:`collect`).
    A run already going stops at its next slice of steps or stretch
    (:func:`bderiv.models.compiled.stopped_by`: its thread reads the batch's stop event
    there), within about ``SLICE_SECONDS``: compiled code does not see signals, and an
    exception set in the thread from outside (``PyThreadState_SetAsyncExc``) lands
    anywhere, even between a lock's acquire and the ``try`` that releases it (numba's
    compiler lock: seen deadlocking the next compilation).
    """

    def __init__(self, one, indices, count):
        self.one, self.indices = one, indices
        self.order = iter(indices)  # next() of a range iterator: atomic under the GIL
        self.done = queue.SimpleQueue()
        self.stop = threading.Event()
        # daemons: after Ctrl-C the interpreter may exit without waiting for the runs going
        self.threads = [threading.Thread(target=self._work, name=f"bderiv.simulate_many-{k}",
                                         daemon=True) for k in range(count)]

    def _work(self):
        with stopped_by(self.stop):  # a run going stops at its next slice or stretch
            while not self.stop.is_set():
                i = next(self.order, None)
                if i is None:
                    return
                try:
                    self.done.put((i, self.one(i), None))
                except Cancelled:
                    return
                except BaseException as exc:  # noqa: BLE001 - the calling thread raises it
                    self.done.put((i, None, exc))
                    return

    def collect(self, store, X0, lead) -> None:
        """Run the threads and ``store`` their trajectories as they finish (:class:`_Store`).
        Raise the first failing run's error in the order of the indices (named), once
        every run before it has finished; or what this thread meets (Ctrl-C, a batch
        grown too large) at once. Either way no thread takes another run, and the runs
        going stop at their next slice of steps."""
        start = self.indices.start
        reported = np.zeros(len(self.indices), dtype=bool)
        low, failed = 0, None  # the first index not reported; (i, exc) of the first failure
        try:
            for thread in self.threads:
                thread.start()
            while low < reported.size and (failed is None or start + low < failed[0]):
                try:
                    i, traj, exc = self.done.get(timeout=_POLL)
                except queue.Empty:
                    continue
                reported[i - start] = True
                while low < reported.size and reported[low]:
                    low += 1
                if exc is not None:
                    self.stop.set()
                    if failed is None or i < failed[0]:
                        failed = (i, exc)
                    continue
                store(i, traj)
        finally:
            self.stop.set()
        if failed is not None:
            _raise(failed[1], failed[0], X0, lead)
        for thread in self.threads:  # each ends at its next index (none left)
            while thread.is_alive():
                thread.join(_POLL)
