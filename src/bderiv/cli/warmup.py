"""Compile bderiv's kernels ahead of their first use: ``python -m bderiv compile``.

A fresh machine (a Docker image being built, a CI job, a new Dask worker, an upgrade of
numba or bderiv) compiles each kernel at its first use and keeps it in numba's disk cache
(``NUMBA_CACHE_DIR``, else ``__pycache__`` beside the sources) for every later process.
:func:`warm_up` does that compiling ahead of time, each family of kernels in its own
process, as many at once as there are cores, so that the machine's first real call only
loads. Each family is a small workload of the public API that reaches its kernels with the
argument types real calls give them:

- ``integrator``: the compiled integrator of compiled models (the driver and the compiled
  run; about one to two minutes of one core, most of the total), after the stop rules as
  the Python integrator calls them (which run as Python until they are on the machine:
  :mod:`bderiv.models.events._python_rules`). Its process holds the
  lock of :mod:`bderiv.models.readiness`, so a process that needs it meanwhile
  waits for it or runs on scipy instead of compiling it a second time.
- ``dense``: the kernels of a B-derivative from a dense corner table (a model's event
  point, as the chair's): single vectors, batches, transposes, orders, and the chair's
  flow map (on its Python functions: the demo's queries, on a model's read-only tables).
- ``structured``: those of corner models: structured corners (n up to 128) and corner
  functions (``CornerFunction``: the kernels are shared by every function; a user's own
  function compiles at its first use, under a second).
- ``resets``: those of B-derivatives with resets (impacts, bounces): the ball in a
  corner's flow map, every query.

Each family's process writes its own cache entries; two families that compile the same
small helper both write the same entry (numba writes a file whole, under a temporary name
first), so the processes need no further order. A user's own model functions are not
here: they compile at the model's first use (seconds), or from its own ``cache=True``.
"""

from __future__ import annotations

import contextlib
import gc
import os
import subprocess
import sys
import tempfile
import time

import numpy as np

#: the families, in the order they are started (the longest first)
FAMILIES = ("integrator", "dense", "structured", "resets")

#: the collector's threshold of full collections (CPython's third, 10 by default; a
#: collector without generations ignores it) in a process of one family: numba's compiler
#: keeps a large graph of objects alive, which every full collection walks; at 10 the
#: integrator's 33 took 7.0 s of CPU (at -O1), at this value its 4 took 2.3 s, for 6 % more
#: memory (design.md, "The collector")
FULL_COLLECTIONS = 100


def _integrator() -> str | None:
    from .. import examples
    from ..models import readiness
    from ..models.events._python_rules import compile_for_python

    elsewhere = readiness.held_elsewhere()
    with readiness.compile_lock(wait=True):
        if readiness.integrator_cached():
            return "compiled by another process, waited for" if elsewhere else \
                "in the cache already"
        readiness.compiling_here()
        compile_for_python(_python_stops)  # first: the rules a first answer needs
        ex = examples.chair(compiled=True)
        s = ex.system
        s.simulate(ex.x0, ex.t_final)  # the compiled run decides the stops
        s.flow_bderivative(ex.x0, ex.t_final)  # with the variational equations


def _python_stops() -> None:
    """Flow maps of Python models, the stops of the chair and of the ball in a corner (its
    resets): the stop rules as the Python integrator calls them."""
    from .. import examples

    for ex in (examples.chair(), examples.ball_in_corner()):
        ex.system.flow_bderivative(ex.x0, ex.t_final)


def _queries(bd, d, rng) -> None:
    """Every operation of ``bd`` (a B-derivative or a flow map) on one vector and on a
    batch (the parallel kernels), and the orders of a small batch and of a large one."""
    for V in (rng.standard_normal(d), rng.standard_normal((20_000, d))):
        T = rng.standard_normal(V.shape)
        bd(V)
        bd.inverse(V)
        bd.event_times(V)
        bd.jvp(V, T)
        bd.vjp(V, T)
    for m in (10, 20_000):
        bd.orders(rng.standard_normal((m, d)))


def _flow_map(example) -> None:
    """The queries of ``example``'s flow map on its Python functions (no integrator): the
    read-only tables of a model's event groups, which the tables built here are not."""
    from .. import examples

    ex = getattr(examples, example)()
    fb = ex.system.flow_bderivative(ex.x0, ex.t_final)
    rng = np.random.default_rng(3)
    _queries(fb, fb.dim, rng)
    orders = fb.orders(rng.standard_normal((1, fb.dim)))
    fb.apply_orders(rng.standard_normal((10, fb.dim)))
    fb.piece([o[0].tolist() for o in orders])  # a piece's matrices (the demo lists them)
    for bd, o in zip(fb.jumps, orders, strict=True):
        bd.piece(o[0])


def _dense() -> None:
    from ..engine.bderivative import BDerivative

    rng = np.random.default_rng(0)
    for n, d in ((2, 6), (3, 4), (8, 8), (3, 66)):  # lanes (d <= 64) and plain blocks
        Dh = np.eye(n, d) + 0.3 / n * rng.uniform(-1, 1, (n, d))
        F = np.linalg.lstsq(Dh, np.ones(n), rcond=None)[0] + \
            0.1 * rng.uniform(-1, 1, (2**n, d))
        _queries(BDerivative(Dh, F), d, rng)
    _flow_map("chair")  # the demo's and a model's flow map


def _structured() -> None:
    from ..engine.bderivative import BDerivative
    from ..geometry.corners import CornerFunction, StructuredCorners

    rng = np.random.default_rng(1)
    for n in (4, 40):  # corners like a multi-contact system, two pairs per event
        Dh = np.eye(n) + 0.3 / n * rng.uniform(-1, 1, (n, n))
        F0 = np.linalg.lstsq(Dh, np.ones(n), rcond=None)[0]
        A = 0.4 / n * rng.uniform(-1, 1, (n, n))
        pairs = np.stack([np.arange(n), (np.arange(n) + 1) % n], axis=1)
        B = 0.2 / n * rng.uniform(-1, 1, (n, n))
        _queries(BDerivative(Dh, StructuredCorners(F0, A, pairs, B)), n, rng)

    def corners(happened, out):  # three events in three dimensions, every rate positive
        for i in range(out.shape[0]):
            out[i] = 1.0 + 0.5 * happened[i] + 0.25 * happened[(i + 1) % out.shape[0]]

    _queries(BDerivative(np.eye(3), CornerFunction(corners)), 3, rng)  # CornerFunction jits


def _resets() -> None:
    _flow_map("ball_in_corner")


_WORK = {"integrator": _integrator, "dense": _dense, "structured": _structured,
         "resets": _resets}


def compile_family(name: str) -> str | None:
    """Compile family ``name`` in this process (its workload; see the module docstring);
    returns what happened instead where nothing was compiled (the integrator found in the
    cache, or compiled by another process meanwhile), else None."""
    if name not in _WORK:
        raise ValueError(f"family must be one of {', '.join(FAMILIES)}, got {name!r}")
    return _WORK[name]()


def rarer_full_collections() -> None:
    """Set this process's threshold of full collections to :data:`FULL_COLLECTIONS` (for a
    process that mostly compiles: a family's, a test worker; never a user's)."""
    young, middle, _ = gc.get_threshold()
    gc.set_threshold(young, middle, FULL_COLLECTIONS)


def compile_here(families, nice: bool = False) -> None:
    """Compile ``families`` in this process, a process of its own (``python -m bderiv
    compile FAMILY --here``: started by :func:`warm_up` and by the integrator's background
    compilation, ``--nice``: at a lower priority, :func:`bderiv.models.readiness.lower_priority`),
    its full collections made rarer first (:func:`rarer_full_collections`)."""
    if nice:  # a background compilation yields to the work
        from ..models.readiness import lower_priority

        lower_priority()
    rarer_full_collections()
    for name in families:
        with _counting_compiles() as compiled:
            note = compile_family(name)
        if note is None and compiled.count == 0:  # every kernel loaded from the disk
            note = "in the cache already"
        if note:  # for warm_up, which reads this process's output
            print(f"{name}: {note}", flush=True)


@contextlib.contextmanager
def _counting_compiles():
    """Counts numba's compile events of dispatchers that cache on disk (a cache hit fires
    none; ``.count``): a family that compiled nothing says so (it said "compiled in 1.8 s",
    having loaded every kernel). numba is imported here, not with the command line."""
    from numba.core import event

    class Count(event.Listener):
        count = 0

        def on_start(self, ev):
            cache = getattr(ev.data.get("dispatcher"), "_cache", None)  # (lifted loops:
            if getattr(cache, "cache_path", None) is not None:  # no cache, no stats)
                self.count += 1

        def on_end(self, ev):
            pass

    counter = Count()
    with event.install_listener("numba:compile", counter):
        yield counter


def warm_up(families=FAMILIES, processes=None, progress=None) -> dict:
    """Compile ``families`` (each in its own process, ``processes`` at a time: default
    the cores this process may use) into numba's disk cache; returns each family's wall
    seconds, in the order of ``families``.

    Parameters
    ----------
    families : str or sequence of str
        One or some of :data:`FAMILIES` (a name given twice is compiled once).
    processes : int, optional
        Families compiled at once (default ``len(os.sched_getaffinity(0))``).
    progress : callable ``progress(message)``, optional
        Told when a family starts and ends (its name, seconds, what is left).

    Raises
    ------
    ValueError
        An unknown family or ``processes`` below 1 (named).
    RuntimeError
        A family's process failed (its name and the end of its error output).
    KeyboardInterrupt
        Ctrl-C: the families' processes are stopped first.
    """
    families = [families] if isinstance(families, str) else list(dict.fromkeys(families))
    for name in families:
        if name not in _WORK:
            raise ValueError(f"families must be among {', '.join(FAMILIES)}, got {name!r}")
    if processes is None:
        processes = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else \
            (os.cpu_count() or 1)
    if isinstance(processes, bool) or not isinstance(processes, int) or processes < 1:
        raise ValueError(f"processes must be an integer >= 1, got {processes!r}")
    say = progress or (lambda message: None)
    waiting, running, seconds = list(families), {}, {}
    try:
        while waiting or running:
            while waiting and len(running) < processes:
                name = waiting.pop(0)
                doing = (f"waiting for another process that compiles {name}"
                         if name == "integrator" and _held_elsewhere() else f"compiling {name}")
                running[name] = (time.perf_counter(), _start(name))
                say(f"{doing} ({len(seconds) + len(running)} of {len(families)})")
            time.sleep(0.05)
            for name, (start, proc) in list(running.items()):
                if proc.poll() is None:
                    continue
                del running[name]
                proc.log.seek(0)
                err = proc.log.read().decode(errors="replace")
                proc.log.close()
                proc.out.seek(0)
                note = proc.out.read().decode(errors="replace").strip()
                proc.out.close()
                if proc.returncode != 0:
                    raise RuntimeError(f"compiling the family {name} failed (exit status "
                                       f"{proc.returncode}):\n{err[-2000:]}")
                seconds[name] = time.perf_counter() - start
                done = note.partition(": ")[2] or "compiled"
                say(f"{name} {done} in {seconds[name]:.1f} s ({len(seconds)} of "
                    f"{len(families)} done)")
    finally:
        for _, proc in running.values():
            proc.kill()
            proc.wait()
            proc.log.close()
            proc.out.close()
    return {name: seconds[name] for name in families}  # in the order asked


def _held_elsewhere() -> bool:
    """Whether another process compiles the integrator now (its lock held)."""
    from ..models import readiness

    return readiness.held_elsewhere()


def _start(name: str) -> subprocess.Popen:
    """The process that compiles family ``name`` (this bderiv: its folder first on
    ``PYTHONPATH``)."""
    from ..models import readiness

    env = readiness.compile_environment() if name == "integrator" else \
        readiness.child_environment()
    proc = subprocess.Popen([sys.executable, "-m", "bderiv", "compile", name, "--here"],
                            env=env, stdin=subprocess.DEVNULL,
                            stdout=(out := tempfile.TemporaryFile()),
                            stderr=(log := tempfile.TemporaryFile()))
    proc.log = log  # its error output, read when it fails
    proc.out = out  # what it says it did where it compiled nothing (compile_here)
    return proc
