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
(``time.process_time``) changes little with other load on the machine; what subprocesses of
a test spend (the command line's tests, fresh-process checks) is not counted.
"""

from __future__ import annotations

import argparse
import collections
import json
import os
import sys
import time

_stack: list = []  # [name, start, nested seconds] of the compilations under way
_per_test: list = []  # (nodeid, cpu seconds, compile seconds)
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


def pytest_runtest_logfinish(nodeid, location):
    _per_test.append((nodeid, time.process_time() - _state["cpu"],
                      _state["compile"] - _state["at"]))


def pytest_sessionfinish(session):
    path = os.environ.get("COMPILE_BY_TEST", "compile_by_test.json")
    with open(path, "w") as fh:
        json.dump({"tests": _per_test,
                   "dispatchers": [[f, n, s, _compiles[(f, n)]]
                                   for (f, n), s in _dispatchers.items()]}, fh)


def main(argv=None):
    ap = argparse.ArgumentParser(description="Print where a recorded test run's time went.")
    ap.add_argument("record", help="the JSON the plugin wrote")
    ap.add_argument("--top", type=int, default=30)
    args = ap.parse_args(argv)
    with open(args.record) as fh:
        data = json.load(fh)
    files = collections.defaultdict(lambda: [0.0, 0.0, 0])
    for nodeid, cpu, compiled in data["tests"]:
        row = files[nodeid.split("::")[0]]
        row[0] += cpu
        row[1] += compiled
        row[2] += 1
    cpu = sum(r[0] for r in files.values())
    compiled = sum(r[1] for r in files.values())
    print(f"{len(data['tests'])} tests: {cpu:.1f} s CPU in the test process, {compiled:.1f} s "
          f"of it compiling ({100 * compiled / max(cpu, 1e-9):.0f} %)")
    print(f"\n{'file':48s} {'CPU s':>7s} {'compile s':>9s} {'tests':>5s}")
    for name, (c, k, n) in sorted(files.items(), key=lambda kv: -kv[1][0])[:args.top]:
        print(f"{name:48s} {c:7.1f} {k:9.1f} {n:5d}")
    per = collections.Counter()
    count = collections.Counter()
    for _, name, seconds, n in data["dispatchers"]:
        per[name] += seconds
        count[name] += n
    print(f"\n{'compile s':>9s} {'times':>5s}  dispatcher (its own compilation)")
    for name, seconds in per.most_common(args.top):
        print(f"{seconds:9.1f} {count[name]:5d}  {name}")


if __name__ == "__main__":
    sys.exit(main())
