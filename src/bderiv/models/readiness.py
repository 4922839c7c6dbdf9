"""Whether the compiled integrator is ready on this machine, and its compilation meanwhile.

The compiled integrator (the driver :func:`._integrate.drive_stretch` and the compiled run
:func:`._run.run_stretches`) takes about a minute or two of one core to compile, once per
machine and bderiv version; later processes load it from numba's disk cache in a fraction
of a second. A compiled model does not need it to get its answers: the Python loop on
scipy's ``solve_ivp`` runs the same method (DOP853, the same tableau and step control), the
same event location and the same stop rules, calling the model's numba functions from
Python (slower per run, never different in what it decides: both paths are held to each
other by the tests). So a process that finds the integrator neither compiled in it nor in
the disk cache does one of three things, chosen by the environment variable
``BDERIV_INTEGRATOR``:

- ``auto`` (the default): it starts ``python -m bderiv compile integrator`` in a
  background process (once per machine at a time: a lock file in the cache folder) and
  runs compiled models on scipy until the disk cache holds the integrator; from the
  next run after that, on the compiled integrator. The first answer comes in seconds; the
  runs become fast when the compilation ends (the logger ``bderiv`` says both).
- ``compiled``: it waits for the integrator (compiling it, or waiting for the process that
  does), then runs compiled. For benchmarks and for work that must run on one integrator
  from its first call.
- ``scipy``: compiled models run on scipy, their numba functions called from Python (a
  check of the compiled path, or a machine that should not spend the integrator's minutes
  of compiling). The model's functions still compile at their first calls, as numba
  compiles any function, and so do the kernels of the B-derivatives; there is no Python
  first under this policy (the check is of the numba functions).

The variable is read when a model's compiled functions are first needed (a model that
runs compiled keeps doing so), and when a model of numba functions is made. Under ``auto``
a new model of numba functions (none compiled in the process, none kept on disk) also
starts on their Python code, the code numba compiles, until its runs on it have taken a
second: its first answers come without compiling it
(:func:`bderiv.models.calls.starts_in_python`).

The lock (``fcntl.flock`` on a file beside the driver's cache index) makes one process
compile while the others wait or go on with scipy; the compiling process checks the cache
again once it holds the lock. Where ``fcntl`` is missing (Windows), a process that needs
the integrator runs ``python -m bderiv compile integrator`` and waits for it (no lock to
share a background compilation by); where no process can be started, the integrator is
compiled in the process that needs it, as numba does by itself. A process forked from
one that started the background compilation (a ``multiprocessing`` pool) does not own
that process: it starts no other while that one runs, and reads the lock and the disk
cache like any other.

Only :func:`integrator_ready` is called on the run's path (through ``ModelCalls.compiled``):
while the integrator is not ready it looks at the disk at most every
:data:`POLL_SECONDS`.
"""

from __future__ import annotations

import contextlib
import logging
import os
import pathlib
import subprocess
import sys
import tempfile
import threading
import time

try:
    import fcntl
except ImportError:  # Windows: no lock, the integrator compiles where it is needed
    fcntl = None

from .._support._policy import POLICY_VARIABLE, policy
from .compiled import machine_has
from .compiled._integrate import drive_stretch
from .compiled._run import run_stretches

_log = logging.getLogger("bderiv")

#: seconds between two looks at the disk cache while the integrator is not ready
POLL_SECONDS = 1.0
#: the dispatchers that make up the integrator (the others are small and compile in
#: seconds wherever they are first called)
DISPATCHERS = (drive_stretch, run_stretches)

#: numba's optimisation level (``NUMBA_OPT``) in the process that compiles the integrator,
#: unless the caller's environment sets one: LLVM's -O1 compiles it in about 12 % less CPU
#: than numba's default 3; the driver and the compiled run are as fast within the runs'
#: spread, and compute the same numbers (no fast-math: no level reorders floating-point
#: arithmetic) (benchmarks/driver_step.py and compiled_path.py; design.md, "The integrator
#: at -O1")
COMPILE_OPT = "1"

class PythonTierEnded(BaseException):
    """Raised in a run on a new model's Python code when its time there is spent
    (:data:`bderiv._limits.PYTHON_FIRST_SECONDS`), or when that code raised (its
    cause: numba may compile what Python refuses): the run is made again on the compiled
    functions. A BaseException, as KeyboardInterrupt: no ``except Exception`` on the way
    takes it for the model's own error."""


#: held by the thread that looks at the disk where the others must wait for its answer
#: (``BDERIV_INTEGRATOR=compiled``)
_LOOKING = threading.Lock()
_state = {"ready": False, "checked": -float("inf"), "child": None, "said": False,
          "here": False, "foreign": None}


def _forget_child() -> None:
    """In a forked process: the background compilation is its parent's child, not its own
    (``poll`` would take it for a process that ended with status 0). Its pid is kept, to
    start no other while it runs (it takes the lock only once its interpreter is up)."""
    child, _state["child"] = _state["child"], None
    if child is not None:
        _state["foreign"] = child.pid
        child.returncode = -1  # Popen's finalizer then neither warns nor waits for it
        child.log.close()


def _foreign_running() -> bool:
    """Whether the background compilation a forked process inherited still runs (a
    zombie, ended but not yet waited for by its parent, does not)."""
    pid = _state["foreign"]
    if pid is None:
        return False
    try:
        with open(f"/proc/{pid}/stat") as fh:
            running = fh.read().rsplit(")", 1)[1].split()[0] != "Z"
    except (OSError, IndexError):  # no /proc: whether the pid exists
        try:
            os.kill(pid, 0)
            running = True
        except OSError:
            running = False
    if not running:
        _state["foreign"] = None
    return running


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_forget_child)


def integrator_cached() -> bool:
    """Whether every part of the integrator is compiled here or in the disk cache."""
    return all(machine_has(d) for d in DISPATCHERS)


def lock_path() -> pathlib.Path | None:
    """The lock file of the integrator's compilation, beside the driver's cache index
    (the folder numba caches it in: ``NUMBA_CACHE_DIR``, or ``__pycache__`` beside the
    sources); None where it cannot be had."""
    try:
        folder = pathlib.Path(drive_stretch._cache._cache_file._cache_path)
        folder.mkdir(parents=True, exist_ok=True)
    except (AttributeError, OSError):
        return None
    return folder / "bderiv-integrator.lock"


@contextlib.contextmanager
def compile_lock(wait: bool = True):
    """Hold the compilation lock (``wait``: until it is free); yields whether it is held
    (False: another process holds it, ``wait`` False; also where no lock can be had)."""
    path = lock_path()
    if fcntl is None or path is None:
        yield False
        return
    with open(path, "a+b") as fh:
        try:
            fcntl.flock(fh, fcntl.LOCK_EX | (0 if wait else fcntl.LOCK_NB))
        except BlockingIOError:
            yield False
            return
        try:
            yield True
        finally:
            fcntl.flock(fh, fcntl.LOCK_UN)


def held_elsewhere() -> bool:
    """Whether another process holds the compilation lock (False where no lock can be
    had: no ``fcntl``, no cache folder)."""
    with compile_lock(wait=False) as free:
        return not free and fcntl is not None and lock_path() is not None


def compile_command() -> list[str]:
    """The command that compiles the integrator: this interpreter, ``-m bderiv compile
    integrator`` (in that process itself: ``--here``)."""
    return [sys.executable, "-m", "bderiv", "compile", "integrator", "--here"]


def child_environment() -> dict:
    """This process's environment, with the folder holding this bderiv first on
    ``PYTHONPATH`` (the child must compile the same sources)."""
    env = dict(os.environ)
    root = str(pathlib.Path(__file__).resolve().parents[2])
    env["PYTHONPATH"] = os.pathsep.join(p for p in (root, env.get("PYTHONPATH")) if p)
    return env


def compile_environment() -> dict:
    """The environment of the process that compiles the integrator:
    :func:`child_environment` with ``NUMBA_OPT`` at :data:`COMPILE_OPT` unless set."""
    env = child_environment()
    env.setdefault("NUMBA_OPT", COMPILE_OPT)
    return env


#: the nice value of the background compilation (its process, and its session's scheduling
#: group where the kernel groups sessions: the "autogroup" of Linux desktops and of these
#: machines, where a process's own nice value counts only against its own session)
NICE = 10


def lower_priority() -> None:
    """Run this process (the background compilation, a session of its own) at :data:`NICE`:
    its nice value, and its session's scheduling group's where Linux has one. Without the
    group's, a new session's process competes with the program that started it as an equal,
    whatever its nice value (measured with two busy loops on one core: 2.0 / 2.0 s; with it
    3.6 / 0.4 s, the program first)."""
    if hasattr(os, "nice"):
        os.nice(NICE)
    try:
        with open("/proc/self/autogroup", "w") as group:
            group.write(str(NICE))
    except OSError:  # no autogroup (another kernel, another system): the nice value alone
        pass


def start_background(nice: bool = True) -> bool | None:
    """Start the compiling process unless another process holds the lock (``nice``: at a
    lower priority than this one): True when started, None when another compiles, False
    when no process could be started."""
    if held_elsewhere():
        return None
    try:
        log = tempfile.TemporaryFile()  # its error output, read if it fails
        child = subprocess.Popen([*compile_command(), *(["--nice"] if nice else [])],
                                 env=compile_environment(),
                                 stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                                 stderr=log, start_new_session=True)
        child.log = log
    except OSError as exc:
        _log.info("bderiv: no background process for the compiled integrator (%s)", exc)
        return False
    _state["child"] = child
    return True


def wait_for_background(timeout: float | None = None) -> bool:
    """Wait for the background compilation this process started to end, its workload
    included (for a script that measures what comes next, or removes the cache folder the
    compilation writes to): True when it has ended or none was started, False when
    ``timeout`` seconds passed first. A failure is reported as before, by the next look
    at the integrator."""
    child = _state["child"]
    if child is None:
        return True
    try:
        child.wait(timeout)
    except subprocess.TimeoutExpired:
        return False
    return True


def compiling_here() -> None:
    """Mark the integrator ready in this process: the process that compiles it
    (``python -m bderiv compile integrator``, holding the lock) runs it compiled, whatever
    ``BDERIV_INTEGRATOR`` says (``scipy`` would compile nothing)."""
    _state["ready"] = _state["here"] = True


def compiling_in_this_process() -> bool:
    """Whether this process compiles the integrator (:func:`compiling_here`): its models
    run compiled from their first use, their functions compiled for the disk cache."""
    return _state["here"]


def ready_now() -> bool:
    """Whether compiled models run compiled now, without looking at the disk (the first
    call of a process looks: :func:`integrator_ready`); runs look when they start."""
    if _state["checked"] == -float("inf"):
        return integrator_ready()
    return _state["here"] or (_state["ready"] and policy() != "scipy")


def _wait_for_integrator() -> None:
    """Compile the integrator in the foreground (policy ``compiled``), or wait for the
    process that compiles it; a compilation that fails there is left to numba here. The
    compiling process takes the lock itself: it is not held here meanwhile."""
    if held_elsewhere():
        _log.warning("bderiv: waiting for another process that compiles the compiled "
                     "integrator for this machine (once: about one to two minutes)")
        with compile_lock(wait=True):  # its end
            pass
    if integrator_cached():
        return
    _log.warning("bderiv: compiling the compiled integrator for this machine (once: "
                 "about one to two minutes; later runs load it from numba's disk cache)")
    with tempfile.TemporaryFile() as log:  # its error output: said only if it fails
        done = subprocess.run(compile_command(), env=compile_environment(), check=False,
                              stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                              stderr=log)
        if done.returncode != 0 and not integrator_cached():
            log.seek(0)
            tail = log.read().decode(errors="replace")[-1500:]
            _log.warning("bderiv: compiling the compiled integrator in its own process "
                         "failed (exit status %d); it is compiled in this process at its "
                         "first use.%s", done.returncode, f"\n{tail}" if tail else "")


def _child_ended() -> bool:
    """Whether the background process ended without the integrator in the cache (warned,
    with the end of its error output): it is then compiled in this process."""
    child = _state["child"]
    if child is None or child.poll() is None:
        return False
    child.log.seek(0)
    tail = child.log.read().decode(errors="replace")[-1500:]
    child.log.close()
    _state["child"] = None
    _log.warning("bderiv: the background compilation of the compiled integrator ended "
                 "(exit status %d) without putting it in numba's disk cache; it is compiled "
                 "in this process at its first use.%s", child.returncode,
                 f"\n{tail}" if tail else "")
    return True


def integrator_ready() -> bool:
    """Whether compiled models run on the compiled integrator now (see the module
    docstring for the policies); the first call that finds it missing starts its
    compilation (``auto``) or waits for it (``compiled``)."""
    if _state["here"]:
        return True
    chosen = policy()
    if chosen == "scipy":
        return False
    if _state["ready"]:
        child = _state["child"]  # the background process, after its workload: waited for
        if child is not None and child.poll() is not None:
            child.log.close()  # (closed already where the cache was seen; not after a wait)
            _state["child"] = None
        return True
    waits = chosen == "compiled" or fcntl is None
    with _LOOKING if waits else contextlib.nullcontext():  # a thread that must wait waits
        if _state["ready"]:  # for the one that looks (it answered False: a review)
            return True
        now = time.monotonic()
        if not waits and now - _state["checked"] < POLL_SECONDS:
            return False
        _state["checked"] = now
        if integrator_cached():
            _state["ready"] = True
            if _state["child"] is not None:  # its error output is not needed (it runs its
                _state["child"].log.close()  # workload still: waited for by later calls)
            if _state["said"]:
                _log.warning("bderiv: the compiled integrator is ready; compiled models run "
                             "on it from the next run on")
            return True
        if waits:
            _wait_for_integrator()
            _state["ready"] = True  # compiled now, or compiled by numba at the first call
            return True
    if _child_ended() or (_state["child"] is None and not _foreign_running()
                          and start_background() is False):
        _state["ready"] = True  # numba compiles it here, at the first call
        return True
    if not _state["said"]:
        _state["said"] = True
        _log.warning(
            "bderiv: the compiled integrator is not compiled on this machine yet; it is "
            "being compiled in a background process (%sabout one to two minutes of one "
            "core, once per machine; it goes on if this program ends first, and later "
            "programs load what it compiled). Until it is ready, compiled models run on "
            "scipy's solve_ivp (the same method and stop rules, slower per run). `python -m "
            "bderiv compile` compiles everything and waits; %s=compiled waits in this "
            "process.", "" if _state["child"] is None else f"pid {_state['child'].pid}; ",
            POLICY_VARIABLE)
    return False
