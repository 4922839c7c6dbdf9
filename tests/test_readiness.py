"""The compiled integrator's readiness: compiled models run on scipy while it compiles in a
background process, wait for it, or never use it (``BDERIV_INTEGRATOR``).

The integrator itself takes a minute or two to compile, so the protocol is tested with a
stand-in: a small cached numba function in a module of a temporary folder, compiled by a
child process that the test's compile command starts, its cache index read as
:func:`bderiv.models.readiness.integrator_cached` reads the integrator's.
"""

from __future__ import annotations

import logging
import subprocess
import sys
import textwrap
import time

import numpy as np
import pytest

from bderiv import examples
from bderiv.models import readiness

STAND_IN = """
import numba

@numba.njit(cache=True)
def part(x):
    return 2.0 * x
"""


@pytest.fixture
def stand_in(tmp_path, monkeypatch):
    """The readiness module on a stand-in integrator: its dispatcher, lock and command."""
    module = f"stand_in_{tmp_path.name.replace('-', '_')}"
    (tmp_path / f"{module}.py").write_text(STAND_IN)
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setenv("PYTHONPATH", str(tmp_path))
    mod = __import__(module)
    monkeypatch.setattr(readiness, "DISPATCHERS", (mod.part,))
    monkeypatch.setattr(readiness, "lock_path", lambda: tmp_path / "integrator.lock")
    monkeypatch.setattr(readiness, "_state", {"ready": False, "checked": -float("inf"),
                                              "child": None, "said": False, "here": False,
                                              "foreign": None})
    monkeypatch.setattr(readiness, "POLL_SECONDS", 0.0)
    monkeypatch.delenv(readiness.POLICY_VARIABLE, raising=False)
    # the compiling process takes the lock, as `bderiv compile integrator` does (at once:
    # a caller holding it while it runs would wait forever)
    command = [sys.executable, "-c", f"import fcntl, {module}; fh = open("
               f"{str(tmp_path / 'integrator.lock')!r}, 'a+b'); fcntl.flock(fh, "
               f"fcntl.LOCK_EX | fcntl.LOCK_NB); {module}.part(1.0)"]
    monkeypatch.setattr(readiness, "compile_command", lambda: command)
    return mod


def _wait_child(timeout=120.0):
    child = readiness._state["child"]
    assert child is not None, "no background process was started"
    child.wait(timeout)


def test_auto_runs_on_scipy_until_the_background_process_has_compiled(stand_in, caplog):
    caplog.set_level(logging.WARNING, logger="bderiv")
    assert not readiness.integrator_cached()
    assert readiness.integrator_ready() is False
    assert "being compiled in a background process" in caplog.text
    assert not stand_in.part.signatures  # not compiled in this process
    _wait_child()
    assert readiness.integrator_ready() is True
    assert "is ready" in caplog.text
    assert not stand_in.part.signatures  # the child compiled it; here it only loads


def test_no_second_process_while_another_holds_the_lock(stand_in):
    with readiness.compile_lock(wait=False) as held:
        assert held
        assert readiness.integrator_ready() is False
        assert readiness._state["child"] is None  # the holder compiles: none started


def test_compiled_policy_waits_for_the_compilation(stand_in, monkeypatch):
    monkeypatch.setenv(readiness.POLICY_VARIABLE, "compiled")
    assert readiness.integrator_ready() is True
    assert readiness.integrator_cached()
    assert readiness._state["child"] is None


def test_a_background_process_waited_for_under_the_compiled_policy_is_let_go_closed(
        stand_in, monkeypatch):
    """A process that started the background compilation (``auto``) and then waited for it
    (``compiled``: pytest's main process under ``-n 0`` and its tests) dropped it with its
    error output's file open: a ResourceWarning at a later call, an error under the suite's
    filters (a review, on an empty cache)."""
    assert readiness.integrator_ready() is False  # auto: started in the background
    child = readiness._state["child"]
    monkeypatch.setenv(readiness.POLICY_VARIABLE, "compiled")
    assert readiness.integrator_ready() is True  # waited for it (its lock)
    child.wait(120)
    assert readiness.integrator_ready() is True  # the ended process let go ...
    assert readiness._state["child"] is None and child.log.closed  # ... its file closed


def test_a_failed_background_process_is_named_and_the_integrator_compiles_here(
        stand_in, monkeypatch, caplog):
    monkeypatch.setattr(readiness, "compile_command", lambda: [
        sys.executable, "-c", "import sys; sys.exit('no compiler here')"])
    caplog.set_level(logging.WARNING, logger="bderiv")
    assert readiness.integrator_ready() is False
    _wait_child()
    assert readiness.integrator_ready() is True
    assert "exit status 1" in caplog.text and "no compiler here" in caplog.text


@pytest.mark.parametrize("policy", ["auto", "compiled"])  # in the background, waited for
@pytest.mark.parametrize("set_by_caller", [None, "2"])
def test_the_compiling_process_runs_at_the_integrators_optimisation_level(
        stand_in, monkeypatch, tmp_path, set_by_caller, policy):
    """The process that compiles the integrator, started in the background or waited for,
    compiles at ``COMPILE_OPT`` (LLVM -O1), unless the caller's environment sets
    ``NUMBA_OPT`` (numba reads its level from that variable: the child says what it got,
    without importing numba)."""
    monkeypatch.setenv(readiness.POLICY_VARIABLE, policy)
    if set_by_caller is None:
        monkeypatch.delenv("NUMBA_OPT", raising=False)
    else:
        monkeypatch.setenv("NUMBA_OPT", set_by_caller)
    said = tmp_path / "opt.txt"
    monkeypatch.setattr(readiness, "compile_command", lambda: [
        sys.executable, "-c", f"import os, pathlib; pathlib.Path({str(said)!r})"
        ".write_text(os.environ.get('NUMBA_OPT', '3'))"])
    readiness.integrator_ready()
    if policy == "auto":
        _wait_child()
        readiness._state["child"].log.close()
    assert said.read_text() == (set_by_caller or readiness.COMPILE_OPT)
    assert readiness.COMPILE_OPT != "3"


_FORKED = """
import os, subprocess, sys, tempfile
from bderiv.models import readiness
# as start_background leaves it (the only reference: dropped in the forked process)
readiness._state["child"] = subprocess.Popen([sys.executable, "-c",
                                              "import time; time.sleep(60)"])
readiness._state["child"].log = tempfile.TemporaryFile()
started = readiness._state["child"].pid
pid = os.fork()
if pid == 0:  # the forked process: the check, then out at once
    code = 1
    try:
        code = 0 if (readiness._state["child"] is None
                     and readiness._child_ended() is False
                     and readiness._state["foreign"] == started
                     and readiness._foreign_running()) else 3
    finally:
        os._exit(code)
_, status = os.waitpid(pid, 0)
child = readiness._state["child"]
mine = child is not None and child.pid == started and readiness._child_ended() is False
child.kill()
child.wait()
print(os.waitstatus_to_exitcode(status), mine)
"""


@pytest.mark.skipif(not hasattr(readiness.os, "fork"), reason="no fork here")
def test_a_forked_process_does_not_take_its_parents_compilation_for_its_own():
    """A process forked after the background compilation started (a multiprocessing pool)
    inherits its handle, but the process is not its child: polled there, it looked ended
    with status 0, and every such worker warned and compiled the integrator itself. It
    keeps the pid, to start no compilation of its own while that one runs. (In a fresh
    interpreter: this one has threads that a fork must not copy.)"""
    out = subprocess.run([sys.executable, "-X", "dev", "-c", _FORKED], capture_output=True,
                         text=True, timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.split() == ["0", "True"], out.stdout + out.stderr[-2000:]
    assert "ResourceWarning" not in out.stderr, out.stderr[-2000:]  # the handle, its file


def test_the_background_process_is_waited_for_once_it_has_ended(stand_in):
    """It runs its workload after the integrator is in the cache; the calls that follow
    wait for its end (a zombie for the rest of the process's life before)."""
    assert readiness.integrator_ready() is False
    child = readiness._state["child"]
    deadline = time.monotonic() + 120
    while not readiness.integrator_cached() and time.monotonic() < deadline:
        time.sleep(0.05)
    while readiness._state["child"] is not None and time.monotonic() < deadline:
        assert readiness.integrator_ready() is True
        time.sleep(0.05)
    assert readiness._state["child"] is None and child.returncode == 0


def test_the_compiling_process_runs_compiled_whatever_the_policy(stand_in, monkeypatch):
    """``BDERIV_INTEGRATOR=scipy python -m bderiv compile``: the process that compiles the
    integrator runs its workload on it (on scipy it compiled nothing and said it had)."""
    monkeypatch.setenv(readiness.POLICY_VARIABLE, "scipy")
    assert readiness.integrator_ready() is False
    readiness.compiling_here()
    assert readiness.integrator_ready() is True and readiness.ready_now() is True


def test_compiled_policy_says_that_it_waits_for_another_process(stand_in, monkeypatch,
                                                                 caplog):
    import threading

    monkeypatch.setenv(readiness.POLICY_VARIABLE, "compiled")
    caplog.set_level(logging.WARNING, logger="bderiv")
    held, release = threading.Event(), threading.Event()

    def other_process():  # another open file: flock sees another holder
        with open(readiness.lock_path(), "a+b") as fh:
            readiness.fcntl.flock(fh, readiness.fcntl.LOCK_EX)
            held.set()
            release.wait(30)
            readiness.fcntl.flock(fh, readiness.fcntl.LOCK_UN)

    holder = threading.Thread(target=other_process)
    holder.start()
    held.wait(30)
    threading.Timer(0.3, release.set).start()
    try:
        assert readiness.integrator_ready() is True
    finally:
        release.set()
        holder.join()
    assert "waiting for another process that compiles" in caplog.text


def test_scipy_policy_and_a_bad_value(stand_in, monkeypatch):
    monkeypatch.setenv(readiness.POLICY_VARIABLE, "scipy")
    assert readiness.integrator_ready() is False
    assert readiness._state["child"] is None
    monkeypatch.setenv(readiness.POLICY_VARIABLE, "fast")
    with pytest.raises(ValueError, match="BDERIV_INTEGRATOR must be one of auto, compiled, "
                       "scipy, got 'fast'"):
        readiness.integrator_ready()


def test_a_compiled_model_on_scipy_gives_the_compiled_paths_answer(monkeypatch):
    """The chair's compiled model with the integrator withheld (``scipy``) and on it: the
    same event groups, flow map and final state to the integration tolerance."""
    ex = examples.chair(compiled=True)
    monkeypatch.setenv(readiness.POLICY_VARIABLE, "scipy")
    scipy_model = examples.chair(compiled=True).system
    assert scipy_model.compiled is None and scipy_model.on_compiled_path
    on_scipy = scipy_model.flow_bderivative(ex.x0, ex.t_final)
    traj_scipy = scipy_model.simulate(ex.x0, ex.t_final)
    monkeypatch.setenv(readiness.POLICY_VARIABLE, "compiled")
    assert ex.system.compiled is not None
    compiled = ex.system.flow_bderivative(ex.x0, ex.t_final)
    traj = ex.system.simulate(ex.x0, ex.t_final)
    assert [g.events for g in traj.groups] == [g.events for g in traj_scipy.groups]
    np.testing.assert_allclose(traj.x_final, traj_scipy.x_final, rtol=1e-8, atol=1e-10)
    V = np.random.default_rng(0).standard_normal((50, ex.system.dim))
    np.testing.assert_allclose(on_scipy(V), compiled(V), rtol=1e-7, atol=1e-9)


def test_a_fresh_process_answers_before_the_integrator_is_compiled(tmp_path):
    """A process with an empty cache: its first flow map comes from scipy with the
    background compilation announced. The background process is paused as soon as it
    starts (SIGSTOP: what it compiles is not this test's, and it would take a core from
    the other tests) and killed at the end."""
    code = textwrap.dedent("""
        import logging, os, signal
        logging.basicConfig(level=logging.WARNING)
        from bderiv import examples
        from bderiv.models import readiness
        start = readiness.start_background
        def start_paused(*args, **kwargs):
            started = start(*args, **kwargs)
            if started:
                os.killpg(readiness._state["child"].pid, signal.SIGSTOP)
            return started
        readiness.start_background = start_paused
        try:
            ex = examples.chair(compiled=True)
            D = ex.system.flow_bderivative(ex.x0, ex.t_final)
            print("compiled" if ex.system.compiled is not None else "scipy",
                  readiness._state["child"] is not None)
        finally:  # the paused process never ends by itself
            if readiness._state["child"] is not None:
                os.killpg(readiness._state["child"].pid, signal.SIGKILL)
    """)
    env = {**readiness.child_environment(), "NUMBA_CACHE_DIR": str(tmp_path / "numba"),
           "BDERIV_CACHE_DIR": str(tmp_path / "bderiv")}
    env.pop(readiness.POLICY_VARIABLE, None)
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True,
                         text=True, timeout=600)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.split() == ["scipy", "True"], (out.stdout, out.stderr[-2000:])
    assert "being compiled in a background process" in out.stderr


def test_wait_for_background_waits_for_the_process_this_one_started(stand_in, monkeypatch):
    """A script that measures what follows, or removes the cache folder, waits for the
    background process to end: False while it runs (the timeout), True once it has ended
    (or when none was started)."""
    assert readiness.wait_for_background(0.01) is True  # none started yet
    monkeypatch.setattr(readiness, "compile_command", lambda: [
        sys.executable, "-c", "import time; time.sleep(60)"])
    assert readiness.start_background() is True
    child = readiness._state["child"]
    assert readiness.wait_for_background(0.2) is False and child.poll() is None
    child.kill()
    assert readiness.wait_for_background(30) is True and child.poll() is not None
    child.log.close()


def test_the_background_compilation_yields_to_the_program_in_its_own_session():
    """Its session's scheduling group gets the nice value too: where Linux groups sessions
    (autogroup), a new session's own nice value counts only within that session, and the
    background compilation took half the cores from the program that started it (a
    review: a 4.5 s first answer spent 1.5 s waiting for a core)."""
    import os

    probe = ("import os\nfrom bderiv.models.readiness import lower_priority\n"
             "before = os.nice(0)\nlower_priority()\nprint(os.nice(0) - before)\n"
             "try:\n    print(open('/proc/self/autogroup').read().split()[-1])\n"
             "except OSError:\n    print('none')\n")
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True,
                         start_new_session=True)  # as start_background starts it
    assert out.returncode == 0, out.stderr
    raised, group = out.stdout.split()
    assert int(raised) == readiness.NICE
    if group != "none" and os.path.exists("/proc/sys/kernel/sched_autogroup_enabled"):
        assert int(group) == readiness.NICE


def test_under_the_compiled_policy_threads_wait_for_the_one_that_looks(monkeypatch):
    """``BDERIV_INTEGRATOR=compiled``: threads whose first runs start together all run
    compiled; those that asked while one looked at the disk answered False, and ran on
    scipy (a review)."""
    import threading

    monkeypatch.setenv("BDERIV_INTEGRATOR", "compiled")
    for key, value in (("ready", False), ("checked", -float("inf")), ("here", False)):
        monkeypatch.setitem(readiness._state, key, value)

    def slow_look():
        time.sleep(0.3)
        return True

    monkeypatch.setattr(readiness, "integrator_cached", slow_look)
    start, answers = threading.Barrier(4), []

    def first_run():
        start.wait()
        answers.append(readiness.integrator_ready())

    threads = [threading.Thread(target=first_run) for _ in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert answers == [True] * 4
