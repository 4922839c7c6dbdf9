"""The figure of the linear pieces of a B-derivative, any dimension."""

from __future__ import annotations

import math

import numpy as np

from .._support._format import format_order
from ._axes import BAR_COLOR, check_bderivative, figure_axes


def pieces(bd, axes=None, *, max_pieces=24, n_samples=4000, seed=0):
    """Determinant and gain (largest singular value) of the linear pieces, any n.

    With ``n! <= max_pieces`` every piece is shown; otherwise the distinct pieces met by
    ``n_samples`` random unit vectors: at most ``max_pieces`` of the most frequent ones,
    or, when none holds 1 % of the vectors (large n: each is met about once), the first
    ones met.
    The determinant follows docs/mathematics.md section 4 (> 0 without resets; 0 for a
    piece through a singular reset, section 9); the gain is the largest stretch of a
    tangent vector in that cone's linear map. One bar per distinct value: pieces with the
    same determinant (or gain) share a bar, whose label says which or how many.

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
    >>> [len(ax.patches) for ax in fig.axes]  # 3! pieces, with 2 dets and 3 gains
    [2, 3]
    >>> [t.get_text() for t in fig.axes[0].get_xticklabels()]  # det 10, then det 1
    ['(0,1,2)', '(0,2,1)\\nand 4 more']
    """
    check_bderivative(bd)
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
    labels = [format_order(o) for o in orders]
    many = n > 6  # one label per bar stops being readable
    gain = "gain $\\|M_\\sigma\\|_2$"
    for ax, values, name in ((axs[0], dets, "determinant"), (axs[1], gains, gain)):
        heights, members = distinct_values(values)
        x = np.arange(len(heights))
        # one colour: the bars' only variable is their height (a colour per piece meant
        # nothing); pieces with the same value share one bar, which says how many
        bars = ax.bar(x, heights, width=0.7, color=BAR_COLOR, ec="k", lw=0.5)
        mid = (len(x) - 1) / 2  # at least 4 bars' room: one bar is not a wall
        ax.set_xlim(min(-0.5, mid - 2.0), max(len(x) - 0.5, mid + 2.0))
        if len(x) <= 8:  # few bars: their values written on them (a zero bar is no bar)
            ax.bar_label(bars, fmt="%.4g", fontsize=8, padding=2)
            ax.set_ylim(top=1.15 * max(heights.max(), 1.0))
        ax.axhline(1.0, color="0.4", lw=0.8, ls=":")  # explained in the titles
        ax.set_ylabel(name)
        names = [labels[m[0]] if len(m) == 1 else _shared(m, labels, len(orders))
                 for m in members]
        ax.set_xticks(x, [""] * len(x) if many and len(x) > 1 else names,
                      rotation=90 if n > 3 and len(x) > 1 else 0, fontsize=8)
        ax.set_xlabel(xlabel if many else "event order")
        if heights.min() > 0 and heights.max() / heights.min() > 30:
            ax.set_yscale("log")
    singular = np.array([np.linalg.matrix_rank(M) < bd.dim for M in mats])
    axs[0].set_title(_det_title(dets, singular), fontsize=10)
    axs[1].set_title("largest singular value\ndotted: gain = 1, no vector stretched",
                     fontsize=10)
    fig.suptitle(f"linear pieces $M_\\sigma$ of the B-derivative M at the event point "
                 f"(n={n}, d={bd.dim})\n{subtitle}", fontsize=10)
    return fig


def distinct_values(values, rtol=1e-9):
    """The distinct values of ``values`` (m,) and the indices sharing each, in order of
    first appearance; values equal to ``rtol`` (relative to the largest) are one value
    (two orders' products of the same factors differ by rounding only).

    Examples
    --------
    >>> heights, members = distinct_values([1.0, 2.0, 1.0 + 1e-15])
    >>> heights.tolist(), members
    ([1.0, 2.0], [[0, 2], [1]])
    """
    values = np.asarray(values, dtype=np.float64)
    tol = rtol * max(np.abs(values).max(initial=0.0), np.finfo(np.float64).tiny)
    heights, members = [], []
    for i, v in enumerate(values):
        for h, m in zip(heights, members, strict=True):
            if abs(v - h) <= tol:
                m.append(i)
                break
        else:
            heights.append(v)
            members.append([i])
    return np.array(heights), members


def _shared(members, labels, shown):
    """The tick label of a bar that several pieces share."""
    if len(members) == shown:
        return f"all {shown} pieces"
    if len(members) <= 2:
        return "\n".join(labels[i] for i in members)
    return f"{labels[members[0]]}\nand {len(members) - 1} more"


def _det_title(dets, singular):
    """The determinant panel's title: what the values met mean. Without resets every
    det is > 0 (docs/mathematics.md section 4); a singular reset makes its pieces singular
    (section 9)."""
    if singular.all():
        sign = "= 0: every piece singular, a reset forgets a direction"
    elif singular.any():
        sign = "= 0 for the pieces through a singular reset"
    elif (dets > 0).all():
        sign = "> 0: orientation kept"
    else:
        sign = "< 0 for some: orientation reversed"
    return f"det $M_\\sigma$ ({sign})\ndotted: det = 1, volume kept"
