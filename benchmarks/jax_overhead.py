"""What ``bderiv.jax`` adds to bderiv's own calls: the JAX route against the NumPy route.

For the chair (``bderiv.examples.chair``, d = 6, both feet landing together) every round
times, back to back, the same work both ways, and each keeps its minimum over the rounds::

    python benchmarks/jax_overhead.py [--m 50] [--rounds 5]

- value: ``phi(x0)`` against ``system.simulate(x0, t_final).x_final``;
- jvp: ``jax.jvp(phi, x0, t)`` against ``simulate`` and ``flow_bderivative(x0, t_final)(t)``
  (a new start each round, so that the B-derivative is built, not taken from the cache);
- vmap: ``jax.vmap(phi)`` over m starts against a loop of ``simulate``.

Prints the seconds of each and the ratio JAX / NumPy (1.0: nothing added); ``--record``
writes the rows of docs/jax.md's table to ``benchmarks/results/jax_overhead.json``
(``_record.py``).
"""

from __future__ import annotations

import argparse
import time

import _record
import numpy as np

from bderiv.examples import chair
from bderiv.jax import flow


def _seconds(fn) -> float:
    t = time.perf_counter()
    fn()
    return time.perf_counter() - t


def measure(m: int, rounds: int) -> dict:
    """Minimum seconds of each route, keyed (case, "jax" or "numpy")."""
    import jax  # here: the benchmarks' modules import without the extras (doctests)

    jax.config.update("jax_enable_x64", True)
    ex = chair()
    system, x0, T = ex.system, ex.x0, ex.t_final
    t = np.eye(6)[2]
    X = x0 + 1e-3 * np.random.default_rng(0).standard_normal((m, 6))
    phi = flow(system, T)
    # moved along x, which the model does not depend on: the feet still land together
    starts = iter(x0 + 1e-3 * np.arange(1, rounds + 2)[:, None] * np.eye(6)[0])
    runs = {
        ("value", "jax"): lambda: np.asarray(phi(x0)),
        ("value", "numpy"): lambda: system.simulate(x0, T).x_final,
        ("jvp", "jax"): lambda: np.asarray(jax.jvp(phi, (next(starts),), (t,))[1]),
        ("jvp", "numpy"): lambda: (system.simulate(x0, T).x_final,
                                   system.flow_bderivative(x0, T)(t)),
        ("vmap", "jax"): lambda: np.asarray(jax.vmap(phi)(X)),
        ("vmap", "numpy"): lambda: [system.simulate(x, T).x_final for x in X],
    }
    for fn in runs.values():  # compiled (numba kernels, JAX's traces)
        fn()
    best = {}
    for _ in range(rounds):
        for key, fn in runs.items():
            best[key] = min(best.get(key, np.inf), _seconds(fn))
    return best


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--m", type=int, default=30)
    ap.add_argument("--rounds", type=int, default=5)
    _record.add_argument(ap, "jax_overhead")
    args = ap.parse_args(argv)
    best = measure(args.m, args.rounds)
    print(f"chair, m = {args.m}, min of {args.rounds} interleaved rounds")
    print("| case | JAX route | NumPy route | ratio |\n|---|---:|---:|---:|")
    for case in ("value", "jvp", "vmap"):
        a, b = best[case, "jax"], best[case, "numpy"]
        print(f"| {case} | {a * 1e3:.2f} ms | {b * 1e3:.2f} ms | {a / b:.3f} |")
    if args.record:
        rows = [dict(case=label, jax=best[case, "jax"], numpy=best[case, "numpy"])
                for case, label in labels(args.m).items()]
        _record.record("jax_overhead", {"main": rows}, path=args.record, meta={
            "note": f"the chair, minima of {args.rounds} interleaved rounds"})


def labels(m: int) -> dict:
    """The rows of docs/jax.md's table."""
    return {"value": "a value, against `simulate`",
            "jvp": "a jvp, against `simulate` plus `flow_bderivative(x0, t_final)(t)`",
            "vmap": f"`vmap` over {m} starts, against a loop of `simulate`"}


if __name__ == "__main__":
    main()
