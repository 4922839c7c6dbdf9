"""A Python model without Jacobians against the same model with them (users' fourth pass).

``python benchmarks/numerical_jacobians.py`` builds the chair's flow B-derivative to
``T_FINAL`` (five event groups) from its Python functions three ways, in one process, in
``ROUNDS`` alternated rounds, min over all: with the example's field and event Jacobians;
without any (the model finds its own: the complex step where the functions take complex
input, held once to a central difference); and without any, its field written into a float
array so that no complex step is possible (central differences, the slow path a user met
before the complex step was tried). Printed: each time, its ratio to the model with
Jacobians, the numerical Jacobians' cost, and the maps' agreement.
"""

from __future__ import annotations

import time

import numpy as np

from bderiv import HybridSystem, examples

T_FINAL = 0.6
ROUNDS = 3


def main():
    ex = examples.chair()
    given = ex.system
    field, events = given.field, given.events

    def float_field(x, mask):  # the same field, through a float array: no complex input
        out = np.zeros(6)
        out[:] = field(x, mask)
        return out

    models = {"with Jacobians": given,
              "without: complex step": HybridSystem(field, events, n_events=2, dim=6),
              "without: central differences": HybridSystem(float_field, events, n_events=2,
                                                           dim=6)}
    maps = {name: m.flow_bderivative(ex.x0, T_FINAL) for name, m in models.items()}  # warm
    best = dict.fromkeys(models, np.inf)
    for _ in range(ROUNDS):
        for name, m in models.items():
            start = time.perf_counter()
            m.flow_bderivative(ex.x0, T_FINAL)
            best[name] = min(best[name], time.perf_counter() - start)
    V = np.random.default_rng(0).standard_normal((20, 6))
    ref = maps["with Jacobians"](V)
    for name, m in models.items():
        cost = {k: v[:2] for k, v in m.numerical_jacobian_cost.items()}
        print(f"{name:<30} {best[name] * 1e3:8.1f} ms  x{best[name] / best['with Jacobians']:5.1f}"
              f"  max rel diff {np.abs(maps[name](V) - ref).max() / np.abs(ref).max():.1e}"
              f"  numerical (Jacobians, calls): {cost}")


if __name__ == "__main__":
    main()
