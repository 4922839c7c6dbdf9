"""Periodic orbit + stability verdict, compiled against Python (issues 19 and 20).

``python benchmarks/gait_orbits.py`` takes the k-leg pronking body of
``benchmarks/compiled_path.py`` (d = 2 (2 + k + p), k = 2 to 8 legs, all feet landing and
lifting off together) with its apex section ``-vz`` (compiled, and as the same Python
function), and times the gait job from the symmetric apex guess: ``periodic_orbit`` (Newton's
method with the B-derivative) followed by ``stability(n_directions=200, iterations=200)``,
on the compiled model and on the Python one (complex-step field Jacobian), in one process:
``ROUNDS`` alternated rounds (the compiled job ``COMPILED_PER_ROUND`` times, the Python job
once), minimum over all. Printed per size: the two times (orbit and verdict apart), their
ratio (issue 19's floor: 20x), the agreement of the two orbits (fixed points, periods,
growth rates) and, for the 8-leg models, the compiled time against issue 20's 1 s. The
first compiled call (compiling the model's functions) is reported apart, not charged.

``--scaling`` times ``stability()`` alone on the compiled orbits, with the small-batch
serial scaling of ``bderiv._kernels.scaling`` (``SERIAL_ENTRIES``) against every batch on
the parallel kernels (``SERIAL_ENTRIES = 0``, the behaviour before), alternated.
``--eight``: issue 20's target, the compiled job alone on the 8-leg models (and on
``gaits.pronking(legs=8, compiled=True)`` where bderiv has it) against 1 s, wall time and
the process's CPU time (what the job costs when other jobs share the cores).
``--quick``: the smallest and largest model only; ``--sizes 8:0,2:0``: these (k, p);
``--rounds N``: N rounds. ``--record``: the comparison's rows (docs/benchmarks.md's table) to
``benchmarks/results/gait_orbits.json`` (``_record.py``).
"""

from __future__ import annotations

import gc
import os
import sys
import time

import _record
import numba
import numpy as np
from compiled_integrator import best  # min wall time of repeated calls (benchmarks/)
from compiled_path import SIZES, systems  # the k-leg model (benchmarks/)

from bderiv._kernels import scaling

os.environ.setdefault("BDERIV_INTEGRATOR", "compiled")  # compiled from the first run

ROUNDS = 3
COMPILED_PER_ROUND = 3
VERDICT = {"n_directions": 200, "iterations": 200}


def apex_section(n):
    """The apex section ``-vz`` (vz the state's coordinate n) and its gradient, compiled."""

    @numba.njit
    def section(x):
        return -x[n]

    @numba.njit
    def gradient(x):
        g = np.zeros(x.size)
        g[n] = -1.0
        return g

    return section, gradient


def gait(system, x0, section, gradient):
    """(orbit seconds, verdict seconds, orbit, stability) of the job from x0."""
    start = time.perf_counter()
    orbit = system.periodic_orbit(x0, section, period_guess=0.5, section_gradient=gradient)
    middle = time.perf_counter()
    st = orbit.stability(**VERDICT)
    return middle - start, time.perf_counter() - middle, orbit, st


def jobs(k, p):
    """The compiled and the Python job of one size, and the apex guess's dimension."""
    compiled, python, x0 = systems(k, p)
    section, gradient = apex_section(2 + k + p)
    return ((lambda: gait(compiled, x0, section, gradient)),
            (lambda: gait(python, x0, section.py_func, gradient.py_func)), x0.size)


def compare(sizes, record=False):
    print(f"periodic orbit (symmetric apex guess) + stability({VERDICT}); min over {ROUNDS} "
          f"alternated rounds ({COMPILED_PER_ROUND} compiled runs, 1 Python run each); "
          f"times in s; load {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores")
    print(f"{'k':>2} {'p':>2} {'d':>3} {'1st':>6} | {'orbit c':>7} {'stab c':>6} "
          f"{'total c':>7} | {'orbit py':>8} {'stab py':>7} {'total py':>8} | {'ratio':>6} | "
          f"{'Newton':>6} {'x0 diff':>7} {'T diff':>7} {'growth c':>8} {'growth py':>9}")
    rows = []
    for k, p in sizes:
        job_c, job_py, d = jobs(k, p)
        start = time.perf_counter()
        job_c()
        first = time.perf_counter() - start
        runs = {"c": [], "py": []}
        gc.disable()
        try:
            for _ in range(ROUNDS):
                for name, job, repeats in (("c", job_c, COMPILED_PER_ROUND), ("py", job_py, 1)):
                    for _ in range(repeats):
                        runs[name].append(job())
        finally:
            gc.enable()
        oc, sc, orb_c, st_c = min(runs["c"], key=lambda r: r[0] + r[1])
        op, sp, orb_p, st_p = min(runs["py"], key=lambda r: r[0] + r[1])
        x_diff = np.abs(orb_c.x0 - orb_p.x0).max()
        t_diff = abs(orb_c.period - orb_p.period)
        target = ("  (8 legs: target < 1 s)" if k == 8 else "")
        print(f"{k:>2} {p:>2} {d:>3} {first:>5.1f}s | {oc:>7.3f} {sc:>6.3f} {oc + sc:>7.3f} | "
              f"{op:>8.2f} {sp:>7.2f} {op + sp:>8.2f} | {(op + sp) / (oc + sc):>5.0f}x | "
              f"{len(orb_c.history) - 1:>3}/{len(orb_p.history) - 1:<2} {x_diff:>7.1e} "
              f"{t_diff:>7.1e} {st_c.growth_rate:>8.5f} {st_p.growth_rate:>9.5f}{target}",
              flush=True)
        rows.append(dict(k=k, p=p, d=d, orbit_c=oc, verdict_c=sc, total_c=oc + sc, orbit_py=op,
                         verdict_py=sp, total_py=op + sp, ratio=(op + sp) / (oc + sc),
                         newton=len(orb_c.history) - 1, growth=st_c.growth_rate))
    if record:  # docs/benchmarks.md's table, from benchmarks/results/gait_orbits.json
        _record.record("gait_orbits", {"main": rows}, meta={
            "note": f"one process, {ROUNDS} alternated rounds ({COMPILED_PER_ROUND} compiled "
                    "runs, 1 Python run each), minima; seconds"})


def eight_legs(sizes):
    """Issue 20's target: an 8-leg orbit + verdict on a compiled model under 1 s (warm)."""
    cases = [(f"k-leg body k={k} p={p} (d={2 * (2 + k + p)})", jobs(k, p)[0]) for k, p in sizes]
    from bderiv.examples import gaits

    try:
        ex = gaits.pronking(legs=8, compiled=True)
    except TypeError:  # an older bderiv without the compiled examples
        print("gaits.pronking(legs=8, compiled=True): not in this bderiv")
    else:
        def pronking8(ex=ex):
            start = time.perf_counter()
            orbit = gaits.pronking_orbit(ex)
            middle = time.perf_counter()
            st = orbit.stability(**VERDICT)
            return middle - start, time.perf_counter() - middle, orbit, st

        cases.append(("gaits.pronking(legs=8, compiled=True) (d=4)", pronking8))
    print(f"compiled: periodic orbit + stability({VERDICT}), min of {ROUNDS * COMPILED_PER_ROUND} "
          f"runs after a first (compiling) one; load {os.getloadavg()[0]:.1f}")
    for name, job in cases:
        start = time.perf_counter()
        job()
        first = time.perf_counter() - start
        runs, cpu = [], []
        gc.disable()
        try:
            for _ in range(ROUNDS * COMPILED_PER_ROUND):
                start = time.process_time()
                runs.append(job())
                cpu.append(time.process_time() - start)
        finally:
            gc.enable()
        orbit_s, stab_s, orbit, st = min(runs, key=lambda r: r[0] + r[1])
        print(f"  {name}: orbit {orbit_s:.3f} s ({len(orbit.history) - 1} Newton steps) + "
              f"verdict {stab_s:.3f} s = {orbit_s + stab_s:.3f} s wall, {min(cpu):.3f} s CPU "
              f"of this process (target 1 s; first call {first:.1f} s); growth rate "
              f"{st.growth_rate:.5f}", flush=True)


def scaling_paths(sizes):
    """stability() with the small-batch serial scaling against parallel launches only."""
    print(f"stability({VERDICT}) on the compiled orbit: serial scaling below "
          f"{scaling.SERIAL_ENTRIES} entries against parallel kernels for every batch; min "
          f"over {ROUNDS} alternated rounds; load {os.getloadavg()[0]:.1f}")
    serial_entries = scaling.SERIAL_ENTRIES
    for k, p in sizes:
        job_c, _, d = jobs(k, p)
        orbit = job_c()[2]
        times = {"serial": [], "parallel": []}
        for _ in range(ROUNDS):
            for name, entries in (("serial", serial_entries), ("parallel", 0)):
                scaling.SERIAL_ENTRIES = entries
                try:
                    times[name].append(best(lambda o=orbit: o.stability(**VERDICT), 1)[0])
                finally:
                    scaling.SERIAL_ENTRIES = serial_entries
        ser, par = min(times["serial"]), min(times["parallel"])
        print(f"  k={k} p={p} d={d}: serial {ser:.3f} s, parallel {par:.3f} s "
              f"({par / ser:.1f}x)", flush=True)


if __name__ == "__main__":
    if "--rounds" in sys.argv:
        ROUNDS = int(sys.argv[sys.argv.index("--rounds") + 1])
    chosen = SIZES[:: len(SIZES) - 1] if "--quick" in sys.argv else SIZES
    if "--sizes" in sys.argv:
        chosen = [tuple(int(v) for v in kp.split(":"))
                  for kp in sys.argv[sys.argv.index("--sizes") + 1].split(",")]
    if "--eight" in sys.argv:
        eight_legs([kp for kp in chosen if kp[0] == 8])
    else:
        if "--scaling" in sys.argv:
            scaling_paths(chosen)
        else:
            compare(chosen, record="--record" in sys.argv)
