"""Figures build with the Agg backend (matplotlib, the extra ``plot``)."""

from __future__ import annotations

import io
import re

import numpy as np
import pytest

from bderiv import BDerivative, CornerFunction, StructuredCorners, plot
from bderiv._support._format import format_order
from bderiv.examples import planar_table, three_event_table

matplotlib = pytest.importorskip("matplotlib")


@pytest.fixture(autouse=True)
def agg_backend():
    matplotlib.use("Agg")


@pytest.fixture(scope="module")
def planar():
    return BDerivative(*planar_table())


def png_bytes(fig):
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=40)
    data = buf.getvalue()
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    return data


def test_corner_field(planar):
    fig = plot.corner_field(planar)
    ax = fig.axes[0]
    assert ax.get_title() == "corner-limit field at the event point (n=2 events)"
    (legend,) = fig.legends  # the lines and arrows say what they are
    assert len(legend.get_texts()) == 3
    assert "mask 0b01" in [t.get_text() for t in ax.texts]
    # 2 event lines and the sampled trajectories are drawn
    assert len(ax.lines) >= 2 + 7
    png_bytes(fig)


def test_triangulation(planar, tmp_path):
    fig = plot.triangulation(planar)
    left, right = fig.axes[:2]
    assert len(left.patches) == len(right.patches) == 4  # 2 * 2! simplices
    assert "pre-event" in left.get_title() and "post-event" in right.get_title()
    assert "B-derivative M at the event point" in fig.get_suptitle()
    assert "U[0b01]" in [t.get_text() for t in left.texts]
    assert "$-$$F_0$" in [t.get_text() for t in left.texts]  # the vertex -F[0], with its sign
    # one scale and both axes labelled, so the two fans compare by eye
    assert left.get_xlim() == right.get_xlim() and left.get_ylim() == right.get_ylim()
    assert left.get_ylabel() == right.get_ylabel() == "$x_1$"
    assert fig.legends and not left.get_legend() and not right.get_legend()
    png_bytes(fig)
    tri = planar.triangulation()
    path = tri.save(tmp_path / "tri.json")
    from bderiv import load_triangulation

    fig2 = plot.triangulation(None, tri=load_triangulation(path))
    png_bytes(fig2)


def _style(artist):
    """What a reader tells lines apart by: colour, line style, width, marker."""
    from matplotlib.colors import to_hex

    return (to_hex(artist.get_color()), artist.get_linestyle(), artist.get_linewidth(),
            artist.get_marker())


def test_tangent_circle(planar):
    """The curves are drawn as the legend shows them: the circle dashed and its image
    solid, each arc in its piece's colour; the points of an arc have the event order of
    its legend entry and its image is the reference map of them (tests/reference.py)."""
    from reference import ref_apply, ref_event_times

    Dh, F = planar_table()
    fig = plot.tangent_circle(planar, n_vectors=90)
    ax = fig.axes[0]
    (legend,) = fig.legends
    drawn = [ln for ln in ax.lines if len(ln.get_xdata())]
    handles = {_style(h): h.get_label() for h in legend.legend_handles}
    assert set(handles) == {_style(ln) for ln in drawn}  # no style unexplained, none unused
    assert sorted(handles.values()) == ["order (0,1): M(u)", "order (0,1): u",
                                        "order (1,0): M(u)", "order (1,0): u"]
    for dashed, solid in zip(drawn[::2], drawn[1::2], strict=True):
        label = handles[_style(dashed)]
        assert label.endswith(": u") and handles[_style(solid)] == label[:-1] + "M(u)"
        U = dashed.get_xydata()
        np.testing.assert_allclose(np.hypot(*U.T), 1.0, rtol=1e-12)
        np.testing.assert_allclose(solid.get_xydata(), [ref_apply(Dh, F, u) for u in U],
                                   rtol=1e-12, atol=1e-12)
        # the ends are shared with the next arc
        orders = {format_order(ref_event_times(Dh, F, u)[1]) for u in U[1:-1]}
        assert orders == {label.split()[1][:-1]}
    # the axes fill the figure (no empty band beside a square plot), the legend below them
    fig.canvas.draw()
    box = ax.get_position()
    assert box.width > 0.7 and box.height > 0.65
    assert legend.get_window_extent().y1 < ax.get_window_extent().y0
    assert "B-derivative M at the event point" in ax.get_title()
    assert [t.get_text() for t in ax.texts if t.get_text()] == ["$F_0$", "$F_{full} = M(F_0)$"]
    png_bytes(fig)


def _bars(ax):
    """Heights, tick labels and face colours of the bars of ``ax``."""
    from matplotlib.colors import to_hex

    bars = ax.patches
    labels = [t.get_text() for t in ax.get_xticklabels()]
    return ([b.get_height() for b in bars], labels,
            {to_hex(b.get_facecolor(), keep_alpha=False) for b in bars})


def test_pieces_one_bar_per_distinct_value():
    """Corners whose rates change only at their own event (F[B, k] = a_k before event k,
    b_k after) give every order the same det, prod b_k / a_k (the saltation determinant
    lemma), while the free component d = n + 1 makes the gains differ: the det panel has
    one bar saying so, the gain panel one bar per distinct gain, all in one colour."""
    from reference import all_orders, ref_piece

    n, a, b = 3, np.array([1.0, 2.0, 1.5]), np.array([2.0, 1.0, 3.0])
    masks = np.arange(1 << n)
    happened = (masks[:, None] >> np.arange(n)) & 1
    free = np.random.default_rng(5).uniform(-1.0, 1.0, (1 << n, 1))
    F = np.hstack([np.where(happened, b, a), free])
    Dh = np.hstack([np.eye(n), np.zeros((n, 1))])
    fig = plot.pieces(BDerivative(Dh, F))
    heights, labels, colors = _bars(fig.axes[0])
    np.testing.assert_allclose(heights, [np.prod(b / a)], rtol=1e-12)  # = 2
    assert labels == ["all 6 pieces"] and len(colors) == 1
    assert [t.get_text() for t in fig.axes[0].texts] == ["2"]  # the value, on the bar
    gains = [np.linalg.norm(ref_piece(Dh, F, o), 2) for o in all_orders(n)]
    distinct = sorted({round(g, 9) for g in gains})
    heights, labels, gain_colors = _bars(fig.axes[1])
    assert len(heights) == len(distinct) and gain_colors == colors
    np.testing.assert_allclose(sorted(heights), distinct, rtol=1e-8)
    assert "orientation kept" in fig.axes[0].get_title()


def test_pieces_of_singular_resets_say_so():
    """A reset that stops a velocity (R = I - e_0 e_0^T) makes every piece singular: the
    determinant is 0, written on its bar, and the title says why instead of '> 0'."""
    from reference import ref_reset_piece

    Dh = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    F = np.array([[1.0, 1.0, 0.5], [2.0, 1.2, 0.1], [1.1, 2.0, 0.3], [2.2, 2.1, -0.4]])
    stop = np.diag([1.0, 1.0, 0.0])
    R = np.broadcast_to(stop, (4, 2, 3, 3)).copy()
    bd = BDerivative(Dh, F, resets=R)
    fig = plot.pieces(bd)
    heights, labels, _ = _bars(fig.axes[0])
    assert heights == [0.0] and labels == ["all 2 pieces"]
    assert [np.linalg.det(ref_reset_piece(Dh, F, R, o)) for o in ([0, 1], [1, 0])] == [0, 0]
    assert "every piece singular" in fig.axes[0].get_title()
    assert "> 0" not in fig.axes[0].get_title()
    png_bytes(fig)


def test_pieces_all_and_sampled():
    from reference import all_orders, ref_det

    fig = plot.pieces(BDerivative(*three_event_table()))
    dets = [ref_det(*three_event_table(), o) for o in all_orders(3)]  # 3! pieces ...
    assert len(set(np.round(dets, 9))) == 3  # ... with 3 determinants: 3 bars
    np.testing.assert_allclose(sorted(p.get_height() for p in fig.axes[0].patches),
                               sorted(set(np.round(dets, 9))), rtol=1e-8)
    # the dotted line at 1 says what it is (in the titles: no legend over the bars)
    assert fig.axes[0].get_title().endswith("dotted: det = 1, volume kept")
    assert fig.axes[1].get_title().endswith("dotted: gain = 1, no vector stretched")
    assert fig.axes[0].get_legend() is None
    assert "B-derivative M at the event point" in fig.get_suptitle()
    png_bytes(fig)
    rng = np.random.default_rng(3)
    F = rng.uniform(0.5, 1.5, (32, 5))  # n = 5: 120 pieces, too many to show all
    fig = plot.pieces(BDerivative(np.eye(5), F), max_pieces=10, n_samples=500)
    assert len(fig.axes[0].patches) == 10
    assert "the 10 most visited of" in fig.get_suptitle()
    png_bytes(fig)
    # n = 9: 362,880 pieces, each met about once; the first ones met, said so
    F = rng.uniform(0.5, 1.5, (512, 9))
    fig = plot.pieces(BDerivative(np.eye(9), F), max_pieces=8, n_samples=300, seed=1)
    assert "the 8 first met of" in fig.get_suptitle() and "most visited" not in (
        fig.get_suptitle() + fig.axes[0].get_xlabel())
    V = np.random.default_rng(1).standard_normal((300, 9))
    _, order = BDerivative(np.eye(9), F).event_times(V)
    first = [tuple(o) for o in order]
    shown = [tuple(first[i]) for i in sorted({first.index(t) for t in first})[:8]]
    dets = [p.get_height() for p in fig.axes[0].patches]
    np.testing.assert_allclose(dets, [np.linalg.det(BDerivative(np.eye(9), F).piece(o))
                                      for o in shown])


def test_scaling():
    rows = [
        {"n": n, "d": n, "m": 10, "method": m, "seconds_per_query": s * n}
        for n in (2, 4, 8)
        for m, s in (("bderiv", 1e-8), ("numpy", 1e-7))
    ]
    fig = plot.scaling(rows)
    ax = fig.axes[0]
    assert len(ax.lines) == 2
    bderiv_line = ax.lines[0]
    assert bderiv_line.get_label() == "bderiv"
    np.testing.assert_allclose(bderiv_line.get_ydata(), [20.0, 40.0, 80.0])  # ns
    assert ax.get_title().splitlines() == [
        "B-derivative at the event point: time per tangent vector", "d = n, batch m = 10"]
    png_bytes(fig)
    # where it was measured: small print under the axes, not in the title, without the
    # environment variables that are unset
    machine = ("CPU X (2 CPUs), numba threads 2, BLAS b 0.3; NUMBA_NUM_THREADS unset, "
               "OMP_NUM_THREADS unset, OPENBLAS_NUM_THREADS 1")
    fig = plot.scaling(rows, machine=machine)
    assert fig.axes[0].get_title() == ax.get_title()
    assert fig.get_supxlabel() == ("measured on CPU X (2 CPUs), numba threads 2, BLAS b "
                                   "0.3; OPENBLAS_NUM_THREADS 1")
    with pytest.raises(ValueError, match="no benchmark rows to plot with batch m = 5"):
        plot.scaling(rows, batch=5)


@pytest.mark.parametrize("ns_per_query", [(0.3, 0.5, 2.0), (12.0, 15.0, 30.0)])
def test_scaling_labels_a_decade_on_each_side_of_the_points(ns_per_query):
    """Below 10^0 too: the y axis runs between whole decades, each labelled, so every point
    lies between two labelled ticks (one decade of data still gets two labels)."""
    rows = [{"n": n, "d": n, "m": 10, "method": "bderiv", "seconds_per_query": 1e-9 * t}
            for n, t in zip((2, 4, 8), ns_per_query, strict=True)]
    fig = plot.scaling(rows)
    fig.canvas.draw()
    ax = fig.axes[0]
    lo, hi = ax.get_ylim()
    labelled = [(tick, label.get_text()) for tick, label in
                zip(ax.get_yticks(), ax.get_yticklabels(), strict=True)
                if lo * (1 - 1e-9) <= tick <= hi * (1 + 1e-9) and label.get_text()]
    ticks = [t for t, _ in labelled]
    assert min(ticks) <= min(ns_per_query) and max(ticks) >= max(ns_per_query)
    assert len(ticks) >= 2
    assert [label for _, label in labelled] == [
        f"$\\mathdefault{{10^{{{int(np.log10(t))}}}}}$" for t in ticks]


def test_scaling_keeps_the_largest_batch_of_each_point():
    """The suite's rows: several batches per n; each point is drawn from the largest."""
    batches = {2: ((1, 5e-6), (10**6, 5e-8), (10**3, 7e-8)), 4: ((10**3, 9e-8), (1, 6e-6))}
    rows = [
        {"n": n, "d": 2 * n, "m": m, "method": "bderiv apply", "seconds_per_query": t}
        for n, measured in batches.items()
        for m, t in measured
    ]
    ax = plot.scaling(rows).axes[0]
    np.testing.assert_allclose(ax.lines[0].get_ydata(), [50.0, 90.0])
    assert ax.get_title().splitlines()[1] == "d = 2 n, largest batch measured, m up to 1,000,000"
    ax = plot.scaling(rows, batch=1).axes[0]
    np.testing.assert_allclose(ax.lines[0].get_ydata(), [5000.0, 6000.0])
    assert ax.get_title().splitlines()[1] == "d = 2 n, batch m = 1"


def test_scaling_refuses_two_dimensions_per_n():
    rows = [{"n": 2, "d": d, "m": 10, "method": "bderiv", "seconds_per_query": 1e-7}
            for d in (2, 4)]
    with pytest.raises(ValueError, match=r"rows mix sweeps: rows\[1\] has d = 4 at n = 2, "
                                         r"rows\[0\] has d = 2; keep one dimension d per n"):
        plot.scaling(rows)


def test_into_existing_axes(planar):
    from matplotlib.figure import Figure

    fig = Figure()
    axs = fig.subplots(1, 2)
    assert plot.pieces(planar, axes=axs) is fig
    with pytest.raises(ValueError, match="needs 2 axes, got 1"):
        plot.triangulation(planar, axes=[axs[0]])


def test_2d_only():
    bd = BDerivative(*three_event_table())
    for fn in (plot.corner_field, plot.triangulation, plot.tangent_circle):
        with pytest.raises(ValueError, match="2-D systems only.*d=3"):
            fn(bd)


# the corner models of a 2-D system with additive corners F[mask] = F0 + sum_{k in mask} A[k]
CORNER_DH = np.array([[1.0, 0.3], [-0.2, 1.0]])
CORNER_F0 = np.array([1.0, 0.9])
CORNER_A = np.array([[0.6, -0.3], [-0.4, 0.5]])


def _additive_table():
    """The same corners as a dense table, written out by hand (rows 00, 01, 10, 11)."""
    F0, (A0, A1) = CORNER_F0, CORNER_A
    return np.array([F0, F0 + A0, F0 + A1, F0 + A0 + A1])


def _corner_function():
    import numba

    A, F0 = CORNER_A, CORNER_F0

    @numba.njit
    def field(happened, out):
        for j in range(2):
            out[j] = F0[j] + happened[0] * A[0, j] + happened[1] * A[1, j]

    return CornerFunction(field)


def _drawn(fig):
    """Everything a figure's first axes draws, as arrays and strings (for comparison)."""
    ax = fig.axes[0]
    out = [line.get_xydata() for line in ax.lines]
    for coll in ax.collections:
        out.append(np.asarray(coll.get_offsets()))
        if hasattr(coll, "U"):  # quiver arrows
            out += [np.asarray(coll.U), np.asarray(coll.V)]
    # text positions and, for annotations, the point the arrow points at
    out.append(np.array([(*t.get_position(), *getattr(t, "xy", (np.nan, np.nan)))
                         for t in ax.texts]))
    return out, [t.get_text() for t in ax.texts]


@pytest.mark.parametrize("model", ["structured", "function"])
@pytest.mark.parametrize("figure", ["corner_field", "tangent_circle"])
def test_2d_figures_of_corner_models(model, figure):
    """A corner model's figure is the figure of its dense table (bd.F is None for it)."""
    corners = (StructuredCorners(CORNER_F0, CORNER_A) if model == "structured"
               else _corner_function())
    bd = BDerivative(CORNER_DH, corners)
    assert bd.F is None
    draw = getattr(plot, figure)
    got_arrays, got_texts = _drawn(draw(bd))
    want_arrays, want_texts = _drawn(draw(BDerivative(CORNER_DH, _additive_table())))
    assert got_texts == want_texts
    assert len(got_arrays) == len(want_arrays)
    for got, want in zip(got_arrays, want_arrays, strict=True):
        np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-12)


# -- the carried fan (the source note's picture) ------------------------------------------


def test_carried_fan(planar):
    """Right panel: the standard fan in impact-time coordinates, translated by -s (closed
    form); left panel: the pre-event simplices before the events, the post-event after."""
    from reference import ref_corner_points

    snapshots = (-2.0, 0.0, 2.0)
    fig = plot.carried_fan(planar, snapshots=snapshots)
    left, right = fig.axes[:2]
    tri = planar.triangulation()
    assert len(left.patches) == len(right.patches) == len(tri.simplices) * len(snapshots)
    # impact times of the vertices: -1 for the events of the mask, 0 for the others; the
    # extra vertex -F[0] meets both events one time unit later
    tau = np.array([[-(S >> k & 1) for k in range(2)] for S in range(4)] + [[1, 1]], float)
    U, W = ref_corner_points(*planar_table())
    F = planar_table()[1]
    pre = np.vstack([U, -F[0]])
    post = np.vstack([W, -F[3]])
    edge = _edge_points()
    for i, simplex in enumerate(tri.simplices):
        for j, s in enumerate(snapshots):
            corners = np.asarray(right.patches[i * len(snapshots) + j].get_xy())[::edge][:3]
            np.testing.assert_allclose(corners, tau[simplex] - s, atol=1e-12)
            state = np.asarray(left.patches[i * len(snapshots) + j].get_xy())[::edge][:3]
            if s < -1:  # every point before both events: the pre simplex moved along F[0]
                np.testing.assert_allclose(state, pre[simplex] + s * F[0], atol=1e-12)
            if s > 1:  # after both: the post simplex moved along F[full]
                np.testing.assert_allclose(state, post[simplex] + s * F[3], atol=1e-12)
    assert "impact-time" in right.get_title() and "state" in left.get_title()
    png_bytes(fig)


def _edge_points():
    from bderiv.plot._carried_fan import EDGE_POINTS

    return EDGE_POINTS


def test_simplices_and_hatching_say_what_they_are(planar):
    """The regions under the simplices are greys (no hue shared with a simplex's colour);
    the legend names each order's colour and the hatching: the hatched simplex of an order
    is its half with the vertex -F[0] (docs/mathematics.md section 5), the plain one has
    F[0] = U[full]; the super-title is a title and a line of detail."""
    from matplotlib.colors import to_rgb

    F = planar_table()[1]
    fig = plot.carried_fan(planar, snapshots=(-2.0,))
    left = fig.axes[0]
    (mesh,) = left.collections
    greys = np.array([to_rgb(c) for c in mesh.get_cmap()(np.linspace(0, 1, 4))])
    assert np.ptp(greys, axis=1).max() == 0  # R = G = B
    tri = planar.triangulation()
    fig2 = plot.triangulation(planar)
    pre = fig2.axes[0]
    for i, patch in enumerate(pre.patches):
        corners = patch.get_xy()[:3]
        hatched = bool(patch.get_hatch())
        assert hatched == (i % 2 == 1)
        far = -F[0] if hatched else F[0]
        assert np.isclose(corners, far, atol=1e-12).all(axis=1).any()
        assert np.ptp(to_rgb(patch.get_facecolor())) > 0.2  # a hue, not a grey
    for f in (fig, fig2):
        (legend,) = f.legends
        labels = [t.get_text() for t in legend.get_texts()]
        assert labels == ["order (0,1)", "order (1,0)",
                          "plain: half toward $+F_0$ (all events past)",
                          "hatched: half toward $-F_0$ (the last event ahead)"]
        hatches = [h.get_hatch() for h in legend.legend_handles]
        assert hatches == [None, None, None, "///"]
    assert len(fig.get_suptitle().splitlines()) == 2
    assert len(tri.simplices) == len(pre.patches)


def test_carried_fan_flow_matches_a_simulation(planar):
    """The positions of the carried points are those of the corner-limit flow, checked by
    small Euler steps of x' = F[mask(x)] (exact inside a region, O(h) at a crossing)."""
    from bderiv.plot._carried_fan import _flow

    Dh, F = planar_table()
    U = np.random.default_rng(4).uniform(-1.5, 1.5, (40, 2))
    times, _ = planar.event_times(U)
    start, h = -4.0, 1e-4
    x = U + start * F[0]  # long before the events, every point is in region 0
    assert ((x @ Dh.T) < 0).all()
    for s in (-1.0, 0.0, 0.5, 1.5):
        steps = int(round((s - start) / h))
        for _ in range(steps):
            mask = (((x @ Dh.T) > 0) << np.arange(2)).sum(axis=1)
            x = x + h * F[mask]
        start = s
        np.testing.assert_allclose(_flow(F, U, times, s), x, atol=20 * h)


def test_carried_fan_refuses():
    with pytest.raises(ValueError, match="2 events in the plane.*n_events=3, dim=3"):
        plot.carried_fan(BDerivative(*three_event_table()))
    with pytest.raises(ValueError, match="snapshots must be a non-empty sequence of finite"):
        plot.carried_fan(BDerivative(*planar_table()), snapshots=[np.nan])


# -- the wrong object: a TypeError naming the parameter, before any drawing ----------------


def _wrong_result(param):
    """An object of the package that is not what ``param`` takes (another result)."""
    if param == "bd":
        return BDerivative(*planar_table()).triangulation()
    return BDerivative(*planar_table())


def _stub(cls_path):
    """An instance of a result class without its data: enough for a type check, which
    comes before any use (a figure that reached the data would fail otherwise)."""
    import importlib

    module, name = cls_path.rsplit(".", 1)
    cls = getattr(importlib.import_module(module), name)
    return cls.__new__(cls)


# (figure, how it is called with the wrong object w, the parameter, what it must be)
_CHECKED = [
    ("corner_field", lambda w: plot.corner_field(w), "bd", "a BDerivative"),
    ("tangent_circle", lambda w: plot.tangent_circle(w), "bd", "a BDerivative"),
    ("pieces", lambda w: plot.pieces(w), "bd", "a BDerivative"),
    ("carried_fan", lambda w: plot.carried_fan(w), "bd", "a BDerivative"),
    ("triangulation", lambda w: plot.triangulation(w), "bd",
     "a BDerivative or a FlowBDerivative"),
    ("triangulation", lambda w: plot.triangulation(None, tri=w), "tri", "a Triangulation"),
    ("gait_orbit", lambda w: plot.gait_orbit(w), "orbit", "a PeriodicOrbit"),
    ("gait_growth", lambda w: plot.gait_growth(w), "orbit", "a PeriodicOrbit"),
    ("gait_growth", lambda w: plot.gait_growth(_stub("bderiv.analysis.orbit.PeriodicOrbit"),
                                               stability=w),
     "stability", "a Stability or None"),
    ("gait_growth", lambda w: plot.gait_growth(_stub("bderiv.analysis.orbit.PeriodicOrbit"),
                                               decay=w),
     "decay", "a DecayCheck or None"),
    ("stability_map", lambda w: plot.stability_map(w), "smap", "a StabilityMap"),
    ("scaling", lambda w: plot.scaling(w), "rows", "a sequence of dicts"),
]


_WRONG = ["array", "dict", "None", "result"]


@pytest.mark.parametrize(("figure", "call", "param", "expected", "wrong"), [
    pytest.param(*row, wrong, id=f"{row[0]}-{row[2]}-{wrong}")
    for row in _CHECKED for wrong in _WRONG
    # None is allowed where it is the default: an optional argument, or tri (bd's own)
    if not (wrong == "None" and ("or None" in row[3] or row[2] == "tri"))])
def test_every_figure_names_a_wrong_object(figure, call, param, expected, wrong):
    """Each public figure refuses an object of the wrong type up front: a TypeError naming
    the parameter, what it must be and the type it got (not an AttributeError inside)."""
    value = {"array": np.zeros((4, 2)), "dict": {"F": np.zeros((4, 2))}, "None": None,
             "result": _wrong_result(param)}[wrong]
    with pytest.raises(TypeError) as info:
        call(value)
    message = str(info.value)
    assert message.startswith(f"{param} must be {expected}"), message
    assert f"got {type(value).__name__}" in message, message


def test_public_figures_are_all_checked():
    """The table above covers every public figure (a new one gets its check and a row)."""
    assert {f for f, *_ in _CHECKED} == set(plot.__all__)


def test_wrong_object_hints(planar):
    """The commonest mix-ups say what to do instead."""
    with pytest.raises(TypeError, match=r"bd must be a BDerivative, got Triangulation \(draw "
                                        r"a triangulation with triangulation\(None, tri="):
        plot.corner_field(planar.triangulation())
    with pytest.raises(TypeError, match=r"got Triangulation \(pass a Triangulation as tri=\)"):
        plot.triangulation(planar.triangulation())
    flow = _stub("bderiv.analysis.flowmap.FlowBDerivative")
    with pytest.raises(TypeError, match="got FlowBDerivative .a flow map's B-derivative has "
                                        "no corner table; triangulation.. draws it"):
        plot.pieces(flow)
    with pytest.raises(TypeError, match=r"orbit must be a PeriodicOrbit, got BDerivative "
                                        r"\(HybridSystem.periodic_orbit finds one\)"):
        plot.gait_orbit(planar)


def test_wrong_axes_and_rows_are_named(planar):
    with pytest.raises(TypeError, match="ax must be a matplotlib Axes, got str"):
        plot.corner_field(planar, ax="left")
    with pytest.raises(TypeError, match=r"axes\[1\] must be a matplotlib Axes, got dict"):
        from matplotlib.figure import Figure

        plot.pieces(planar, axes=[Figure().subplots(), {}])
    row = {"n": 2, "d": 2, "m": 10, "method": "bderiv", "seconds_per_query": 1e-8}
    with pytest.raises(TypeError, match=r"rows\[1\] must be a dict with the keys n, method and "
                                        r"seconds_per_query, got \[2, 'bderiv', 1e-08\]"):
        plot.scaling([row, [2, "bderiv", 1e-8]])
    with pytest.raises(TypeError, match="rows must be a sequence of dicts .* got str"):
        plot.scaling("rows.json")
    with pytest.raises(ValueError, match=r"rows\[0\] must have the keys n, method and "
                                         r"seconds_per_query, but lacks method"):
        plot.scaling([{"n": 2, "seconds_per_query": 1e-8}])


@pytest.mark.parametrize("key, value, words", [
    ("seconds_per_query", "1e-8", "rows[0]['seconds_per_query'] is '1e-8', not a positive number"),
    ("seconds_per_query", float("nan"), "rows[0]['seconds_per_query'] is nan, not a positive"),
    ("seconds_per_query", -1e-8, "is -1e-08, not a positive number"),
    ("n", 2.0, "rows[0]['n'] is 2.0, not a positive integer"),
    ("n", True, "rows[0]['n'] is True, not a positive integer"),
    ("method", None, "rows[0]['method'] is None, not a string"),
    ("m", 0, "rows[0]['m'] is 0, not a positive integer"),
    # a valid JSON integer that no figure can draw (matplotlib's OverflowError: a review)
    ("n", 10**400, "rows[0]['n'] is 1000000000000000000000000000000000000000, not a positive "
                   "integer up to 2**53"),
])
def test_scaling_rows_of_the_wrong_kind_are_named(key, value, words):
    """A value the figure would draw wrongly (a string's log, a NaN, a count of 2.0 events)
    is refused by the row and key, before any figure is made; numpy's numbers are numbers."""
    row = {"n": 2, "d": 2, "m": 10, "method": "bderiv", "seconds_per_query": 1e-8}
    with pytest.raises(ValueError, match=re.escape(words)):
        plot.scaling([dict(row, **{key: value})])
    plot.scaling([dict(row, n=np.int64(2), d=np.int64(2), seconds_per_query=np.float32(1e-8))])
