"""The layout of every benchmark table the docs show, defined once: the columns of each
table (header, the row key it shows, how the value is written, alignment).

A benchmark records rows (dicts keyed by these keys) with ``_record.record``;
``tools/render_benchmarks.py`` writes them into the docs with these layouts. Plain Python
(no NumPy, no bderiv), so the renderer and its test load it in milliseconds.

A column's ``fmt`` is a format string applied to ``value * scale``, or a function of
``(value, row)``; a value that is a string is written as it is, ``None`` as ``-``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass


@dataclass(frozen=True)
class Column:
    head: str
    key: str
    fmt: str | Callable = "{}"
    align: str = "r"  # "r" ---:, "l" ---, "c" :---:
    scale: float = 1.0

    def cell(self, row: dict) -> str:
        value = row.get(self.key)
        if value is None:
            return "-"
        if isinstance(value, str):
            return value
        if callable(self.fmt):
            return self.fmt(value, row)
        return self.fmt.format(value * self.scale if self.scale != 1.0 else value)


ALIGN = {"r": "---:", "l": "---", "c": ":---:"}


def markdown_table(columns: list[Column], rows: list[dict]) -> list[str]:
    """The lines of the Markdown table of ``rows`` in the layout ``columns``."""
    lines = ["| " + " | ".join(c.head for c in columns) + " |",
             "|" + "|".join(ALIGN[c.align] for c in columns) + "|"]
    return lines + ["| " + " | ".join(c.cell(row) for c in columns) + " |" for row in rows]


def time_unit(seconds: float, row=None) -> str:
    """3 significant digits in s, ms, us or ns (``tools/bench_table.py``'s cells)."""
    for unit, scale in (("s", 1.0), ("ms", 1e-3), ("us", 1e-6), ("ns", 1e-9)):
        if seconds >= scale or unit == "ns":
            return f"{seconds / scale:.3g} {unit}"
    raise AssertionError("unreachable")


def short_e(fmt: str) -> Callable:
    """``fmt`` with ``e+0N`` written ``eN`` (1e+03 -> 1e3)."""
    return lambda value, row=None: fmt.format(value).replace("e+0", "e")


def measured(value: float, row: dict) -> str:
    """A target's measured value in the unit the row names (x, %, s)."""
    return {"x": "{:.3g}x", "%": "{:.2g}%", "s": "{:.3g} s"}[row["unit"]].format(value)


def in_unit(value: float, row: dict) -> str:
    """Seconds (:func:`time_unit`) or a ratio, as the row's ``unit`` ("s" or "x") says."""
    return time_unit(value) if row["unit"] == "s" else f"{value:.3g}x"


def seconds_case(value, row: dict) -> str:
    """A cold-start case: its seconds (several joined by " / "), the import's (and how
    much of it numba compiled), the second call's."""
    out = " / ".join(f"{v:.3g}" for v in (value if isinstance(value, list) else [value]))
    if row.get("import") is not None:
        out += f" (+{row['import']:.1f} import"
        if row.get("import_compile"):  # numba compiling kernels at their definition
            out += f", {row['import_compile']:.1f} of it compiling"
        out += ")"
    if row.get("second") is not None:
        out += f"; the second {row['second']:#.2g}"
    return out


def iterations(key: str) -> Callable:
    """Iterations, marked when the run did not converge (``row[key]`` false)."""
    return lambda value, row: f"{value}{'' if row[key] else ' (not converged)'}"


def point(value, row=None) -> str:
    return "(" + ", ".join(f"{v:.5f}" for v in value) + ")"


def switches(value, row=None) -> str:
    """The order switches of an iLQR run, [[iteration, step, old order, new order], ...]."""
    if not value:
        return "-"
    return f"{len(value)} (" + "; ".join(
        f"iteration {i}, step {k}: {tuple(a)} -> {tuple(b)}" for i, k, a, b in value) + ")"


def C(head, key, fmt="{}", align="r", scale=1.0) -> Column:  # noqa: N802 (a table row)
    return Column(head, key, fmt, align, scale)


N, D = C("n", "n"), C("d", "d")
M = C("m", "m", short_e("{:.0e}"))
K, P = C("k", "k"), C("p", "p")
RATIO = short_e("{:.3g}x")

LAYOUTS: dict[str, dict[str, list[Column]]] = {
    # benchmarks/test_bench_dense.py, through tools/bench_table.py
    "dense": {
        "eval": [N, D, M, C("bderiv apply", "apply", time_unit),
                 C("bderiv inverse", "inverse", time_unit),
                 C("batched NumPy", "numpy", time_unit),
                 C("per-query ref*", "ref", time_unit),
                 C("vs NumPy", "vs_numpy", RATIO), C("vs ref", "vs_ref", RATIO),
                 C("useful GFLOP/s", "gflops", "{:.3g}"), C("% of BLAS", "blas_pct", "{:.2g}%"),
                 C("copy", "copy", time_unit), C("apply / copy", "apply_copy", RATIO)],
        "build": [N, D, C("tables", "mib", "{:.3g} MiB"), C("build time", "seconds", time_unit)],
        "threads": [N, D, M, C("1 thread", "t1", time_unit), C("2 threads", "t2", time_unit),
                    C("speed-up", "speedup", RATIO)],
        "targets": [C("target", "target", align="l"), C("measured", "value", measured),
                    C("met", "met", align="c")],
    },
    # benchmarks/copy_ratio.py
    "copy_ratio": {"main": [
        C("n = d", "n"), C("copy", "copy", "{:.2f} ns", scale=1e9),
        C("apply", "apply", "{:.1f} ns", scale=1e9),
        C("inverse", "inverse", "{:.1f} ns", scale=1e9),
        C("apply / copy", "apply_copy", "{:.1f}x"), C("target", "target", "{:g}x")]},
    # benchmarks/test_bench_corners.py
    "corners": {"main": [
        N, C("µs/query (wall)", "wall", "{:.2f}", scale=1e6),
        C("queries/s", "rate", short_e("{:.3g}")),
        C("CPU µs/query", "cpu", "{:.2f}", scale=1e6)]},
    # benchmarks/compiled_path.py
    "compiled_path": {"main": [
        K, P, D, C("simulate compiled", "sim_c", "{:.2f}", scale=1e3),
        C("Python", "sim_py", "{:.1f}", scale=1e3), C("ratio", "sim_ratio", "{:.0f}x"),
        C("build compiled", "build_c", "{:#.3g}", scale=1e3),
        C("Python", "build_py", "{:.0f}", scale=1e3), C("ratio", "build_ratio", "{:.0f}x"),
        C("FD of Python (2d runs)", "fd_py", "{:.0f}", scale=1e3),
        C("FD / build", "fd_ratio", "{:.0f}x")]},
    # benchmarks/gait_orbits.py
    "gait_orbits": {"main": [
        K, P, D, C("orbit compiled", "orbit_c", "{:.3f}"), C("verdict", "verdict_c", "{:.3f}"),
        C("total", "total_c", "{:.3f}"), C("orbit Python", "orbit_py", "{:.2f}"),
        C("verdict", "verdict_py", "{:.2f}"), C("total", "total_py", "{:.2f}"),
        C("ratio", "ratio", "{:.0f}x"), C("Newton steps", "newton"),
        C("growth rate", "growth", "{:.5f}")]},
    # benchmarks/test_bench_flow.py
    "flow": {"main": [
        C("example", "example", align="l"), N, D, C("orders seen", "orders_seen"),
        C("FD err eps=1e-3", "fd_1e-3", "{:.2e}"), C("1e-4", "fd_1e-4", "{:.2e}"),
        C("1e-5", "fd_1e-5", "{:.2e}"), C("build", "build", "{:.0f} ms", scale=1e3),
        C("B-deriv per vector (batch of 1000)", "batch", "{:.2f} µs", scale=1e6),
        C("(single call)", "single", "{:.1f} µs", scale=1e6),
        C("flow_fd per vector", "flow_fd", "{:.1f} ms", scale=1e3),
        C("speed-up (batch)", "speedup", short_e("{:.1e}x"))]},
    # benchmarks/cold_start.py --demo
    "cold_start": {"main": [C("case", "case", align="l"),
                            C("seconds", "seconds", seconds_case, align="l")]},
    # benchmarks/shooting.py (one table per ball)
    "shooting": {ball: [
        C("ball", "ball", align="l"), C("guess", "guess", "{:g}", align="l"),
        C("hybrid-tools: iterations", "theirs_iterations", iterations("theirs_converged")),
        C("optimum", "theirs_optimum", point, align="l"), C("s", "theirs_s", "{:.2f}"),
        C("bderiv: iterations", "ours_iterations", iterations("ours_converged")),
        C("optimum", "ours_optimum", point, align="l"), C("s", "ours_s", "{:.2f}"),
        C("same optimum", "same", align="c")] for ball in ("2-D", "1-D")},
    # benchmarks/ilqr.py
    "ilqr": {"main": [
        C("linearisation", "linearisation", align="l"),
        C("iterations to 1e-14 of the first cost", "iterations"),
        C("switches", "switches", switches),
        C("time per iteration", "seconds", "{:.0f} ms", scale=1e3),
        C("cost at iterations 0 .. 6", "costs",
          lambda v, row: " ".join(f"{c:.1e}" for c in v[:7]), align="l")]},
    # benchmarks/kalman_consistency.py
    "kalman_consistency": {"main": [
        C("filter (1,000 runs, d = 6)", "filter", align="l"),
        C("mean NEES", "mean_nees", "{:.3f}", align="l"),
        C("95 % band", "band", lambda v, row: f"[{v[0]:.3f}, {v[1]:.3f}]", align="l"),
        C("verdict", "verdict", align="l")]},
    # benchmarks/robots.py (Solo12's touchdown; robots_rigid.json with --rigid)
    "robots": {
        "main": [C("", "what", align="l"), C("wall", "wall", in_unit),
                 C("CPU", "cpu", in_unit)],
        "where": [C("run", "run", align="l"), C("part", "part", align="l"),
                  C("calls", "calls"), C("CPU per call", "per_call", time_unit),
                  C("of which Pinocchio's routines", "pinocchio", time_unit),
                  C("CPU in the run", "seconds", time_unit),
                  C("share", "share", "{:.0f} %", scale=100)]},
    # benchmarks/jax_overhead.py
    "jax_overhead": {"main": [
        C("case", "case", align="l"), C("JAX route", "jax", time_unit),
        C("bderiv's own calls", "numpy", time_unit)]},
}
