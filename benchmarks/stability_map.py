"""Time a stability map of the pronking gait serially and on a two-worker LocalCluster.

    python benchmarks/stability_map.py --size 20 --figure docs/stability_map.png

The grid is the pitch inertia (0.10 to 0.24) against the ground damping (0.5 to 6): the
pitch motion of the hop is stable in a band of inertias only (about 0.14 to 0.185 at the
default damping), so the map shows the boundary on both sides. Both maps run in this
process one after the other (the same grid, the same guesses), serially first, so their
ratio is read on the same machine state; the figure is drawn from the serial map. The
cluster's workers first build and solve the model once (``client.run``), as the serial
map's process did before its timing: worker start-up and the first call's compilation
are reported apart, not charged. ``--compiled``: the compiled model
(``gaits.pronking(compiled=True)``, its section compiled): its functions take the body's
constants at run time, so each process compiles them once (or loads them from numba's
disk cache) and the grid points compile nothing. The load average is printed: on a
machine shared with other jobs the speed-up of two workers is below 2.
"""

from __future__ import annotations

import argparse
import functools
import os
import time

import numpy as np

from bderiv.analysis.stability_map import LOCAL_WORKERS, stability_map
from bderiv.examples import gaits

os.environ.setdefault("BDERIV_INTEGRATOR", "compiled")  # compiled from the first run

#: each point's stability verdict (the rate to about 1e-3 here, enough for a map)
VERDICT = {"n_directions": 100, "iterations": 200}
#: the figure's axes (gaits.pronking's parameters)
LABELS = ("pitch inertia (per unit mass)", "ground damping of each leg (per unit mass)")


def hops(orbit):
    """The hopping gait, not the body standing still (an equilibrium on the section is a
    fixed point of the return map too): feet land and lift off every stride."""
    return len(orbit.trajectory.groups) > 0


def model(compiled):
    """``(make_system, section)`` of the Python or the compiled pronking body."""
    if not compiled:
        return gaits.pronking, gaits.apex_section
    return functools.partial(gaits.pronking, compiled=True), gaits.compiled_apex_section


def warm_up(make_system, section):
    """Build and solve the model once in this process (loads and compiles what it needs)."""
    ex = make_system()
    orbit = ex.system.periodic_orbit(ex.x0, section, period_guess=0.5)
    orbit.stability(n_directions=10, iterations=10)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=20, help="grid points per parameter")
    parser.add_argument("--figure", help="save the map's figure here (.png)")
    parser.add_argument("--no-serial", action="store_true", help="only the LocalCluster")
    parser.add_argument("--no-cluster", action="store_true", help="only the serial map")
    parser.add_argument("--compiled", action="store_true", help="the compiled model")
    args = parser.parse_args()
    make_system, section = model(args.compiled)
    grid = {"inertia": np.linspace(0.10, 0.24, args.size),
            "damping": np.linspace(0.5, 6.0, args.size)}
    common = dict(make_system=make_system, grid=grid, x_guess=gaits.pronking().x0,
                  section=section, period_guess=0.5, accept=hops, progress=True,
                  **VERDICT)
    print(f"{args.size} x {args.size} map of the {'compiled' if args.compiled else 'Python'} "
          f"pronking model, stability({VERDICT}); load {os.getloadavg()[0]:.1f} on "
          f"{os.cpu_count()} cores")
    times, maps = {}, {}
    if not args.no_serial:
        start = time.perf_counter()
        warm_up(make_system, section)
        print(f"serial: first build and solve {time.perf_counter() - start:.1f} s (not charged)")
        start = time.perf_counter()
        maps["serial"] = stability_map(**common)
        times["serial"] = time.perf_counter() - start
        print(f"serial: {times['serial']:.1f} s (load {os.getloadavg()[0]:.1f})")
        print(maps["serial"].summary())
    if not args.no_cluster:
        from distributed import Client, LocalCluster

        start = time.perf_counter()
        with LocalCluster(n_workers=LOCAL_WORKERS, threads_per_worker=1, processes=True,
                          dashboard_address=None) as cluster, Client(cluster) as client:
            client.run(warm_up, make_system, section)
            print(f"LocalCluster ({LOCAL_WORKERS} workers): started and warmed up in "
                  f"{time.perf_counter() - start:.1f} s (not charged)")
            start = time.perf_counter()
            maps["cluster"] = stability_map(**common, client=client)
            times["cluster"] = time.perf_counter() - start
        print(f"LocalCluster ({LOCAL_WORKERS} workers): {times['cluster']:.1f} s (load "
              f"{os.getloadavg()[0]:.1f})")
        print(maps["cluster"].summary())
    if len(times) == 2:
        a, b = maps["serial"].growth_rate, maps["cluster"].growth_rate
        same = np.allclose(a, b, rtol=1e-8, equal_nan=True)
        differ = np.nanmax(np.abs(a - b)) if np.isfinite(a - b).any() else 0.0
        print(f"speed-up of {LOCAL_WORKERS} workers: {times['serial'] / times['cluster']:.2f}x "
              f"(growth rates {'equal' if same else 'DIFFERENT'} to 1e-8: largest "
              f"difference {differ:.2g}; the same points without an orbit: "
              f"{np.array_equal(np.isnan(a), np.isnan(b))})")
    if args.figure:
        from bderiv.plot import stability_map as figure

        fig = figure(next(iter(maps.values())), labels=LABELS)
        fig.savefig(args.figure, dpi=120)
        print(f"wrote {args.figure}")


if __name__ == "__main__":
    main()
