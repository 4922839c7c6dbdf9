"""Ctrl-C during a stability map on a Dask cluster (a review of long work).

Oracle: what a terminal's Ctrl-C leaves. On the call's own LocalCluster: the caller's
KeyboardInterrupt and nothing else, no worker's traceback on stderr, no worker process
left (a subprocess, SIGINT to its process group as a terminal sends it). On a user's own
Client: the wave's tasks not begun are cancelled, none started after the interrupt.
"""

from __future__ import annotations

import gc
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from test_stability_map import cycle, section

import bderiv
from bderiv.analysis.stability_map import stability_map

SCRIPT = """
import os, sys, time
import numpy as np
from bderiv.analysis.stability_map import stability_map
from test_stability_map import cycle, section

def slow_cycle(**params):
    time.sleep(0.2)
    return cycle(**params)

def report(done, total):
    if done == 1:
        from distributed import default_client
        print("running", *default_client().run(os.getpid).values(), flush=True)

if __name__ == "__main__":
    import signal  # Ctrl-C as in a terminal, whatever the test runner ignores
    signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        stability_map(slow_cycle, {"multiplier": np.linspace(0.5, 0.9, 8),
                                   "turns": np.linspace(1.0, 4.5, 8)}, [1.05, 0.0], section,
                      period_guess=1.0, n_directions=5, iterations=10, client="local",
                      progress=report)
    except KeyboardInterrupt:
        print("interrupted", flush=True)
        sys.exit(3)
    print("finished")
"""


def ended(pid):
    """The process is gone (or a zombie: ended, not yet reaped)."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return True
    return stat.rsplit(")", 1)[1].split()[0] == "Z"


@pytest.mark.skipif(not Path("/proc/self/stat").exists() or not hasattr(os, "killpg"),
                    reason="reads /proc, sends SIGINT to a process group")
def test_ctrl_c_on_a_local_cluster_prints_no_worker_traceback_and_leaves_no_process(
        tmp_path):
    """A review: the workers, in the terminal's process group, printed their own
    KeyboardInterrupt's tracebacks (a hundred lines on stderr); ignoring SIGINT, they were
    given 4 s to finish their point ("Worker process still alive after 4.0 seconds,
    killing"): now the caller ends them at once, its loggers quiet meanwhile."""
    pytest.importorskip("distributed")
    script = tmp_path / "smap.py"
    script.write_text(SCRIPT)
    src = str(Path(bderiv.__file__).parents[1])
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([src, str(Path(__file__).parent)])}
    proc = subprocess.Popen([sys.executable, str(script)], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env=env,
                            start_new_session=True)
    try:
        running = proc.stdout.readline().split()
        assert running[:1] == ["running"], proc.communicate(timeout=60)
        os.killpg(proc.pid, signal.SIGINT)  # as a terminal's Ctrl-C: the whole group
        out, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    assert (proc.returncode, out.strip()) == (3, "interrupted"), err
    # no worker's traceback, nor the nanny's "still alive after 4.0 seconds, killing" (nor
    # the scheduler's logs of the comms broken, with their tracebacks, now and then)
    shown = [line for line in err.splitlines() if not line.startswith("bderiv:")]
    assert not [line for line in shown if any(
        word in line for word in ("Traceback", "KeyboardInterrupt", "still alive"))], err
    pids = [int(pid) for pid in running[1:]]
    assert len(pids) == 2
    for _ in range(100):  # ended by the caller before it exits; reaped a moment later
        if all(ended(pid) for pid in pids):
            break
        time.sleep(0.05)
    assert all(ended(pid) for pid in pids)


_STARTED = []
_INTERRUPTED_AT = {"multiplier": 0.5, "turns": 3.0}  # the first point of the third wave


def _interrupting_cycle(**params):
    _STARTED.append(params)
    if params == _INTERRUPTED_AT:  # Ctrl-C while this point runs; it goes on to its end
        signal.pthread_kill(threading.main_thread().ident, signal.SIGINT)
        time.sleep(0.3)
    return cycle(**params)


def test_ctrl_c_on_a_users_client_cancels_the_tasks_not_begun(caplog):
    """The wave's two other points are cancelled, not run after the interrupt, and the
    client's loop is left clean (an interrupted ``client.gather`` left its waits, printed
    as "Task exception was never retrieved ... AllExit")."""
    distributed = pytest.importorskip("distributed")
    grid = {"multiplier": [0.5, 0.9, 1.5], "turns": [1.0, 2.0, 3.0]}
    _STARTED.clear()
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        with (distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=False,
                                       dashboard_address=None,
                                       scheduler_kwargs={"dashboard_address": ":0"}) as cluster,
              distributed.Client(cluster) as client):
            with pytest.raises(KeyboardInterrupt):
                stability_map(_interrupting_cycle, grid, [1.05, 0.0], section,
                              period_guess=1.0, n_directions=5, iterations=10, client=client)
            for _ in range(200):  # the point running ends, the others were cancelled
                if not client.run_on_scheduler(lambda dask_scheduler: len(
                        dask_scheduler.tasks)):
                    break
                time.sleep(0.05)
            time.sleep(0.3)  # a task started after the interrupt would have begun by now
            assert client.run_on_scheduler(lambda dask_scheduler: len(dask_scheduler.tasks)) == 0
            gc.collect()
    finally:
        signal.signal(signal.SIGINT, previous)
    later = [p for p in _STARTED if np.searchsorted(grid["multiplier"], p["multiplier"])
             + np.searchsorted(grid["turns"], p["turns"]) >= 2]
    assert later == [_INTERRUPTED_AT]
    assert "never retrieved" not in caplog.text


def test_ctrl_c_while_the_local_cluster_starts_ends_it_once_it_stands(monkeypatch):
    """A Ctrl-C inside LocalCluster's constructor (its first second or two) left a
    half-made cluster, and distributed's exit handler printed a hundred lines ending in
    "AssertionError: Status.init" (a review, 2 of 13 tries): the cluster starts in a
    thread, the caller's KeyboardInterrupt comes at once, and the cluster is ended as soon
    as it stands. A constructor that takes 0.5 s stands in for distributed's."""
    distributed = pytest.importorskip("distributed")
    from bderiv._support import _dask

    made, ended = [], []

    class SlowCluster:
        def __init__(self, **kwargs):
            time.sleep(0.5)
            made.append(self)

    monkeypatch.setattr(distributed, "LocalCluster", SlowCluster)
    monkeypatch.setattr(distributed, "Client", lambda cluster: ("client", cluster))
    monkeypatch.setattr(_dask, "end_now", lambda client, cluster: ended.append(cluster))
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        threading.Timer(0.1, signal.pthread_kill,
                        (threading.main_thread().ident, signal.SIGINT)).start()
        start = time.monotonic()
        with pytest.raises(KeyboardInterrupt):
            _dask.start_local(2)
        assert time.monotonic() - start < 0.4 and not made  # at once, not when it stands
        for _ in range(100):
            if ended:
                break
            time.sleep(0.02)
    finally:
        signal.signal(signal.SIGINT, previous)
    assert len(made) == 1 and ended == made
