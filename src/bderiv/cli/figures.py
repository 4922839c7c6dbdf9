"""``bderiv plot``: the figures of :mod:`bderiv.plot` written to files.

(Named ``figures`` so that ``bderiv.plot``, the figures themselves, keeps its name.)
"""

from __future__ import annotations

import json
import os

from .. import _bench
from .systems import load_example
from .usage import UsageError, require_memory, require_module

#: figures that draw the plane (need d = 2)
FIGURES_2D = ("field", "triangulation", "circle")
#: every figure, by its file name
FIGURES = (*FIGURES_2D, "pieces", "scaling")
#: Agg's bound on the pixels of a side of a raster image
MAX_SIDE_PIXELS = 1 << 16
#: the small sweep drawn by the scaling figure when no ``--bench-json`` is given
DEFAULT_SWEEP = dict(ns=(2, 4, 8), batch=20_000, repeat=1)


def run_figures(example=None, n=None, extended=False, figures=None, out="bderiv-figures",
                fmt="png", dpi=120, bench_json=None) -> dict:
    """Write the figures asked for; return ``{"example", "dim", "n_events", "files"}``.

    Parameters
    ----------
    example, n, extended
        The system (default ``network`` with n = 2), as for
        :func:`bderiv.cli.systems.load_example`.
    figures : list of str, optional
        Names from :data:`FIGURES` or ``"all"`` (default: all that apply to the system).
    out : str
        Directory of the files (created if missing).
    fmt : {"png", "pdf", "svg"}
    dpi : int
    bench_json : str, optional
        Rows of ``bderiv bench --json`` for the scaling figure.
    """
    require_module("matplotlib", "bderiv plot")
    from .. import plot

    if example is None:
        example, n = "network", (2 if n is None else n)
    wanted = list(dict.fromkeys(figures or ["all"]))
    if "all" in wanted:
        wanted = [f for f in FIGURES if f != "scaling" or bench_json]
    _, bd = load_example(example, n, extended)
    if bd.dim != 2:
        asked_2d = [f for f in wanted if f in FIGURES_2D]
        if figures and "all" not in figures and asked_2d:
            raise UsageError(
                f"figures {asked_2d} need a 2-D system but {example} has d = {bd.dim}; use "
                f"--example planar or --example network --n 2"
            )
        wanted = [f for f in wanted if f not in FIGURES_2D]
    rows = None
    if "scaling" in wanted:
        rows = read_bench_rows(bench_json) if bench_json else _bench.sweep(**DEFAULT_SWEEP)
    draw = {"field": plot.corner_field, "triangulation": plot.triangulation,
            "circle": plot.tangent_circle, "pieces": plot.pieces}
    figs = {name: plot.scaling(rows) if name == "scaling" else draw[name](bd)
            for name in wanted}
    for name, fig in figs.items():  # refuse a --dpi before writing anything
        check_raster(fig, dpi, name)
    _make_directory(out)
    written = []
    for name, fig in figs.items():
        written.append(os.path.join(out, f"{name}.{fmt}"))
        save_figure(fig, written[-1], dpi)
    return {"example": example, "dim": bd.dim, "n_events": bd.n_events, "files": written}


def read_bench_rows(path: str) -> list:
    """The rows of ``bderiv bench --json`` saved in ``path`` (``--bench-json``)."""
    try:
        with open(path, encoding="utf-8") as fh:
            rows = json.load(fh)
    except (OSError, json.JSONDecodeError) as exc:
        raise UsageError(
            f"--bench-json: cannot read benchmark rows from {path!r}: {exc}"
        ) from None
    if not isinstance(rows, list) or not all(
        isinstance(r, dict) and {"n", "method", "seconds_per_query"} <= r.keys() for r in rows
    ):
        raise UsageError(f"--bench-json: {path!r} is not the output of `bderiv bench --json`")
    return rows


def _make_directory(path: str) -> None:
    try:
        os.makedirs(path, exist_ok=True)
    except OSError as exc:
        raise UsageError(f"--out: cannot make the directory {path!r}: {exc}") from None


def check_raster(fig, dpi: int, name: str) -> None:
    """Refuse a ``dpi`` that makes ``fig`` an image Agg or the memory cannot hold."""
    width, height = fig.get_size_inches() * dpi
    if max(width, height) >= MAX_SIDE_PIXELS:
        raise UsageError(
            f"--dpi {dpi} makes the figure {name} {width:.0f} x {height:.0f} pixels; at most "
            f"{MAX_SIDE_PIXELS - 1} pixels per side are possible"
        )
    require_memory(int(width * height) * 4, f"--dpi {dpi} ({width:.0f} x {height:.0f} pixels)")


def save_figure(fig, path: str, dpi: int) -> None:
    """Save ``fig`` to ``path``; a path that cannot be written is a usage error."""
    check_raster(fig, dpi, os.path.basename(path))
    try:
        fig.savefig(path, dpi=dpi)
    except OSError as exc:
        raise UsageError(f"cannot write the figure {path!r}: {exc}") from None
