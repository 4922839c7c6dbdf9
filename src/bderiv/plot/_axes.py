"""What every figure shares: the pyplot-free figure set-up and the palette."""

from __future__ import annotations

import numpy as np

PLOT_HINT = (
    "bderiv's figures need matplotlib: install it with `pip install 'bderiv[plot]'` "
    "(or `pip install matplotlib`)"
)

#: a qualitative palette indexed by piece (event order) number
PALETTE = (
    "#4477AA", "#EE6677", "#228833", "#CCBB44", "#66CCEE", "#AA3377", "#BBBBBB", "#000000",
)

#: opacity of a simplex (its colour is its event order)
SIMPLEX_ALPHA = 0.55
#: colours of the regions under the simplices: greys, so no region shares a simplex's hue
REGION_GREYS = ("#FFFFFF", "#EEEEEE", "#E0E0E0", "#D0D0D0")

#: the one colour of bars whose only variable is their height
BAR_COLOR = PALETTE[0]


def figure_axes(ax, ncols=1, figsize=(5.5, 5.0)):
    """The figure to draw into and its ``ncols`` axes.

    A figure's first call to matplotlib (here or in :func:`new_figure`), so a missing
    matplotlib is reported with the install hint.

    Parameters
    ----------
    ax : matplotlib Axes or sequence of ``ncols`` Axes, or None
        The caller's axes; None for a new figure built without pyplot (no global state).
    ncols : int
        Axes the figure needs, side by side.
    figsize : (float, float)
        Size in inches of a new figure.

    Returns
    -------
    (matplotlib.figure.Figure, list of ``ncols`` matplotlib Axes)
    """
    if ax is not None:
        axes = list(np.atleast_1d(np.asarray(ax, dtype=object)))
        if len(axes) != ncols:
            raise ValueError(f"this figure needs {ncols} axes, got {len(axes)}")
        from matplotlib.axes import Axes

        name = "ax" if ncols == 1 else "axes"
        for i, one in enumerate(axes):
            check_type(one, name if ncols == 1 else f"{name}[{i}]", (Axes,),
                       expected="a matplotlib Axes")
        return axes[0].figure, axes
    fig = new_figure(figsize)
    axes = fig.subplots(1, ncols, squeeze=False)[0]
    return fig, list(axes)


def new_figure(figsize):
    """A new figure of ``figsize`` inches, built without pyplot (no global state), laid out
    by matplotlib's constrained layout; a missing matplotlib is reported with the install
    hint."""
    try:
        from matplotlib.figure import Figure
    except ImportError as exc:  # pragma: no cover - exercised without matplotlib only
        raise ImportError(PLOT_HINT) from exc
    return Figure(figsize=figsize, layout="constrained")


def check_type(value, name, types, *, optional=False, expected=None, hint=""):
    """Refuse a ``value`` that is none of ``types`` (nor None, if ``optional``): a
    ``TypeError`` naming the parameter ``name``, what it must be (``expected``, by default
    the types' names) and the type it got, then ``hint``. A figure checks the objects it
    draws with it before it draws anything, so that a wrong object (an array, a dict, the
    result of another analysis) is named, not met as a missing attribute deep inside."""
    if isinstance(value, types) or (optional and value is None):
        return value
    if expected is None:
        names = [f"a {t.__name__}" for t in types] + (["None"] if optional else [])
        expected = " or ".join([", ".join(names[:-1]), names[-1]] if len(names) > 1 else names)
    raise TypeError(f"{name} must be {expected}, got {type(value).__name__}{hint}")


def check_bderivative(bd, name="bd"):
    """Refuse a ``bd`` that is not a :class:`~bderiv.BDerivative` (a figure of its corner
    table), the commonest wrong objects named with what to do instead."""
    from ..engine.bderivative import BDerivative

    if isinstance(bd, BDerivative):
        return
    from ..analysis.flowmap import FlowBDerivative
    from ..geometry.triangulation import Triangulation

    hint = ""
    if isinstance(bd, FlowBDerivative):
        hint = " (a flow map's B-derivative has no corner table; triangulation() draws it)"
    elif isinstance(bd, Triangulation):
        hint = " (draw a triangulation with triangulation(None, tri=...))"
    check_type(bd, name, (BDerivative,), hint=hint)
