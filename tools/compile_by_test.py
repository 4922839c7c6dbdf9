"""Where a test run's time goes: a pytest plugin that records, per test, the CPU time of the
test process and the part of it numba spent compiling, and per dispatcher the compile time
it took itself (nested compilations subtracted).

Usage (an empty cache measures a cold start; ``-n 0`` keeps every test in one process, so
that a kernel is charged to the first test that compiles it)::

    NUMBA_CACHE_DIR=$(mktemp -d) BDERIV_CACHE_DIR=$(mktemp -d) PYTHONPATH=tools \\
        python -m pytest -n 0 -p compile_by_test [FILES ...]
    python tools/compile_by_test.py compile_by_test.json [--top 30]

The plugin writes ``compile_by_test.json`` (or ``$COMPILE_BY_TEST``) at the end of the
session; the second command prints the files and the dispatchers that cost most. CPU time
(``time.process_time``) changes little with other load on the machine. What the
subprocesses a test waited for spent (the command line's tests, fresh-process checks) is
recorded apart (``RUSAGE_CHILDREN``, on Unix): a subprocess is charged to the test during
which it is reaped (under ``-n 0`` the background compilation of the integrator that the
session starts goes to whichever test reaps it), and one never waited for is not
counted.

Under pytest-xdist (``-n 2``) each worker writes its own record, the path with ``-gw0``,
``-gw1``, ... before ``.json``; give the second command all of them. Each test's record
also holds its wall-clock start (seconds since the epoch) and duration, so that
``--timeline`` shows what each worker ran when, and where it waited (wall time far above
its CPU time: the compiled integrator, a lock, a subprocess).
"""

from __future__ import annotations

import argparse
import collections
import json
import os
import sys
import time

try:
    import resource
except ImportError:  # Windows: no record of the subprocesses
    resource = None

_stack: list = []  # [name, start, nested seconds] of the compilations under way
#: (nodeid, cpu seconds, compile seconds, wall start, wall seconds, subprocesses' cpu seconds)
_per_test: list = []
_dispatchers: collections.Counter = collections.Counter()  # (file, dispatcher) -> seconds
_compiles: collections.Counter = collections.Counter()
_state = {"file": "?", "compile": 0.0}


def _listener():
    from numba.core import event

    class Compiles(event.Listener):
        def on_start(self, ev):
            d = ev.data["dispatcher"]
            _stack.append([f"{d.py_func.__module__}.{d.py_func.__qualname__}",
                           time.process_time(), 0.0])

        def on_end(self, ev):
            name, start, nested = _stack.pop()
            spent = time.process_time() - start
            _dispatchers[(_state["file"], name.split(".k")[0])] += spent - nested
            _compiles[(_state["file"], name.split(".k")[0])] += 1
            if _stack:
                _stack[-1][2] += spent
            else:
                _state["compile"] += spent

    event.register("numba:compile", Compiles())


def pytest_configure(config):
    _listener()


def pytest_runtest_protocol(item, nextitem):
    _state["file"] = item.nodeid.split("::")[0]
    _state["cpu"], _state["at"] = time.process_time(), _state["compile"]
    _state["wall"], _state["children"] = time.time(), _children()


def pytest_runtest_logfinish(nodeid, location):
    if "cpu" not in _state:  # the controller of an xdist run: its workers record
        return
    _per_test.append((nodeid, time.process_time() - _state["cpu"],
                      _state["compile"] - _state["at"], _state["wall"],
                      time.time() - _state["wall"], _children() - _state["children"]))


def _children() -> float:
    """CPU seconds of the terminated subprocesses this process waited for."""
    if resource is None:
        return 0.0
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def pytest_sessionfinish(session):
    path = os.environ.get("COMPILE_BY_TEST", "compile_by_test.json")
    worker = os.environ.get("PYTEST_XDIST_WORKER")
    if worker:
        path = f"{path.removesuffix('.json')}-{worker}.json"
    elif not _per_test:  # the controller of an xdist run: the workers write
        return
    with open(path, "w") as fh:
        json.dump({"tests": _per_test,
                   "dispatchers": [[f, n, s, _compiles[(f, n)]]
                                   for (f, n), s in _dispatchers.items()]}, fh)


def main(argv=None):
    ap = argparse.ArgumentParser(description="Print where a recorded test run's time went.")
    ap.add_argument("records", nargs="+", help="the JSON the plugin wrote (one per worker)")
    ap.add_argument("--top", type=int, default=30)
    ap.add_argument("--timeline", action="store_true",
                    help="per worker, the files in the order run: wall and CPU seconds")
    args = ap.parse_args(argv)
    data = {"tests": [], "dispatchers": []}
    for record in args.records:
        with open(record) as fh:
            part = json.load(fh)
        data["tests"] += part["tests"]
        data["dispatchers"] += part["dispatchers"]
        if args.timeline:
            _timeline(record, part["tests"])
    files = collections.defaultdict(lambda: [0.0, 0.0, 0, 0.0])
    for nodeid, cpu, compiled, *rest in data["tests"]:
        row = files[nodeid.split("::")[0]]
        row[0] += cpu
        row[1] += compiled
        row[2] += 1
        row[3] += rest[2] if len(rest) > 2 else 0.0  # older records: no subprocesses
    cpu = sum(r[0] for r in files.values())
    compiled = sum(r[1] for r in files.values())
    children = sum(r[3] for r in files.values())
    print(f"{len(data['tests'])} tests: {cpu:.1f} s CPU in the test process, {compiled:.1f} s "
          f"of it compiling ({100 * compiled / max(cpu, 1e-9):.0f} %); {children:.1f} s in "
          f"the subprocesses the tests waited for")
    print(f"\n{'file':48s} {'CPU s':>7s} {'compile s':>9s} {'tests':>5s} {'subproc s':>9s}")
    for name, (c, k, n, sub) in sorted(files.items(), key=lambda kv: -kv[1][0])[:args.top]:
        print(f"{name:48s} {c:7.1f} {k:9.1f} {n:5d} {sub:9.1f}")
    per = collections.Counter()
    count = collections.Counter()
    for _, name, seconds, n in data["dispatchers"]:
        per[name] += seconds
        count[name] += n
    print(f"\n{'compile s':>9s} {'times':>5s}  dispatcher (its own compilation)")
    for name, seconds in per.most_common(args.top):
        print(f"{seconds:9.1f} {count[name]:5d}  {name}")


def _timeline(record, tests):
    """The runs of consecutive tests of one file in a worker's record: start (seconds after
    its first test), wall, CPU and compile seconds."""
    if not tests or len(tests[0]) < 5:
        return
    t0 = tests[0][3]
    print(f"\n{record}: {'start':>6s} {'wall':>6s} {'CPU':>6s} {'compile':>7s}  file")
    runs = []
    for nodeid, cpu, compiled, start, wall, *_ in tests:
        name = nodeid.split("::")[0]
        if runs and runs[-1][0] == name:
            runs[-1][2:] = [start + wall - runs[-1][1], runs[-1][3] + cpu, runs[-1][4] + compiled]
        else:
            runs.append([name, start, wall, cpu, compiled])
    for name, start, wall, cpu, compiled in runs:
        print(f"{'':{len(record) + 1}s} {start - t0:6.0f} {wall:6.1f} {cpu:6.1f} {compiled:7.1f}  "
              f"{name}")


if __name__ == "__main__":
    sys.exit(main())
