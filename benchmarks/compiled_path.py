"""The compiled path against the Python path on a k-leg pronking body (issue 19's targets).

``python benchmarks/compiled_path.py`` builds, for d = 8 to 44 and k = 2 to 8 legs, a planar
body pronking on k compliant legs with a leg-extension coordinate each and p passive body
modes (state ``(z, theta, s_1..s_k, q_1..q_p)`` and their rates: d = 2 (2 + k + p)); all
feet touch down and lift off together. The model is written once as ``numba.njit``
functions; the Python path runs the same code as Python functions (the dispatchers'
``py_func``), with the field Jacobian by complex step in Python (exact, as the examples do);
the compiled path gets no ``field_jacobian`` (complex step in compiled code). One stride:
from the apex through touchdown and lift-off to ``T_FINAL``.

Timed in one process with the garbage collector off, in ``ROUNDS`` alternated rounds (each:
the compiled job ``COMPILED_PER_ROUND`` times, the Python job once), min over all:
``simulate``, ``flow_bderivative`` (the build), and central finite differences of the Python
path's simulation (2 d runs: the brute-force flow Jacobian, once). On a machine shared by
other jobs a millisecond-long compiled run is often interrupted: its minimum over more runs
is what it costs. The first call of each compiled model (compiling its functions
and loading the driver; the library's own kernels are loaded before) is reported apart,
not charged. Printed: the times, the ratios, and
the agreement of the two paths (end states, flow maps on random directions, event logs).
``--record`` writes the table's rows (docs/benchmarks.md) to
``benchmarks/results/compiled_path.json`` (``_record.py``).
``--quick`` runs the smallest and largest model only; ``--many`` times ``simulate_many`` of
64 starts against a loop of ``simulate`` on the compiled model (smallest and largest;
perturbed starts, whose stops go back to Python, and level ones, all compiled), and
``flow_fd`` at d = 8 with its batch on threads against one thread.
``--perturbed`` times runs from perturbed starts (the feet land apart) against the run from
the apex, on both paths, with the excursion screen as it is and with its end rule off (every
bracket at a stretch's end searched, as before: ``perturbed``), and ``flow_fd`` at d = 8.
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

from bderiv.analysis.checks import FD_SIMULTANEITY_TOL
from bderiv.analysis.system import HybridSystem
from bderiv.models.events import excursions
from bderiv.models.integrate import compiled_path as compiled_stretches
from bderiv.models.integrate import many as many_runs
from bderiv.models.integrate import scipy_path

os.environ.setdefault("BDERIV_INTEGRATOR", "compiled")  # compiled from the first run

G = 9.81
T_FINAL = 0.5
APEX = 0.66
ROUNDS = 5
COMPILED_PER_ROUND = 4
#: (legs, passive modes): d = 2 (2 + k + p)
SIZES = ((2, 0), (4, 2), (6, 4), (8, 4), (4, 10), (8, 8), (8, 12))


def body(k, p):
    """``field, events, event_jacobian`` (njit) of the body on k legs with p modes."""
    a = np.linspace(-0.4, 0.4, k)
    share = 2.0 / k
    K, C, gain, v_ref, coupling = 400.0 * share, 2.0 * share, 4.0 * share, 2.0, 0.5
    leg, inertia, k_leg, c_leg, push = 0.5, 0.16, 900.0, 6.0, 0.2
    w = 10.0 + 3.0 * np.arange(p)
    all_down = (1 << k) - 1
    n = 2 + k + p  # positions; rates after them

    @numba.njit
    def field(x, mask):
        c, s = np.cos(x[1]), np.sin(x[1])
        vz, om = x[n], x[n + 1]
        g = gain * (1.0 + coupling) if mask == all_down else gain
        thrust = g * (1.0 - vz**2 / v_ref**2) * vz
        out = np.empty_like(x)
        out[:n] = x[n:]
        az = -G + 0.0 * x[0]
        alpha = 0.0 * x[0]
        for j in range(p):
            az += 0.5 * x[2 + k + j] / max(p, 1)
        for i in range(k):
            length = leg + x[2 + i]
            out[n + 2 + i] = -k_leg * x[2 + i] - c_leg * x[n + 2 + i]
            if mask >> i & 1:
                rx = a[i] * c + length * s
                height = x[0] + a[i] * s - length * c
                f = -K * height - C * (vz + om * rx - x[n + 2 + i] * c) + thrust
                az += f
                alpha += rx * f / inertia
                out[n + 2 + i] -= push * f
        out[n], out[n + 1] = az, alpha
        for j in range(p):
            out[n + 2 + k + j] = (-w[j] ** 2 * x[2 + k + j] - 0.1 * w[j] * x[n + 2 + k + j]
                                  - 0.3 * (az + G))
        return out

    @numba.njit
    def events(x):
        c, s = np.cos(x[1]), np.sin(x[1])
        out = np.empty(k)
        for i in range(k):
            out[i] = -(x[0] + a[i] * s - (leg + x[2 + i]) * c)
        return out

    @numba.njit
    def event_jacobian(x):
        c, s = np.cos(x[1]), np.sin(x[1])
        D = np.zeros((k, 2 * n))
        for i in range(k):
            D[i, 0] = -1.0
            D[i, 1] = -(a[i] * c + (leg + x[2 + i]) * s)
            D[i, 2 + i] = c
        return D

    return field, events, event_jacobian


def complex_step(f, d):
    """The Python path's field Jacobian: complex step of the Python field."""

    def jacobian(x, mask):
        J = np.empty((d, d))
        z = np.asarray(x, dtype=np.complex128)
        for j in range(d):
            zj = z.copy()
            zj[j] += 1e-30j
            J[:, j] = f(zj, mask).imag / 1e-30
        return J

    return jacobian


def systems(k, p):
    """The compiled and the Python system of the same model, and the apex start."""
    field, events, event_jacobian = body(k, p)
    d = 2 * (2 + k + p)
    compiled = HybridSystem(field, events, n_events=k, dim=d, event_jacobian=event_jacobian)
    python = HybridSystem(field.py_func, events.py_func, n_events=k, dim=d,
                          event_jacobian=event_jacobian.py_func,
                          field_jacobian=complex_step(field.py_func, d))
    x0 = np.zeros(d)
    x0[0] = APEX
    return compiled, python, x0


def central_differences(system, x0, eps=1e-6):
    """The flow Jacobian by central differences of the simulation (2 d runs)."""
    d = x0.size
    J = np.empty((d, d))
    for j in range(d):
        e = np.zeros(d)
        e[j] = eps
        plus = system.simulate(x0 + e, T_FINAL, simultaneity_tol=FD_SIMULTANEITY_TOL).x_final
        minus = system.simulate(x0 - e, T_FINAL, simultaneity_tol=FD_SIMULTANEITY_TOL).x_final
        J[:, j] = (plus - minus) / (2 * eps)
    return J


def log_of(traj):
    return [(e.event, e.mask, e.direction) for e in traj.events]


def main(sizes=SIZES, record=False):
    print(f"one stride (apex to t = {T_FINAL}), rtol 1e-10, atol 1e-12; min over {ROUNDS} "
          f"alternated rounds ({COMPILED_PER_ROUND} compiled runs, 1 Python run each); "
          f"times in ms")
    print(f"{'k':>2} {'p':>2} {'d':>3} {'1st call':>8} | {'sim c':>6} {'sim py':>7} "
          f"{'ratio':>6} | {'build c':>7} {'build py':>8} {'ratio':>6} | {'FD py':>7} "
          f"{'ratio':>6} | {'x rel':>7} {'map rel':>7} {'log':>4}")
    rows = []
    for k, p in sizes:
        compiled, python, x0 = systems(k, p)
        d = x0.size
        python.flow_bderivative(x0, T_FINAL)  # the library's own kernels: loaded for both
        start = time.perf_counter()
        compiled.flow_bderivative(x0, T_FINAL)
        first = time.perf_counter() - start
        runs = {}
        gc.disable()
        try:
            for _ in range(ROUNDS):  # alternated: the compiled and the Python jobs in turn
                for name, system in (("c", compiled), ("py", python)):
                    repeats = COMPILED_PER_ROUND if name == "c" else 1
                    runs.setdefault(("sim", name), []).append(best(
                        lambda s=system, x=x0: s.simulate(x, T_FINAL, simultaneity_tol=1e-7),
                        repeats))
                    runs.setdefault(("build", name), []).append(best(
                        lambda s=system, x=x0: s.flow_bderivative(x, T_FINAL), repeats))
            t_fd, _ = best(lambda s=python, x=x0: central_differences(s, x), 1)
        finally:
            gc.enable()
        (sc, tc), (sp, tp), (bc, Dc), (bp, Dp) = (
            min(runs[key], key=lambda r: r[0])
            for key in (("sim", "c"), ("sim", "py"), ("build", "c"), ("build", "py")))
        V = np.random.default_rng(0).standard_normal((64, d))
        x_rel = np.abs(tc.x_final - tp.x_final).max() / np.abs(tp.x_final).max()
        map_rel = np.abs(Dc(V) - Dp(V)).max() / np.abs(Dp(V)).max()
        same = log_of(tc) == log_of(tp)
        print(f"{k:>2} {p:>2} {d:>3} {first:>6.2f} s | {sc * 1e3:>6.2f} {sp * 1e3:>7.1f} "
              f"{sp / sc:>5.0f}x | {bc * 1e3:>7.2f} {bp * 1e3:>8.1f} {bp / bc:>5.0f}x | "
              f"{t_fd * 1e3:>7.0f} {t_fd / bc:>5.0f}x | {x_rel:>7.1e} {map_rel:>7.1e} "
              f"{'same' if same else 'DIFF':>4}", flush=True)
        rows.append(dict(k=k, p=p, d=d, sim_c=sc, sim_py=sp, sim_ratio=sp / sc, build_c=bc,
                         build_py=bp, build_ratio=bp / bc, fd_py=t_fd, fd_ratio=t_fd / bc))
    if record:  # docs/benchmarks.md's table, from benchmarks/results/compiled_path.json
        _record.record("compiled_path", {"main": rows}, meta={
            "note": f"one process, {ROUNDS} alternated rounds, minima; times in ms"})


def many(sizes=(SIZES[0], SIZES[-1]), batch=64):
    """``simulate_many`` of ``batch`` starts near the apex against a loop of ``simulate``
    on the compiled model (the batch's runs on threads: ``integrate.many``); the feet of a
    perturbed start land apart, so they switch one by one (``FD_SIMULTANEITY_TOL``), and
    those stops are handed back to the Python loop; level starts (z and its rate perturbed)
    keep the feet together, every stop in compiled code. Then ``flow_fd`` at d = 8, the
    batch on threads against one thread. Wall and CPU (all threads) times, ms."""
    print(f"simulate_many of {batch} starts against a loop of simulate (compiled model, "
          f"{many_runs.worker_count(batch)} threads); min over {ROUNDS} alternated rounds; "
          f"wall (CPU) ms")
    for k, p in sizes:
        compiled, _, x0 = systems(k, p)
        d = x0.size
        level = np.tile(x0, (batch, 1))
        level[:, [0, d // 2]] += 1e-4 * np.random.default_rng(1).standard_normal((batch, 2))
        starts = {"perturbed": x0 + 1e-4 * np.random.default_rng(1).standard_normal(
            (batch, d)), "level": level}
        for name, X0 in starts.items():
            compiled.simulate_many(X0[:2], T_FINAL, simultaneity_tol=FD_SIMULTANEITY_TOL)
            runs = {"many": [], "loop": []}
            gc.disable()
            try:
                for _ in range(ROUNDS):
                    runs["many"].append(_timed(lambda s=compiled, X=X0: s.simulate_many(
                        X, T_FINAL, simultaneity_tol=FD_SIMULTANEITY_TOL)))
                    runs["loop"].append(_timed(lambda s=compiled, X=X0: [s.simulate(
                        x, T_FINAL, simultaneity_tol=FD_SIMULTANEITY_TOL) for x in X]))
            finally:
                gc.enable()
            (w_many, c_many), (w_loop, c_loop) = (min(runs[key]) for key in ("many", "loop"))
            print(f"k={k} p={p} d={d} {name:>9}: simulate_many {w_many * 1e3:.1f} "
                  f"({c_many * 1e3:.1f}), loop {w_loop * 1e3:.1f} ({c_loop * 1e3:.1f}): "
                  f"{w_loop / w_many:.2f}x", flush=True)
    compiled, _, x0 = systems(*SIZES[0])
    d = x0.size
    compiled.flow_fd(x0, T_FINAL, np.eye(d)[:2], 1e-6)
    fd, threads = {}, many_runs.worker_count
    gc.disable()
    try:
        for _ in range(ROUNDS):
            for name, count in (("threads", threads), ("one", lambda m: 1)):
                many_runs.worker_count = count
                fd.setdefault(name, []).append(_timed(
                    lambda: compiled.flow_fd(x0, T_FINAL, np.eye(d), 1e-6)))
    finally:
        many_runs.worker_count = threads
        gc.enable()
    (w_t, c_t), (w_1, c_1) = min(fd["threads"]), min(fd["one"])
    print(f"flow_fd(x0, {T_FINAL}, I, 1e-6) at d = {d} (1 + {d} runs): threads {w_t * 1e3:.1f} "
          f"({c_t * 1e3:.1f}), one thread {w_1 * 1e3:.1f} ({c_1 * 1e3:.1f}): "
          f"{w_1 / w_t:.2f}x", flush=True)


def _timed(job):
    """``(wall, CPU)`` seconds of ``job()`` (CPU of all the process's threads)."""
    wall, cpu = time.perf_counter(), time.process_time()
    job()
    return time.perf_counter() - wall, time.process_time() - cpu


class _UnknownRates(excursions._EndRates):
    """The excursion screen's rates at a stretch's ends unknown: every bracket at an end is
    searched (the screen before its end rule)."""

    def _rate(self, model, x):
        return np.full(self.sign.size, np.nan)


#: ``(name, rates class)`` of the screen with and without its end rule
RULES = (("new", excursions._EndRates), ("old", _UnknownRates))


def _alternated(rounds, compiled, python):
    """``(path, system, rule)`` for each round, path and screen rule, alternated, with the
    rule set and the garbage collector off while the caller times; both restored after."""
    gc.disable()
    try:
        for _ in range(rounds):
            for path, system in (("c", compiled), ("py", python)):
                for rule, rates in RULES:
                    excursions._EndRates = rates
                    yield path, system, rule
    finally:
        gc.enable()
        excursions._EndRates = RULES[0][1]


def perturbed(sizes=(SIZES[0], SIZES[-1]), rounds=5):
    """Runs from perturbed starts against the run from the apex, both paths, the screen
    with its end rule (new) and without (old), alternated in one process; per start the
    minimum over ``rounds``. The starts: ``x0 + 1e-6 e_j`` (``flow_fd``'s, 8 coordinates)
    and 4 random ones (normal, 1e-4). Then ``flow_fd(x0, T, I, 1e-6)`` at d = 8."""
    print(f"simulate from the apex and from 12 perturbed starts (simultaneity_tol "
          f"{FD_SIMULTANEITY_TOL:g}), min over {rounds} alternated rounds per start; "
          f"old: every bracket at a stretch's end searched; times in ms per run")
    print(f"{'d':>3} {'path':>4} {'rule':>4} | {'apex':>7} {'perturbed':>9} {'ratio':>6} | "
          f"{'searches':>8} {'stretches':>9} (apex); per perturbed run")
    real_peak_of, real_screen = excursions.peak_of, excursions.without_lost_crossings
    searches, stretches = [0], [0]

    def counted(*args):
        searches[0] += 1
        return real_peak_of(*args)

    def screened(*args, **kwargs):
        stretches[0] += 1
        return real_screen(*args, **kwargs)

    excursions.peak_of = counted
    for module in (compiled_stretches, scipy_path):
        module.without_lost_crossings = screened
    try:
        for k, p in sizes:
            compiled, python, x0 = systems(k, p)
            d = x0.size
            rng = np.random.default_rng(2)
            starts = [x0 + 1e-6 * np.eye(d)[j] for j in np.linspace(0, d - 1, 8).astype(int)]
            starts += [x0 + 1e-4 * rng.standard_normal(d) for _ in range(4)]
            times, counts = {}, {}
            for system in (compiled, python):  # compiled, the kernels loaded: not timed
                system.simulate(starts[0], T_FINAL, simultaneity_tol=FD_SIMULTANEITY_TOL)
            for path, system, rule in _alternated(rounds, compiled, python):
                for i, x in enumerate([x0, *starts]):
                    searches[0] = stretches[0] = 0
                    t, _ = best(lambda s=system, x=x: s.simulate(
                        x, T_FINAL, simultaneity_tol=FD_SIMULTANEITY_TOL), 1)
                    times.setdefault((path, rule, i), []).append(t)
                    counts[(path, rule, i)] = searches[0], stretches[0]
            for path in ("c", "py"):
                # the run from the apex searches nothing: the same work under both rules
                apex = min(times[(path, "new", 0)] + times[(path, "old", 0)])
                pert = {rule: np.mean([min(times[(path, rule, i)])
                                       for i in range(1, len(starts) + 1)])
                        for rule, _ in RULES}
                for rule, _ in RULES:
                    n, m = np.mean([counts[(path, rule, i)] for i in range(1, len(starts) + 1)],
                                   axis=0)
                    print(f"{d:>3} {path:>4} {rule:>4} | {apex * 1e3:>7.2f} "
                          f"{pert[rule] * 1e3:>9.2f} {pert[rule] / apex:>5.1f}x | {n:>8.2f} "
                          f"{m:>9.1f} ({counts[(path, rule, 0)][1]})", flush=True)
                print(f"{'':>8} old/new, perturbed: {pert['old'] / pert['new']:.2f}x")
        compiled, python, x0 = systems(*SIZES[0])
        d = x0.size
        print(f"flow_fd(x0, {T_FINAL}, I, 1e-6) at d = {d} (d + 1 runs), min over {rounds} "
              f"alternated rounds; ms")
        fd = {}
        for system in (compiled, python):  # its first call compiles the batch: not timed
            system.flow_fd(x0, T_FINAL, np.eye(d)[:1], 1e-6)
        for path, system, rule in _alternated(rounds, compiled, python):
            t, _ = best(lambda s=system: s.flow_fd(x0, T_FINAL, np.eye(d), 1e-6), 1)
            fd.setdefault((path, rule), []).append(t)
        for path in ("c", "py"):
            old, new = min(fd[(path, "old")]), min(fd[(path, "new")])
            print(f"  {path:>2}: old {old * 1e3:8.1f}  new {new * 1e3:8.1f}  old/new "
                  f"{old / new:5.2f}x", flush=True)
    finally:
        excursions.peak_of = real_peak_of
        for module in (compiled_stretches, scipy_path):
            module.without_lost_crossings = real_screen


if __name__ == "__main__":
    if "--many" in sys.argv:
        many()
    elif "--perturbed" in sys.argv:
        perturbed()
    else:
        main(SIZES[:: len(SIZES) - 1] if "--quick" in sys.argv else SIZES,
             record="--record" in sys.argv)
