"""The figure of the linear pieces of a B-derivative, any dimension."""

from __future__ import annotations

import math

import numpy as np

from .._format import format_order
from ._axes import PALETTE, figure_axes


def pieces(bd, axes=None, *, max_pieces=24, n_samples=4000, seed=0):
    """Determinant and gain (largest singular value) of the linear pieces, any n.

    With ``n! <= max_pieces`` every piece is shown; otherwise the distinct pieces met by
    ``n_samples`` random unit vectors: at most ``max_pieces`` of the most frequent ones,
    or, when none holds 1 % of the vectors (large n: each is met about once), the first
    ones met.
    The determinant follows MATH.md section 4 (always > 0); the gain is the largest
    stretch of a tangent vector in that cone's linear map.

    Parameters
    ----------
    bd : BDerivative
    axes : sequence of 2 matplotlib Axes, optional
    max_pieces : int
        Most pieces shown.
    n_samples : int
        Random vectors used to find the pieces when there are too many to show all.
    seed : int
        Seed of those vectors.

    Returns
    -------
    matplotlib.figure.Figure

    Examples
    --------
    >>> import numpy as np
    >>> from bderiv import BDerivative, plot
    >>> F = np.ones((8, 3)); F[0b001] = (1.0, 0.1, 1.0)
    >>> fig = plot.pieces(BDerivative(np.eye(3), F))
    >>> len(fig.axes[0].patches)         # 3! pieces
    6
    """
    n = bd.n_events
    total = math.factorial(n)
    xlabel = "event order"
    if total <= max_pieces:
        orders = [o for o, _ in bd.pieces(max_pieces=max_pieces)]
        subtitle = f"all {total} pieces"
    else:
        rng = np.random.default_rng(seed)
        V = rng.standard_normal((n_samples, bd.dim))
        _, order = bd.event_times(V)
        uniq, first, counts = np.unique(order, axis=0, return_index=True,
                                        return_counts=True)
        if counts.max() >= 0.01 * n_samples:
            keep = np.argsort(-counts, kind="stable")[:max_pieces]
            what, xlabel = "most visited", "piece, most visited first"
        else:  # each piece met about once: "most visited" would be an arbitrary tie-break
            keep = np.argsort(first)[:max_pieces]
            what, xlabel = "first met", "piece, in the order the random vectors met them"
        orders = list(uniq[keep])
        subtitle = (
            f"the {len(orders)} {what} of {len(uniq)} pieces met by {n_samples} random "
            f"vectors ({n}! = {total:,} in all)"
        )
    mats = [bd.piece(o) for o in orders]
    dets = np.array([np.linalg.det(M) for M in mats])
    gains = np.array([np.linalg.norm(M, 2) for M in mats])
    fig, axs = figure_axes(axes, ncols=2, figsize=(max(8.0, 0.35 * len(orders) + 4), 4.2))
    x = np.arange(len(orders))
    labels = [format_order(o) for o in orders]
    many = n > 6  # labels and per-piece colours stop being readable
    colors = ["#4477AA" if many else PALETTE[i % len(PALETTE)] for i in range(len(orders))]
    gain = "gain $\\|M_\\sigma\\|_2$"
    for ax, values, name in ((axs[0], dets, "determinant"), (axs[1], gains, gain)):
        ax.bar(x, values, color=colors, ec="k", lw=0.5)
        ax.axhline(1.0, color="0.4", lw=0.8, ls=":")  # explained in the titles
        ax.set_ylabel(name)
        ax.set_xticks(x, [""] * len(x) if many else labels, rotation=90 if n > 3 else 0,
                      fontsize=8)
        ax.set_xlabel(xlabel if many else "event order")
        if values.max() / max(values.min(), 1e-300) > 30:
            ax.set_yscale("log")
    axs[0].set_title("det $M_\\sigma$ (> 0: orientation kept)\ndotted: det = 1, volume kept",
                     fontsize=10)
    axs[1].set_title("largest singular value\ndotted: gain = 1, no vector stretched",
                     fontsize=10)
    fig.suptitle(f"linear pieces $M_\\sigma$ of the B-derivative M at the event point "
                 f"(n={n}, d={bd.dim})\n{subtitle}", fontsize=10)
    return fig
