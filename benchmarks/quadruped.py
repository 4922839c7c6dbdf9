"""The quadruped from its equations to an orbit and a stability verdict, step by step.

``python benchmarks/quadruped.py`` runs, each in a fresh process so that nothing is
shared but the disk cache:

1. cold: an empty cache folder: the symbolic derivation and the printing of the kernels
   (``build.derive_seconds``), then numba's compilation (``build.load_seconds``);
2. warm (run ``WARM_RUNS`` times, the minimum kept): the same cache, so the model is
   loaded (no derivation, no compilation), then the orbit by Newton's method
   (:func:`bderiv.examples.quadruped.quadruped_orbit`) and two stability verdicts: the
   demo's (200 directions, 200 iterations) and a quick one (50 directions, 60
   iterations);

and prints each part's seconds and the total against the target of issue 21 (model to
orbit and verdict under 2 s on a warm cache). The same process also times one call of
the field and its Jacobian through ``system.functions`` (numpy in, numpy out, checks)
against the njit kernel called directly: the Python wrapper's share of a field call.
Timings on a shared machine are noisy: compare minima.
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
from bderiv.examples.quadruped import quadruped, quadruped_orbit
t1 = time.perf_counter()
system = quadruped()
t2 = time.perf_counter()
out = {"import": t1 - t0, "build": t2 - t1, "cached": system.build.cached,
       "derive": system.build.derive_seconds, "load": system.build.load_seconds}
if sys.argv[1] == "warm":
    orb = quadruped_orbit(system)
    t3 = time.perf_counter()
    st = orb.stability(n_directions=200, iterations=200)
    t4 = time.perf_counter()
    quick = orb.stability(n_directions=50, iterations=60)
    t5 = time.perf_counter()
    out.update(orbit=t3 - t2, stability=t4 - t3, quick=t5 - t4, growth=st.growth_rate,
               quick_growth=quick.growth_rate, stable=bool(st.stable and quick.stable))
    x, p = orb.x0.copy(), system.functions.p
    res = np.empty(14)
    jac = np.empty((14, 14))
    for name, call in (("field", lambda: system.functions.field(x, 15)),
                       ("field kernel", lambda: system.kernels.field(x, 15, p, res)),
                       ("jacobian", lambda: system.functions.field_jacobian(x, 15)),
                       ("jacobian kernel",
                        lambda: system.kernels.field_jacobian(x, 15, p, jac))):
        best = float("inf")
        for _ in range(5):
            s = time.perf_counter()
            for _ in range(2000):
                call()
            best = min(best, (time.perf_counter() - s) / 2000)
        out[name] = best
print(json.dumps(out))
"""


def run(kind: str, cache: str) -> dict:
    env = dict(os.environ, BDERIV_CACHE_DIR=cache)
    done = subprocess.run([sys.executable, "-c", STEP, kind], env=env, check=True,
                          capture_output=True, text=True)
    return json.loads(done.stdout.strip().splitlines()[-1])


def main():
    with tempfile.TemporaryDirectory() as cache:
        cold = run("cold", cache)
        print(f"cold cache: derivation and printing {cold['derive']:.2f} s, numba "
              f"compilation {cold['load']:.2f} s (import of bderiv {cold['import']:.2f} s)")
        warm = [run("warm", cache) for _ in range(WARM_RUNS)]
    best = {k: min(w[k] for w in warm) for k in ("import", "build", "orbit", "stability",
                                                  "quick", "field", "field kernel",
                                                  "jacobian", "jacobian kernel")}
    assert all(w["cached"] for w in warm) and all(w["stable"] for w in warm)
    print(f"warm cache, minimum of {WARM_RUNS} processes:")
    print(f"  model loaded (no derivation, no compilation) {best['build']:.2f} s")
    print(f"  periodic orbit (Newton, 4 iterations)        {best['orbit']:.2f} s")
    print(f"  stability, 200 directions x 200 iterations   {best['stability']:.2f} s "
          f"(growth rate {warm[0]['growth']:.6f})")
    print(f"  stability, 50 directions x 60 iterations     {best['quick']:.2f} s "
          f"(growth rate {warm[0]['quick_growth']:.6f})")
    total = best["build"] + best["orbit"] + best["quick"]
    print(f"  model to orbit and quick verdict: {total:.2f} s (target of issue 21: 2 s)")
    for name in ("field", "jacobian"):
        wrapped, kernel = best[name], best[f"{name} kernel"]
        print(f"  one {name} call: {wrapped * 1e6:.1f} us through system.functions, "
              f"{kernel * 1e6:.1f} us the kernel alone (ratio {wrapped / kernel:.1f})")


if __name__ == "__main__":
    start = time.perf_counter()
    main()
    print(f"({time.perf_counter() - start:.0f} s in all)")
