"""Cold start: what a fresh machine pays before the first answer (issue 36's yardstick).

``python benchmarks/cold_start.py [--demo] [--no-diffrax]`` runs each case in a fresh
Python process, with numba's cache in a temporary folder (``NUMBA_CACHE_DIR``, bderiv's
symbolic cache beside it), and reports wall seconds as each child measures them, and the
CPU seconds of each child (``cpu``: its own and its subprocesses', what the load does not
move much). The children get a clean environment: ``BDERIV_INTEGRATOR=auto``, none of the
caller's ``NUMBA_*``, ``JAX_*`` or ``XLA_*`` settings.

- ``import bderiv``, with the cache empty: its time, and the part of it numba spent
  compiling (``import_compile``: the kernels compiled at their definition, which a warm
  cache loads); target 1 counts that part with the first answer;
- the chair's first flow B-derivative (its compiled model: ``examples.chair(compiled=True)``)
  in a process with the cache empty, applied to the six unit vectors (``first``: the first
  numbers, the analogue of a Jacobian, with the kernels that this first use compiles;
  ``built``: the map alone, before them), and a second map (``second``): on scipy
  while the compiled integrator compiles in a background process (``on scipy``; the default
  ``BDERIV_INTEGRATOR=auto``, :mod:`bderiv.models.readiness`), then, in the same process,
  the time until it is in the cache (``ready``, from the first call), then flow maps until
  the chair's functions have left their Python code (they were not on this machine either:
  "Python first"; ``maps_on_python`` of them in ``until_compiled``, their compilation
  included), the first flow map after (``switch``) and the next (``compiled``); each child
  waits for its background compilation to end before it exits, so that none runs into the
  next case;
- the same in a second process, the cache now warm (loading only), and the warm call;
- the chair with the cache empty and ``BDERIV_INTEGRATOR=compiled``: the integrator compiled
  before the first answer (what every first call paid before the background compilation);
- a new model, its source never seen (a module written for the run: the chair's equations
  as numba functions under a fresh name), with the library's cache warm: the case of every
  edit a user makes: under ``BDERIV_INTEGRATOR=auto`` its runs start on the functions'
  Python code ("Python first", :mod:`bderiv.models.calls`), so the child goes on with flow
  maps until they are compiled (``maps_on_python``, ``until_compiled``) and times one after
  (``compiled``); and the same equations as plain Python functions (no compilation of the
  user's code: they run on scipy's integrator);
- a new corner function (``CornerFunction``, its source never seen), the library's cache
  warm: its first B-derivative's apply, inverse, event times and jvp on 10 and 5,000
  queries (the serial and the parallel drivers);
- diffrax's first Jacobian of the same flow (the chair written in JAX as in docs/jax.md,
  ``jax.jacfwd`` of its event-switching loop: trace, compile and run; the loop's time
  starts as a traced value, so that one compilation of its segment serves every call, as
  docs/jax.md writes it; the child checks that it compiled once) in a fresh process, where
  jax and diffrax are installed;
- with ``--demo``: ``python -m bderiv demo`` with the cache empty, its first line's time and
  its total.

The answers are checked, not only timed: the chair's flow B-derivative, the new models' and
diffrax's Jacobian are applied to the same 64 random vectors; the bderiv ones must agree
(one model, one flow), and diffrax's Jacobian must be one piece of them (the piece of the
event order its loop follows: on at least one vector in eight).

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
import threading
import time

import _record
import numpy as np

try:
    import resource
except ImportError:  # Windows: no CPU times of the children
    resource = None

#: the numba compilation a child's import does, summed (outermost compilations only):
#: installed before ``import bderiv``; the same 64 tangent vectors for every answer checked
PRELUDE = """
import json, time
t0 = time.perf_counter()
from numba.core import event as _event
_depth, _compiling = [0], [0.0]


class _Compiles(_event.Listener):
    def on_start(self, ev):
        _depth[0] += 1
        if _depth[0] == 1:
            self.start = time.perf_counter()

    def on_end(self, ev):
        _depth[0] -= 1
        if _depth[0] == 0:
            _compiling[0] += time.perf_counter() - self.start


_event.register("numba:compile", _Compiles())
import numpy as np
V = np.random.default_rng(36).standard_normal((64, 6))
"""

CHAIR = PRELUDE + """
import bderiv
from bderiv import examples
from bderiv.models import readiness
t1 = time.perf_counter()
import_compile = _compiling[0]
ex = examples.chair(compiled=True)
D = ex.system.flow_bderivative(ex.x0, ex.t_final)
tb = time.perf_counter()
D(np.eye(6))  # the first numbers: its kernels compile (or load) at this first use
t2 = time.perf_counter()
on = "compiled" if ex.system.compiled is not None else "scipy"
ex.system.flow_bderivative(ex.x0 + 1e-3, ex.t_final)
t3 = time.perf_counter()
row = {"import": t1 - t0, "import_compile": import_compile, "first": t2 - t1,
       "built": tb - t1, "second": t3 - t2, "on": on, "DV": np.asarray(D(V)).tolist()}
if on == "scipy":  # the integrator compiles in a background process: until it is cached
    while not readiness.integrator_cached():
        time.sleep(0.1)
    t4 = time.perf_counter()
    while not readiness.integrator_ready():  # this process's look (once a second)
        time.sleep(0.05)
    t5, k = time.perf_counter(), 0  # its functions on their Python code (not compiled on
    while ex.system.calls.python_first:  # this machine yet): flow maps until they compile
        k += 1
        ex.system.flow_bderivative(ex.x0 + 1e-4 * k, ex.t_final)
    t6 = time.perf_counter()
    ex.system.flow_bderivative(ex.x0, ex.t_final)  # on the compiled integrator
    t7 = time.perf_counter()
    ex.system.flow_bderivative(ex.x0 + 1e-3, ex.t_final)
    row.update(ready=t4 - t1, maps_on_python=k, until_compiled=t6 - t5, switch=t7 - t6,
               compiled=time.perf_counter() - t7)
readiness.wait_for_background()  # its workload too: none runs into the next case
print(json.dumps(row))
"""

NEW_MODEL = PRELUDE + """
import sys
import bderiv
sys.path.insert(0, {folder!r})
import {module} as m
from bderiv import HybridSystem
t1 = time.perf_counter()
import_compile = _compiling[0]
s = HybridSystem(m.field, m.events, n_events=2, dim=6, event_jacobian=m.event_jacobian)
D = s.flow_bderivative(m.X0, 0.15)
tb = time.perf_counter()
D(np.eye(6))  # the first numbers
t2 = time.perf_counter()
row = {{"import": t1 - t0, "import_compile": import_compile, "first": t2 - t1,
       "built": tb - t1,
       "on": "python" if s.calls.python_first else (
           "compiled" if s.compiled is not None else "scipy"),
       "DV": np.asarray(D(V)).tolist()}}
if s.calls.python_first:  # more flow maps until its functions are compiled, and one after
    k = 0
    while s.calls.python_first:
        k += 1
        s.flow_bderivative(m.X0 + 1e-4 * k, 0.15)
    t3 = time.perf_counter()
    s.flow_bderivative(m.X0, 0.15)
    row.update(maps_on_python=k, until_compiled=t3 - t2, compiled=time.perf_counter() - t3)
print(json.dumps(row))
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

#: the chair (``bderiv.examples.chair``'s equations and constants, d = 6, n = 2) as numba
#: functions, written out under a fresh module name for each run (``python_source``: the
#: same without the decorators)
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
    damping = C * (1.0 + KAPPA) if (mask & 3) == 3 else C
    out = np.empty_like(x)  # complex for complex x: the complex step
    out[0], out[1], out[2] = x[3], x[4], x[5]
    ax, az, alpha = 0.0 * x[0], -G + 0.0 * x[0], 0.0 * x[0]
    c, s = np.cos(x[2]), np.sin(x[2])
    for k in range(2):
        if mask >> k & 1:
            rx = LEGS[k, 0] * c - LEGS[k, 1] * s
            rz = LEGS[k, 0] * s + LEGS[k, 1] * c
            fz = -K * (x[1] + rz) - damping * (x[4] + x[5] * rx)
            fx = -CT * (x[3] - x[5] * rz)
            ax = ax + fx
            az = az + fz
            alpha = alpha + (rx * fz - rz * fx) / INERTIA
    out[3], out[4], out[5] = ax, az, alpha
    return out
"""


def python_source(source: str) -> str:
    """``source`` without its numba decorators: the same functions in plain Python."""
    return source.replace("@numba.njit\n", "")


DIFFRAX = """
import json, time
t0 = time.perf_counter()
import jax, jax.numpy as jnp
jax.config.update("jax_enable_x64", True)
import diffrax, optimistix as optx
import numpy as np
compiled = []  # the backend compilations of segment (one expected)
jax.monitoring.register_event_duration_secs_listener(
    lambda event, seconds, fun_name=None, **_: compiled.append(seconds)
    if event == "/jax/core/compile/backend_compile_duration" and fun_name == "jit(segment)"
    else None)
t1 = time.perf_counter()
G, K, C, KAPPA, CT, INERTIA = 9.81, 400.0, 4.0, 1.0, 1.0, 0.1
A = jnp.array([-0.5, 0.6]); B = jnp.array([-0.4, -0.4 + (-0.5 - 0.6) * np.tan(0.1)])


def events(x):
    c, s = jnp.cos(x[2]), jnp.sin(x[2])
    return -(x[1] + A * s + B * c)


def field(x, mask):  # the chair's (bderiv.examples.chair), as in docs/jax.md
    c, s = jnp.cos(x[2]), jnp.sin(x[2])
    on = jnp.array([mask & 1, mask >> 1 & 1]).astype(x.dtype)
    rx, rz = A * c - B * s, A * s + B * c
    damping = C * (1.0 + KAPPA * (mask == 3))
    fz = on * (-K * (x[1] + rz) - damping * (x[4] + x[5] * rx))
    fx = on * (-CT * (x[3] - x[5] * rz))
    return jnp.array([x[3], x[4], x[5], fx.sum(), -G + fz.sum(),
                      (rx * fz - rz * fx).sum() / INERTIA])


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
    # t starts as a value of x's type with a tangent, as every later t (docs/jax.md): one
    # compilation of segment serves every call (0.0 would be another type: two)
    t, mask = 0.0 * x[0], 0
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
assert len(compiled) == 1, f"segment compiled {len(compiled)} times"
V = np.random.default_rng(36).standard_normal((64, 6))
print(json.dumps({"import": t1 - t0, "first": t2 - t1,
                  "DV": (V @ np.asarray(J).T).tolist()}))
"""


def clean_environment(tmp: str) -> dict:
    """The children's environment: this one without the settings that would change what is
    measured (``BDERIV_*``, ``NUMBA_*``, ``JAX_*``, ``XLA_*``), with numba's and bderiv's
    caches in ``tmp`` and ``BDERIV_INTEGRATOR=auto``."""
    env = {k: v for k, v in os.environ.items()
           if not k.startswith(("BDERIV_", "NUMBA_", "JAX_", "XLA_"))}
    return {**env, "NUMBA_CACHE_DIR": os.path.join(tmp, "numba"),
            "BDERIV_CACHE_DIR": os.path.join(tmp, "bderiv"), "BDERIV_INTEGRATOR": "auto"}


def children_cpu() -> float:
    """CPU seconds of the children waited for so far (0 where the OS does not say)."""
    if resource is None:
        return 0.0
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def child(code, env, timeout):
    """Run ``code`` in a fresh interpreter; its JSON line, with the wall seconds and the CPU
    seconds of the child and its subprocesses (``cpu``)."""
    cpu, start = children_cpu(), time.perf_counter()
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True,
                         text=True, timeout=timeout)
    wall = time.perf_counter() - start
    if out.returncode != 0:
        raise RuntimeError(f"child failed ({out.returncode}):\n{out.stderr[-2000:]}")
    return {**json.loads(out.stdout.strip().splitlines()[-1]), "wall": wall,
            "cpu": children_cpu() - cpu}


def demo(env, timeout):
    """``python -m bderiv demo``: the seconds to its first line and to its end; killed
    after ``timeout`` seconds, and a failure raised with the end of its error output."""
    cpu, start = children_cpu(), time.perf_counter()
    with tempfile.TemporaryFile() as err:
        proc = subprocess.Popen([sys.executable, "-m", "bderiv", "demo", "--no-progress"],
                                env=env, stdout=subprocess.PIPE, stderr=err, text=True)
        watchdog = threading.Timer(timeout, proc.kill)
        watchdog.start()
        first = None
        try:
            for _ in proc.stdout:
                if first is None:
                    first = time.perf_counter() - start
            proc.wait()
        finally:
            watchdog.cancel()
        wall = time.perf_counter() - start
        if proc.returncode != 0:
            err.seek(0)
            raise RuntimeError(f"the demo failed ({proc.returncode}; killed after {timeout} s"
                               f" if negative):\n{err.read().decode()[-2000:]}")
    return {"first_line": first, "wall": wall, "cpu": children_cpu() - cpu}


def check_answers(rows: dict) -> None:
    """The flow B-derivatives and diffrax's Jacobian measured are of one flow: the bderiv
    answers agree on the 64 vectors (relative 1e-6: one on scipy, one compiled), and
    diffrax's Jacobian agrees with them on at least 8 of those (its loop's event order:
    one piece of the B-derivative)."""
    answers = {name: np.asarray(row.pop("DV")) for name, row in rows.items() if "DV" in row}
    jax_name = "diffrax: first Jacobian (trace, compile, run)"
    ours = [a for name, a in answers.items() if name != jax_name]
    scale = np.linalg.norm(ours[0], axis=1)
    for name, a in answers.items():
        agree = np.linalg.norm(a - ours[0], axis=1) <= 1e-6 * scale
        if name != jax_name and not agree.all():
            raise RuntimeError(f"{name}: its flow B-derivative is not the chair's "
                               f"({(~agree).sum()} of {agree.size} vectors differ)")
        if name == jax_name and agree.sum() < 8:
            raise RuntimeError(f"diffrax's Jacobian is no piece of the chair's flow "
                               f"B-derivative (it agrees on {agree.sum()} of 64 vectors)")
    if jax_name in answers:
        rows[jax_name]["agrees on"] = int((np.linalg.norm(answers[jax_name] - ours[0], axis=1)
                                           <= 1e-6 * scale).sum())


def new_model(folder: pathlib.Path, name: str, env: dict, timeout: float, python=False):
    """A new model's first flow B-derivative: the chair's equations written out under a
    fresh module name (plain Python functions with ``python``)."""
    (folder / f"{name}.py").write_text(python_source(MODEL_SOURCE) if python else MODEL_SOURCE)
    return child(NEW_MODEL.format(folder=str(folder), module=name), env, timeout)


def pairs(count: int, env: dict, folder: pathlib.Path, timeout: float) -> list[tuple]:
    """Target 2's cases alternated ``count`` times: ``[(diffrax_first, new_model_first)]``,
    each printed with its ratio as it comes."""
    out = []
    for k in range(count):
        rows = {"diffrax: first Jacobian (trace, compile, run)": child(DIFFRAX, env, timeout),
                "a new model": new_model(folder, f"user_model_{os.getpid()}_pair{k}", env,
                                         timeout)}
        check_answers(rows)
        jax_first, model_first = (row["first"] for row in rows.values())
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
        env = clean_environment(tmp)
        print(f"load {os.getloadavg()[0]:.2f}, {os.cpu_count()} CPUs, cache in {tmp}",
              flush=True)
        folder = pathlib.Path(tmp, "models")
        folder.mkdir()
        if args.pairs:
            if args.pairs < 0 or args.no_diffrax or args.demo or args.record:
                parser.error("--pairs N takes a positive N and none of --no-diffrax, --demo,"
                             " --record")
            child(CHAIR, env, args.timeout)  # the library's cache warm
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
        module = f"user_model_{os.getpid()}"
        rows["bderiv: a new model, library warm"] = new_model(folder, module, env,
                                                              args.timeout)
        rows["bderiv: a new model in plain Python, library warm"] = new_model(
            folder, f"{module}_python", env, args.timeout, python=True)
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
            wait_for_compilations(demo_env["NUMBA_CACHE_DIR"], args.timeout)
        print(f"load {os.getloadavg()[0]:.2f} at the end")
    check_answers(rows)
    width = max(map(len, rows))
    for name, row in rows.items():
        parts = ", ".join(f"{k} {v:.3g} s" if isinstance(v, float) else f"{k} {v}"
                          for k, v in row.items() if v is not None)
        print(f"{name:<{width}}  {parts}")
    for line in targets(rows):
        print(line)
    if args.record:
        _record.record("cold_start", {"main": doc_rows(rows)}, path=args.record, meta={
            "note": "each case in a fresh process, numba's cache in a temporary folder"})
    return rows


def wait_for_compilations(cache: str, timeout: float) -> None:
    """Wait until no background compilation of the integrator into ``cache`` runs (the
    demo's outlives it: it would write into the folder removed next, and run into what
    the machine does next): until its lock is free."""
    code = ("from bderiv.models import readiness\n"
            "with readiness.compile_lock(wait=True):\n    pass\n")
    subprocess.run([sys.executable, "-c", code], env={**os.environ, "NUMBA_CACHE_DIR": cache},
                   timeout=timeout, check=False)


def targets(rows: dict) -> list[str]:
    """Targets 1 and 2 read off the rows (first answers, the import's compilation counted
    with bderiv's: a warm cache loads it)."""
    jax_row = rows.get("diffrax: first Jacobian (trace, compile, run)")
    if jax_row is None:
        return []
    jax_first = jax_row["first"]
    empty, model = rows["bderiv: chair, cache empty"], rows["bderiv: a new model, library warm"]
    python = rows["bderiv: a new model in plain Python, library warm"]
    cold = empty["first"] + empty["import_compile"]
    return [
        f"target 1: the chair's first numbers (its map on the unit vectors), cache empty, "
        f"with its import's compilation "
        f"{cold:.2f} s against diffrax's {jax_first:.2f} s: "
        f"{'holds' if cold <= jax_first else 'over'}",
        f"target 2: a new model's first answer {model['first']:.2f} s against a quarter of "
        f"diffrax's, {jax_first / 4:.2f} s: "
        f"{'holds' if model['first'] <= jax_first / 4 else 'over'} "
        f"(ratio {model['first'] / jax_first:.3f}); in plain Python {python['first']:.2f} s "
        f"(ratio {python['first'] / jax_first:.3f})"]


def doc_rows(rows: dict) -> list[dict]:
    """The rows of docs/design.md's cold-start table (``_layouts.py``) from :func:`main`'s."""
    def case(label, r, second=True):
        return dict(case=label, seconds=r["first"], second=r["second"] if second else None,
                    import_compile=r.get("import_compile"), **{"import": r["import"]})
    out = []
    if "diffrax: first Jacobian (trace, compile, run)" in rows:
        out.append(case("diffrax: first Jacobian of the chair's event-switching flow (trace, "
                        "compile, run; its segment compiled once)",
                        rows["diffrax: first Jacobian (trace, compile, run)"], second=False))
    empty = rows["bderiv: chair, cache empty"]
    out.append(case("bderiv: the chair's first flow B-derivative applied to the six unit "
                    f"vectors, cache empty (the map alone {empty['built']:.2f} s)" + (
                        "; on scipy, the integrator compiling in the background"
                        if empty["on"] == "scipy" else ""), empty))
    if "ready" in empty:
        out.append({"case": "... the integrator ready (from the first call) / flow maps "
                    f"until the chair's functions are compiled ({empty['maps_on_python']} on "
                    "their Python code, the compilation included) / the first after / the "
                    "next", "seconds": [empty["ready"], empty["until_compiled"],
                                        empty["switch"], empty["compiled"]],
                    "import": None, "second": None})
    out.append(case("bderiv: the same, cache warm", rows["bderiv: chair, cache warm"]))
    out.append(case("bderiv: cache empty, `BDERIV_INTEGRATOR=compiled` (waiting for the "
                    "integrator)", rows["bderiv: chair, cache empty, BDERIV_INTEGRATOR=compiled"],
                    second=False))
    model = rows["bderiv: a new model, library warm"]
    out.append(case("bderiv: a new model (source never seen) applied to the six unit "
                    "vectors, the library's cache warm" + (
                        " (on its Python code: Python first)" if model.get("on") == "python"
                        else ""), model, second=False))
    if "until_compiled" in model:
        out.append({"case": f"... flow maps until compiled ({model['maps_on_python']} on "
                    "Python code, the compilation included) / the next, compiled",
                    "seconds": [model["until_compiled"], model["compiled"]],
                    "import": None, "second": None})
    out.append(case("bderiv: the same model's functions in plain Python (none compiled: on "
                    "scipy), the library's cache warm",
                    rows["bderiv: a new model in plain Python, library warm"], second=False))
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
