"""The quadruped from its equations to an orbit and a stability verdict, step by step.

``python benchmarks/quadruped.py`` runs, each in a fresh process so that nothing is
shared but the disk caches (the generated module and numba's cache of it, and numba's
cache of bderiv's own kernels, warm from the first run):

1. cold: an empty cache folder for the generated module: the symbolic derivation and
   the printing of the kernels (``build.derive_seconds``), then numba's compilation
   (``build.load_seconds``), then the same orbit and verdicts as below;
2. warm (run ``WARM_RUNS`` times, the minimum of each row kept): the same cache, so the
   model is loaded (no derivation, no compilation), then the orbit by Newton's method
   (:func:`bderiv.examples.quadruped.quadruped_orbit`, on the compiled integrator) and
   two stability verdicts: a quick one (50 directions, 60 iterations) and the demo's
   (200 directions, 200 iterations).

Each row is a part of "model to orbit and verdict" (the target of issue 21: under 2 s on
a warm cache, derivation and compilation included): ``import sympy``; the user's code
(the quadruped's expressions: mass matrix, forces, gaps); ``contact_system``'s checks and
cache key; the kernels' load from numba's cache (or derivation and compilation, cold);
the orbit; the quick verdict, each as wall time and as the process's CPU time (on a
shared machine the CPU time is the steadier one; the build's parts timed inside
``contact_system`` are wall time only). ``import bderiv`` is printed apart. The same
process then finds the orbit again (the first one's share of loading bderiv's own
compiled kernels from numba's cache is the difference) and times one call of the field
and its Jacobian through ``ModelFunctions(system)`` (numpy in, numpy out, checks) against the
njit kernel called directly. Timings on a shared machine are noisy: compare minima.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time

WARM_RUNS = 3

STEP = r"""
import json, sys, time
def now():
    return time.perf_counter(), time.process_time()
def since(a, b):  # wall and CPU seconds from a to b
    return [b[0] - a[0], b[1] - a[1]]
t0 = now()
import numpy as np
from bderiv.examples import quadruped as example
t1 = now()
import sympy
t2 = now()
import bderiv.symbolic

os.environ.setdefault("BDERIV_INTEGRATOR", "compiled")  # compiled from the first run
marks = {}
contact_system = bderiv.symbolic.contact_system
def timed(*args, **kwargs):  # the user's expressions end where contact_system starts
    marks["user"] = now()
    return contact_system(*args, **kwargs)
bderiv.symbolic.contact_system = timed
system = example.quadruped()
t3 = now()
b = system.source.build
out = {"import": since(t0, t1), "sympy": since(t1, t2), "user": since(t2, marks["user"]),
       "checks": [b.check_seconds] * 2, "derive": [b.derive_seconds] * 2,
       "load": [b.load_seconds] * 2, "cached": b.cached}
orb = example.quadruped_orbit(system)
t4 = now()
quick = orb.stability(n_directions=50, iterations=60)
t5 = now()
st = orb.stability(n_directions=200, iterations=200)
t6 = now()
example.quadruped_orbit(system)  # again: nothing left to load from the caches
t7 = now()
out.update(orbit=since(t3, t4), quick=since(t4, t5), stability=since(t5, t6),
           again=since(t6, t7), total=since(t1, t5), period=orb.period, growth=st.growth_rate,
           quick_growth=quick.growth_rate, stable=bool(st.stable and quick.stable))
x, xp = orb.x0.copy(), np.concatenate((orb.x0, system.params))
functions = bderiv.symbolic.ModelFunctions(system)
for name, call in (("field", lambda: functions.field(x, 15)),
                   ("field kernel", lambda: system.source.kernels.field(xp, 15)),
                   ("jacobian", lambda: functions.field_jacobian(x, 15)),
                   ("jacobian kernel", lambda: system.source.kernels.field_jacobian(xp, 15))):
    best = float("inf")
    for _ in range(5):
        s = time.perf_counter()
        for _ in range(2000):
            call()
        best = min(best, (time.perf_counter() - s) / 2000)
    out[name] = best
print(json.dumps(out))
"""

ROWS = (("sympy", "import sympy"),
        ("user", "the user's expressions (examples/quadruped.py)"),
        ("checks", "contact_system: checks and cache key"),
        ("derive", "derivation, cse and printing"),
        ("load", "numba: kernels compiled or loaded from cache"),
        ("orbit", "periodic orbit (Newton, compiled integrator)"),
        ("quick", "stability, 50 directions x 60 iterations"))


def run(cache: str) -> dict:
    env = dict(os.environ, BDERIV_CACHE_DIR=cache)
    done = subprocess.run([sys.executable, "-c", STEP], env=env, check=True,
                          capture_output=True, text=True)
    return json.loads(done.stdout.strip().splitlines()[-1])


def main():
    with tempfile.TemporaryDirectory() as cache:
        cold = run(cache)
        warm = [run(cache) for _ in range(WARM_RUNS)]
    assert not cold["cached"] and all(w["cached"] for w in warm)
    assert all(r["stable"] for r in (cold, *warm))
    best = {k: min(w[k] for w in warm) for k in ("field", "field kernel", "jacobian",
                                                  "jacobian kernel")}
    for k, v in warm[0].items():
        if isinstance(v, list):  # [wall, CPU]: each the minimum over the warm runs
            best[k] = [min(w[k][i] for w in warm) for i in range(2)]
    print(f"quadruped (d = 14, n = 4), seconds; warm: minimum of {WARM_RUNS} processes; "
          f"wall (CPU of the process)")
    print(f"  {'':50s} {'cold':>15s} {'warm':>15s}")

    def row(label, key):
        c, w = cold[key], best[key]
        print(f"  {label:50s} {c[0]:6.2f} ({c[1]:6.2f}) {w[0]:6.2f} ({w[1]:6.2f})")

    for key, label in ROWS:
        row(label, key)
    row("model to orbit and quick verdict (target: 2 s)", "total")
    row("stability, 200 directions x 200 iterations", "stability")
    row("the orbit again in the same process", "again")
    row("(import bderiv, apart)", "import")
    print(f"  period {warm[0]['period']:.12g}, growth rate {warm[0]['growth']:.6f} "
          f"(quick: {warm[0]['quick_growth']:.6f})")
    for name in ("field", "jacobian"):
        wrapped, kernel = best[name], best[f"{name} kernel"]
        print(f"  one {name} call: {wrapped * 1e6:.1f} us through ModelFunctions(system), "
              f"{kernel * 1e6:.1f} us the kernel alone (ratio {wrapped / kernel:.1f})")


if __name__ == "__main__":
    start = time.perf_counter()
    main()
    print(f"({time.perf_counter() - start:.0f} s in all)")
