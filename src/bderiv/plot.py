"""Figures of a B-derivative (matplotlib, the optional extra ``plot``).

matplotlib is imported inside each function, so ``import bderiv.plot`` works without it.
Every function returns a ``matplotlib.figure.Figure`` built without pyplot (no global
state, no window); save it with ``fig.savefig("name.png")``. Pass ``ax=`` (or ``axes=``)
to draw into an existing figure instead.

- :func:`corner_field`: 2-D systems, the corner-limit field with the event lines and a
  few sampled trajectories;
- :func:`triangulation`: 2-D systems, the pre-event and post-event fans of simplices;
- :func:`tangent_circle`: 2-D systems, a circle of tangent vectors and its image;
- :func:`pieces`: any n, determinant and gain of the linear pieces;
- :func:`scaling`: time per query against n from a benchmark sweep.
"""

from __future__ import annotations

import math

import numpy as np

_PLOT_HINT = (
    "bderiv's figures need matplotlib: install it with `pip install 'bderiv[plot]'` "
    "(or `pip install matplotlib`)"
)

#: a qualitative palette indexed by piece (event order) number
_PALETTE = (
    "#4477AA", "#EE6677", "#228833", "#CCBB44", "#66CCEE", "#AA3377", "#BBBBBB", "#000000",
)


#: legend labels of the methods of ``bderiv bench``
_METHOD_LABELS = {
    "bderiv": "bderiv",
    "numpy": "batched NumPy baseline",
    "blas": "BLAS matrix product, same flops",
}


def _figure(ax, ncols=1, figsize=(5.5, 5.0)):
    """(figure, list of axes): the caller's axes, or a new pyplot-free figure."""
    try:
        from matplotlib.figure import Figure
    except ImportError as exc:  # pragma: no cover - exercised without matplotlib only
        raise ImportError(_PLOT_HINT) from exc
    if ax is not None:
        axes = list(np.atleast_1d(ax))
        if len(axes) != ncols:
            raise ValueError(f"this figure needs {ncols} axes, got {len(axes)}")
        return axes[0].figure, axes
    fig = Figure(figsize=figsize, layout="constrained")
    axes = fig.subplots(1, ncols, squeeze=False)[0]
    return fig, list(axes)


def _require_2d(bd, what):
    if bd.dim != 2:
        raise ValueError(
            f"{what} draws 2-D systems only, but this map has dimension d={bd.dim}; use "
            f"pieces() for any dimension"
        )


def _order_label(order) -> str:
    return "(" + ",".join(str(int(k)) for k in order) + ")"


def _mask_label(mask: int, n: int) -> str:
    return format(int(mask), f"0{n}b")


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
        A map with ``dim == 2``.
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
    'corner-limit field (n=2 events)'
    """
    _require_2d(bd, "corner_field")
    fig, (ax,) = _figure(ax)
    n, Dh, F = bd.n_events, bd.Dh, bd.F
    # shaded regions
    s = np.linspace(-radius, radius, 301)
    X, Y = np.meshgrid(s, s)
    P = np.stack([X.ravel(), Y.ravel()], axis=1)
    masks = (((P @ Dh.T) > 0) << np.arange(n)).sum(axis=1).reshape(X.shape)
    ax.pcolormesh(X, Y, masks, cmap="Pastel1", vmin=0, vmax=8, shading="auto", alpha=0.7,
                  rasterized=True)
    # arrows of F[mask] on a coarse grid
    g = np.linspace(-radius, radius, density + 2)[1:-1]
    GX, GY = np.meshgrid(g, g)
    Q = np.stack([GX.ravel(), GY.ravel()], axis=1)
    qm = (((Q @ Dh.T) > 0) << np.arange(n)).sum(axis=1)
    vec = F[qm]
    ax.quiver(Q[:, 0], Q[:, 1], vec[:, 0], vec[:, 1], color="0.35", angles="xy",
              scale_units="xy", scale=np.abs(F).max() * density / radius * 0.9, width=0.004)
    # region labels at the centre of mass of each region
    for mask in range(1 << n):
        sel = masks == mask
        if sel.any():
            cx, cy = X[sel].mean(), Y[sel].mean()
            ax.text(cx, cy, f"mask {_mask_label(mask, n)}", fontsize=8, ha="center",
                    va="center", bbox=dict(boxstyle="round", fc="white", alpha=0.8, lw=0))
    _event_lines(ax, Dh, radius * 1.05)
    # sampled trajectories: virtual start points spread across F[0], all crossing both
    # surfaces inside the box (MATH.md section 3: piecewise straight, bending at events)
    f0 = F[0] / np.linalg.norm(F[0])
    normal = np.array([-f0[1], f0[0]])
    span = (np.linspace(-0.6, 0.6, n_trajectories) * radius)[:, None] * normal
    times, order = bd.event_times(span)
    for u, t, o in zip(span, times, order, strict=True):
        pts, x, B = [], u.copy(), 0
        t_lo = -2.0 * radius / np.linalg.norm(F[0])
        pts.append(x + t_lo * F[B])
        for k in o:
            tk = t[k]
            pts.append(x + tk * F[B])
            B2 = B | (1 << int(k))
            x = x + tk * (F[B] - F[B2])
            B = B2
        t_hi = max(t.max(), 0.0) + 2.0 * radius / np.linalg.norm(F[B])
        pts.append(x + t_hi * F[B])
        pts = np.array(pts)
        ax.plot(pts[:, 0], pts[:, 1], color="#AA3377", lw=1.0, alpha=0.85)
    ax.plot([0], [0], "ko", ms=4)
    ax.set_xlim(-radius, radius)
    ax.set_ylim(-radius, radius)
    ax.set_aspect("equal")
    ax.set_xlabel("$x_0$ (from the event point)")
    ax.set_ylabel("$x_1$")
    ax.set_title(f"corner-limit field (n={n} events)")
    return fig


def triangulation(bd, axes=None, *, tri=None):
    """The triangulation carried through the flow: pre-event and post-event fans (2-D).

    Left: the simplices of the pre-event fan (vertices ``U[mask]``, MATH.md section 5);
    right: the same simplices on the post-event vertices ``W[mask]``. A simplex keeps its
    colour, so the picture shows how each cone of one event order is carried by its
    linear piece.

    Parameters
    ----------
    bd : BDerivative
        A map with ``dim == 2`` and Dh of full rank.
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
    if tri is None:
        _require_2d(bd, "triangulation")
        tri = bd.triangulation()
    elif tri.dim != 2:
        raise ValueError(f"triangulation draws 2-D systems only, got dimension {tri.dim}")
    from matplotlib.patches import Polygon

    fig, axs = _figure(axes, ncols=2, figsize=(10.0, 4.8))
    n = tri.n_events
    n_vertex = tri.pre.shape[0]
    n_order = tri.simplices.shape[0] // 2
    for ax, verts, name in ((axs[0], tri.pre, "pre-event"), (axs[1], tri.post, "post-event")):
        for i, simplex in enumerate(tri.simplices):
            color = _PALETTE[(i // 2) % len(_PALETTE)]
            hatch = None if i % 2 == 0 else "///"
            ax.add_patch(Polygon(verts[simplex], closed=True, fc=color, ec="k", lw=0.8,
                                 alpha=0.45, hatch=hatch))
        ax.plot(verts[:, 0], verts[:, 1], "ko", ms=3)
        letter, flow = ("U", "$F_0$") if name == "pre-event" else ("W", "$F_{full}$")
        for v in range(n_vertex):
            label = f"$-${flow}" if v == n_vertex - 1 else f"{letter}[{_mask_label(v, n)}]"
            if v == 0:
                label = f"{letter}[{_mask_label(0, n)}] = 0"
            ax.annotate(label, verts[v], textcoords="offset points", xytext=(5, -12 if v == 0
                        else 4), fontsize=8)
        _arrow(ax, verts[n_vertex - 1], verts[n_vertex - 2], f"flow direction {flow}")
        lim = np.abs(verts).max() * 1.25
        ax.set_xlim(-lim, lim)
        ax.set_ylim(-lim, lim)
        ax.set_aspect("equal")
        ax.set_title(f"{name} fan ({2 * n_order} simplices)")
        ax.set_xlabel("$x_0$")
    axs[0].set_ylabel("$x_1$")
    handles = _order_handles(tri, n)
    axs[1].legend(handles=handles, title="event order", fontsize=8, loc="lower right")
    return fig


def _arrow(ax, start, end, label, at=0.75, offset=(8, -6), ha="left"):
    ax.annotate("", end, start, arrowprops=dict(arrowstyle="->", color="k", lw=1.2))
    ax.annotate(label, start + at * (end - start), textcoords="offset points",
                xytext=offset, fontsize=8, ha=ha,
                bbox=dict(boxstyle="round", fc="white", alpha=0.8, lw=0))


def _order_handles(tri, n):
    """Legend patches: one colour per event order (the order is read off the chain)."""
    from matplotlib.patches import Patch

    handles = [Patch(fc="white", ec="k", hatch="///", label="half toward $-F$")]
    for j in range(tri.simplices.shape[0] // 2):
        chain = [0, *tri.simplices[2 * j, 1:n], (1 << n) - 1]
        order = [int(np.log2(b ^ a)) for a, b in zip(chain[:-1], chain[1:], strict=True)]
        handles.append(Patch(fc=_PALETTE[j % len(_PALETTE)], alpha=0.45, ec="k",
                             label=_order_label(order)))
    return handles


def tangent_circle(bd, ax=None, *, n_vectors=720):
    """A circle of unit pre-event tangent vectors and its image under the map (2-D).

    Points are coloured by their piece (event order); the image is a closed curve made of
    linear images of arcs (each piece is linear), kinked on the piece boundaries. The
    arrows ``F_0`` and ``F_full`` (scaled by ``1/|F_0|``) show ``M(F_0) = F_full``.

    Parameters
    ----------
    bd : BDerivative
        A map with ``dim == 2``.
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
    >>> fig.savefig(__import__("io").BytesIO(), format="png")
    """
    _require_2d(bd, "tangent_circle")
    fig, (ax,) = _figure(ax)
    _, U = _unit_circle(n_vectors)
    W = bd(U)
    _, order = bd.event_times(U)
    uniq, ids = _piece_ids(order)
    ax.plot(np.r_[U[:, 0], U[0, 0]], np.r_[U[:, 1], U[0, 1]], color="0.6", ls="--", lw=1,
            label="unit circle $u$")
    ax.plot(np.r_[W[:, 0], W[0, 0]], np.r_[W[:, 1], W[0, 1]], color="k", lw=0.8,
            label="image $M(u)$", zorder=1)
    for p, o in enumerate(uniq):
        sel = ids == p
        color = _PALETTE[p % len(_PALETTE)]
        ax.scatter(U[sel, 0], U[sel, 1], s=4, color=color, zorder=2)
        ax.scatter(W[sel, 0], W[sel, 1], s=7, color=color, label=f"order {_order_label(o)}",
                   zorder=3)
    # a few correspondences u -> M(u)
    for i in range(0, n_vectors, max(1, n_vectors // 12)):
        ax.annotate("", W[i], U[i], arrowprops=dict(arrowstyle="->", color="0.5", lw=0.6))
    # the flow directions: F[0] -> F[full] (M(F_0) = F_full, MATH.md section 2)
    f0, ff = bd.F[0], bd.F[-1]
    for vec, color, label in ((f0, "#117733", "$F_0$ (flow before)"),
                              (ff, "#882255", "$M(F_0) = F_{full}$ (flow after)")):
        tip = vec / np.linalg.norm(f0)
        ax.annotate("", tip, (0.0, 0.0), arrowprops=dict(arrowstyle="-|>", color=color, lw=1.5))
        ax.plot([], [], color=color, lw=1.5, label=label)
    lim = 1.2 * max(1.0, np.abs(W).max())
    ax.set_xlim(-lim, lim)
    ax.set_ylim(-lim, lim)
    ax.set_aspect("equal")
    ax.legend(fontsize=8, loc="upper left", markerscale=2)
    ax.set_title("tangent vectors and their images")
    return fig


def pieces(bd, axes=None, *, max_pieces=24, n_samples=4000, seed=0):
    """Determinant and gain (largest singular value) of the linear pieces, any n.

    With ``n! <= max_pieces`` every piece is shown; otherwise the distinct pieces met by
    ``n_samples`` random unit vectors (at most ``max_pieces`` of the most frequent ones).
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
    if total <= max_pieces:
        orders = [o for o, _ in bd.pieces(max_pieces=max_pieces)]
        subtitle = f"all {total} pieces"
    else:
        rng = np.random.default_rng(seed)
        V = rng.standard_normal((n_samples, bd.dim))
        _, order = bd.event_times(V)
        uniq, counts = np.unique(order, axis=0, return_counts=True)
        keep = np.argsort(-counts, kind="stable")[:max_pieces]
        orders = list(uniq[keep])
        subtitle = (
            f"{len(orders)} most visited of {len(uniq)} pieces met by {n_samples} random "
            f"vectors ({n}! = {total:,} in all)"
        )
    mats = [bd.piece(o) for o in orders]
    dets = np.array([np.linalg.det(M) for M in mats])
    gains = np.array([np.linalg.norm(M, 2) for M in mats])
    fig, axs = _figure(axes, ncols=2, figsize=(max(8.0, 0.35 * len(orders) + 4), 4.2))
    x = np.arange(len(orders))
    labels = [_order_label(o) for o in orders]
    many = n > 6  # labels and per-piece colours stop being readable
    colors = ["#4477AA" if many else _PALETTE[i % len(_PALETTE)] for i in range(len(orders))]
    gain = "gain $\\|M_\\sigma\\|_2$"
    for ax, values, name in ((axs[0], dets, "determinant"), (axs[1], gains, gain)):
        ax.bar(x, values, color=colors, ec="k", lw=0.5)
        ax.axhline(1.0, color="0.4", lw=0.8, ls=":")
        ax.set_ylabel(name)
        ax.set_xticks(x, [""] * len(x) if many else labels, rotation=90 if n > 3 else 0,
                      fontsize=8)
        ax.set_xlabel("piece, most visited first" if many else "event order")
        if values.max() / max(values.min(), 1e-300) > 30:
            ax.set_yscale("log")
    axs[0].set_title("det $M_\\sigma$ (> 0: orientation kept)")
    axs[1].set_title("largest singular value")
    fig.suptitle(f"linear pieces of the B-derivative (n={n}, d={bd.dim}): {subtitle}",
                 fontsize=10)
    return fig


def scaling(rows, ax=None, *, batch=None):
    """Time per query against the number of events n, log-log (a benchmark sweep).

    Parameters
    ----------
    rows : sequence of dict
        Each with keys ``n``, ``method`` and ``seconds_per_query`` (optionally ``d``
        and ``m``, the batch size), as produced by ``bderiv bench --json``.
    ax : matplotlib Axes, optional
    batch : int, optional
        Keep only rows with this batch size ``m``.

    Returns
    -------
    matplotlib.figure.Figure

    Examples
    --------
    >>> from bderiv import plot
    >>> rows = [{"n": n, "method": "bderiv", "seconds_per_query": 1e-8 * n * n}
    ...         for n in (2, 4, 8)]
    >>> plot.scaling(rows).axes[0].get_xscale()
    'log'
    """
    rows = [r for r in rows if batch is None or r.get("m") == batch]
    if not rows:
        raise ValueError("no benchmark rows to plot")
    fig, (ax,) = _figure(ax, figsize=(6.0, 4.5))
    methods = list(dict.fromkeys(r["method"] for r in rows))
    markers = "osD^v<>"
    for i, method in enumerate(methods):
        sel = sorted((r for r in rows if r["method"] == method), key=lambda r: r["n"])
        n = np.array([r["n"] for r in sel], dtype=float)
        t = np.array([r["seconds_per_query"] for r in sel], dtype=float)
        ax.loglog(n, t * 1e9, marker=markers[i % len(markers)],
                  label=_METHOD_LABELS.get(method, method),
                  color=_PALETTE[i % len(_PALETTE)])
    ns = sorted({r["n"] for r in rows})
    ax.set_xticks(ns, [str(v) for v in ns])
    ax.minorticks_off()
    ax.set_xlabel("number of simultaneous events n")
    ax.set_ylabel("time per query (ns)")
    ax.grid(True, which="major", alpha=0.3)
    ax.legend(fontsize=9)
    ax.set_title("evaluation time per tangent vector")
    return fig
