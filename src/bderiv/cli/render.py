"""Rendering of the commands' results: text for people, JSON for programs, progress bars.

Every function takes the data a command returned (dicts and lists, as in its JSON output)
and returns text; nothing here computes or prints.
"""

from __future__ import annotations

import importlib.util
import json
import sys

import numpy as np

from .._bench import format_table
from .._format import format_mask, format_order


def to_json(data, indent=None) -> str:
    """The JSON document of a command's result."""
    return json.dumps(data, indent=indent)


def progress_bar(desc: str):
    """A ``progress(done, total)`` tqdm bar on stderr (terminals only); None without tqdm."""
    if importlib.util.find_spec("tqdm") is None:
        return None  # the bar is a nicety in the CLI; without tqdm run silently
    from .._progress import TqdmCallback

    return TqdmCallback(desc, leave=False, disable=None, file=sys.stderr)


# -- demo -------------------------------------------------------------------------------------


def demo_section(section: str, res: dict) -> str:
    """The text of one section of :func:`bderiv.cli.demo.run_demo`'s results, as reported.

    Examples
    --------
    >>> print(demo_section("total", {"total_seconds": 2.0}), end="")
    total 2.0 s
    """
    return _DEMO_SECTIONS[section](res)


def _model(res):
    return f"bderiv demo: {res['name']}\n  {res['description']}\n"


def _trajectory(res):
    groups, n = res["groups"], res["n_events"]
    lines = [f"trajectory from x0 to t_final = {res['t_final']:g}: {len(groups)} event group(s)"]
    for i, g in enumerate(groups):
        kind = "simultaneous" if len(g["events"]) > 1 else "single"
        lines.append(
            f"  group {i}: t = {g['time']:.6f}, events {tuple(g['events'])} {kind}, mask "
            f"{format_mask(g['mask_before'], n)} -> {format_mask(g['mask_after'], n)}"
        )
    lines.append(
        f"B-derivative of x -> Phi({res['t_final']:g}, x) at x0: D = L_m M_m ... L_1 M_1 L_0 "
        f"(L: variational equations of the smooth stretches, M: one BDerivative per "
        f"group), built in {res['build_seconds']:.2f} s"
    )
    return "\n".join(lines) + "\n"


def _pieces(res):
    b = res["batch"]
    lines = [f"pieces: {res['n_pieces']:,} in all (one event order per group), "
             f"{res['n_pieces_visited']:,} met by {res['pieces_sample']:,} random tangent "
             f"vectors; the most visited:"]
    labels = [" ".join(f"g{i}={format_order(o)}" for i, o in enumerate(p["orders"])) or "-"
              for p in res["pieces"]]
    width = max(map(len, labels), default=1)
    for label, p in zip(labels, res["pieces"], strict=True):
        lines.append(f"  order {label:<{width}}  share {100 * p['share']:6.3g} %   det = "
                     f"{p['det']:<10.6g} |D|_2 = {p['norm']:.6g}")
    lines.append(
        f"batch: {b['size']:,} tangent vectors in {b['seconds']:.3f} s = "
        f"{b['ns_per_vector']:.0f} ns per vector (first call, compiling or loading the cached "
        f"kernels: {b['first_call_seconds']:.2f} s); |D V| max = {b['max_abs_output']:.4g}"
    )
    return "\n".join(lines) + "\n"


def _check(res):
    c = res["check"]
    lines = [f"check against finite differences of the simulation ({c['vectors']} unit "
             f"vectors, {c['pieces_covered']} distinct pieces): max |FD - D V| / max |D V|"]
    for e, err in zip(c["eps"], c["max_rel_error"], strict=True):
        lines.append(f"  eps = {e:.0e}: {err:.3e}")
    if c["error_ratios"]:
        lines.append("  error shrinks with eps by "
                     + ", ".join(f"{r:.1f}x" for r in c["error_ratios"])
                     + " per step (O(eps) expected)")
    per_batch = c["bd_seconds_per_vector_batch"]
    lines.append(f"  one simulation per vector: {c['fd_seconds_per_vector'] * 1e3:.1f} ms; "
                 f"B-derivative: {per_batch * 1e9:.0f} ns per vector in the batch "
                 f"({c['speedup']:,.0f}x faster; {c['bd_seconds_per_vector'] * 1e6:.1f} us per "
                 f"vector in a call of {c['vectors']})")
    return "\n".join(lines) + "\n"


def _corner_table(res):
    lines = [f"bderiv demo: {res['name']}, Dh = event Jacobian, F = corner table",
             "vector u -> event order, event times, M(u):"]
    for row in res["vectors"]:
        u, times, w = (np.array(row[key]) for key in ("u", "times", "Mu"))
        lines.append(f"  u={u}  order={format_order(row['order'])}  "
                     f"times={np.round(times[row['order']], 4)}  M(u)={w}")
    lines.append(f"pieces: {res['n_pieces']}")
    for p in res["pieces"]:
        lines.append(f"  order {format_order(p['orders'][0]):<10} det = {p['det']:<8.4g} "
                     f"|M|_2 = {p['norm']:.4g}")
    lines.append(f"inverse round trip max |M^-1(M(u)) - u| = "
                 f"{res['check']['inverse_round_trip']:.2e}")
    b = res["batch"]
    lines.append(f"batch: {b['size']:,} vectors in {b['seconds']:.3f} s = "
                 f"{b['ns_per_vector']:.0f} ns per vector (first call: "
                 f"{b['first_call_seconds']:.2f} s)")
    return "\n".join(lines) + "\n"


def _total(res):
    return f"total {res['total_seconds']:.1f} s\n"


_DEMO_SECTIONS = {"model": _model, "trajectory": _trajectory, "pieces": _pieces,
                  "check": _check, "corner_table": _corner_table, "total": _total}


# -- bench, plot, export ----------------------------------------------------------------------


def bench_text(rows, *, d_factor: int, batch: int, repeat: int, plot=None) -> str:
    """The text of ``bderiv bench``: a header, the sweep table, what its columns mean."""
    lines = [f"bderiv bench: d = {d_factor} n, batch m = {batch:,}, best of {repeat}; ns/q = "
             f"nanoseconds per query (tangent vector)",
             format_table(rows),
             "speed-up = numpy / bderiv; % of BLAS = useful work rate (n^2 + 2 n d flops per "
             "query) over a matrix product of the same flop count"]
    if plot:
        lines.append(f"plot written to {plot}")
    return "\n".join(lines) + "\n"


def figures_text(summary: dict) -> str:
    """The text of ``bderiv plot``: the files written (and why 2-D figures are missing)."""
    lines = [f"bderiv plot: {summary['example']} (n = {summary['n_events']}, d = "
             f"{summary['dim']})"]
    lines += [f"  wrote {path}" for path in summary["files"]]
    if summary["dim"] != 2:
        lines.append("  (field, triangulation and circle need a 2-D system: --example planar "
                     "or --example network --n 2)")
    return "\n".join(lines) + "\n"


def export_text(summary: dict) -> str:
    """The text of ``bderiv export``: the triangulation, its layout and each file written."""
    lines = [f"bderiv export: {summary['example']}: triangulation of {summary['n_events']} "
             f"events in R^{summary['dim']}, {summary['vertices']} vertices, "
             f"{summary['simplices']} simplices",
             "  pre-event vertices (n_vertices, d), post-event images, simplices "
             "(n_simplices, n + 1; column 0 the apex), kernel basis of Dh"]
    for f in summary["files"]:
        lines.append(f"  wrote {f['path']} ({f['bytes']:,} bytes); reloaded with "
                     f"bderiv.load_triangulation: max |tri(V) - bd(V)| = "
                     f"{f['max_error_reloaded']:.2e} on {summary['check_vectors']} vectors")
    return "\n".join(lines) + "\n"
