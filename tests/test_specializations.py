"""Each kernel compiles once per genuinely different need (issue 36): writeable and read-only
inputs reach the kernels in one form (read-only for the B-derivative's kernels; writeable
for the stop rules, as the compiled run passes them), and ``tools/specializations.py``
counts the signatures.

The workload runs in a fresh process: the signatures a dispatcher holds are those of every
call in its process, and other tests call kernels directly with arrays of their own.
"""

from __future__ import annotations

import ast
import json
import os
import pathlib
import subprocess
import sys

ROOT = pathlib.Path(__file__).resolve().parents[1]

#: every entry point below called with writeable and with read-only arrays
WORKLOAD = r"""
import importlib.util, json, sys
from types import SimpleNamespace
import numpy as np
from bderiv import BDerivative
from bderiv.models.compiled import rules
from bderiv.models.events import crossings, excursions, locate, sides

spec = importlib.util.spec_from_file_location("spec_tool", sys.argv[1])
tool = importlib.util.module_from_spec(spec)
spec.loader.exec_module(tool)

def both(a):
    r = np.array(a, dtype=np.float64)
    r.flags.writeable = False
    return np.array(a, dtype=np.float64), r

Dh = np.array([[1.0, 0.2, 0.0], [0.1, 1.0, 0.3]])
F = np.array([[1.0, 1.0, 0.5], [0.8, 1.2, 0.4], [1.1, 0.7, 0.6], [0.9, 0.9, 0.3]])
V = np.random.default_rng(0).standard_normal((5, 3))
for bd in (BDerivative(Dh, F), BDerivative(*both(Dh)[1:], *both(F)[1:])):
    for X in both(V):
        bd(X), bd.inverse(X), bd.event_times(X), bd.jvp(X, X), bd.vjp(X, X)
        bd.piece(np.array([1, 0]))
for scale in both([500.0, 1e-3]):
    for carried in both([0.0, 1e-9]):
        locate.state_error(1e-12, 1e-10, scale, carried)
for D in both(Dh):
    for rate in both([1.0, 1e-4]):
        locate.windows(D, rate, np.array([1e-9, 1e-11]), [1])
        locate.classify(np.array([0.0, -1e-12]), rate, np.full(2, 1e-9), [0], 1e-10)
    crossings.group_tolerance(D, SimpleNamespace(atol=1e-12, rtol=1e-10), 1.0)
# the stop rules the compiled run calls too, on its writeable scratch (_validate.scratch)
from bderiv.models.events import peaks, stopcalls
for D in both(Dh):
    for f in both(F[1]):
        stopcalls.local_rates(np.array([1.0, -1.0]), D, f)
        crossings._check_crossings([0], np.array([True, False]), D, f, 0, "before", 0.0,
                                   np.ones(2), 2)
system = SimpleNamespace(eval_field=lambda x, m: both(F[m])[1],
                         eval_field_jacobian=lambda x, m: both(np.eye(3) * (m + 1))[0])
crossings.holds(system, np.zeros(3), 1, 0)
for ends in both([0.0, 1.0, 3.0]):
    peaks.sample_times(ends)
for h in both([[-1.0, -0.5], [-0.2, 0.5], [-0.9, -0.1]]):
    for tol in both([1e-9, 1e-9]):
        peaks.peak_brackets(h, tol), excursions._return(h, tol)
for h in both([[1e-16, -1.0], [2e-16, -0.5], [3e-16, -0.2]]):
    excursions._start_dip(h, np.full(2, 1e-9), np.array([0.0, 0.5, 1.0]), lambda t, k: 1.0)
    sides.check_sides(h[0], 0b00, both([1e-9, 1e-9])[1], 0.5)
    crossings._clearly_positive(h[1], h[2])
# ... as the compiled run's own calls type them (writeable, C-contiguous; from njit code)
H = np.array([[1e-16, -1.0], [2e-16, -0.5], [3e-16, -0.2]])
rules.start_dip_steps(H), rules.wrong_side(H[0], 0, np.full(2, 1e-9))
rules.clearly_positive(H[1], H[2])
W, err = np.array(Dh), np.full(3, 1e-9)
rules.state_error(1e-12, 1e-10, np.array([500.0, 1e-3]), np.zeros(2), np.empty(2))
rules.windows(W, np.array([1.0, 1e-4]), err, np.array([False, True]), np.empty(2))
rules.classify(np.array([0.0, -1e-12]), np.ones(2), np.full(2, 1e-9), np.array([True, False]),
               1e-10, np.empty(2, dtype=np.int64))
rules.tolerances(W, err, np.empty(2))
rules.local_rates(np.array([1.0, -1.0]), W, np.array(F[1]), np.empty((2, 3)), np.empty(2))
rules.first_grazing(np.array([True, False]), W, np.array(F[1]))
rules.same_flow(np.array(F[0]), np.array(F[1]), np.eye(3), 2.0 * np.eye(3))
rules.sample_times(np.array([0.0, 1.0, 3.0]), np.empty(5))
rules.peak_rows(H, np.full(2, 1e-9), True, 3.0), rules.return_sample(H, np.full(2, 1e-9))
print("JSON" + json.dumps(tool.collect()))
"""


def _signatures():
    env = dict(os.environ, PYTHONPATH=str(ROOT / "src"))
    env.pop("BDERIV_SPECIALIZATIONS", None)
    out = subprocess.run([sys.executable, "-c", WORKLOAD, str(ROOT / "tools" /
                                                             "specializations.py")],
                         capture_output=True, text=True, env=env, timeout=600, check=True)
    return json.loads(out.stdout.split("JSON", 1)[1])


def test_writeable_and_read_only_inputs_compile_each_kernel_once():
    table = _signatures()
    # the parallel driver's launcher has a signature per type of tables and outputs
    more = {name: e["signatures"] for name, e in table.items()
            if e["cached"] and len(e["signatures"]) > 1 and not name.endswith(":_launch")}
    assert not more, more
    # the workload reached the kernels it is about
    names = {name for name, e in table.items() if e["signatures"]}
    for kernel in ("rules:state_error", "rules:windows", "rules:classify", "rules:tolerances",
                   "rules:start_dip_steps", "rules:wrong_side", "rules:clearly_positive",
                   "rules:local_rates", "rules:first_grazing", "rules:same_flow",
                   "rules:sample_times", "rules:peak_rows", "rules:return_sample",
                   "linear:piece_from_corners", "scaling:_scale_rows_serial"):
        assert any(name.endswith(kernel) for name in names), kernel


def test_the_tool_merges_the_tables_of_processes(tmp_path):
    import importlib.util

    spec = importlib.util.spec_from_file_location("spec_tool", ROOT / "tools" /
                                                  "specializations.py")
    tool = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(tool)
    a = {"m:f": {"signatures": ["(int64,)"], "instances": 1, "cached": True}}
    b = {"m:f": {"signatures": ["(float64,)", "(int64,)"], "instances": 2, "cached": True},
         "m:g": {"signatures": [], "instances": 1, "cached": False}}
    for name, t in (("gw0-1.json", a), ("gw1-2.json", b)):
        (tmp_path / name).write_text(json.dumps(t))
    merged = tool.merge(sorted(tmp_path.glob("*.json")))
    assert merged["m:f"] == {"signatures": ["(float64,)", "(int64,)"], "instances": 2,
                             "cached": True}
    assert "| `m:f` | yes | 2 | 2 |" in tool.render(merged)
    assert "2 dispatchers, 2 signatures" in tool.render(merged)


def _jitted_calls(tree):
    """The names of a module's njit functions that numba compiles as functions of their own
    (not ``inline="always"``): each literal argument would be another signature of them."""
    names = set()
    for node in tree.body:
        if not isinstance(node, ast.FunctionDef):
            continue
        for deco in node.decorator_list:
            call = deco if isinstance(deco, ast.Call) else None
            name = (call.func if call else deco)
            name = name.id if isinstance(name, ast.Name) else getattr(name, "attr", "")
            inline = call and any(k.arg == "inline" for k in call.keywords)
            if name in ("njit", "cached") and not inline:
                names.add(node.name)
    return names


def test_no_literal_constants_reach_a_chain():
    """A constant passed from njit code to an njit function that is not inlined is a
    literal type (``Literal[bool](False)``, ``Literal[int](0)``): numba compiles the callee,
    and what it calls with the value, once more than for the run-time value. The kernels
    pass ``np.bool_(False)``, ``np.int64(0)`` (checked on the sources: nothing compiles),
    except where a line says ``# literal: kept``: the plain dense chains forwards, whose
    copy with ``inverse`` folded away runs 4-6 % faster (benchmarks/ab.py, plain8 times)
    for about a second more of compiling."""
    package = ROOT / "src" / "bderiv"  # the kernels, and the robots' contact kernels
    files = [*(package / "_kernels").glob("*.py"), *(package / "robots").glob("_*.py")]
    modules = {p: ast.parse(p.read_text()) for p in files}
    jitted = set().union(*(_jitted_calls(tree) for tree in modules.values()))
    found = []
    for path, tree in modules.items():
        stem = path.stem
        lines = path.read_text().splitlines()
        for node in ast.walk(tree):
            if (isinstance(node, ast.Call) and isinstance(node.func, ast.Name)
                    and node.func.id in jitted):
                literal = [ast.unparse(a) for a in node.args if isinstance(a, ast.Constant)
                           and isinstance(a.value, (bool, int))]
                if literal and not lines[node.lineno - 1].endswith("# literal: kept"):
                    found.append(f"{stem}.py:{node.lineno} {node.func.id}({', '.join(literal)})")
    assert not found, found
