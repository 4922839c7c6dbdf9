"""flow_bderivative(...)(V) per vector against one flow_fd evaluation per vector.

Two ways to run it:

- as a script, ``python benchmarks/test_bench_flow.py [--json out.json]``: for every example,
  the one-sided finite-difference error of simulation against the B-derivative at
  eps = 1e-3, 1e-4, 1e-5 (max relative error over random vectors), the time of one
  ``flow_bderivative`` construction, of the map per vector (batch of 1000 and one vector
  at a time) and of one ``flow_fd`` per vector, all in the same run; prints a markdown
  table (the numbers of the issue 3 closing note); ``--record`` writes the rows of
  docs/benchmarks.md's table to ``benchmarks/results/flow.json`` (``_record.py``);
- with pytest-benchmark (``pytest benchmarks/test_bench_flow.py -n 0 --benchmark-enable``): the
  same contenders, grouped per example so that the ratio can be read; with the default
  ``--benchmark-disable`` they run once as smoke tests.
"""

from __future__ import annotations

import argparse
import json
import time

import _record
import numpy as np
import pytest

from bderiv import examples
from bderiv.analysis.checks import fd_check
from bderiv.engine._baselines import best_time

EPS = (1e-3, 1e-4, 1e-5)

CASES = {
    "chair": lambda: examples.chair(),
    "chair-additive": lambda: examples.chair(mode_damping=0.0),
    "table": lambda: examples.table(),
    "network-n3": lambda: examples.network(3),
    "network-n3-d6": lambda: examples.network(3, extended=True),
    "network-n8": lambda: examples.network(8),
    "network-n16": lambda: examples.network(16),
    "network-n20": lambda: examples.network(20),
}
QUICK = ("chair", "table", "network-n3")
LABELS = {"chair": "chair", "chair-additive": "chair, additive",
          "table": "table (n > rank Dh)", "network-n3": "network n = 3",
          "network-n3-d6": "network n = 3, d = 6", "network-n8": "network n = 8",
          "network-n16": "network n = 16", "network-n20": "network n = 20"}


def measure(name, n_vectors=10, seed=0):
    """All numbers for one example (a dict)."""
    ex = CASES[name]()
    s = ex.system
    t = time.perf_counter()
    fb = s.flow_bderivative(ex.x0, ex.t_final)
    t_build = time.perf_counter() - t
    rng = np.random.default_rng(seed)
    V = rng.standard_normal((n_vectors, s.dim))
    check = fd_check(s, ex.x0, ex.t_final, V, fb(V), EPS)
    errors = [float(e) for e in check.errors.max(axis=0)]
    n_orders = len({tuple(o) for o in fb.orders(V)[0]}) if fb.n_groups else 0
    batch = rng.standard_normal((1000, s.dim))
    fb(batch)  # warm
    t_batch = best_time(lambda: fb(batch), 5, warmup=False).wall / len(batch)
    t_single = best_time(lambda: [fb(v) for v in batch[:50]], 5, warmup=False).wall / 50
    t_fd = check.seconds_per_vector  # one perturbed simulation (the base run amortised)
    return {
        "example": name,
        "n": s.n_events,
        "d": s.dim,
        "orders_seen": n_orders,
        "fd_error": dict(zip([f"{e:g}" for e in EPS], errors, strict=True)),
        "t_build_s": t_build,
        "t_apply_batch_per_vector_s": t_batch,
        "t_apply_single_per_vector_s": t_single,
        "t_flow_fd_per_vector_s": t_fd,
        "speedup_batch": t_fd / t_batch,
    }


def table(rows):
    head = (
        "| example | n | d | orders seen | FD err eps=1e-3 | 1e-4 | 1e-5 | build | "
        "B-deriv per vector (batch) | (single call) | flow_fd per vector | speed-up |\n"
        "|---|---|---|---|---|---|---|---|---|---|---|---|\n"
    )
    lines = []
    for r in rows:
        e = list(r["fd_error"].values())
        lines.append(
            f"| {r['example']} | {r['n']} | {r['d']} | {r['orders_seen']} | {e[0]:.2e} | "
            f"{e[1]:.2e} | {e[2]:.2e} | {r['t_build_s'] * 1e3:.0f} ms | "
            f"{r['t_apply_batch_per_vector_s'] * 1e6:.2f} us | "
            f"{r['t_apply_single_per_vector_s'] * 1e6:.1f} us | "
            f"{r['t_flow_fd_per_vector_s'] * 1e3:.1f} ms | {r['speedup_batch']:.1e}x |"
        )
    return head + "\n".join(lines)


# ------------------------------------------------------------------------------------------
# pytest-benchmark suite
# ------------------------------------------------------------------------------------------
@pytest.fixture(scope="module", params=QUICK)
def case(request):
    ex = CASES[request.param]()
    fb = ex.system.flow_bderivative(ex.x0, ex.t_final)
    V = np.random.default_rng(0).standard_normal((1000, ex.system.dim))
    fb(V)  # compile and warm the kernels outside the timing
    return request.param, ex, fb, V


def test_flow_bderivative_batch(benchmark, case):
    name, ex, fb, V = case
    benchmark.group = f"flow {name}"
    benchmark.extra_info["vectors"] = len(V)
    out = benchmark(fb, V)
    assert out.shape == V.shape


def test_flow_fd_one_vector(benchmark, case):
    name, ex, fb, V = case
    benchmark.group = f"flow {name}"
    benchmark.extra_info["vectors"] = 1
    out = benchmark.pedantic(
        ex.system.flow_fd, args=(ex.x0, ex.t_final, V[:1], 1e-4), rounds=1, iterations=1
    )
    assert np.allclose(out, fb(V[:1]), rtol=1e-2, atol=1e-2 * np.abs(out).max())


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", help="write the numbers to this file")
    parser.add_argument("--quick", action="store_true", help=f"only {', '.join(QUICK)}")
    parser.add_argument("--only", nargs="+", choices=tuple(CASES), help="these examples")
    parser.add_argument("--vectors", type=int, default=10, help="vectors for the FD errors")
    _record.add_argument(parser, "flow")
    args = parser.parse_args(argv)
    names = args.only or (QUICK if args.quick else tuple(CASES))
    rows = []
    for name in names:
        rows.append(measure(name, n_vectors=args.vectors))
        print(f"done {name}", flush=True)
    print(table(rows))
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(rows, fh, indent=2)
    if args.record:
        _record.record("flow", {"main": [record_row(r) for r in rows]}, path=args.record)


def record_row(r: dict) -> dict:
    """A row of :func:`measure` in the keys of the docs' table (``_layouts.py``)."""
    errors = dict(zip(("fd_1e-3", "fd_1e-4", "fd_1e-5"), r["fd_error"].values(), strict=True))
    return dict(example=LABELS[r["example"]], n=r["n"], d=r["d"],
                orders_seen=r["orders_seen"], **errors, build=r["t_build_s"],
                batch=r["t_apply_batch_per_vector_s"], single=r["t_apply_single_per_vector_s"],
                flow_fd=r["t_flow_fd_per_vector_s"], speedup=r["speedup_batch"])


if __name__ == "__main__":
    main()
