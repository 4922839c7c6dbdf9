"""The figures of a 2-D system: the corner-limit field, the triangulation, the tangent circle.

Each draws the plane around the event point (the origin) and refuses a map of another
dimension; :func:`bderiv.plot.pieces` serves any dimension.
"""

from __future__ import annotations

import numpy as np

from .._support._format import format_mask, format_order
from ._axes import PALETTE, SIMPLEX_ALPHA, check_bderivative, check_type, figure_axes


def _require_2d(bd, what):
    """Refuse a map ``bd`` whose dimension is not 2 (``what``: the figure's name)."""
    if bd.dim != 2:
        raise ValueError(
            f"{what} draws 2-D systems only, but this map has dimension d={bd.dim}; use "
            f"pieces() for any dimension"
        )


def _event_lines(ax, Dh, radius, colors=("k",)):
    """Draw the lines {x : Dh[k] . x = 0} through the origin, labelled h_k = 0."""
    for k, row in enumerate(Dh):
        direction = np.array([-row[1], row[0]]) / np.linalg.norm(row)
        ends = np.outer([-radius, radius], direction)
        ax.plot(ends[:, 0], ends[:, 1], color=colors[k % len(colors)], lw=1.2, ls="--")
        ax.annotate(
            f"$h_{k} = 0$", ends[1] * 0.8, fontsize=9, ha="center", va="center",
            color=colors[k % len(colors)],
            bbox=dict(boxstyle="round", fc="white", ec="0.6", lw=0.5),
        )


def _unit_circle(n_vectors):
    theta = np.linspace(0.0, 2.0 * np.pi, n_vectors, endpoint=False)
    return theta, np.column_stack([np.cos(theta), np.sin(theta)])


def _piece_ids(order):
    """Number the distinct rows of ``order`` (m, n) in lexicographic order of the orders."""
    uniq, ids = np.unique(order, axis=0, return_inverse=True)
    return uniq, ids.reshape(-1)


def corner_field(bd, ax=None, *, radius=1.0, density=13, n_trajectories=7):
    """The corner-limit vector field of a 2-D system, with the event lines.

    Each region between the lines ``Dh[k] . x = 0`` is shaded and carries its constant
    field ``F[mask]`` (arrows); thin lines are trajectories of the sampled system
    ``x' = F[mask(x)]`` that cross both surfaces, bending at each event.

    Parameters
    ----------
    bd : BDerivative
        A map with ``dim == 2``: a dense table, or a corner model whose dense table
        (``bd.to_dense()``) is built for the figure.
    ax : matplotlib Axes, optional
    radius : float
        Half-width of the square shown, around the event point (the origin).
    density : int
        Arrows per side.
    n_trajectories : int
        Number of sampled trajectories drawn.

    Returns
    -------
    matplotlib.figure.Figure

    Examples
    --------
    >>> import numpy as np
    >>> from bderiv import BDerivative
    >>> from bderiv import plot
    >>> F = np.array([[1.0, 1.0], [0.4, 1.6], [1.5, 0.5], [0.8, 0.9]])
    >>> fig = plot.corner_field(BDerivative(np.eye(2), F))
    >>> fig.axes[0].get_title()
    'corner-limit field at the event point (n=2 events)'
    """
    check_bderivative(bd)
    _require_2d(bd, "corner_field")
    F = bd.to_dense("the corner-field figure").F
    fig, (ax,) = figure_axes(ax, figsize=(5.5, 6.0))
    n, Dh = bd.n_events, bd.Dh
    # shaded regions
    s = np.linspace(-radius, radius, 301)
    X, Y = np.meshgrid(s, s)
    P = np.stack([X.ravel(), Y.ravel()], axis=1)
    masks = _region_masks(P, Dh).reshape(X.shape)
    ax.pcolormesh(X, Y, masks, cmap="Pastel1", vmin=0, vmax=8, shading="auto", alpha=0.7,
                  rasterized=True)
    # arrows of F[mask] on a coarse grid
    g = np.linspace(-radius, radius, density + 2)[1:-1]
    GX, GY = np.meshgrid(g, g)
    Q = np.stack([GX.ravel(), GY.ravel()], axis=1)
    vec = F[_region_masks(Q, Dh)]
    ax.quiver(Q[:, 0], Q[:, 1], vec[:, 0], vec[:, 1], color="0.35", angles="xy",
              scale_units="xy", scale=np.abs(F).max() * density / radius * 0.9, width=0.004)
    # region labels at the centre of mass of each region
    for mask in range(1 << n):
        sel = masks == mask
        if sel.any():
            cx, cy = X[sel].mean(), Y[sel].mean()
            ax.text(cx, cy, f"mask {format_mask(mask, n)}", fontsize=8, ha="center",
                    va="center", bbox=dict(boxstyle="round", fc="white", alpha=0.8, lw=0))
    _event_lines(ax, Dh, radius * 1.05)
    _draw_trajectories(ax, bd, F, radius, n_trajectories)
    ax.plot([0], [0], "ko", ms=4)
    fig.legend(handles=_field_handles(), fontsize=8, loc="outside lower center", ncols=2)
    ax.set_xlim(-radius, radius)
    ax.set_ylim(-radius, radius)
    ax.set_aspect("equal")
    ax.set_xlabel("$x_0$ (from the event point)")
    ax.set_ylabel("$x_1$")
    ax.set_title(f"corner-limit field at the event point (n={n} events)")
    return fig


def _field_handles():
    """Legend entries of :func:`corner_field`: what its lines and arrows are."""
    from matplotlib.lines import Line2D

    return [Line2D([], [], color="k", ls="--", lw=1.2, label="event surface $h_k = 0$"),
            Line2D([], [], color="#AA3377", lw=1.0, label="trajectories of $x' = F[mask(x)]$"),
            Line2D([], [], color="0.35", marker="$\\rightarrow$", ls="", ms=10,
                   label="field $F[mask]$ of the region")]


def _region_masks(points, Dh):
    """The region mask (m,) of each of the points (m, 2): bit k set where Dh[k] . x > 0."""
    return (((points @ Dh.T) > 0) << np.arange(Dh.shape[0])).sum(axis=1)


def _draw_trajectories(ax, bd, F, radius, n_trajectories):
    """Draw sampled trajectories of ``bd`` (dense corners ``F``) across the box.

    Their virtual start points are spread across F[0], so all cross both surfaces inside
    the box (docs/mathematics.md section 3: piecewise straight, bending at events).
    """
    f0 = F[0] / np.linalg.norm(F[0])
    normal = np.array([-f0[1], f0[0]])
    span = (np.linspace(-0.6, 0.6, n_trajectories) * radius)[:, None] * normal
    times, order = bd.event_times(span)
    for u, t, o in zip(span, times, order, strict=True):
        pts = _sampled_trajectory(F, u, t, o, 2.0 * radius)
        ax.plot(pts[:, 0], pts[:, 1], color="#AA3377", lw=1.0, alpha=0.85)


def _sampled_trajectory(F, u, times, order, length):
    """Corners (j, 2) of the trajectory of ``x' = F[mask(x)]`` through the virtual start u.

    Straight in each region, bending at each event time (docs/mathematics.md section 3); it starts
    ``length`` (in distance) before the first region's end and runs on as far after the
    last event.
    """
    x, B = np.array(u, dtype=float), 0
    pts = [x - length / np.linalg.norm(F[0]) * F[0]]
    for k in order:
        pts.append(x + times[k] * F[B])
        B2 = B | (1 << int(k))
        x = x + times[k] * (F[B] - F[B2])
        B = B2
    t_end = max(times.max(), 0.0) + length / np.linalg.norm(F[B])
    pts.append(x + t_end * F[B])
    return np.array(pts)


def triangulation(bd, axes=None, *, tri=None):
    """The triangulation carried through the flow: pre-event and post-event fans (2-D).

    Left: the simplices of the pre-event fan (vertices ``U[mask]``, docs/mathematics.md section 5);
    right: the same simplices on the post-event vertices ``W[mask]``. A simplex keeps its
    colour, so the picture shows how each cone of one event order is carried by its
    linear piece.

    Parameters
    ----------
    bd : BDerivative or FlowBDerivative
        A map with ``dim == 2`` and Dh of full rank (ignored, may be None, with ``tri``).
    axes : sequence of 2 matplotlib Axes, optional
    tri : Triangulation, optional
        Drawn instead of ``bd.triangulation()`` (for example one loaded from a file).

    Returns
    -------
    matplotlib.figure.Figure

    Examples
    --------
    >>> import numpy as np
    >>> from bderiv import BDerivative, plot
    >>> F = np.array([[1.0, 1.0], [0.4, 1.6], [1.5, 0.5], [0.8, 0.9]])
    >>> fig = plot.triangulation(BDerivative(np.eye(2), F))
    >>> [ax.get_title() for ax in fig.axes]
    ['pre-event fan (4 simplices)', 'post-event fan (4 simplices)']
    """
    from ..analysis.flowmap import FlowBDerivative
    from ..engine.bderivative import BDerivative
    from ..geometry.triangulation import Triangulation

    if tri is None:
        hint = " (pass a Triangulation as tri=)" if isinstance(bd, Triangulation) else ""
        check_type(bd, "bd", (BDerivative, FlowBDerivative), hint=hint)
        _require_2d(bd, "triangulation")
        tri = bd.triangulation()
    elif check_type(tri, "tri", (Triangulation,)).dim != 2:
        raise ValueError(f"triangulation draws 2-D systems only, got dimension {tri.dim}")
    fig, axs = figure_axes(axes, ncols=2, figsize=(10.0, 5.4))  # first: the install hint
    from matplotlib.patches import Polygon

    n = tri.n_events
    n_vertex = tri.pre.shape[0]
    n_order = tri.simplices.shape[0] // 2
    for ax, verts, name in ((axs[0], tri.pre, "pre-event"), (axs[1], tri.post, "post-event")):
        for i, simplex in enumerate(tri.simplices):
            color = PALETTE[(i // 2) % len(PALETTE)]
            hatch = None if i % 2 == 0 else "///"
            ax.add_patch(Polygon(verts[simplex], closed=True, fc=color, ec="k", lw=0.8,
                                 alpha=SIMPLEX_ALPHA, hatch=hatch))
        ax.plot(verts[:, 0], verts[:, 1], "ko", ms=3)
        letter, flow = ("U", "$F_0$") if name == "pre-event" else ("W", "$F_{full}$")
        for v in range(n_vertex):
            label = f"{letter}[{format_mask(v, n)}]"
            if v == 0:
                label += " = 0"
            elif v == n_vertex - 1:
                label = f"$-${flow}"  # the vertex opposite the flow direction
            # -F (the last vertex) labelled on its far side from the fan, the others above
            far = v == n_vertex - 1
            ax.annotate(label, verts[v], textcoords="offset points",
                        xytext=(-6, -6) if far else (6, -12 if v == 0 else 6),
                        ha="right" if far else "left", va="top" if far else "baseline",
                        fontsize=8,
                        bbox=dict(boxstyle="round", fc="white", alpha=0.85, lw=0, pad=0.15))
        _arrow(ax, verts[n_vertex - 1], verts[n_vertex - 2], f"flow direction {flow}")
        ax.set_aspect("equal")
        ax.set_title(f"{name} fan ({2 * n_order} simplices)")
        ax.set_xlabel("$x_0$")
        ax.set_ylabel("$x_1$")
    lim = max(np.abs(tri.pre).max(), np.abs(tri.post).max()) * 1.25  # one scale for both
    for ax in axs:
        ax.set_xlim(-lim, lim)
        ax.set_ylim(-lim, lim)
    fig.legend(handles=_order_handles(tri, n), title="the simplices of each event order",
               fontsize=8, loc="outside lower center", ncols=2)
    fig.suptitle(f"triangulation of the B-derivative M at the event point (n={n}, d=2)\n"
                 f"a simplex keeps its colour from its pre-event vertices U to W = M(U)",
                 fontsize=10)
    return fig


def _arrow(ax, start, end, label, at=0.75, offset=(8, -6), ha="left"):
    ax.annotate("", end, start, arrowprops=dict(arrowstyle="->", color="k", lw=1.2))
    ax.annotate(label, start + at * (end - start), textcoords="offset points",
                xytext=offset, fontsize=8, ha=ha,
                bbox=dict(boxstyle="round", fc="white", alpha=0.8, lw=0))


def _order_handles(tri, n):
    """Legend patches: one colour per event order (the order is read off the chain), and
    what the hatching means (docs/mathematics.md section 5: each order's cone is cut into
    the halves toward +F_0 and -F_0)."""
    from matplotlib.patches import Patch

    handles = []
    for j in range(tri.simplices.shape[0] // 2):
        chain = [0, *tri.simplices[2 * j, 1:n], (1 << n) - 1]
        order = [int(np.log2(b ^ a)) for a, b in zip(chain[:-1], chain[1:], strict=True)]
        handles.append(Patch(fc=PALETTE[j % len(PALETTE)], alpha=SIMPLEX_ALPHA, ec="k",
                             label=f"order {format_order(order)}"))
    return handles + [
        Patch(fc="white", ec="k", label="plain: half toward $+F_0$ (all events past)"),
        Patch(fc="white", ec="k", hatch="///",
              label="hatched: half toward $-F_0$ (the last event ahead)")]


def tangent_circle(bd, ax=None, *, n_vectors=720):
    """A circle of unit pre-event tangent vectors and its image under the map (2-D).

    Both curves are drawn in arcs coloured by their piece (event order): the circle
    dashed, its image solid. The image is a closed curve made of linear images of arcs
    (each piece is linear), kinked on the piece boundaries. Grey arrows join a few ``u``
    to ``M(u)``; the arrows ``F_0`` and ``F_full`` (scaled by ``1/|F_0|``) show
    ``M(F_0) = F_full``.

    Parameters
    ----------
    bd : BDerivative
        A map with ``dim == 2``: a dense table, or a corner model whose dense table
        (``bd.to_dense()``) is built for the two arrows.
    ax : matplotlib Axes, optional
    n_vectors : int
        Vectors on the circle.

    Returns
    -------
    matplotlib.figure.Figure

    Examples
    --------
    >>> import numpy as np
    >>> from bderiv import BDerivative, plot
    >>> F = np.array([[1.0, 1.0], [0.4, 1.6], [1.5, 0.5], [0.8, 0.9]])
    >>> fig = plot.tangent_circle(BDerivative(np.eye(2), F), n_vectors=90)
    >>> print(fig.axes[0].get_title())
    B-derivative M at the event point:
    unit tangent vectors u (dashed) and their images M(u)
    """
    check_bderivative(bd)
    _require_2d(bd, "tangent_circle")
    F = bd.to_dense("the tangent-circle figure").F
    fig, (ax,) = figure_axes(ax, figsize=(5.2, 5.6))
    _, U = _unit_circle(n_vectors)
    W = bd(U)
    _, order = bd.event_times(U)
    uniq, ids = _piece_ids(order)
    for p in range(len(uniq)):
        color = PALETTE[p % len(PALETTE)]
        for arc in _arcs(ids == p):  # each run of the piece, closed over its ends
            ax.plot(U[arc, 0], U[arc, 1], color=color, ls="--", lw=1.2)
            ax.plot(W[arc, 0], W[arc, 1], color=color, ls="-", lw=2.0)
    # a few correspondences u -> M(u)
    for i in range(0, n_vectors, max(1, n_vectors // 12)):
        ax.annotate("", W[i], U[i], arrowprops=dict(arrowstyle="->", color="0.55", lw=0.6))
    # the flow directions: F[0] -> F[full] (M(F_0) = F_full, docs/mathematics.md section 2),
    # each named beside its tip, on the side away from the other
    f0, ff = F[0], F[-1]
    turn = np.sign(f0[0] * ff[1] - f0[1] * ff[0]) or 1.0  # ff left (+1) or right of f0
    for vec, label, side in ((f0, "$F_0$", -turn), (ff, "$F_{full} = M(F_0)$", turn)):
        tip = vec / np.linalg.norm(f0)
        normal = side * np.array([-vec[1], vec[0]]) / np.linalg.norm(vec)
        ax.annotate("", tip, (0.0, 0.0), arrowprops=dict(arrowstyle="-|>", color="k", lw=1.3))
        ax.annotate(label, 0.7 * tip, textcoords="offset points", xytext=12 * normal,
                    fontsize=9, ha="left" if normal[0] > 0 else "right", va="center",
                    bbox=dict(boxstyle="round", fc="white", alpha=0.85, lw=0, pad=0.15))
    lim = 1.06 * max(1.0, np.abs(W).max())
    ax.set_xlim(-lim, lim)
    ax.set_ylim(-lim, lim)
    ax.set_aspect("equal")
    ax.set_xlabel("$x_0$")
    ax.set_ylabel("$x_1$")
    fig.legend(handles=_circle_handles(uniq), fontsize=8, loc="outside lower center",
               ncols=2)
    ax.set_title("B-derivative M at the event point:\nunit tangent vectors u (dashed) and "
                 "their images M(u)", fontsize=10)
    return fig


def _arcs(selected):
    """Index runs (wrapping around) of the True entries of ``selected`` (m,) on a closed
    curve, each extended by one point into the next run so that the arcs meet."""
    m = selected.size
    starts = np.flatnonzero(selected & ~np.roll(selected, 1))
    if starts.size == 0:  # the whole circle is one piece
        return [np.r_[np.arange(m), 0]]
    runs = []
    for s in starts:
        length = 0
        while length < m and selected[(s + length) % m]:
            length += 1
        runs.append(np.arange(s, s + length + 1) % m)
    return runs


def _circle_handles(orders):
    """Legend entries of :func:`tangent_circle`: one per piece, both line styles of its
    colour."""
    from matplotlib.lines import Line2D

    handles = []
    for p, o in enumerate(orders):
        color = PALETTE[p % len(PALETTE)]
        handles += [Line2D([], [], color=color, ls="--", lw=1.2,
                           label=f"order {format_order(o)}: u"),
                    Line2D([], [], color=color, ls="-", lw=2.0,
                           label=f"order {format_order(o)}: M(u)")]
    return handles
