"""Solo12's four-foot touchdown from its URDF: the flow's B-derivative against finite
differences of the same simulation, and where the time goes.

``python benchmarks/robots.py [--repeat 3] [--fd] [--profile]`` builds Solo12
(:func:`bderiv.robots.quadruped`), drops it level from 1 cm at 0.5 m/s so that its four
feet touch at once (t = 17.1 ms) and times, over touchdown + 50 ms of stance (the
minimum of ``--repeat`` runs, wall and CPU seconds):

- ``simulate``: one simulation of that span;
- ``flow_bderivative``: the B-derivative of the flow map (the trajectory and its
  variational equation, the group's corner table and ``BDerivative``);
- central finite differences of the same simulation: 2 d = 72 simulations; measured
  with ``--fd`` (about 2 d times ``simulate``), else estimated as 2 d times the measured
  ``simulate`` (the line says which);

and, with ``--profile``, the B-derivative's time by function (cProfile): the Pinocchio
calls, the model's Python around them, bderiv's integrator and scipy. The machine's load
is printed with the date (timings on a shared machine: compare minima).
"""

from __future__ import annotations

import argparse
import cProfile
import datetime
import os
import pstats
import time

import numpy as np


def _timed(fn, repeat):
    best = None
    for _ in range(repeat):
        w, c = time.perf_counter(), time.process_time()
        out = fn()
        row = (time.perf_counter() - w, time.process_time() - c)
        best = row if best is None or row[0] < best[0] else best
    return best, out


def _profile(fn, top=14):
    prof = cProfile.Profile()
    prof.enable()
    fn()
    prof.disable()
    stats = pstats.Stats(prof)
    total = stats.total_tt
    rows = sorted(((tt, nc, func) for func, (_, nc, tt, _, _) in stats.stats.items()),
                  reverse=True)
    print(f"profile of flow_bderivative: {total:.2f} s under cProfile; own time by "
          f"function (top {top}):")
    for tt, nc, (file, line, name) in rows[:top]:
        where = name if file == "~" else f"{os.path.basename(file)}:{line} {name}"
        print(f"  {tt:6.2f} s {100 * tt / total:5.1f} %  {nc:7d} calls  {where}")
    pin_time = sum(tt for tt, _, (file, _, name) in rows
                   if file == "~" and "Boost.Python" not in name and "pinocchio" in name)
    print(f"  Pinocchio's own calls (built-ins named pinocchio...): {pin_time:.2f} s "
          f"({100 * pin_time / total:.0f} %)")


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--fd", action="store_true", help="measure the 2 d simulations")
    parser.add_argument("--profile", action="store_true")
    args = parser.parse_args(argv)

    from bderiv.robots import drop_state, quadruped

    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    print(f"{datetime.datetime.now(datetime.timezone.utc):%Y-%m-%d %H:%M} UTC, load "
          f"{load:.1f} on {os.cpu_count()} CPUs")
    robot = quadruped("solo12")
    x0 = drop_state(robot, 0.01, -0.5)
    T = 0.017123551038388 + 0.05
    d = robot.system.dim
    robot.system.flow_bderivative(x0, T)  # the first: Jacobians checked once per region
    (sim_w, sim_c), traj = _timed(lambda: robot.system.simulate(x0, T), args.repeat)
    (flow_w, flow_c), D = _timed(lambda: robot.system.flow_bderivative(x0, T), args.repeat)
    print(f"Solo12 (d = {d}, n = 4), touchdown of {traj.groups[0].events} at "
          f"t = {traj.groups[0].time:.6f} s, then {T - traj.groups[0].time:.3f} s of stance; "
          f"{len(traj.t)} steps")
    print(f"  simulate          {sim_w * 1e3:8.1f} ms wall {sim_c * 1e3:8.1f} ms CPU")
    print(f"  flow_bderivative  {flow_w * 1e3:8.1f} ms wall {flow_c * 1e3:8.1f} ms CPU")
    if args.fd:
        h = 1e-6

        def central():
            return np.array([(robot.system.simulate(x0 + h * s, T).x_final
                              - robot.system.simulate(x0 - h * s, T).x_final) / (2 * h)
                             for s in np.eye(d)]).T

        (fd_w, fd_c), _ = _timed(central, 1)
        how = "measured"
    else:
        fd_w, fd_c, how = 2 * d * sim_w, 2 * d * sim_c, "estimated: 2 d x simulate"
    print(f"  central FD (2 d = {2 * d} simulations, {how}) {fd_w:8.2f} s wall "
          f"{fd_c:8.2f} s CPU: {fd_w / flow_w:.1f}x the B-derivative (wall), "
          f"{fd_c / flow_c:.1f}x (CPU)")
    if args.profile:
        _profile(lambda: robot.system.flow_bderivative(x0, T))


if __name__ == "__main__":
    main()
