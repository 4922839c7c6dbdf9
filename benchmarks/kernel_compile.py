"""Compile CPU of the kernels a first call needs, per kernel called from Python (issue 36).

    python benchmarks/kernel_compile.py [--src SRC] [--cases demo,dense2,...] [--repeat 1]

Each case runs in a fresh Python process with numba's cache and bderiv's in new temporary
folders (everything compiles), with ``SRC`` (default: this checkout's ``src``) first on the
path. A listener on numba's compile events adds up the CPU time (``time.process_time``:
the load of a shared machine changes it little) of each compilation that starts outside
any other, i.e. of each kernel called from Python, its blocks, steps and NumPy
implementations included; the table lists those of ``bderiv._kernels`` (the digest that
names their cache files left out), their sum, and the compile CPU of everything else
(``other``: the model's and the integrator's functions). Cases:

- ``demo``: the ``pieces`` and ``batch`` phases of ``bderiv demo`` (the chair, its
  Python model on solve_ivp: the integrator's kernels are not in the way), 10**6 vectors;
- ``dense2``: a dense n = 2 table in R^3 (no fast path): ``BDerivative`` and its first
  ``jvp`` on 100 vectors, then ``apply`` and ``event_times`` on the same;
- ``dense2-batch``: the same table's first ``jvp`` on 10**5 vectors (the parallel driver);
- ``own2``: an own-rates dense table (n = 2, d = 6: the chair's kind of group) and its
  first ``apply``, ``event_times`` and ``jvp`` on 100 vectors.

``--src /work/main/src`` (another checkout) measures the same cases there: the before and
after of a change, side by side.
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import re
import subprocess
import sys
import tempfile

HERE = pathlib.Path(__file__).resolve().parent

LISTEN = """
import collections, json, time
from numba.core import event
depth, top = [0], collections.Counter()
class Listener(event.Listener):
    def on_start(self, ev):
        if depth[0] == 0:
            self.t0 = time.process_time()
        depth[0] += 1
    def on_end(self, ev):
        depth[0] -= 1
        if depth[0] == 0:
            d = ev.data["dispatcher"]
            top[f"{d.py_func.__module__}.{d.py_func.__qualname__}"] += (
                time.process_time() - self.t0)
event.register("numba:compile", Listener())
"""

DENSE2 = """
import numpy as np
from bderiv import BDerivative
Dh = np.array([[1.0, 0.2, 0.0], [0.1, 1.0, 0.3]])
F = np.array([[1.0, 1.0, 0.5], [0.8, 1.2, 0.4], [1.1, 0.7, 0.6], [0.9, 0.9, 0.3]])
bd = BDerivative(Dh, F)
assert bd.fast_path is None, bd.fast_path
V = np.random.default_rng(0).standard_normal(({m}, 3))
bd.jvp(V, V)
"""

CASES = {
    "demo": """
import numpy as np
from bderiv import examples
from bderiv.cli.demo import PIECE_SAMPLE, _time_batch
from bderiv.cli.pieces import piece_summary
ex = examples.chair(compiled=False)
fb = ex.system.flow_bderivative(ex.x0, ex.t_final)
V = np.random.default_rng(0).standard_normal((1_000_000, ex.system.dim))
piece_summary(fb, V[:PIECE_SAMPLE])
_time_batch(fb, V)
""",
    "dense2": DENSE2.format(m=100) + "bd(V)\nbd.event_times(V)\n",
    "dense2-batch": DENSE2.format(m=100_000),
    "own2": """
import numpy as np
from bderiv import BDerivative
Dh = np.array([[1.0, 0.0, 0.3, 0.0, 0.0, 0.1], [0.0, 1.0, 0.0, 0.2, 0.1, 0.0]])
rates = np.array([[1.0, 2.0], [0.3, 2.0], [1.0, 0.5], [0.3, 0.5]])  # own rates only
F = np.linalg.lstsq(Dh, rates.T, rcond=None)[0].T
F[3] += np.linalg.svd(Dh)[2][-1]  # not additive: a move unseen by the events
bd = BDerivative(Dh, F)
assert bd.fast_path == "own-rates", bd.fast_path
V = np.random.default_rng(0).standard_normal((100, 6))
bd(V)
bd.event_times(V)
bd.jvp(V, V)
""",
}

REPORT = """
print("JSON" + json.dumps(dict(top)))
"""


def run(case: str, src: pathlib.Path) -> dict:
    """{kernel: compile CPU seconds} of one case in a fresh process with empty caches."""
    with tempfile.TemporaryDirectory() as tmp:
        env = dict(os.environ, NUMBA_CACHE_DIR=f"{tmp}/numba", BDERIV_CACHE_DIR=f"{tmp}/bd",
                   PYTHONPATH=str(src))
        out = subprocess.run([sys.executable, "-c", LISTEN + CASES[case] + REPORT], env=env,
                             capture_output=True, text=True, check=True, cwd=tmp).stdout
    return json.loads(out.split("JSON", 1)[1])


def family(name: str) -> str | None:
    """The kernel's name without the digest of its cache key; None outside the kernels."""
    if not name.startswith("bderiv._kernels."):
        return None
    return re.sub(r"\.k[0-9a-f]{16}$", "", name.removeprefix("bderiv._kernels."))


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--src", type=pathlib.Path, default=HERE.parent / "src")
    parser.add_argument("--cases", default=",".join(CASES))
    parser.add_argument("--repeat", type=int, default=1, help="runs per case (median)")
    args = parser.parse_args(argv)
    print(f"src: {args.src.resolve()}; compile CPU seconds of the kernels called from Python "
          f"(median of {args.repeat})")
    for case in args.cases.split(","):
        runs = [run(case, args.src) for _ in range(args.repeat)]
        rows = {}
        for r in runs:
            for name, sec in r.items():
                rows.setdefault(family(name) or "other", []).append(sec)
        med = {k: sorted(v + [0.0] * (len(runs) - len(v)))[len(runs) // 2]
               for k, v in rows.items()}
        other = med.pop("other", 0.0)
        print(f"{case}: kernels {sum(med.values()):.2f} s, other {other:.2f} s")
        for name, sec in sorted(med.items(), key=lambda kv: -kv[1]):
            print(f"  {sec:6.2f}  {name}")


if __name__ == "__main__":
    main()
