"""Cold start: what a fresh machine pays before the first answer (issue 36's yardstick).

``python benchmarks/cold_start.py [--demo] [--no-diffrax]`` runs each case in a fresh
Python process, with numba's cache in a temporary folder (``NUMBA_CACHE_DIR``, bderiv's
symbolic cache beside it), and reports wall seconds as each child measures them:

- ``import bderiv``, with the cache empty;
- the chair's first flow B-derivative (its compiled model: ``examples.chair(compiled=True)``)
  in a process with the cache empty (``first``), and a second one (``second``): on scipy
  while the compiled integrator compiles in a background process (``on scipy``; the default
  ``BDERIV_INTEGRATOR=auto``, :mod:`bderiv.models.readiness`), then, in the same process,
  the time until it is ready (``ready``, from the first call), the first flow map on it
  (``switch``: loading it) and the next (``compiled``);
- the same in a second process, the cache now warm (loading only), and the warm call;
- the chair with the cache empty and ``BDERIV_INTEGRATOR=compiled``: the integrator compiled
  before the first answer (what every first call paid before the background compilation);
- a new model, its source never seen (a module written for the run: the chair's equations
  as numba functions under a fresh name), with the library's cache warm: the case of every
  edit a user makes;
- a new corner function (``CornerFunction``, its source never seen), the library's cache
  warm: its first B-derivative's apply, inverse, event times and jvp on 10 and 5,000
  queries (the serial and the parallel drivers);
- diffrax's first Jacobian of the same flow (``jax.jacfwd`` of the event-switching loop of
  docs/jax.md: trace, compile and run) in a fresh process, where jax and diffrax are
  installed;
- with ``--demo``: ``python -m bderiv demo`` with the cache empty, its first line's time and
  its total.

``--pairs N`` runs only target 2's two cases, diffrax's first Jacobian and a new model's
first flow B-derivative (the library's cache warmed once first), N times one after the
other, and prints each pair's ratio against the target's quarter: both sides move by a
third within an hour on a shared machine, so one pair says little.

A benchmark, not a test: cold runs take minutes on two cores, and their times move with the
machine's load, so the rows are read side by side (same run, same load), and the load is
printed.
``--record`` writes the
rows of docs/design.md's table to ``benchmarks/results/cold_start.json`` (``_record.py``).
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import subprocess
import sys
import tempfile
import time

import _record

CHAIR = """
import json, time
t0 = time.perf_counter()
import bderiv
from bderiv import examples
from bderiv.models import readiness
t1 = time.perf_counter()
ex = examples.chair(compiled=True)
D = ex.system.flow_bderivative(ex.x0, ex.t_final)
t2 = time.perf_counter()
on = "compiled" if ex.system.compiled is not None else "scipy"
ex.system.flow_bderivative(ex.x0 + 1e-3, ex.t_final)
t3 = time.perf_counter()
row = {"import": t1 - t0, "first": t2 - t1, "second": t3 - t2, "on": on}
if on == "scipy":  # the integrator compiles in a background process: until it is ready
    while not readiness.integrator_ready():
        time.sleep(0.1)
    t4 = time.perf_counter()
    ex.system.flow_bderivative(ex.x0, ex.t_final)  # it loads, the model's calls compile
    t5 = time.perf_counter()
    ex.system.flow_bderivative(ex.x0 + 1e-3, ex.t_final)
    row.update(ready=t4 - t1, switch=t5 - t4, compiled=time.perf_counter() - t5)
print(json.dumps(row))
"""

NEW_MODEL = """
import json, sys, time
t0 = time.perf_counter()
import bderiv
sys.path.insert(0, {folder!r})
import {module} as m
from bderiv import HybridSystem
t1 = time.perf_counter()
s = HybridSystem(m.field, m.events, n_events=2, dim=6, event_jacobian=m.event_jacobian)
s.flow_bderivative(m.X0, 0.15)
t2 = time.perf_counter()
print(json.dumps({{"import": t1 - t0, "first": t2 - t1}}))
"""

NEW_CORNERS = """
import json, sys, time
t0 = time.perf_counter()
import numpy as np
import bderiv
sys.path.insert(0, {folder!r})
import {module} as m
from bderiv import BDerivative, CornerFunction
t1 = time.perf_counter()
bd = BDerivative(m.DH, CornerFunction(m.corners))
for V in (m.V[:10], m.V):
    bd(V), bd.inverse(V), bd.event_times(V), bd.jvp(V, V)
t2 = time.perf_counter()
print(json.dumps({{"import": t1 - t0, "first": t2 - t1}}))
"""

#: a corner function of four events in dimension 5, written out under a fresh module name
CORNERS_SOURCE = """
import numba
import numpy as np

DH = np.eye(4, 5) + 0.1 * np.arange(20.0).reshape(4, 5) / 20
F0 = np.array([1.0, 1.5, 2.0, 1.2, 0.8])
V = np.random.default_rng(0).standard_normal((5000, 5))

@numba.njit
def corners(happened, out):
    s = 0.0
    for k in range(happened.shape[0]):
        s += 0.05 * happened[k] * (k + 1)
    for i in range(out.shape[0]):
        out[i] = F0[i] * (1.0 + s)
"""

#: a planar body landing on two legs at once (the chair's geometry, d = 6, n = 2) as numba
#: functions, written out under a fresh module name for each run
MODEL_SOURCE = """
import numba
import numpy as np

G, K, C, KAPPA, CT, INERTIA = 9.81, 400.0, 4.0, 1.0, 1.0, 0.1
TH = 0.1
A0, B0, A1 = -0.5, -0.4, 0.6
B1 = B0 + (A0 - A1) * np.tan(TH)
LEGS = np.array([[A0, B0], [A1, B1]])
Z = -(A0 * np.sin(TH) + B0 * np.cos(TH))
VX, VZ, OM, T = 0.5, -2.0, 0.3, 0.1  # both feet on the ground after T of free flight
X0 = np.array([-VX * T, Z - (VZ + G * T) * T + 0.5 * G * T**2, TH - OM * T, VX, VZ + G * T,
               OM])

@numba.njit
def events(x):
    out = np.empty(2)
    c, s = np.cos(x[2]), np.sin(x[2])
    for k in range(2):
        out[k] = -(x[1] + LEGS[k, 0] * s + LEGS[k, 1] * c)
    return out


@numba.njit
def event_jacobian(x):
    J = np.zeros((2, 6))
    c, s = np.cos(x[2]), np.sin(x[2])
    for k in range(2):
        J[k, 1] = -1.0
        J[k, 2] = -(LEGS[k, 0] * c - LEGS[k, 1] * s)
    return J


@numba.njit
def field(x, mask):
    out = np.zeros_like(x)
    out[0], out[1], out[2] = x[3], x[4], x[5]
    out[4] = -G
    c, s = np.cos(x[2]), np.sin(x[2])
    both = mask == 3
    for k in range(2):
        if mask >> k & 1:
            rx = LEGS[k, 0] * c - LEGS[k, 1] * s
            depth = -(x[1] + LEGS[k, 0] * s + LEGS[k, 1] * c)
            rate = -(x[4] + rx * x[5])
            damping = C * (1.0 + KAPPA) if both else C
            f = K * depth + damping * rate
            out[4] += f
            out[3] -= CT * x[3]
            out[5] += rx * f / INERTIA
    return out
"""

DIFFRAX = """
import json, time
t0 = time.perf_counter()
import jax, jax.numpy as jnp
jax.config.update("jax_enable_x64", True)
import diffrax, optimistix as optx
import numpy as np
t1 = time.perf_counter()
G, K, C, KAPPA, CT, INERTIA = 9.81, 400.0, 4.0, 1.0, 1.0, 0.1
A = jnp.array([-0.5, 0.6]); B = jnp.array([-0.4, -0.4 + (-0.5 - 0.6) * np.tan(0.1)])


def events(x):
    c, s = jnp.cos(x[2]), jnp.sin(x[2])
    return -(x[1] + A * s + B * c)


def field(x, mask):
    c, s = jnp.cos(x[2]), jnp.sin(x[2])
    on = jnp.array([mask & 1, mask >> 1 & 1]).astype(x.dtype)
    rx = A * c - B * s
    depth, rate = events(x), -(x[4] + rx * x[5])
    damping = C * (1.0 + KAPPA * (mask == 3))
    f = on * (K * depth + damping * rate)
    return jnp.array([x[3], x[4], x[5], -CT * x[3] * on.sum(), -G + f.sum(),
                      (rx * f).sum() / INERTIA])


T_FINAL = 0.15


@jax.jit
def segment(x, t0, mask):
    up = jnp.where(jnp.array([mask & 1, mask >> 1 & 1]) == 1, -1.0, 1.0)
    crossing = [lambda t, y, args, k=k, **kw: up[k] * events(y)[k] for k in range(2)]
    sol = diffrax.diffeqsolve(
        diffrax.ODETerm(lambda t, y, mask: field(y, mask)), diffrax.Tsit5(), t0, T_FINAL,
        None, x, args=mask, max_steps=100_000, adjoint=diffrax.ForwardMode(),
        stepsize_controller=diffrax.PIDController(rtol=1e-10, atol=1e-12),
        event=diffrax.Event(crossing, optx.Newton(rtol=1e-12, atol=1e-12), direction=True))
    return sol.ts[-1], sol.ys[-1], jnp.stack(sol.event_mask)


def flow(x):
    t, mask = 0.0, 0
    while True:
        t, x, fired = segment(x, t, mask)
        if not fired.any():
            return x
        mask ^= int(fired[0]) | int(fired[1]) << 1


z = -(-0.5 * np.sin(0.1) + -0.4 * np.cos(0.1))
x0 = jnp.array([-0.05, z + 2.0 * 0.1 - 0.5 * G * 0.1**2, 0.1 - 0.03, 0.5, -2.0 + G * 0.1, 0.3])
J = jax.jacfwd(flow)(x0)
J.block_until_ready()
t2 = time.perf_counter()
print(json.dumps({"import": t1 - t0, "first": t2 - t1}))
"""


def child(code, env, timeout):
    """Run ``code`` in a fresh interpreter; its JSON line, with the wall seconds."""
    start = time.perf_counter()
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True,
                         text=True, timeout=timeout)
    wall = time.perf_counter() - start
    if out.returncode != 0:
        raise RuntimeError(f"child failed ({out.returncode}):\n{out.stderr[-2000:]}")
    return {**json.loads(out.stdout.strip().splitlines()[-1]), "wall": wall}


def demo(env, timeout):
    """``python -m bderiv demo``: the seconds to its first line and to its end."""
    start = time.perf_counter()
    proc = subprocess.Popen([sys.executable, "-m", "bderiv", "demo", "--no-progress"],
                            env=env, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL,
                            text=True)
    first = None
    for _ in proc.stdout:
        if first is None:
            first = time.perf_counter() - start
    proc.wait(timeout=timeout)
    return {"first_line": first, "wall": time.perf_counter() - start}


def pairs(count: int, env: dict, folder: pathlib.Path, timeout: float) -> list[tuple]:
    """Target 2's cases alternated ``count`` times: ``[(diffrax_first, new_model_first)]``,
    each printed with its ratio as it comes."""
    out = []
    for k in range(count):
        jax_first = child(DIFFRAX, env, timeout)["first"]
        module = f"user_model_{os.getpid()}_pair{k}"
        (folder / f"{module}.py").write_text(MODEL_SOURCE)
        model_first = child(NEW_MODEL.format(folder=str(folder), module=module), env,
                            timeout)["first"]
        ratio = model_first / jax_first
        print(f"pair {k + 1}/{count}: diffrax {jax_first:.2f} s, a new model {model_first:.2f}"
              f" s, ratio {ratio:.3f} ({'within' if ratio <= 0.25 else 'over'} a quarter),"
              f" load {os.getloadavg()[0]:.2f}", flush=True)
        out.append((jax_first, model_first))
    return out


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--demo", action="store_true", help="also the demo, cache empty")
    parser.add_argument("--no-diffrax", action="store_true", help="skip diffrax's case")
    parser.add_argument("--timeout", type=float, default=1800.0)
    parser.add_argument("--pairs", type=int, default=0, metavar="N",
                        help="only diffrax's first Jacobian and a new model's first flow "
                             "B-derivative, N times alternated (target 2)")
    _record.add_argument(parser, "cold_start")
    args = parser.parse_args(argv)
    rows = {}
    with tempfile.TemporaryDirectory() as tmp:
        env = {**os.environ, "NUMBA_CACHE_DIR": os.path.join(tmp, "numba"),
               "BDERIV_CACHE_DIR": os.path.join(tmp, "bderiv")}
        print(f"load {os.getloadavg()[0]:.2f}, {os.cpu_count()} CPUs, cache in {tmp}",
              flush=True)
        if args.pairs:
            if args.pairs < 0 or args.no_diffrax or args.demo or args.record:
                parser.error("--pairs N takes a positive N and none of --no-diffrax, --demo,"
                             " --record")
            child(CHAIR, env, args.timeout)  # the library's cache warm
            folder = pathlib.Path(tmp, "models")
            folder.mkdir()
            return pairs(args.pairs, env, folder, args.timeout)
        if not args.no_diffrax:
            rows["diffrax: first Jacobian (trace, compile, run)"] = child(DIFFRAX, env,
                                                                         args.timeout)
        rows["bderiv: chair, cache empty"] = child(CHAIR, env, args.timeout)
        rows["bderiv: chair, cache warm"] = child(CHAIR, env, args.timeout)
        waiting = {**env, "NUMBA_CACHE_DIR": os.path.join(tmp, "numba-wait"),
                   "BDERIV_INTEGRATOR": "compiled"}
        rows["bderiv: chair, cache empty, BDERIV_INTEGRATOR=compiled"] = child(
            CHAIR, waiting, args.timeout)
        folder = pathlib.Path(tmp, "models")
        folder.mkdir()
        module = f"user_model_{os.getpid()}"
        (folder / f"{module}.py").write_text(MODEL_SOURCE)
        rows["bderiv: a new model, library warm"] = child(
            NEW_MODEL.format(folder=str(folder), module=module), env, args.timeout)
        # the first corner function compiles the library's function kernels; the second,
        # another source, is the case measured
        for k, scale in enumerate(("0.05", "0.04")):
            name = f"{module}_corners{k}"
            (folder / f"{name}.py").write_text(CORNERS_SOURCE.replace("0.05", scale))
            rows["bderiv: a new corner function, library warm"] = child(
                NEW_CORNERS.format(folder=str(folder), module=name), env, args.timeout)
        if args.demo:
            demo_env = {**env, "NUMBA_CACHE_DIR": os.path.join(tmp, "numba-demo")}
            rows["bderiv demo, cache empty"] = demo(demo_env, args.timeout)
        print(f"load {os.getloadavg()[0]:.2f} at the end")
    width = max(map(len, rows))
    for name, row in rows.items():
        parts = ", ".join(f"{k} {v:.3g} s" if isinstance(v, float) else f"{k} {v}"
                          for k, v in row.items() if v is not None)
        print(f"{name:<{width}}  {parts}")
    if args.record:
        _record.record("cold_start", {"main": doc_rows(rows)}, path=args.record, meta={
            "note": "each case in a fresh process, numba's cache in a temporary folder"})
    return rows


def doc_rows(rows: dict) -> list[dict]:
    """The rows of docs/design.md's cold-start table (``_layouts.py``) from :func:`main`'s."""
    def case(label, r, second=True):
        return dict(case=label, seconds=r["first"], second=r["second"] if second else None,
                    **{"import": r["import"]})
    out = []
    if "diffrax: first Jacobian (trace, compile, run)" in rows:
        out.append(case("diffrax: first Jacobian of the chair's event-switching flow (trace, "
                        "compile, run)", rows["diffrax: first Jacobian (trace, compile, run)"],
                        second=False))
    empty = rows["bderiv: chair, cache empty"]
    out.append(case("bderiv: the chair's first flow B-derivative, cache empty" + (
        " (on scipy; the integrator compiling in the background)"
        if empty["on"] == "scipy" else ""), empty))
    if "ready" in empty:
        out.append({"case": "... the integrator ready (from the first call) / the first flow "
                    "map on it / the next", "seconds": [empty["ready"], empty["switch"],
                                                      empty["compiled"]],
                    "import": None, "second": None})
    out.append(case("bderiv: the same, cache warm", rows["bderiv: chair, cache warm"]))
    out.append(case("bderiv: cache empty, `BDERIV_INTEGRATOR=compiled` (waiting for the "
                    "integrator)", rows["bderiv: chair, cache empty, BDERIV_INTEGRATOR=compiled"],
                    second=False))
    out.append(case("bderiv: a new model (source never seen), the library's cache warm",
                    rows["bderiv: a new model, library warm"], second=False))
    if "bderiv: a new corner function, library warm" in rows:
        out.append(case("bderiv: a new corner function's first apply, inverse, event times "
                        "and jvp (10 and 5,000 queries), the library's cache warm",
                        rows["bderiv: a new corner function, library warm"], second=False))
    if "bderiv demo, cache empty" in rows:
        r = rows["bderiv demo, cache empty"]
        out.append({"case": "`python -m bderiv demo`, cache empty: first line / total",
                    "seconds": [r["first_line"], r["wall"]], "import": None, "second": None})
    return out


if __name__ == "__main__":
    main()
