"""Time a stability map of the pronking gait serially and on a two-worker LocalCluster.

    python benchmarks/stability_map.py --size 20 --figure docs/stability_map.png

Both maps run in this process one after the other (the same grid, the same guesses), so
their ratio is read on the same machine state; the figure is drawn from the serial map.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from bderiv.examples import gaits
from bderiv.stability_map import stability_map


def hops(orbit):
    """The hopping gait, not the body standing still (an equilibrium on the section is a
    fixed point of the return map too): feet land and lift off every stride."""
    return len(orbit.trajectory.groups) > 0


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=20, help="grid points per parameter")
    parser.add_argument("--figure", help="save the map's figure here (.png)")
    parser.add_argument("--no-serial", action="store_true", help="only the LocalCluster")
    args = parser.parse_args()
    grid = {"gain": np.linspace(0.5, 6.0, args.size),
            "damping": np.linspace(0.5, 8.0, args.size)}
    common = dict(make_system=gaits.pronking, grid=grid, x_guess=gaits.pronking().x0,
                  section=gaits.apex_section, period_guess=0.5, accept=hops, progress=True)
    times = {}
    maps = {}
    for name, client in (("serial", None), ("LocalCluster (2 workers)", "local")):
        if args.no_serial and client is None:
            continue
        t0 = time.perf_counter()
        maps[name] = stability_map(**common, client=client)
        times[name] = time.perf_counter() - t0
        print(f"{name}: {times[name]:.1f} s for {args.size}x{args.size} points")
        print(maps[name].summary())
    if len(times) == 2:
        serial, local = times.values()
        print(f"LocalCluster / serial: {local / serial:.2f} (speed-up {serial / local:.2f}x)")
    if args.figure:
        from bderiv.plot import stability_map as figure

        fig = figure(next(iter(maps.values())))
        fig.savefig(args.figure, dpi=120)
        print(f"wrote {args.figure}")


if __name__ == "__main__":
    main()
