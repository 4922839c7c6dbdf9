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

with ``--rigid``, the same for rigid frictionless feet on the pacing posture whose two
left feet land at once and commute (``SOLO12_PACE``; the four-foot drop of rigid feet is
refused: docs/robots.md), the differences over the 2 nv = 36 coordinates of ``(e, v)``
(not the feet's latches); and, with ``--profile``, the B-derivative's time by function
(cProfile): the Pinocchio calls, the model's Python around them, bderiv's integrator and
scipy. The machine's load
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


def _pinocchio_only(robot, x, mask, repeat=300):
    """Seconds per call of the Pinocchio routines alone of one field and one field
    Jacobian evaluation (the same calls, without the Python around them)."""
    import pinocchio as pin

    model, data = robot.model, robot.data
    q, v = robot.configuration(x)
    tau = np.zeros(robot.nv)
    fext = pin.StdVec_Force()
    for _ in range(model.njoints):
        fext.append(pin.Force.Zero())
    feet = [k for k in range(len(robot.feet)) if mask >> k & 1]

    def field():
        pin.forwardKinematics(model, data, q, v)
        pin.updateFramePlacements(model, data)
        for k in feet:
            pin.getFrameVelocity(model, data, robot.frame_ids[k], pin.LOCAL_WORLD_ALIGNED)
        pin.aba(model, data, q, v, tau, fext)

    def jacobian():
        pin.computeForwardKinematicsDerivatives(model, data, q, v, tau)
        pin.computeJointJacobians(model, data, q)
        pin.updateFramePlacements(model, data)
        pin.computeABADerivatives(model, data, q, v, tau, fext)
        for k in feet:
            fid = robot.frame_ids[k]
            pin.getFrameJacobian(model, data, fid, pin.LOCAL_WORLD_ALIGNED)
            pin.getFrameVelocityDerivatives(model, data, fid, pin.LOCAL)
            pin.getFrameVelocity(model, data, fid, pin.LOCAL)
            pin.getFrameJacobian(model, data, fid, pin.LOCAL)
            pin.getJointJacobian(model, data, robot.joint_ids[k], pin.LOCAL)

    out = []
    for fn in (field, jacobian):
        t = time.perf_counter()
        for _ in range(repeat):
            fn()
        out.append((time.perf_counter() - t) / repeat)
    return out


def _profile(robot, x0, T):
    """Where the B-derivative's time goes: the model's calls (cumulative, cProfile) and,
    within them, Pinocchio's routines (timed apart per call: cProfile does not see
    Boost.Python functions), against bderiv and scipy around them."""
    prof = cProfile.Profile()
    prof.enable()
    robot.system.flow_bderivative(x0, T)
    prof.disable()
    stats = pstats.Stats(prof)
    total = stats.total_tt
    model = {}
    for (file, _, name), (_, nc, _, ct, _) in stats.stats.items():
        if file.endswith("legged.py") and name in ("field", "field_jacobian", "events",
                                                   "event_jacobian"):
            model[name] = (nc, ct)
    print(f"profile of flow_bderivative ({total:.2f} s under cProfile):")
    in_model = sum(ct for _, ct in model.values())
    for name, (nc, ct) in sorted(model.items(), key=lambda kv: -kv[1][1]):
        print(f"  {name:15s} {nc:6d} calls {ct:6.2f} s ({100 * ct / total:4.1f} %), "
              f"{1e6 * ct / nc:6.0f} us per call under the profiler")
    x = robot.system.simulate(x0, T).x_final
    pin_field, pin_jac = _pinocchio_only(robot, x, (1 << len(robot.feet)) - 1)
    pin_total = (model.get("field", (0, 0))[0] * pin_field
                 + model.get("field_jacobian", (0, 0))[0] * pin_jac)
    print(f"  Pinocchio's routines alone: {1e6 * pin_field:.0f} us per field, "
          f"{1e6 * pin_jac:.0f} us per Jacobian (four feet in stance): about "
          f"{pin_total:.2f} s of the model's {in_model:.2f} s, the rest the model's "
          f"Python (the base's SE(3) rate and its complex step, forces, NumPy glue)")
    print(f"  bderiv and scipy around the model: {total - in_model:.2f} s "
          f"({100 * (total - in_model) / total:.0f} %)")


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--fd", action="store_true", help="measure the 2 d simulations")
    parser.add_argument("--profile", action="store_true")
    parser.add_argument("--rigid", action="store_true", help="rigid feet, the pacing pair")
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

        (fd_w, fd_c), _ = _timed(central, 1)
        how = "measured"
    else:
        fd_w, fd_c, how = 2 * d * sim_w, 2 * d * sim_c, "estimated: 2 d x simulate"
    print(f"  central FD (2 d = {2 * d} simulations, {how}) {fd_w:8.2f} s wall "
          f"{fd_c:8.2f} s CPU: {fd_w / flow_w:.1f}x the B-derivative (wall), "
          f"{fd_c / flow_c:.1f}x (CPU)")
    if args.profile:
        _profile(robot, x0, T)


if __name__ == "__main__":
    main()
