"""The source note's picture: the triangulation carried through the corner-limit flow.

Two panels of one 2-D system with two events. In state coordinates (left) the simplices
of the fan start as the pre-event fan, bend where they cross the event lines and arrive
as the post-event fan; in impact-time coordinates (right) the same simplices are the
standard fan, and the flow only translates them.
"""

from __future__ import annotations

import numpy as np

from .._support._format import format_mask
from ._axes import PALETTE, REGION_GREYS, SIMPLEX_ALPHA, check_bderivative, figure_axes
from ._planar import _event_lines, _order_handles, _region_masks

#: points per edge of a simplex when its boundary is carried through the flow
EDGE_POINTS = 120


def carried_fan(bd, axes=None, *, snapshots=(-2.0, 0.0, 2.0)):
    """The simplices of the triangulation carried through the corner-limit flow (n = d = 2).

    Left, state coordinates ``x`` (measured from the event point): the regions of the
    corner-limit system ``x' = F[mask(x)]`` and the fan's simplices at the times of
    ``snapshots``. A simplex at time ``s`` is the set of points ``x(s)`` of the
    trajectories whose virtual pre-event position at time 0 lies in the pre-event simplex;
    well before the events it is the pre-event simplex moved along ``F[0]``, well after
    them the post-event simplex moved along ``F[full]``, and in between it bends along the
    event lines. Thin lines: the trajectories of the vertices.

    Right, impact-time coordinates ``tau_k`` = time until event k (docs/mathematics.md
    section 3: the event times of the trajectory, minus the time elapsed): here every
    trajectory moves along ``-(1, 1)``, the event lines are the axes, and the simplices
    are the standard fan (vertex ``mask``: ``tau_k = -1`` for the events of the mask, else
    0), translated and never bent.

    Parameters
    ----------
    bd : BDerivative
        A map with ``n_events == dim == 2`` (a dense table, or a corner model whose table is
        built for the figure).
    axes : sequence of 2 matplotlib Axes, optional
    snapshots : sequence of float
        Times at which the simplices are drawn (the events happen at time 0; the fan's
        vertices reach their events between times -1 and 1).

    Returns
    -------
    matplotlib.figure.Figure

    Examples
    --------
    >>> import numpy as np
    >>> from bderiv import BDerivative, plot
    >>> F = np.array([[1.0, 1.0], [0.4, 1.6], [1.5, 0.5], [0.8, 0.9]])
    >>> fig = plot.carried_fan(BDerivative(np.array([[1.0, 0.3], [0.2, 1.0]]), F))
    >>> [ax.get_xlabel() for ax in fig.axes]
    ['$x_0$ (from the event point)', '$\\\\tau_0$ (time until event 0)']
    """
    check_bderivative(bd)
    if (bd.n_events, bd.dim) != (2, 2):
        raise ValueError(
            f"carried_fan draws systems with 2 events in the plane, but this map has "
            f"n_events={bd.n_events}, dim={bd.dim}; use pieces() for any dimension"
        )
    snapshots = np.asarray(snapshots, dtype=np.float64).reshape(-1)
    if snapshots.size == 0 or not np.isfinite(snapshots).all():
        raise ValueError(f"snapshots must be a non-empty sequence of finite times, got "
                         f"{snapshots.tolist()}")
    bd = bd.to_dense("the carried-fan figure")
    tri = bd.triangulation()
    fig, (left, right) = figure_axes(axes, ncols=2, figsize=(11.0, 5.6))
    from matplotlib.patches import Polygon

    # every simplex's boundary, densely: a straight edge bends where it crosses an event
    edges = [_boundary(tri.pre[simplex]) for simplex in tri.simplices]
    times = [bd.event_times(points)[0] for points in edges]
    verts = tri.pre[1:]  # the vertices' trajectories (vertex 0 stays the origin's)
    vtimes = bd.event_times(verts)[0]
    span = np.array([snapshots.min() - 0.5, snapshots.max() + 0.5])
    path_t = np.linspace(*span, 400)
    state_paths = np.stack([_flow(bd.F, verts, vtimes, s) for s in path_t], axis=1)
    for i, (points, tau) in enumerate(zip(edges, times, strict=True)):
        color = PALETTE[(i // 2) % len(PALETTE)]
        hatch = None if i % 2 == 0 else "///"
        for s in snapshots:
            for ax, xy in ((left, _flow(bd.F, points, tau, s)), (right, tau - s)):
                ax.add_patch(Polygon(xy, closed=True, fc=color, ec="k", lw=0.7,
                                     alpha=SIMPLEX_ALPHA, hatch=hatch))
    for ax, paths in ((left, state_paths), (right, vtimes[:, None, :] - path_t[:, None])):
        for path in paths:
            ax.plot(path[:, 0], path[:, 1], color="0.35", lw=0.6, zorder=1)
    _state_panel(left, bd, state_paths, snapshots)
    _time_panel(right, vtimes, snapshots, span)
    fig.legend(handles=_order_handles(tri, 2), title="the simplices of each event order",
               fontsize=8, loc="outside lower center", ncols=2)
    fig.suptitle(
        "The triangulation of the B-derivative at the event point, carried through the "
        "corner-limit flow\n"
        f"snapshots at t = {', '.join(f'{s:g}' for s in snapshots)}; the events happen at "
        "t = 0", fontsize=11)
    return fig


def _boundary(corners):
    """Points (3 * EDGE_POINTS, 2) along the closed boundary of a triangle (3, 2)."""
    s = np.linspace(0.0, 1.0, EDGE_POINTS, endpoint=False)[:, None]
    ends = np.roll(corners, -1, axis=0)
    return np.concatenate([a + s * (b - a) for a, b in zip(corners, ends, strict=True)])


def _flow(F, U, times, s):
    """Positions (m, 2) at time ``s`` of the corner-limit trajectories of virtual starts U.

    ``times`` (m, n): each trajectory's event times (``bd.event_times``). The events that
    have happened by time ``s`` move the virtual position as in docs/mathematics.md
    section 3 (so the trajectory is continuous); the position is then the virtual one plus
    ``s`` times the field of the region reached.
    """
    x = np.array(U, dtype=np.float64)
    mask = np.zeros(len(x), dtype=np.int64)
    for k in np.argsort(times, axis=1, kind="stable").T:  # the j-th event of every row
        t = np.take_along_axis(times, k[:, None], axis=1)[:, 0]
        now = t <= s
        after = mask | (1 << k)
        x[now] += t[now, None] * (F[mask[now]] - F[after[now]])
        mask[now] = after[now]
    return x + s * F[mask]


def _state_panel(ax, bd, paths, snapshots):
    """Regions, event lines, labels and limits of the state-coordinates panel."""
    lo, hi = paths.reshape(-1, 2).min(axis=0), paths.reshape(-1, 2).max(axis=0)
    pad = 0.05 * (hi - lo).max()
    lo, hi = lo - pad, hi + pad
    X, Y = np.meshgrid(np.linspace(lo[0], hi[0], 301), np.linspace(lo[1], hi[1], 301))
    masks = _region_masks(np.stack([X.ravel(), Y.ravel()], axis=1), bd.Dh).reshape(X.shape)
    from matplotlib.colors import ListedColormap

    # regions in greys: the hues belong to the simplices (their event orders)
    ax.pcolormesh(X, Y, masks, cmap=ListedColormap(REGION_GREYS), vmin=-0.5, vmax=3.5,
                  shading="auto", rasterized=True, zorder=0)
    _event_lines(ax, bd.Dh, 2.0 * np.abs(np.r_[lo, hi]).max())
    for mask in range(4):
        sel = masks == mask
        if sel.any():  # the region's name near its far corner, away from the simplices
            far = np.argmax(np.hypot(X[sel], Y[sel]))
            x, y = X[sel][far], Y[sel][far]  # inside the axes, aligned on that corner
            ax.annotate(f"mask {format_mask(mask, 2)}\nfield F[{mask}]", (x, y),
                        textcoords="offset points",
                        xytext=(-4 if x > 0 else 4, -4 if y > 0 else 4), fontsize=7,
                        ha="right" if x > 0 else "left", va="top" if y > 0 else "bottom",
                        bbox=dict(boxstyle="round", fc="white", alpha=0.8, lw=0))
    for s, label in _snapshot_labels(snapshots):
        ax.annotate(label, _flow(bd.F, np.zeros((1, 2)), np.zeros((1, 2)), s)[0],
                    textcoords="offset points", xytext=(6, -14), fontsize=8,
                    bbox=dict(boxstyle="round", fc="white", alpha=0.85, lw=0))
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    ax.set_aspect("equal")
    ax.set_xlabel("$x_0$ (from the event point)")
    ax.set_ylabel("$x_1$")
    ax.set_title("state coordinates: the corner-limit flow bends the simplices\n"
                 "(pre-event fan before, post-event fan after)", fontsize=10)


def _time_panel(ax, vtimes, snapshots, span):
    """Quadrants, axes as event lines, labels and limits of the impact-time panel."""
    lim = np.abs(np.r_[vtimes.ravel() - span[0], vtimes.ravel() - span[1]]).max() * 1.05
    for k in range(2):  # tau_k = 0: event k happens now
        ends = np.zeros((2, 2))
        ends[:, 1 - k] = (-lim, lim)
        ax.plot(ends[:, 0], ends[:, 1], color="k", lw=1.2, ls="--", zorder=2)
    for mask, (sx, sy) in enumerate(((1, 1), (-1, 1), (1, -1), (-1, -1))):
        ax.text(0.82 * lim * sx, 0.92 * lim * sy, f"mask {format_mask(mask, 2)}", fontsize=7,
                ha="center", va="center",
                bbox=dict(boxstyle="round", fc="white", alpha=0.8, lw=0))
    for s, label in _snapshot_labels(snapshots):
        ax.annotate(label, (-s, -s), textcoords="offset points", xytext=(6, -14),
                    fontsize=8, bbox=dict(boxstyle="round", fc="white", alpha=0.85, lw=0))
    ax.set_xlim(-lim, lim)
    ax.set_ylim(-lim, lim)
    ax.set_aspect("equal")
    ax.set_xlabel("$\\tau_0$ (time until event 0)")
    ax.set_ylabel("$\\tau_1$ (time until event 1)")
    ax.set_title("impact-time coordinates: the standard fan, carried by a translation\n"
                 "(dashed: $\\tau_k = 0$, event k happens now)", fontsize=10)


def _snapshot_labels(snapshots):
    """(time, label) of each snapshot, the apex of whose simplices the label marks."""
    return [(s, f"t = {s:g}" + (" (before)" if s < -1 else " (after)" if s > 1 else ""))
            for s in snapshots]
