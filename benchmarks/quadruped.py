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
the orbit; the quick verdict. ``import bderiv`` is printed apart. The same process also
times one call of the field and its Jacobian through ``system.functions`` (numpy in,
numpy out, checks) against the njit kernel called directly. Timings on a shared machine
are noisy: compare minima.
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
t0 = time.perf_counter()
import numpy as np
from bderiv.examples import quadruped as example
t1 = time.perf_counter()
import sympy
t2 = time.perf_counter()
import bderiv.symbolic
marks = {}
contact_system = bderiv.symbolic.contact_system
def timed(*args, **kwargs):  # the user's expressions end where contact_system starts
    marks["user"] = time.perf_counter()
    return contact_system(*args, **kwargs)
bderiv.symbolic.contact_system = timed
system = example.quadruped()
t3 = time.perf_counter()
b = system.build
out = {"import": t1 - t0, "sympy": t2 - t1, "user": marks["user"] - t2,
       "checks": b.check_seconds, "derive": b.derive_seconds, "load": b.load_seconds,
       "build": t3 - t2, "cached": b.cached}
orb = example.quadruped_orbit(system)
t4 = time.perf_counter()
quick = orb.stability(n_directions=50, iterations=60)
t5 = time.perf_counter()
st = orb.stability(n_directions=200, iterations=200)
t6 = time.perf_counter()
out.update(orbit=t4 - t3, quick=t5 - t4, stability=t6 - t5, total=t5 - t1,
           period=orb.period, growth=st.growth_rate, quick_growth=quick.growth_rate,
           stable=bool(st.stable and quick.stable))
x, xp = orb.x0.copy(), np.concatenate((orb.x0, system.params))
for name, call in (("field", lambda: system.functions.field(x, 15)),
                   ("field kernel", lambda: system.kernels.field(xp, 15)),
                   ("jacobian", lambda: system.functions.field_jacobian(x, 15)),
                   ("jacobian kernel", lambda: system.kernels.field_jacobian(xp, 15))):
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
    best = {k: min(w[k] for w in warm) for k in warm[0] if isinstance(warm[0][k], float)}
    print(f"quadruped (d = 14, n = 4), seconds; warm: minimum of {WARM_RUNS} processes")
    print(f"  {'':50s} {'cold':>7s} {'warm':>7s}")
    for key, label in ROWS:
        print(f"  {label:50s} {cold[key]:7.2f} {best[key]:7.2f}")
    print(f"  {'model to orbit and quick verdict (target: 2 s)':50s} {cold['total']:7.2f} "
          f"{best['total']:7.2f}")
    print(f"  {'stability, 200 directions x 200 iterations':50s} {cold['stability']:7.2f} "
          f"{best['stability']:7.2f}")
    print(f"  {'(import bderiv, apart)':50s} {cold['import']:7.2f} {best['import']:7.2f}")
    print(f"  period {warm[0]['period']:.12g}, growth rate {warm[0]['growth']:.6f} "
          f"(quick: {warm[0]['quick_growth']:.6f})")
    for name in ("field", "jacobian"):
        wrapped, kernel = best[name], best[f"{name} kernel"]
        print(f"  one {name} call: {wrapped * 1e6:.1f} us through system.functions, "
              f"{kernel * 1e6:.1f} us the kernel alone (ratio {wrapped / kernel:.1f})")


if __name__ == "__main__":
    start = time.perf_counter()
    main()
    print(f"({time.perf_counter() - start:.0f} s in all)")
