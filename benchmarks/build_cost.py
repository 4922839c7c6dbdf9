"""A/B of the fixed cost of building small maps against another checkout, in this process.

    python benchmarks/build_cost.py /work/main/src [--rounds 7] [--repeats 200]

What is timed is what follows the integration in ``flow_bderivative`` at small n and d
(issue 19: a compiled build takes milliseconds, so a NumPy call on a 4-row table counts):
``BDerivative(Dh, F)`` on dense tables of n = 1 to 4 events (the pronking body's own
table at n = 2, d = 8, and tables of the three fast-path kinds), and
``analysis.assembly.flow_map_along`` on the trajectory of one stride of the d = 8 pronking
body of ``benchmarks/compiled_path.py`` (two groups, touchdown and lift-off, n = 2 each),
integrated once by each package, and the whole compiled ``flow_bderivative`` of that
stride (the integration, then the assembly). The other checkout is imported as ``bderiv_base``
(``benchmarks/ab.py``); both must give the same bits (checked first). Each round times
``repeats`` calls of each side, the sides alternated; printed: the median and the minimum
of the rounds' per-call times after the first, and the ratios this / base (below 1: this
checkout is faster), with the load average.
"""

from __future__ import annotations

import argparse
import gc
import importlib
import os
import pathlib
import statistics
import sys
import time

import numpy as np
from ab import base_package
from compiled_path import APEX, T_FINAL, body


def tables(rng):
    """name -> (Dh, F): dense tables with rates > 0 (own-rates, linear and general)."""
    out = {}
    for n, d in ((1, 4), (2, 8), (3, 8), (4, 20)):
        Dh = rng.standard_normal((n, d))
        P = np.linalg.pinv(Dh)  # Dh P = I: a field along P's columns has chosen rates
        bits = ((np.arange(1 << n)[:, None] >> np.arange(n)) & 1).astype(float)
        A = (P * (0.5 + rng.random(n))).T
        F = P @ (1.0 + rng.random(n)) + bits @ A  # additive: the linear path
        out[f"linear n={n} d={d}"] = Dh, F
        if n > 1:
            general = F + 0.1 * bits.prod(axis=1)[:, None] * (P @ rng.random(n))
            out[f"general n={n} d={d}"] = Dh, general
    return out


def assembly(pkg):
    """The module of ``flow_map_along`` in ``pkg``: ``analysis.assembly`` (in a checkout
    from before the layers were folders, ``models.assembly``)."""
    for name in ("analysis.assembly", "models.assembly"):
        try:
            return importlib.import_module(f"{pkg.__name__}.{name}")
        except ModuleNotFoundError:
            continue
    raise SystemExit(f"{pkg.__name__} has no flow_map_along")


def pronking(pkg):
    """The d = 8 pronking body's system in ``pkg``, its trajectory with the variational
    equations, and the BDerivative table (Dh, F) of its touchdown group."""
    field, events, event_jacobian = body(2, 0)
    system = pkg.HybridSystem(field, events, n_events=2, dim=8, event_jacobian=event_jacobian)
    x0 = np.zeros(8)
    x0[0] = APEX
    run = pkg.models.integrate.run
    options = pkg.SolverOptions.resolve(None)
    if hasattr(options, "simultaneity_tol"):  # the tolerance travels in the options
        traj = run.run(system, x0, T_FINAL, variational=True,
                       options=options.with_overrides(simultaneity_tol=1e-7))
    else:  # a checkout from before (benchmarks/ab.py's base)
        traj = run.run(system, x0, T_FINAL, simultaneity_tol=1e-7, options=options,
                       variational=True)
    jump = assembly(pkg).flow_map_along(system, traj).jumps[0]
    return system, traj, (np.array(jump.Dh), np.array(jump.F))


def bits_of(result):
    """The bytes a build gives: a map's tables and its values on fixed vectors."""
    V = np.random.default_rng(5).standard_normal((32, result.dim))
    parts = [result(V), result.inverse(V)]
    for bd in getattr(result, "jumps", (result,)):
        parts += [bd.Dh, bd.F, bd.rates, np.array([bd.rate_spread]), bd._engine.R]
    return b"".join(np.ascontiguousarray(a).tobytes() for a in parts)


def main(argv=None):
    import bderiv
    import bderiv.models.integrate.run  # noqa: F401 (pronking reads it as an attribute)

    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("base", type=pathlib.Path, help="the other checkout's src folder")
    parser.add_argument("--rounds", type=int, default=7)
    parser.add_argument("--repeats", type=int, default=200, help="calls per round and side")
    parser.add_argument("--clock", choices=("wall", "cpu"), default="wall",
                        help="cpu: the process's CPU time (time.process_time), which time "
                             "spent waiting for a core on a busy machine does not inflate")
    args = parser.parse_args(argv)
    clock = time.process_time if args.clock == "cpu" else time.perf_counter
    base = base_package(args.base)
    importlib.import_module("bderiv_base.models.integrate.run")
    print(f"this: {pathlib.Path(bderiv.__file__).parent}\nbase: {args.base / 'bderiv'}")
    jobs = {}
    for name, (Dh, F) in tables(np.random.default_rng(0)).items():
        jobs[f"BDerivative {name}"] = {
            who: (lambda pkg=pkg, Dh=Dh, F=F: pkg.BDerivative(Dh, F))
            for who, pkg in (("this", bderiv), ("base", base))}
    runs = {who: pronking(pkg) for who, pkg in (("this", bderiv), ("base", base))}
    jobs["BDerivative pronking n=2 d=8"] = {
        who: (lambda pkg=pkg, t=runs["this"][2]: pkg.BDerivative(*t))
        for who, pkg in (("this", bderiv), ("base", base))}
    along = {who: assembly(pkg).flow_map_along for who, pkg in (("this", bderiv), ("base", base))}
    jobs["flow_map_along pronking d=8"] = {
        who: (lambda f=along[who], r=runs[who]: f(r[0], r[1])) for who in runs}
    x0 = runs["this"][1].x[0]
    jobs["flow_bderivative pronking d=8"] = {  # the whole build: integration, then assembly
        who: (lambda r=runs[who]: r[0].flow_bderivative(x0, T_FINAL)) for who in runs}
    for name, job in jobs.items():  # the same bits, or the timing means nothing
        if bits_of(job["this"]()) != bits_of(job["base"]()):
            raise SystemExit(f"{name}: the two checkouts give different bits")
    print(f"load average {os.getloadavg()[0]:.2f}; {args.rounds} rounds of {args.repeats} "
          f"calls per side, alternated; per-call {args.clock} times in us, median and min of "
          f"the rounds after the first")
    print(f"{'job':>35} {'this':>8} {'base':>8} {'ratio':>6} {'this min':>9} {'base min':>9} "
          f"{'ratio':>6}")
    gc.disable()
    try:
        for name, job in jobs.items():
            times = {"this": [], "base": []}
            for r in range(args.rounds):
                for who in ("this", "base") if r % 2 else ("base", "this"):
                    fn = job[who]
                    t0 = clock()
                    for _ in range(args.repeats):
                        fn()
                    times[who].append((clock() - t0) / args.repeats * 1e6)
            med = {w: statistics.median(t[1:]) for w, t in times.items()}
            low = {w: min(t[1:]) for w, t in times.items()}
            print(f"{name:>35} {med['this']:8.1f} {med['base']:8.1f} "
                  f"{med['this'] / med['base']:6.3f} {low['this']:9.1f} {low['base']:9.1f} "
                  f"{low['this'] / low['base']:6.3f}", flush=True)
    finally:
        gc.enable()
    print(f"load average {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    sys.exit(main())
