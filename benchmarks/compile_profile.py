"""Where a cold start's compilation goes: ``python benchmarks/compile_profile.py [N]``.

Run with an empty cache (``NUMBA_CACHE_DIR=$(mktemp -d) BDERIV_CACHE_DIR=$(mktemp -d)``),
and with ``NUMBA_OPT=1`` for what the integrator's own compiling process does (it runs at
-O1: :data:`bderiv.models.readiness.COMPILE_OPT`; the chair's functions then compile at -O1
too); like that process it makes full collections rarer
(:func:`bderiv.cli.warmup.rarer_full_collections`). Refused where the integrator is in the
cache already or ``BDERIV_INTEGRATOR=scipy``. It compiles and runs the chair's first flow
B-derivative (``examples.chair(compiled=True)``, ``flow_bderivative(x0, t_final)``), the
compiled integrator compiled in this process, and prints, from numba's compile and pass
events, CPU time (``time.process_time``: other load on the machine changes it little):

- per dispatcher, the N (default 25) most expensive: exclusive seconds (its own
  compilation, nested compilations subtracted), inclusive seconds, compilations, name;
- per numba pass, exclusive seconds, and the (dispatcher, pass) pairs that cost most;
- LLVM per code library: ``finalize`` (the module optimized with the modules of its
  callees linked in, and its machine code), and the per-function passes at lowering;
- bderiv's dispatchers compiled for more than one signature (each one more compilation).
"""

from __future__ import annotations

import collections
import sys
import time

from numba.core import codegen, event
from numba.core.dispatcher import Dispatcher

_compiles, _passes, _names = [], [], []
excl, incl, count = collections.Counter(), collections.Counter(), collections.Counter()
per_pass, per_pair = collections.Counter(), collections.Counter()
llvm = collections.defaultdict(lambda: [0.0, 0.0])


def _short(name):
    return name.split(".k")[0]  # without bderiv's sources digest


class _Compiles(event.Listener):
    def on_start(self, ev):
        d = ev.data["dispatcher"]
        _names.append(f"{d.py_func.__module__}.{d.py_func.__qualname__}")
        _compiles.append([time.process_time(), 0.0])

    def on_end(self, ev):
        start, nested = _compiles.pop()
        spent, name = time.process_time() - start, _names.pop()
        excl[name] += spent - nested
        incl[name] += spent
        count[name] += 1
        if _compiles:
            _compiles[-1][1] += spent


class _Passes(event.Listener):
    def on_start(self, ev):
        _passes.append([time.process_time(), 0.0])

    def on_end(self, ev):
        start, nested = _passes.pop()
        spent, name = time.process_time() - start, ev.data["name"].split(" [")[0]
        per_pass[name] += spent - nested
        per_pair[(_short(_names[-1]) if _names else "?", name)] += spent - nested
        if _passes:
            _passes[-1][1] += spent


def _timed(method, slot):
    original = getattr(codegen.JITCodeLibrary, method)

    def timed(self, *args):
        start = time.process_time()
        try:
            return original(self, *args)
        finally:
            llvm[_short(self.name)][slot] += time.process_time() - start

    setattr(codegen.JITCodeLibrary, method, timed)


def main(n):
    _timed("finalize", 0)
    _timed("_optimize_functions", 1)
    event.register("numba:compile", _Compiles())
    event.register("numba:run_pass", _Passes())
    from bderiv import examples
    from bderiv.cli.warmup import rarer_full_collections
    from bderiv.models import readiness

    if readiness.policy() == "scipy" or readiness.integrator_cached():
        sys.exit("compile_profile: the integrator is in numba's cache already, or "
                 "BDERIV_INTEGRATOR=scipy: run with an empty NUMBA_CACHE_DIR, without it")
    # the integrator compiles in this process at its first use, not in a process of its
    # own: this process's events see it (as ``python -m bderiv compile integrator`` does)
    readiness.compiling_here()
    rarer_full_collections()
    start = time.process_time()
    ex = examples.chair(compiled=True)
    ex.system.flow_bderivative(ex.x0, ex.t_final)
    print(f"cpu {time.process_time() - start:.1f} s; compile cpu {sum(excl.values()):.1f} s "
          f"in {sum(count.values())} compilations")
    print("excl_cpu incl_cpu n dispatcher")
    for name, t in excl.most_common(n):
        print(f"{t:7.2f} {incl[name]:7.2f} {count[name]:3d} {_short(name)}")
    print("pass (exclusive cpu)")
    for name, t in per_pass.most_common(8):
        print(f"{t:7.2f} {name}")
    for (name, step), t in per_pair.most_common(n):
        print(f"{t:7.2f} {step:28s} {name}")
    print(f"LLVM: finalize {sum(v[0] for v in llvm.values()):.1f} s, per-function passes "
          f"{sum(v[1] for v in llvm.values()):.1f} s; per library:")
    for name, (fin, fun) in sorted(llvm.items(), key=lambda r: -sum(r[1]))[:12]:
        print(f"{fin:7.2f} {fun:7.2f} {name}")
    for module in list(sys.modules.values()):
        for value in list(vars(module).values()) if module and module.__name__.startswith(
                "bderiv") else ():
            if isinstance(value, Dispatcher) and value.py_func.__module__ == module.__name__ \
                    and len(value.signatures) > 1:
                print(f"compiled {len(value.signatures)} times: {module.__name__}."
                      f"{_short(value.py_func.__qualname__)}")


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 25)
