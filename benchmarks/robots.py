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
  with ``--fd`` (the minimum of ``--repeat`` runs too; more than 2 d times ``simulate``:
  the perturbed runs meet the feet one by one), else estimated as 2 d times the
  measured ``simulate`` (the line says which);

with ``--rigid``, the same for rigid frictionless feet on the pacing posture whose two
left feet land at once and commute (``SOLO12_PACE``; the four-foot drop of rigid feet is
refused: docs/robots.md), the differences over the 2 nv = 36 coordinates of ``(e, v)``
(not the feet's latches). With ``--profile`` (compliant feet), where the CPU time of a
simulation and of the B-derivative goes: the model's calls (timers around each, no
profiler: cProfile's own cost per call was larger than the calls), Pinocchio's routines
within a field and a Jacobian (timed apart, the same calls in four-foot stance), and
bderiv and scipy around the model (the rest). ``--record [PATH]`` writes the rows to
``benchmarks/results/robots.json`` (``robots_rigid.json`` with ``--rigid``) for
docs/robots.md's tables (``python tools/render_benchmarks.py``). The machine's load is
printed with the date (timings on a shared machine: compare CPU times and minima).
"""

from __future__ import annotations

import argparse
import datetime
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import _record  # noqa: E402


def _timed(fn, repeat):
    best = None
    for _ in range(repeat):
        w, c = time.perf_counter(), time.process_time()
        out = fn()
        row = (time.perf_counter() - w, time.process_time() - c)
        best = row if best is None or row[0] < best[0] else best
    return best, out


def _pinocchio_only(robot, x, mask, repeat=500):
    """CPU seconds per call of the Pinocchio routines alone of one field and one field
    Jacobian of the compliant model in region ``mask`` (the same calls, without the
    Python around them)."""
    import pinocchio as pin

    model, data = robot.model, robot.data
    q, v = robot.configuration(x)
    tau = np.zeros(robot.nv)
    oMf = data.oMf

    def kinematics():
        if mask:
            pin.computeJointJacobians(model, data, q)
            pin.updateFramePlacements(model, data)

    def field():
        kinematics()
        pin.aba(model, data, q, v, tau)

    def jacobian():
        kinematics()
        pin.computeABADerivatives(model, data, q, v, tau)

    def positions():  # the feet's positions read out of data: a Python call per foot
        return [oMf[i].translation for i in robot.frame_ids]

    out = []
    for fn in (field, jacobian, positions):
        t = time.process_time()
        for _ in range(repeat):
            fn()
        out.append((time.process_time() - t) / repeat)
    return out


class _Timed:
    """The model's four functions wrapped with CPU timers (a fraction of a microsecond
    per call): :meth:`system` is the same HybridSystem with them."""

    NAMES = ("field", "field_jacobian", "events", "event_jacobian")

    def __init__(self, robot):
        self.robot, self.calls, self.seconds = robot, {}, {}

    def wrap(self, name):
        # the unchecked twins the robot's HybridSystem is built from (the public methods
        # check their input first)
        fn, clock = getattr(self.robot, "_" + name), time.process_time

        def timed(*args):
            t = clock()
            out = fn(*args)
            self.seconds[name] = self.seconds.get(name, 0.0) + clock() - t
            self.calls[name] = self.calls.get(name, 0) + 1
            return out
        return timed

    def system(self):
        from bderiv import HybridSystem

        w = self.wrap
        return HybridSystem(w("field"), w("events"), n_events=len(self.robot.feet),
                            dim=self.robot.system.dim, field_jacobian=w("field_jacobian"),
                            event_jacobian=w("event_jacobian"))


def _where(robot, x0, T):
    """Where the time of a simulation and of the flow B-derivative goes: the model's
    calls (CPU time per call, by timers around them), Pinocchio's routines within them
    (timed apart in four-foot stance), and bderiv and scipy around the model (the
    rest). Returns the rows of the record's table ``where``."""
    mask = (1 << len(robot.feet)) - 1
    x = robot.system.simulate(x0, T).x_final
    pin_field, pin_jac, pin_pos = _pinocchio_only(robot, x, mask)
    pinocchio = {"field": pin_field, "field_jacobian": pin_jac}
    rows = []
    for run in ("simulate", "flow_bderivative"):
        timed = _Timed(robot)
        system = timed.system()
        getattr(system, run)(x0, T)  # the Jacobians' first check, once per region
        timed.calls.clear()
        timed.seconds.clear()
        c = time.process_time()
        getattr(system, run)(x0, T)
        total = time.process_time() - c
        in_model = sum(timed.seconds.values())
        print(f"{run}: {total * 1e3:.1f} ms CPU, of which")
        for name in _Timed.NAMES:
            n = timed.calls.get(name, 0)
            if not n:
                continue
            sec = timed.seconds[name]
            pin = pinocchio.get(name)
            rows.append({"run": run, "part": f"the model's {name}", "calls": n,
                         "per_call": sec / n, "pinocchio": pin, "seconds": sec,
                         "share": sec / total})
            print(f"  {name:15s} {n:5d} calls {sec * 1e3:7.1f} ms ({100 * sec / total:4.1f} %)"
                  f", {sec / n * 1e6:5.1f} us per call"
                  + (f" (Pinocchio's routines {pin * 1e6:.1f} us of it)" if pin else ""))
        rest = total - in_model
        rows.append({"run": run, "part": "bderiv and scipy around the model", "calls": None,
                     "per_call": None, "pinocchio": None, "seconds": rest,
                     "share": rest / total})
        print(f"  bderiv and scipy around the model {rest * 1e3:.1f} ms "
              f"({100 * rest / total:.0f} %)")
    print(f"  (the feet's positions read out of Pinocchio's data: {pin_pos * 1e6:.1f} us "
          f"per call of the field or its Jacobian in stance, counted as ours)")
    return rows


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--fd", action="store_true", help="measure the 2 d simulations")
    parser.add_argument("--profile", action="store_true",
                        help="where the time goes: the model's calls, Pinocchio, bderiv")
    parser.add_argument("--rigid", action="store_true", help="rigid feet, the pacing pair")
    _record.add_argument(parser, "robots")
    args = parser.parse_args(argv)

    from bderiv.robots import SOLO12_PACE, drop_state, quadruped

    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    print(f"{datetime.datetime.now(datetime.timezone.utc):%Y-%m-%d %H:%M} UTC, load "
          f"{load:.1f} on {os.cpu_count()} CPUs")
    robot = (quadruped("solo12", joints=SOLO12_PACE, contact="rigid", sticking=False)
             if args.rigid else quadruped("solo12"))
    x0 = drop_state(robot, 0.01, -0.5)
    T = 0.017123551038388 + 0.05
    d = 2 * robot.nv  # the directions of (e, v)
    robot.system.flow_bderivative(x0, T)  # the first: Jacobians checked once per region
    (sim_w, sim_c), traj = _timed(lambda: robot.system.simulate(x0, T), args.repeat)
    (flow_w, flow_c), D = _timed(lambda: robot.system.flow_bderivative(x0, T), args.repeat)
    print(f"Solo12 ({'rigid' if args.rigid else 'compliant'} feet, d = {robot.system.dim}, "
          f"n = 4), touchdown of {traj.groups[0].events} at "
          f"t = {traj.groups[0].time:.6f} s, then {T - traj.groups[0].time:.3f} s of stance; "
          f"{len(traj.t)} steps")
    print(f"  simulate          {sim_w * 1e3:8.1f} ms wall {sim_c * 1e3:8.1f} ms CPU")
    print(f"  flow_bderivative  {flow_w * 1e3:8.1f} ms wall {flow_c * 1e3:8.1f} ms CPU")
    if args.fd:
        h = 1e-6

        def central():
            return np.array([(robot.system.simulate(x0 + h * s, T).x_final
                              - robot.system.simulate(x0 - h * s, T).x_final) / (2 * h)
                             for s in np.eye(robot.system.dim)[:d]]).T

        (fd_w, fd_c), _ = _timed(central, args.repeat)
        how = "measured"
    else:
        fd_w, fd_c, how = 2 * d * sim_w, 2 * d * sim_c, "estimated: 2 d x simulate"
    print(f"  central FD (2 d = {2 * d} simulations, {how}) {fd_w:8.2f} s wall "
          f"{fd_c:8.2f} s CPU: {fd_w / flow_w:.1f}x the B-derivative (wall), "
          f"{fd_c / flow_c:.1f}x (CPU)")
    rows = [{"what": "simulate", "wall": sim_w, "cpu": sim_c, "unit": "s"},
            {"what": "flow_bderivative", "wall": flow_w, "cpu": flow_c, "unit": "s"},
            {"what": f"central differences of the same simulation ({2 * d} simulations, "
                     f"{how})", "wall": fd_w, "cpu": fd_c, "unit": "s"},
            {"what": "ratio central differences / B-derivative", "wall": fd_w / flow_w,
             "cpu": fd_c / flow_c, "unit": "x"}]
    tables = {"main": rows}
    if args.profile and not args.rigid:
        tables["where"] = _where(robot, x0, T)
    if args.record:
        path = args.record
        if args.rigid and path == os.path.join(_record.RESULTS, "robots.json"):
            path = os.path.join(_record.RESULTS, "robots_rigid.json")
        note = (f"Solo12 ({'rigid' if args.rigid else 'compliant'} feet), touchdown + "
                f"{T - traj.groups[0].time:.3f} s of stance, {len(traj.t)} steps; minimum "
                f"of {args.repeat} runs, one process")
        _record.record("robots", tables, path=path, meta={"note": note})


if __name__ == "__main__":
    main()
