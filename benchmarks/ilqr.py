"""iLQR through the chair's simultaneous touchdown: the nominal's piece against one order.

The chair with thrusters (``bderiv.control.controlled_chair``: a vertical and an angular
acceleration, held over 5 steps of 30 ms) starts in flight; the target is the state it
reaches at 0.15 s by landing on both feet at once (its free fall, no input). The first
guess applies a constant angular acceleration, so one foot lands first. Cost
``1/2 |x_N - x*|^2 + 1/2 10^-6 |U|^2``. Three linearisations, each step's B-derivative with
the same window (``--window``: touchdowns closer in time form one group):

- ``nominal``: each group's piece by the order the nominal trajectory crossed its events;
- ``order (0, 1)``, ``order (1, 0)``: one fixed order's piece at every iteration (a
  single-order linearisation, what a one-guard-at-a-time saltation computes there).

Prints, for each, the cost per iteration, the iterations to reach 1e-14 of the first cost,
the switches of order met and the time per iteration; ``--figure`` draws the costs.

    python benchmarks/ilqr.py --figure docs/control_ilqr.png [--record]

``--record`` writes the table's rows (docs/control.md) to ``benchmarks/results/ilqr.json``
(``_record.py``).
"""

from __future__ import annotations

import argparse
import time

import _record
import numpy as np

from bderiv.control import controlled_chair, ilqr, rollout

METHODS = {"nominal": "nominal", "order (0, 1)": (0, 1), "order (1, 0)": (1, 0)}
LABELS = {"nominal": "nominal order", "order (0, 1)": "fixed order (0, 1)",
          "order (1, 0)": "fixed order (1, 0)"}  # the rows of docs/control.md


def run(mode_damping, torque, window, iters):
    flow = controlled_chair(mode_damping=mode_damping, simultaneity_tol=window)
    N, dt = 5, 0.03
    U0 = np.zeros((N, 2))
    target = rollout(flow, flow.x0, U0, dt)[-1]
    U0[:, 1] = torque
    ilqr(flow, flow.x0, U0, dt, target, Qf=np.eye(6), R=1e-6 * np.eye(2), max_iters=1)
    out = {}
    for name, lin in METHODS.items():
        t = time.perf_counter()
        res = ilqr(flow, flow.x0, U0, dt, target, Qf=np.eye(6), R=1e-6 * np.eye(2),
                   linearisation=lin, max_iters=iters, tol=0.0)
        out[name] = (res, (time.perf_counter() - t) / len(res.history))
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--mode-damping", type=float, default=60.0)
    ap.add_argument("--torque", type=float, default=4.0)
    ap.add_argument("--window", type=float, default=5e-3)
    ap.add_argument("--iters", type=int, default=12)
    ap.add_argument("--figure", default=None)
    _record.add_argument(ap, "ilqr")
    args = ap.parse_args(argv)
    out = run(args.mode_damping, args.torque, args.window, args.iters)
    print(f"chair, mode_damping={args.mode_damping:g}, first guess a_theta={args.torque:g}, "
          f"window {args.window:g} s")
    print("| linearisation | iterations to 1e-14 | switches | time per iteration | "
          "cost at iterations 0, 1, 2, ... |")
    print("|---|---:|---:|---:|---|")
    rows = []
    for name, (res, per) in out.items():
        c = np.array(res.costs)
        hit = np.flatnonzero(c < 1e-14 * c[0])
        sw = [(i, s[0], s[2], s[3]) for i, it in enumerate(res.history) for s in it.switches]
        print(f"| {name} | {hit[0] if hit.size else 'not in ' + str(len(c) - 1)} | "
              f"{len(sw)} | {per * 1e3:.0f} ms | {' '.join(f'{x:.1e}' for x in c)} |")
        for i, k, a, b in sw:
            print(f"|   | iteration {i}: step {k}, order {a} -> {b} | | | |")
        rows.append(dict(linearisation=LABELS[name],
                         iterations=int(hit[0]) if hit.size else f"not in {len(c) - 1}",
                         switches=[[int(i), int(k), list(a), list(b)] for i, k, a, b in sw],
                         seconds=per, costs=[float(x) for x in c]))
    if args.record:
        _record.record("ilqr", {"main": rows}, path=args.record)
    if args.figure:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig, ax = plt.subplots(figsize=(6.4, 4.0))
        for (name, (res, _)), mark in zip(out.items(), "os^", strict=True):
            c = np.array(res.costs)
            ax.semilogy(range(len(c)), c, marker=mark, label=name)
            for i, it in enumerate(res.history):
                if it.switches:
                    ax.annotate("switch", (i, c[i]), textcoords="offset points",
                                xytext=(4, 6), fontsize=7)
        ax.axhline(1e-14 * out["nominal"][0].costs[0], color="grey", lw=0.8, ls="--",
                   label="1e-14 of the first cost")
        ax.set_xlabel("iteration")
        ax.set_ylabel("cost")
        ax.set_title(f"iLQR through the chair's simultaneous touchdown "
                     f"(window {args.window:g} s)", fontsize=9)
        ax.legend()
        ax.grid(True, which="both", alpha=0.3)
        fig.tight_layout()
        fig.savefig(args.figure, dpi=120)
        print(f"figure: {args.figure}")


if __name__ == "__main__":
    main()
