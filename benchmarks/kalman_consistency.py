"""The hybrid Kalman filter against hybrid-tools' SKF and a salted filter (issue 40).

    python benchmarks/kalman_consistency.py [--runs 1000] [--figure docs/estimation.png]

1. Side by side with hybrid-tools' SKF on its 1-D and 2-D bouncing balls, the same
   measurements: the largest differences of the means and covariances over whole runs,
   (a) with its guards made terminal and no process noise (its predict is then the salted
   filter), (b) as shipped, with its process noise (it propagates the prior over the whole
   step before a guard: docs/estimation.md).
2. Monte Carlo through the chair's two-foot landing (and the ball in a corner): the mean
   NEES of each filter (ours: mixture, sigma; salted: the mean's own order, either fixed
   order), each with its default window, against the 95 % chi-square band
   (bderiv.estimate.consistency).
3. The figure: covariance ellipses through the chair's touchdown.

``--record`` writes the chair's rows of 2. (docs/estimation.md's table) to
``benchmarks/results/kalman_consistency.json`` (``_record.py``).
"""

from __future__ import annotations

import argparse
import pathlib
import sys
import time

import _record
import numpy as np

from bderiv import examples
from bderiv.estimate import HybridKalmanFilter
from bderiv.estimate.consistency import FILTERS, consistency

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent.parent / "tests"))
from hybrid_tools_balls import ball_2d  # noqa: E402

G = 9.81


def side_by_side(dim, terminal, steps=40, dt=0.05, r=1e-4):
    """Largest |mean difference| and largest |cov difference| / max|cov| over a run."""
    import hybrid_tools
    import hybrid_tools.skf as skf_module
    from hybrid_tools import ModeNoise
    from hybrid_tools.basic_hybrid_systems import bouncing_ball, bouncing_ball_2d

    e = 0.7
    if dim == 2:
        model, system = examples.bouncing_ball(e=e, g=G).system, bouncing_ball()
        params, x0 = np.array([e, G]), np.array([1.0, 0.0])
    else:
        model, system = ball_2d(e, G, 0.25), bouncing_ball_2d()
        params, x0 = np.array([e, G, 0.25]), np.array([0.0, 1.2, 0.4, 0.0])
    W = 0.0 if terminal else 0.01
    system.noises = {m: ModeNoise(W=W * np.eye(n.W.shape[0]), V=r * np.eye(dim))
                     for m, n in system.noises.items()}
    original = skf_module.solve_ivp_guard_funcs

    def terminal_guards(*args, **kwargs):
        guards, modes = original(*args, **kwargs)
        for g in guards:
            g.terminal = True
        return guards, modes

    if terminal:
        skf_module.solve_ivp_guard_funcs = terminal_guards
    try:
        rng = np.random.default_rng(5)
        ours = HybridKalmanFilter(model, x0, 1e-4 * np.eye(dim))
        skf = hybrid_tools.SKF(x0.copy(), "I", 1e-4 * np.eye(dim), dt, params, system)
        x, dm, dP, bounces = x0, 0.0, 0.0, 0
        Q = np.zeros((dim, dim))
        Q[dim // 2:, dim // 2:] = W * dt * dt * np.eye(dim // 2)  # its B W B^T, B = dt
        for k in range(steps):
            x = model.simulate(x, dt, t_eval=()).x_final
            z = x + np.sqrt(r) * rng.standard_normal(dim)
            ours.predict(dt, Q=Q)
            skf.predict(k * dt, np.zeros(dim // 2))
            bounces += len(ours.mode.groups)
            for m, P in (ours.update(z, r * np.eye(dim), H=np.eye(dim)),):
                hm, hP = skf.update((k + 1) * dt, np.zeros(dim // 2), z)
                dm = max(dm, np.abs(m - hm).max())
                dP = max(dP, np.abs(P - hP).max() / np.abs(P).max())
    finally:
        skf_module.solve_ivp_guard_funcs = original
    return dm, dP, bounces


def figure(path, prior_sd=1e-4, samples=400):
    """Covariance ellipses of the chair's state through its touchdown, in (z, theta)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ex = examples.chair(compiled=True)
    model, d = ex.system, ex.system.dim
    P0 = prior_sd**2 * np.eye(d)
    X0 = ex.x0 + prior_sd * np.random.default_rng(7).standard_normal((samples, d))
    times = (0.095, 0.105, 0.12, ex.t_final)
    i, j = 1, 2  # z and theta
    fig, axes = plt.subplots(1, len(times), figsize=(3.2 * len(times), 3.6))
    t_draw = np.linspace(0, 2 * np.pi, 200)
    styles = {"mixture": ("C0", "-"), "sigma": ("C2", ":"),
              "salted, mean's order": ("C4", (0, (1, 3))),
              "salted, order (0, 1)": ("C3", "--"), "salted, order (1, 0)": ("C1", "-.")}
    for ax, t in zip(axes, times, strict=True):
        Y = model.simulate_many(X0, t, progress=False).x_final
        centre = model.simulate(ex.x0, t, t_eval=()).x_final
        ax.scatter((Y[:, i] - centre[i]) * 1e3, (Y[:, j] - centre[j]) * 1e3, s=3,
                   color="0.6", alpha=0.6, label="true states")
        for name, kw in FILTERS.items():
            f = HybridKalmanFilter(model, ex.x0, P0, **kw)
            m, P = f.predict(t)
            w, U = np.linalg.eigh(P[np.ix_([i, j], [i, j])])
            pts = (m[[i, j], None] - centre[[i, j], None]) + 2 * U @ (
                np.sqrt(w)[:, None] * [np.cos(t_draw), np.sin(t_draw)])
            color, ls = styles[name]
            ax.plot(pts[0] * 1e3, pts[1] * 1e3, linestyle=ls, color=color,
                    label=f"2 sd, {name}")
        ax.set_title(f"t = {t:.3f} s" + (" (before)" if t < ex.t_event else ""),
                     fontsize=10)
        ax.set_xlabel(r"$\delta z$ [mm]")
    axes[0].set_ylabel(r"$\delta\theta$ [mrad]")
    handles, labels = axes[-1].get_legend_handles_labels()
    fig.legend(handles, labels, loc="lower center", ncol=6, fontsize=8, frameon=False)
    fig.suptitle(f"chair: both feet touch down at t = {ex.t_event} s; prior sd "
                 f"{prior_sd:g} in every coordinate, {samples} sampled true states",
                 fontsize=10)
    fig.tight_layout(rect=(0, 0.07, 1, 1))
    fig.savefig(path, dpi=110)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=1000)
    ap.add_argument("--figure", default=None, help="write the ellipse figure here (PNG)")
    ap.add_argument("--figure-only", action="store_true")
    _record.add_argument(ap, "kalman_consistency")
    args = ap.parse_args()
    if args.figure_only:
        figure(args.figure or "estimation.png")
        return
    print("1. side by side with hybrid-tools' SKF (max |mean diff|, max |cov diff| / "
          "max|cov|, groups met)")
    for dim, name in ((2, "1-D ball"), (4, "2-D ball")):
        for terminal, how in ((True, "guards terminal, W = 0"), (False, "as shipped, W = 0.01")):
            dm, dP, n = side_by_side(dim, terminal)
            print(f"   {name}, {how:24s}: {dm:.2e}  {dP:.2e}  ({n} bounces)")
    for ex, sd in ((examples.chair(compiled=True), 1e-4),
                   (examples.ball_in_corner(compiled=True), 1e-4)):
        t0 = time.perf_counter()
        c = consistency(ex, args.runs, prior_sd=sd, seed=1)
        print(f"\n2. {ex.name}, prior sd {sd:g} ({time.perf_counter() - t0:.1f} s)")
        print(c.table())
        if args.record and ex.name == "chair":  # docs/estimation.md's table
            lo, hi = c.band
            rows = [dict(filter=name, mean_nees=float(np.mean(v)), band=[lo, hi],
                         verdict="consistent" if lo <= np.mean(v) <= hi else
                         "overconfident" if np.mean(v) > hi else "underconfident")
                    for name, v in c.nees.items()]
            _record.record("kalman_consistency", {"main": rows}, path=args.record, meta={
                "note": f"{args.runs} runs, d = {c.dim}, "
                        f"{time.perf_counter() - t0:.0f} s for the chair"})
    if args.figure:
        figure(args.figure)
        print(f"\nwrote {args.figure}")


if __name__ == "__main__":
    main()
