"""``bderiv plot``: the figures of :mod:`bderiv.plot` written to files.

(Named ``figures`` so that ``bderiv.plot``, the figures themselves, keeps its name.)
"""

from __future__ import annotations

import json
import math
import os

import numpy as np

from .._limits import MAX_PIXELS, MAX_SIDE_PIXELS
from .machine import describe
from .names import (  # noqa: E402, F401  (the figures' names live in .names)
    DECAY_DIRECTIONS,
    DECAY_EPS,
    DECAY_STRIDES,
    DEFAULT_OUT,
    FIGURES,
    FIGURES_2D,
    GAIT_FIGURES,
    MIN_TEXT_PIXELS,
)
from .systems import ORBIT_EXAMPLES, load_example, load_gait, load_orbit
from .usage import (
    UsageError,
    check_output_directory,
    check_output_file,
    make_output_directory,
    not_writable,
    require_memory,
    require_module,
)


def run_figures(example=None, n=None, extended=False, figures=None, out=None,
                fmt="png", dpi=120, bench_json=None, report=None) -> dict:
    """Write the figures asked for; return what was drawn and the files written.

    Parameters
    ----------
    example, n, extended
        The system (default ``planar``; ``--n`` alone means ``network``), as for
        :func:`bderiv.cli.systems.load_example`, or a gait of :data:`ORBIT_EXAMPLES`
        (:func:`bderiv.cli.systems.load_orbit`).
    figures : list of str, optional
        Names from :data:`FIGURES` or ``"all"`` (default: all that apply to the system;
        ``scaling`` only with ``bench_json``).
    out : str, optional
        Directory of the files (made if missing, with its missing parents); default
        ``bderiv-figures/<example>``. Files of the same name in it are replaced, and the
        summary lists them.
    fmt : {"png", "pdf", "svg"}
    dpi : int
    bench_json : str, optional
        The output of ``bderiv bench --json``, for the scaling figure.
    report : callable ``report(text)``, optional
        Told what takes seconds before it starts (finding a gait's orbit, simulating its
        strides), so that no minute passes silent.

    Returns
    -------
    dict
        ``example``, ``dim``, ``n_events``, ``files`` (the paths written), ``replaced``
        (those of them that replaced an earlier file), ``created`` (the topmost directory
        made, or None) and ``skipped`` (figures of "all" that do not apply, with the
        reason).
    """
    require_module("matplotlib", "bderiv plot")
    from .. import plot

    if example is None:
        example = "network" if n is not None or extended else "planar"
    out = os.path.join(DEFAULT_OUT, example) if out is None else out
    check_output_directory(out, "--out")  # before the work: finding an orbit takes seconds
    wanted = list(dict.fromkeys(figures or ["all"]))
    if "scaling" in wanted and not bench_json:
        raise UsageError(
            "--figure scaling plots a benchmark run: run `bderiv bench --json > rows.json` "
            "(or `bderiv bench --plot scaling.png`) and pass --bench-json rows.json"
        )
    bench = read_bench(bench_json) if bench_json else None
    # what the figures draw: a gait's periodic orbit (found below, once the figures asked
    # for are known to apply: it takes seconds), or the B-derivative at an event point
    if example in ORBIT_EXAMPLES:
        model = load_gait(example, n, extended)
        sizes = (model.system.dim, model.system.n_events)
    else:
        _, subject = load_example(example, n, extended)
        sizes = (subject.dim, subject.n_events)
    skipped = {}
    if "all" in wanted:
        wanted = [f for f in FIGURES if f != "scaling" or bench]
        skipped = _not_applicable(wanted, example, *sizes)
        wanted = [f for f in wanted if f not in skipped]
        if not bench:
            skipped["scaling"] = "needs --bench-json"
    else:
        refused = _not_applicable(wanted, example, *sizes)
        if refused:
            raise UsageError(_refusal(*next(iter(refused.items())), example, *sizes))
    written = [os.path.join(out, f"{name}.{fmt}") for name in wanted]
    for path in written:  # every file, before the first is drawn
        check_output_file(path, "--out")
    say = report or (lambda text: None)
    if example in ORBIT_EXAMPLES and set(wanted) - {"scaling"}:
        say(f"finding the {example} orbit by Newton's method (a few seconds)")
        _, subject = load_orbit(example, model=model)
    figs = {}
    for name in wanted:
        if name == "growth":
            say(f"simulating {DECAY_STRIDES} strides from {DECAY_DIRECTIONS} perturbed starts "
                f"for the growth figure (a few seconds)")
        figs[name] = (plot.scaling(bench["rows"], machine=bench["machine"])
                      if name == "scaling" else _draw(plot, name, example, subject))
    for name, fig in figs.items():  # refuse a --dpi before writing anything
        check_raster(fig, dpi, name)
    replaced = [path for path in written if os.path.exists(path)]
    created = make_output_directory(out, "--out")
    for fig, path in zip(figs.values(), written, strict=True):
        save_figure(fig, path, dpi, "--out")
    return {"example": example, "dim": sizes[0], "n_events": sizes[1], "files": written,
            "replaced": replaced, "created": created, "skipped": skipped}


def _draw(plot, name, example, subject):
    """The figure ``name`` of a B-derivative, or of a gait's periodic orbit."""
    if name == "orbit":
        return plot.gait_orbit(subject, **ORBIT_EXAMPLES[example])
    if name == "growth":
        return plot.gait_growth(subject, iterations=DECAY_STRIDES, decay=_decay(subject))
    draw = {"field": plot.corner_field, "triangulation": plot.triangulation,
            "circle": plot.tangent_circle, "note": plot.carried_fan, "pieces": plot.pieces}
    return draw[name](subject)


def _decay(orbit):
    """Simulated decay of perturbations of ``orbit`` along random unit directions tangent
    to its section: the growth figure's check against the nonlinear system."""
    from ..analysis.checks import decay_check  # simulates: only here

    R = orbit.return_map
    D = np.random.default_rng(0).standard_normal((DECAY_DIRECTIONS, R.tangent_basis.shape[1]))
    D = D @ R.tangent_basis.T
    return decay_check(orbit.system, orbit.x0, orbit.section,
                       D / np.linalg.norm(D, axis=1)[:, None], eps=DECAY_EPS,
                       strides=DECAY_STRIDES)


def _not_applicable(names, example, dim, n_events) -> dict:
    """The figures of ``names`` that cannot draw ``example`` (a B-derivative at an event
    point, or the periodic orbit of a gait; ``dim`` and ``n_events`` its d and n), each
    with the reason."""
    why = {}
    gait = example in ORBIT_EXAMPLES
    for name in names:
        if name in GAIT_FIGURES and not gait:
            why[name] = "needs a gait's periodic orbit"
        elif name in (*FIGURES_2D, "pieces") and gait:
            why[name] = "draws a B-derivative at an event point, not a gait's orbit"
        elif name in FIGURES_2D and dim != 2:
            why[name] = "draws the plane (needs d = 2)"
        elif name == "note" and n_events != 2:
            why[name] = "draws 2 events in the plane (needs n = d = 2)"
    return why


def _refusal(name, why, example, dim, n_events) -> str:
    """The usage error of a figure asked for that cannot draw ``example``: why, where it
    applies, and the figures that do."""
    if name in GAIT_FIGURES:
        why, where = f"{why}, but {example} is not a gait", ", ".join(ORBIT_EXAMPLES)
    elif example not in ORBIT_EXAMPLES:
        why, where = f"{why}, but {example} has n = {n_events}, d = {dim}", "planar"
    else:  # the reason says it: a gait's figures are those of its orbit
        where = "planar"
    drawn = [f for f in FIGURES if f != "scaling"
             and f not in _not_applicable(FIGURES, example, dim, n_events)]
    return (f"figure {name} {why}: use --example {where}, or a figure of {example}: "
            f"{', '.join(drawn)} (or scaling, with --bench-json)")


def read_bench(path: str) -> dict:
    """The output of ``bderiv bench --json`` saved in ``path`` (``--bench-json``).

    Returns
    -------
    dict
        ``rows`` (the sweep's rows) and ``machine`` (one line describing where they were
        measured).
    """
    try:
        with open(path, encoding="utf-8") as fh:
            data = json.load(fh)
    except (OSError, json.JSONDecodeError) as exc:
        raise UsageError(
            f"--bench-json: cannot read benchmark rows from {path!r}: {exc}"
        ) from None
    rows = data.get("rows") if isinstance(data, dict) else None
    if not isinstance(rows, list) or not rows:
        raise UsageError(f"--bench-json: {path!r} is not the output of `bderiv bench --json`")
    from ..plot._scaling import check_rows

    try:  # the figure's own check, its values spelled as in the file
        check_rows(rows, spell=json.dumps)
    except (TypeError, ValueError) as exc:
        raise UsageError(f"--bench-json: {path!r} is not the output of `bderiv bench "
                         f"--json` as the figure reads it: {exc}") from None
    try:
        machine = describe(data["machine"])
    except (KeyError, TypeError, AttributeError):
        raise UsageError(f"--bench-json: {path!r} lacks the machine record of `bderiv bench "
                         f"--json`") from None
    return {"rows": rows, "machine": machine}


def check_raster(fig, dpi: int, name: str) -> None:
    """Refuse a ``dpi`` that makes ``fig`` an image Agg or the memory cannot hold, or its
    text too small for Agg to draw (fonts made small by matplotlib's settings)."""
    from matplotlib.text import Text

    small = min((t.get_fontsize() for t in fig.findobj(Text) if t.get_text()), default=None)
    if small is not None and small * dpi / 72 < MIN_TEXT_PIXELS:
        raise UsageError(
            f"--dpi {dpi} makes the smallest text of the figure {name} ({small:g} pt) "
            f"{small * dpi / 72:.2g} pixel high, too small to draw; at least --dpi "
            f"{math.ceil(MIN_TEXT_PIXELS * 72 / small)} for this figure"
        )
    width, height = fig.get_size_inches() * dpi
    if max(width, height) >= MAX_SIDE_PIXELS:
        raise UsageError(
            f"--dpi {dpi} makes the figure {name} {width:.0f} x {height:.0f} pixels; at most "
            f"{MAX_SIDE_PIXELS - 1} pixels per side are possible"
        )
    if width * height > MAX_PIXELS:
        raise UsageError(
            f"--dpi {dpi} makes the figure {name} {width:.0f} x {height:.0f} = "
            f"{width * height:.3g} pixels; image viewers and libraries refuse more than "
            f"{MAX_PIXELS:.3g} (at most --dpi {int(dpi * (MAX_PIXELS / (width * height)) ** 0.5)} "
            f"for this figure)"
        )
    require_memory(int(width * height) * 4, f"--dpi {dpi} ({width:.0f} x {height:.0f} pixels)")


def save_figure(fig, path: str, dpi: int, option: str) -> None:
    """Save ``fig`` to ``path``; a path that cannot be written is a usage error of
    ``option``."""
    check_raster(fig, dpi, os.path.basename(path))
    try:  # the format named: matplotlib reads ".png" as a name without one, and adds .png
        fig.savefig(path, dpi=dpi, format=path.rsplit(".", 1)[-1].lower())
    except OSError as exc:
        raise UsageError(not_writable(option, path, exc)) from None
