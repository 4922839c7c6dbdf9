"""The figure of a benchmark sweep: time per query against the number of events."""

from __future__ import annotations

import math
import numbers
import textwrap
from collections.abc import Mapping, Sequence

from ._axes import PALETTE, figure_axes

#: legend label, line style and colour of the methods of ``bderiv bench`` and of the
#: contenders of ``benchmarks/test_bench_dense.py`` in :func:`scaling`
_METHODS = {
    "bderiv": ("bderiv", "-", PALETTE[0]),
    "bderiv apply": ("bderiv apply", "-", PALETTE[0]),
    "bderiv inverse": ("bderiv inverse", "--", PALETTE[1]),
    "numpy": ("batched NumPy baseline", "-", PALETTE[2]),
    "numpy batched": ("batched NumPy baseline", "-", PALETTE[2]),
    "reference per-query": ("per-query NumPy oracle\n(Python loop, on a subset)", "-",
                            PALETTE[3]),
    "blas": ("BLAS matrix product, same flops", ":", PALETTE[4]),
    "BLAS matmul": ("BLAS matrix product, same flops", ":", PALETTE[4]),
    "parallel copy": ("parallel copy of the queries\n(the memory-bandwidth limit)", ":",
                      PALETTE[5]),
}


def scaling(rows, ax=None, *, batch=None, machine=None):
    """Time per query against the number of events n, log-log (a benchmark sweep).

    One line per method; at each n the row of the largest batch measured (or of
    ``batch``). Used for the rows of ``bderiv bench --json`` and, through
    ``tools/bench_table.py --plot``, for the pytest-benchmark suite.

    Parameters
    ----------
    rows : sequence of dict
        Each with keys ``n``, ``method`` and ``seconds_per_query``, optionally ``d`` and
        ``m`` (the batch size), as produced by ``bderiv bench --json``. One dimension d per
        n: the figure states the relation of d to n.
    ax : matplotlib Axes, optional
    batch : int, optional
        Keep only rows with this batch size ``m``.
    machine : str, optional
        Where the rows were measured (CPU, threads, BLAS), shown in small print under the
        axes (without the environment variables it names as unset).

    Returns
    -------
    matplotlib.figure.Figure

    Raises
    ------
    TypeError
        If ``rows`` is not a sequence of dicts.
    ValueError
        If a row lacks a key or has a value of the wrong kind (:data:`ROW_KEYS`), rows of
        one n have different dimensions d, or no row is left.

    Examples
    --------
    >>> from bderiv import plot
    >>> rows = [{"n": n, "d": n, "m": 1000, "method": "bderiv",
    ...          "seconds_per_query": 1e-8 * n * n} for n in (2, 4, 8)]
    >>> print(plot.scaling(rows).axes[0].get_title())
    B-derivative at the event point: time per tangent vector
    d = n, batch m = 1,000
    """
    check_rows(rows)
    kept = [r for r in rows if batch is None or r.get("m") == batch]
    if not kept:
        where = "" if batch is None else f" with batch m = {batch}"
        raise ValueError(f"no benchmark rows to plot{where}")
    points = {}  # (method, n) -> the row of the largest batch
    for r in kept:
        key = (r["method"], r["n"])
        if key not in points or r.get("m", 0) > points[key].get("m", 0):
            points[key] = r
    fig, (ax,) = figure_axes(ax, figsize=(8.0, 4.8))
    for i, method in enumerate(dict.fromkeys(r["method"] for r in kept)):
        sel = sorted((r for (meth, _), r in points.items() if meth == method),
                     key=lambda r: r["n"])
        label, style, color = _METHODS.get(method, (method, "-", PALETTE[i % len(PALETTE)]))
        ax.loglog([r["n"] for r in sel], [r["seconds_per_query"] * 1e9 for r in sel],
                  marker="osD^v<>"[i % 7], ls=style, label=label, color=color)
    ns = sorted({n for _, n in points})
    ax.set_xticks(ns, [str(v) for v in ns])
    ax.minorticks_off()
    _whole_decades(ax, [r["seconds_per_query"] * 1e9 for r in points.values()])
    ax.set_xlabel("number of simultaneous events n")
    ax.set_ylabel("time per query (ns)")
    ax.grid(True, which="major", alpha=0.3)
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.02, 1.0))  # beside the lines
    ax.set_title("B-derivative at the event point: time per tangent vector\n"
                 + _sweep_caption(list(points.values())), fontsize=10)
    if machine:
        fig.supxlabel(textwrap.fill(f"measured on {_machine_note(machine)}", 110),
                      fontsize=7, color="0.3")
    return fig


def _whole_decades(ax, values) -> None:
    """Limits of the log axis y at whole decades around ``values``, each decade labelled:
    every point lies between two labelled ticks (below 10^0 too)."""
    from matplotlib.ticker import LogFormatterSciNotation, LogLocator

    lo = math.floor(math.log10(min(values)))
    hi = max(math.ceil(math.log10(max(values))), lo + 1)
    ax.set_ylim(10.0**lo, 10.0**hi)
    ax.yaxis.set_major_locator(LogLocator(base=10.0, numticks=hi - lo + 2))
    ax.yaxis.set_major_formatter(LogFormatterSciNotation(labelOnlyBase=True))


def _machine_note(machine: str) -> str:
    """``machine`` without the clauses that only say an environment variable is unset.

    Examples
    --------
    >>> _machine_note("CPU X (2 CPUs), BLAS b; OMP_NUM_THREADS unset, MKL_NUM_THREADS 1")
    'CPU X (2 CPUs), BLAS b; MKL_NUM_THREADS 1'
    """
    parts = [", ".join(c for c in part.split(", ") if not c.endswith(" unset"))
             for part in machine.split("; ")]
    return "; ".join(p for p in parts if p)


#: the keys of a benchmark row that :func:`scaling` reads, each with what its value must be
#: (``d`` and ``m`` may be left out)
ROW_KEYS = {"n": "a positive integer up to 2**53", "method": "a string",
            "seconds_per_query": "a positive number", "d": "a positive integer up to 2**53",
            "m": "a positive integer up to 2**53"}


def check_rows(rows, spell=repr) -> None:
    """Refuse ``rows`` that :func:`scaling` cannot draw: not a sequence of dicts (a
    ``TypeError``), a row without a key it reads or with a value of the wrong kind, or two
    dimensions d at one n (a ``ValueError`` naming the row). ``spell(value)`` writes a
    value into the message (``bderiv plot --bench-json`` spells them as JSON)."""
    if isinstance(rows, str | bytes) or not isinstance(rows, Sequence):
        raise TypeError(f"rows must be a sequence of dicts (the rows of `bderiv bench "
                        f"--json`), got {type(rows).__name__}")
    for i, r in enumerate(rows):
        if not isinstance(r, Mapping):
            raise TypeError(f"rows[{i}] must be a dict with the keys n, method and "
                            f"seconds_per_query, got {spell(r)[:40]}")
        missing = [k for k in ("n", "method", "seconds_per_query") if k not in r]
        if missing:
            raise ValueError(f"rows[{i}] must have the keys n, method and seconds_per_query, "
                             f"but lacks {', '.join(missing)}")
        for key, expected in ROW_KEYS.items():
            if key in r and not _good(key, r[key]):
                raise ValueError(f"rows[{i}][{key!r}] is {spell(r[key])[:40]}, not {expected}")
    first = {}  # n -> the index of its first row: one dimension d per n, as drawn
    for i, r in enumerate(rows):
        j = first.setdefault(r["n"], i)
        if rows[j].get("d") != r.get("d"):
            raise ValueError(f"rows mix sweeps: rows[{i}] has d = {r.get('d')} at n = "
                             f"{r['n']}, rows[{j}] has d = {rows[j].get('d')}; keep one "
                             f"dimension d per n")


def _good(key, value) -> bool:
    if key == "method":
        return isinstance(value, str)
    if isinstance(value, bool):
        return False
    if key == "seconds_per_query":  # numpy's floats too
        return isinstance(value, numbers.Real) and math.isfinite(value) and value > 0
    # (drawn as floats: 10**400 reached matplotlib's OverflowError)
    return isinstance(value, numbers.Integral) and 1 <= value <= 2**53


def _sweep_caption(rows) -> str:
    """``d = 2 n, batch m = 1,000``: the dimension and batch of the rows drawn."""
    ratios = {r["d"] / r["n"] for r in rows if r.get("d") is not None}
    parts = []
    if len(ratios) == 1:
        k = ratios.pop()
        parts.append("d = n" if k == 1 else f"d = {k:g} n")
    ms = {r["m"] for r in rows if r.get("m") is not None}
    if len(ms) == 1:
        parts.append(f"batch m = {ms.pop():,}")
    elif ms:
        parts.append(f"largest batch measured, m up to {max(ms):,}")
    return ", ".join(parts)
