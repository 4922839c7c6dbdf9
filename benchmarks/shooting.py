"""Shooting through bounces: bderiv.control.shoot against hybrid-tools' ShootingMethodOptimizer.

On hybrid-tools' own bouncing balls, the same problem for both: the start velocity that
puts the ball at a target position at T (its 2-D script: from (0, 1) at rest to (4, 1) at
T = 5 s; the 1-D ball from q = 1 to q = 0.5 at T = 2 s), from the same initial guesses,
with the same Levenberg-Marquardt rules and stopping rule (error_tol 0.005, input_state_tol
1e-5); they differ in the Jacobian only (ours: the flow's B-derivative; theirs: Euler
steps of 5 ms with the saltation matrix at the step that holds the impact). hybrid-tools'
process noise is set to 0 (its simulator draws it on the inputs).

    python benchmarks/shooting.py [--record]

``--record`` writes the two tables' rows (docs/control.md) to
``benchmarks/results/shooting.json`` (``_record.py``).
"""

from __future__ import annotations

import sys
import time

import _record
import numpy as np

from bderiv.control import ShootingConfig, ball_1d, ball_2d, shoot

TOLS = {"max_iters": 50, "error_tol": 0.005, "input_state_tol": 1e-5}


def theirs(system, params, T, x0, controls, guess, target, outputs):
    from hybrid_tools.shooting_method_optimizer import (
        ShootingMethodOptimizer,
        ShootingMethodOptimizerConfig,
    )
    for mode in system.noises:
        system.noises[mode].W *= 0
    opt = ShootingMethodOptimizer(system, "I", np.array(params), dt=0.005, T=T)
    return opt.optimize(np.array(x0, float), controls, np.array(guess, float),
                        np.array(target, float), outputs, np.zeros(len(x0) // 2),
                        ShootingMethodOptimizerConfig(verbose=False, **TOLS))


def main(record=False):
    from hybrid_tools.basic_hybrid_systems import bouncing_ball, bouncing_ball_2d

    cases = [("2-D", ball_2d(), bouncing_ball_2d, [0.8, 9.81, 0.0], 5.0,
              [0.0, 1.0, 0.0, 0.0], [2, 3], [0, 1], [4.0, 1.0],
              [[0.8, v] for v in (5.0, 6.0, 7.0, 8.0, 9.0, 10.0, 11.0)]),
             ("1-D", ball_1d(), bouncing_ball, [0.8, 9.81], 2.0, [1.0, 0.0], [1], [0],
              [0.5], [[v] for v in (1.0, 2.0, 3.0, 4.0, 5.0)])]
    print("| ball | guess | hybrid-tools: iterations | optimum | s | bderiv: iterations | "
          "optimum | s | same optimum |")
    print("|---|---|---:|---|---:|---:|---|---:|:---:|")
    tables = {}
    for name, flow, make, params, T, x0, ctrl, outs, target, guesses in cases:
        for guess in guesses:
            t = time.perf_counter()
            r = theirs(make(), params, T, x0, ctrl, guess, target, outs)
            t_theirs = time.perf_counter() - t
            t = time.perf_counter()
            o = shoot(flow, x0, flow.defaults, T, target, output_indices=outs,
                      state_indices=ctrl, initial_guess=guess, config=ShootingConfig(**TOLS))
            t_ours = time.perf_counter() - t
            same = np.abs(o.decision - r.optimal_controls).max() < 2e-3
            fmt = lambda w: "(" + ", ".join(f"{v:.5f}" for v in w) + ")"  # noqa: E731
            no = " (not converged)"
            print(f"| {name} | {guess[-1]:g} | {r.iterations}{'' if r.converged else no}"
                  f" | {fmt(r.optimal_controls)} | {t_theirs:.2f} | {o.iterations}"
                  f"{'' if o.converged else no} | {fmt(o.decision)} | "
                  f"{t_ours:.2f} | {'yes' if same else 'no'} |", flush=True)
            tables.setdefault(name, []).append(dict(
                ball=name, guess=guess[-1], theirs_iterations=int(r.iterations),
                theirs_converged=bool(r.converged),
                theirs_optimum=[float(v) for v in r.optimal_controls], theirs_s=t_theirs,
                ours_iterations=int(o.iterations), ours_converged=bool(o.converged),
                ours_optimum=[float(v) for v in o.decision], ours_s=t_ours,
                same="yes" if same else "no"))
    if record:
        _record.record("shooting", tables)


if __name__ == "__main__":
    main(record="--record" in sys.argv)
