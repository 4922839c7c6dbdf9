"""The figure of a stability map: a gait's growth rate over a grid of two parameters."""

from __future__ import annotations

import numpy as np

from ._axes import check_type, figure_axes

#: the colour of the grid points without an orbit
NO_ORBIT = "0.75"


def stability_map(smap, ax=None, labels=None):
    """The growth rate over a two-parameter grid, the unstable region marked.

    Colour: the growth rate of the orbit at each grid point, on a diverging scale centred
    at 1 (blue: perturbations decay, red: they grow; each side linear, with its own
    labelled ticks, and 1 marked on the bar); the contour ``growth rate = 1`` (the
    stability boundary) in black; unstable points hatched; points without an orbit grey.

    Parameters
    ----------
    smap : StabilityMap
        Of two parameters (:func:`bderiv.analysis.stability_map.stability_map`).
    ax : matplotlib Axes, optional
    labels : (str, str), optional
        The axes' labels (default: the parameters' names).

    Returns
    -------
    matplotlib.figure.Figure
    """
    from ..analysis.stability_map import StabilityMap

    check_type(smap, "smap", (StabilityMap,))
    if len(smap.names) != 2:
        raise ValueError(f"the figure needs a map over two parameters, got {len(smap.names)}: "
                         f"{list(smap.names)}")
    import matplotlib
    from matplotlib.colors import TwoSlopeNorm

    fig, (ax,) = figure_axes(ax, figsize=(5.8, 4.6))
    x, y = smap.values
    rate = smap.growth_rate.T  # rows: the second parameter (y)
    finite = rate[np.isfinite(rate)]
    low = min(float(finite.min()), 0.99) if finite.size else 0.5
    high = max(float(finite.max()), 1.01) if finite.size else 1.5
    cmap = matplotlib.colormaps["RdBu_r"].with_extremes(bad=NO_ORBIT)
    mesh = ax.pcolormesh(x, y, np.ma.masked_invalid(rate), shading="nearest", cmap=cmap,
                         norm=TwoSlopeNorm(vcenter=1.0, vmin=low, vmax=high))
    bar = fig.colorbar(mesh, ax=ax, label="growth rate per stride")
    ticks = _ticks(low, high)
    bar.set_ticks(ticks, labels=[f"{t:g}" for t in ticks])
    bar.ax.axhline(1.0, color="black", linewidth=1.2)
    if x.size > 1 and y.size > 1 and finite.size and low < 1.0 < high:
        # the unstable region hatched, bounded by the contour growth rate = 1
        ax.contourf(x, y, rate, levels=[1.0, np.inf], colors="none", hatches=["//"])
        ax.contour(x, y, rate, levels=[1.0], colors="black", linewidths=1.2)
    xlabel, ylabel = smap.names if labels is None else labels
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    n_stable, n_found = int(smap.stable.sum()), int(np.isfinite(rate).sum())
    ax.set_title(f"{n_stable} of {n_found} orbits stable (growth rate < 1: blue)\nhatched: "
                 f"unstable" + ("; grey: no orbit found" if n_found < rate.size else ""),
                 fontsize=9)
    return fig


def _ticks(low, high):
    """Ticks of the colour bar: a few round values on each side of 1, and 1 (each side of
    the diverging scale is linear on its own range)."""
    from matplotlib.ticker import MaxNLocator

    below = MaxNLocator(4).tick_values(low, 1.0)
    above = MaxNLocator(5).tick_values(1.0, high)
    return np.concatenate((below[(below >= low) & (below < 1.0)], [1.0],
                           above[(above > 1.0) & (above <= high)]))
