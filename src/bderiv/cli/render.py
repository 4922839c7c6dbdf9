"""Rendering of the commands' results: text for people, JSON for programs, progress bars.

Every function takes the data a command returned (dicts and lists, as in its JSON output)
and returns text; nothing here computes or prints.
"""

from __future__ import annotations

import importlib.util
import json
import math
import sys

import numpy as np

from .._support._format import format_mask, format_order, format_steps
from .machine import describe


def to_json(data, indent=None) -> str:
    """The JSON document of a command's result: standard JSON, which has no Infinity or
    NaN, so a number that is not finite is written ``null`` (the demo's error ratios where
    a step's error is exactly 0, an estimate that found no number)."""
    return json.dumps(_finite(data), indent=indent, allow_nan=False)


def _finite(data):
    """``data`` with every float that is not finite replaced by None, in its dicts,
    lists and tuples (a copy where one changes)."""
    if isinstance(data, float):  # np.float64 too
        return data if math.isfinite(data) else None
    if isinstance(data, dict):
        return {k: _finite(v) for k, v in data.items()}
    if isinstance(data, list | tuple):
        return [_finite(v) for v in data]
    return data


def progress_bar(desc: str, unit: str = "vec"):
    """A ``progress(done, total)`` tqdm bar on stderr (terminals only) counting ``unit``;
    None without tqdm."""
    if importlib.util.find_spec("tqdm") is None:
        return None  # the bar is a nicety in the CLI; without tqdm run silently
    from .._support._progress import TqdmCallback

    return TqdmCallback(desc, unit=unit, leave=False, disable=None, file=sys.stderr)


# -- demo -------------------------------------------------------------------------------------


def demo_section(section: str, res: dict) -> str:
    """The text of one section of :func:`bderiv.cli.demo.run_demo`'s results, as reported.

    Examples
    --------
    >>> print(demo_section("total", {"total_seconds": 2.0}), end="")
    total 2 s
    """
    return _DEMO_SECTIONS[section](res)


def numbers(values, digits: int = 6) -> str:
    """``[a, b, ...]`` with ``digits`` significant digits, one format for every vector.

    Examples
    --------
    >>> numbers([-2.9, 1 / 3, 0.0, -0.0, -1e-9])
    '[-2.9, 0.333333, 0, 0, -1e-09]'
    """
    # + 0.0 turns -0.0 into 0.0 (a printed "-0" reads as a small negative number)
    return "[" + ", ".join(f"{float(v) + 0.0:.{digits}g}" for v in values) + "]"


def _matrix(name, rows, indent="    ") -> list:
    """``name`` then one line per row of a matrix."""
    return [f"{indent[:-2]}{name}:", *(indent + numbers(r) for r in rows)]


def _model(res):  # the line "bderiv demo: <example>" came first, before the imports
    return f"  {res['description']}\n"


#: where a compiled model's check simulations ran (the speed-up's reference), as its line
#: says it
_SIMULATIONS_ON = {
    "python": " (its Python code on scipy: the functions not compiled yet)",
    "scipy": " (on scipy: the compiled integrator not ready yet)",
    "compiled": "",
    "python-scipy": " (on scipy, first on its Python code, then compiled: the integrator "
                    "not ready yet)",
    "python-compiled": " (first its Python code on scipy, then the compiled integrator, "
                       "ready meanwhile: a mean of both)",
    "scipy-compiled": " (first on scipy, then the compiled integrator, ready meanwhile: a "
                      "mean of both)"}


def _integrator(res):
    """Which integrator the simulations ran on (a compiled model's, or scipy)."""
    if not res.get("compiled"):
        return ""
    if res.get("integrator") == "python":
        return ("  its field, events and Jacobians are numba functions, not compiled on this "
                "machine yet: its runs go on their Python code (the code numba compiles) on "
                "scipy's solve_ivp until that has taken a second, then they are compiled, "
                "and run on the compiled integrator once it is ready (on a fresh machine it "
                "compiles in a background process; BDERIV_INTEGRATOR=compiled compiles both "
                "at once)\n")
    if res.get("integrator") == "scipy":
        return ("  its field, events and Jacobians are numba-compiled functions; the compiled "
                "integrator is not ready on this machine (being compiled in a background "
                "process, once per machine; or withheld: BDERIV_INTEGRATOR=scipy): the "
                "simulations run on scipy's solve_ivp until it is (the same method and "
                "stops, slower per run)\n")
    return ("  its field, events and Jacobians are numba-compiled functions: every "
            "simulation runs on the compiled integrator (--python: the same equations "
            "as Python functions on scipy's solve_ivp)\n")


def _trajectory(res):
    groups, n, tf = res["groups"], res["n_events"], res["t_final"]
    lines = [*_integrator(res).splitlines(),
             f"trajectory from x0 over [0, {tf:g}]: {len(groups)} event group(s)"]
    for i, g in enumerate(groups):
        kind = "simultaneous" if len(g["events"]) > 1 else "single"
        lines.append(
            f"  group {i}: t = {g['time']:.6f}, events {tuple(g['events'])} {kind}, mask "
            f"{format_mask(g['mask_before'], n)} -> {format_mask(g['mask_after'], n)}"
        )
        if "Dh" in g:
            lines += _matrix(f"Dh of group {i} (event Jacobian, one row per event)", g["Dh"])
            if g["F"] is None:
                lines.append(f"    (corner table of group {i}: too large to print)")
            else:
                lines += _matrix(f"F of group {i} (corner table, row = mask)", g["F"])
    lines += [
        "two maps: M = the B-derivative at the event point of a group (a BDerivative)",
        f"          D = the B-derivative of the flow x -> Phi({tf:g}, x) at x0 (a "
        f"FlowBDerivative, built in {seconds(res['build_seconds'])})",
        "            = L_m M_m ... L_1 M_1 L_0, L: variational equations of the smooth "
        "stretches",
    ]
    for i, L in enumerate(res.get("linear", ())):
        lines += _matrix(f"L_{i} (linear stage {i})", L)
    return "\n".join(lines) + "\n"


def _pieces(res):
    p = res["pieces"]
    lines = [f"pieces of D (the flow map): {p['count']:,} in all (one event order per group); "
             f"{p['sample']:,} random tangent vectors met {p['distinct']:,} of them"]
    shown = p["most_visited"]
    labels = [" ".join(f"g{i}={format_order(o)}" for i, o in enumerate(e["orders"])) or "-"
              for e in shown]
    width = max(map(len, labels), default=1)
    if shown:
        lines.append("  the most visited (det M: the group's piece at its event point):")
    for label, e in zip(labels, shown, strict=True):
        event = ", ".join(f"{d:.6g}" for d in e["event_dets"]) or "-"
        lines.append(f"  order {label:<{width}}  share {100 * e['share']:6.3g} %   det D = "
                     f"{e['det']:<10.6g} |D|_2 = {e['norm']:<9.6g} det M = {event}")
        if "matrix" in e:
            lines += _matrix("D's piece", e["matrix"], "      ")
            for i, M in enumerate(e["event_matrices"]):
                lines += _matrix(f"M's piece, group {i}", M, "      ")
    if not shown:
        lines.append("  (no piece holds 1 % of the vectors: each is met about once, so the "
                     "ranges say more)")
    r = p["ranges"]
    if p["distinct"] > len(shown):
        lines.append(
            f"  over the {r['pieces']:,} pieces met by the first {r['vectors']:,} vectors: "
            f"det D {r['det'][0]:.4g} .. {r['det'][1]:.4g}, |D|_2 {r['norm'][0]:.4g} .. "
            f"{r['norm'][1]:.4g}, det M {r['event_det'][0]:.4g} .. {r['event_det'][1]:.4g}"
        )
    for spread in p["time_spread"]:
        q = spread["values"]
        lines.append(
            f"  group {spread['group']}: spread of the event times t_last - t_first per "
            f"vector: {q[0]:.3g} (5 %), {q[1]:.3g} (median), {q[2]:.3g} (95 %)"
        )
    return "\n".join(lines) + "\n"


def seconds(value: float) -> str:
    """A duration with three significant digits in s, ms or us.

    >>> seconds(21.63), seconds(0.000123), seconds(0.0456)
    ('21.6 s', '123 us', '45.6 ms')
    """
    for unit, scale in (("s", 1.0), ("ms", 1e-3)):
        if value >= scale:
            return f"{value / scale:.3g} {unit}"
    return f"{value * 1e6:.3g} us"


def _batch(res, what="D"):
    b = res["batch"]
    runs = b["runs_seconds"]
    return (
        f"batch: {what} applied to {b['size']:,} tangent vectors: {b['ns_per_vector']:.0f} ns "
        f"per vector (best of {len(runs)} runs of {seconds(min(runs))} .. "
        f"{seconds(max(runs))}, after an untimed first call); "
        f"|{what} V| max = {b['max_abs_output']:.4g}\n"
        f"  measured on {describe(b['machine'])}\n"
    )


def _check(res):
    c = res["check"]
    k, pieces = c["vectors"], c["pieces_covered"]
    lines = [f"check of D against finite differences of the simulation ({k} unit "
             f"vector{'s' * (k != 1)}, {pieces} distinct piece{'s' * (pieces != 1)}): "
             f"max |FD - D V| / max |D V|"]
    lines += format_steps(c["eps"], c["max_rel_error"])
    if c["error_ratios"]:
        lines.append("  error shrinks with eps by "
                     + ", ".join("- (to 0)" if r is None else f"{r:.1f}x"
                                 for r in c["error_ratios"])
                     + " per step (O(eps) expected)")
    on = _SIMULATIONS_ON.get(c.get("simulations_on"), "") if res.get("compiled") else ""
    lines.append(f"  one simulation per vector{on}: {c['fd_seconds_per_vector'] * 1e3:.1f} ms; "
                 f"D: {res['batch']['ns_per_vector']:.0f} ns per vector in the batch "
                 f"({c['speedup']:,.0f}x faster; {c['map_seconds_per_vector'] * 1e6:.1f} us per "
                 f"vector in a call of {c['vectors']})")
    return "\n".join(lines) + "\n"


def _corner_table(res):
    n = res["n_events"]
    lines = [f"bderiv demo: {res['example']}, {res['description']}",
             "  M = the B-derivative at the event point, BDerivative(Dh, F)",
             *_matrix("Dh (event Jacobian, one row per event)", res["Dh"]),
             "  F (corner table; row mask = the field once the events of the mask happened):",
             *(f"    {format_mask(m, n)}  {numbers(row)}" for m, row in enumerate(res["F"])),
             "vector u -> event order, event times (in that order), M(u):"]
    for row in res["vectors"]:
        times = np.array(row["times"])[row["order"]]
        lines.append(f"  u = {numbers(row['u'])}  order {format_order(row['order'])}  "
                     f"times {numbers(times)}  M(u) = {numbers(row['Mu'])}")
    lines.append(f"pieces of M: {len(res['pieces'])}")
    for p in res["pieces"]:
        lines.append(f"  order {format_order(p['order']):<10} det M = {p['det']:<8.6g} "
                     f"|M|_2 = {p['norm']:.6g}")
        if "matrix" in p:
            lines += _matrix("M's piece", p["matrix"], "      ")
    lines.append(f"inverse round trip max |M^-1(M(u)) - u| = "
                 f"{res['check']['inverse_round_trip']:.2e}")
    return "\n".join(lines) + "\n" + _batch(res, "M")


def _total(res):
    """The total and where it went; compilation (the kernels compiled, or loaded from
    numba's on-disk cache: the first run on a machine) said once, apart."""
    phases = res.get("phases", {})
    compiling = sum(p["compiling_seconds"] for p in phases.values())
    parts = [f"{name} {seconds(p['seconds'] - p['compiling_seconds'])}"
             for name, p in phases.items()]
    text = f"total {seconds(res['total_seconds'])}"
    if parts:
        text += ": " + ", ".join(parts)
    if compiling >= 0.05:
        text += (f"; and compiling or loading the cached kernels {seconds(compiling)} "
                 f"(once: numba keeps them on disk)")
    return text + "\n"


_DEMO_SECTIONS = {"model": _model, "trajectory": _trajectory, "pieces": _pieces,
                  "batch": _batch, "check": _check, "corner_table": _corner_table,
                  "total": _total}


# -- bench, plot, export ----------------------------------------------------------------------


def bench_text(result: dict) -> str:
    """The text of ``bderiv bench``: a header, the sweep table, what its columns mean, the
    machine it ran on, and the plot written."""
    from .sweep import format_table  # the sweep's module: loaded by `bench` only

    k = result["d_factor"]
    dim = "d = n" if k == 1 else f"d = {k}n"
    lines = [f"bderiv bench: {dim}, batch m = {result['batch']:,}, best of "
             f"{result['repeat']}; ns/q = nanoseconds per query (tangent vector)",
             format_table(result["rows"]),
             "speed-up = numpy / bderiv; % of BLAS = useful work rate (n^2 + 2 n d flops per "
             "query) over a matrix product of the same flop count",
             *_without_numpy(result["rows"]),
             f"measured on {describe(result['machine'])}"]
    if any(r["method"] == "bderiv" and r["gflops"] > _blas_gflops(result["rows"], r)
           for r in result["rows"]):
        lines.append("note: above 100 % of BLAS, the yardstick product ran slower than the "
                     "kernels could: other work on the cores in this run (compare on a quiet "
                     "machine)")
    if "plot" in result:
        plot = result["plot"]
        lines += _made(plot["created"])
        lines.append(f"plot written to {plot['path']}{_replaced(plot['replaced'])}")
    return "\n".join(lines) + "\n"


def _without_numpy(rows) -> list:
    """The note on the sizes whose NumPy baseline was not timed (none when all were)."""
    from .sweep import NUMPY_MAX_N

    ns = [r["n"] for r in rows if r["method"] == "bderiv" and "speedup" not in r]
    if not ns:
        return []
    return [f"numpy ns/q and speed-up '-' at n = {', '.join(map(str, ns))}: the NumPy "
            f"baseline is timed up to n = {NUMPY_MAX_N} only"]


def _blas_gflops(rows, row) -> float:
    """The BLAS yardstick's rate of the sweep row of ``row``'s size (inf without one)."""
    return next((r["gflops"] for r in rows if r["method"] == "blas" and
                 (r["n"], r["d"], r["m"]) == (row["n"], row["d"], row["m"])), float("inf"))


def _made(directory, indent="") -> list:
    """The line saying that an output directory was made (none when it existed)."""
    return [f"{indent}made the directory {directory}"] if directory else []


def _replaced(replaced: bool) -> str:
    return " (replacing the file there)" if replaced else ""


def figures_text(summary: dict) -> str:
    """The text of ``bderiv plot``: the files written, and the figures left out and why."""
    lines = [f"bderiv plot: {summary['example']} (n = {summary['n_events']}, d = "
             f"{summary['dim']})"]
    lines += _made(summary["created"], "  ")
    lines += [f"  wrote {path}{_replaced(path in summary['replaced'])}"
              for path in summary["files"]]
    for name, why in summary["skipped"].items():
        hint = {"scaling": "", "orbit": " (try --example pronking)",
                "growth": " (try --example pronking)"}.get(name, " (try --example planar)")
        lines.append(f"  not drawn: {name}, which {why}{hint}")
    return "\n".join(lines) + "\n"


def export_text(summary: dict) -> str:
    """The text of ``bderiv export``: the map, its triangulation, each file written."""
    lines = [f"bderiv export: {summary['example']}: {summary['map_description']}",
             f"  triangulation of {summary['n_events']} events in R^{summary['dim']}: "
             f"{summary['vertices']} vertices, {summary['simplices']} simplices",
             "  pre-event vertices (n_vertices, d), post-event images, simplices "
             "(n_simplices, n + 1; column 0 the apex), kernel basis and its images"]
    what = "D" if summary["map"] == "flow" else "M"
    lines += _made(summary["created"], "  ")
    for f in summary["files"]:
        lines.append(f"  wrote {f['path']} ({f['bytes']:,} bytes){_replaced(f['replaced'])}; "
                     f"reloaded with "
                     f"bderiv.load_triangulation: max |tri(V) - {what}(V)| = "
                     f"{f['max_error_reloaded']:.2e} on {summary['check_vectors']} vectors")
    return "\n".join(lines) + "\n"
