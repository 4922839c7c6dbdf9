"""``bderiv demo --example solo12``: Solo12's four-foot touchdown from its URDF, the flow's
B-derivative, its pieces, and a check against finite differences of the simulation.

Kept apart from the model (:mod:`bderiv.robots.quadrupeds`) as the gait examples keep
their summaries: it times the steps a user takes (load the URDF, simulate, the
B-derivative) and says what the map is (its group, its 24 pieces, the orders a batch of
directions meets). The check is bderiv's own :func:`~bderiv.analysis.checks.fd_check` (the
independent simulation is in the tests).
"""

from __future__ import annotations

import time

import numpy as np

__all__ = ["solo12_summary", "summary_text"]

#: the drop: feet 1 cm above the ground, falling at 0.5 m/s; 50 ms of stance after
DROP = {"height": 0.01, "vz": -0.5, "stance": 0.05}


def solo12_summary(*, seed=0, n_check=3, eps=(1e-5, 1e-6), figure=None) -> dict:
    """The demo's numbers (JSON-friendly): build, simulate and B-derivative times, the
    group, the orders met by 2000 random directions, and ``fd_check`` on ``n_check`` of
    them (relative errors at the steps ``eps``, largest first)."""
    from ..analysis.checks import fd_check
    from .quadrupeds import drop_state, quadruped, touchdown_figure

    t0 = time.perf_counter()
    robot = quadruped("solo12")
    t1 = time.perf_counter()
    x0 = drop_state(robot, DROP["height"], DROP["vz"])
    touch = (np.sqrt(DROP["vz"] ** 2 + 2 * 9.81 * DROP["height"]) + DROP["vz"]) / 9.81
    T = touch + DROP["stance"]
    traj = robot.system.simulate(x0, T)
    t2 = time.perf_counter()
    D = robot.system.flow_bderivative(x0, T)
    t3 = time.perf_counter()
    V = np.random.default_rng(seed).standard_normal((2000, robot.system.dim))
    orders = D.orders(V)[0]
    met = {tuple(int(D.group_events[0][k]) for k in o) for o in orders}
    check = fd_check(robot.system, x0, T, V[:n_check], D(V[:n_check]), eps=eps)
    t4 = time.perf_counter()
    res = {
        "name": "solo12",
        "description": "Solo12 (example-robot-data's solo12.urdf, Pinocchio) dropped level "
                       "so that its four feet touch at once; compliant feet, the base in "
                       "SE(3) tangent coordinates (d = 36, n = 4)",
        "seconds": {"build": t1 - t0, "simulate": t2 - t1, "flow_bderivative": t3 - t2,
                    "check": t4 - t3},
        "groups": [{"time": g.time, "feet": [robot.feet[k] for k in g.events]}
                   for g in traj.groups],
        "t_final": T,
        "pieces": int(np.prod(range(1, len(D.group_events[0]) + 1))),
        "orders_met": len(met),
        "check": {"eps": list(check.eps), "max_errors": list(map(float, check.max_errors))},
    }
    if figure is not None:
        touchdown_figure(robot, x0, T).savefig(figure)
        res["figure"] = str(figure)
    return res


def summary_text(res) -> str:
    """The lines of :func:`solo12_summary` for a terminal."""
    s, c = res["seconds"], res["check"]
    lines = [f"bderiv demo: {res['name']}", f"  {res['description']}",
             f"model from the URDF in {s['build']:.2f} s; simulate to t = "
             f"{res['t_final']:.4f} s in {s['simulate']:.2f} s"]
    lines += [f"  touchdown of {', '.join(g['feet'])} at t = {g['time']:.6f} s"
              for g in res["groups"]]
    lines.append(f"flow B-derivative in {s['flow_bderivative']:.2f} s: {res['pieces']} "
                 f"pieces (foot orders); 2000 random directions met {res['orders_met']}")
    lines.append("against finite differences of the simulation: relative error "
                 + ", ".join(f"{e:.1e} at eps {h:g}" for h, e in zip(c["eps"], c["max_errors"],
                                                                     strict=True))
                 + f" ({s['check']:.1f} s)")
    if "figure" in res:
        lines.append(f"figure: {res['figure']}")
    return "\n".join(lines)
