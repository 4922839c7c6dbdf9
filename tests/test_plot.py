"""Figures build with the Agg backend (matplotlib, the extra ``plot``)."""

from __future__ import annotations

import io
import sys

import numpy as np
import pytest

from bderiv import BDerivative, CornerFunction, StructuredCorners, plot
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


def test_tangent_circle(planar):
    fig = plot.tangent_circle(planar, n_vectors=90)
    legend = fig.axes[0].get_legend()
    labels = [t.get_text() for t in legend.get_texts()]
    assert "order (0,1)" in labels and "order (1,0)" in labels
    assert legend.get_bbox_to_anchor().x0 > fig.axes[0].get_window_extent().x1  # beside
    assert "B-derivative at the event point" in fig.axes[0].get_title()
    png_bytes(fig)


def test_pieces_all_and_sampled():
    fig = plot.pieces(BDerivative(*three_event_table()))
    assert len(fig.axes[0].patches) == 6
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
    title = plot.scaling(rows, machine="CPU X (2 CPUs), numba threads 2").axes[0].get_title()
    assert title.splitlines()[-1] == "measured on CPU X (2 CPUs), numba threads 2"
    with pytest.raises(ValueError, match="no benchmark rows to plot with batch m = 5"):
        plot.scaling(rows, batch=5)


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
    with pytest.raises(ValueError, match=r"one dimension d per n, got d in \[2, 4\] at n = 2"):
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


def _run(code):
    import subprocess

    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          check=True).stdout


def test_matplotlib_imported_lazily():
    """bderiv and bderiv.plot import without matplotlib; each figure asks to install it."""
    assert _run("import sys, bderiv, bderiv.plot\n"
                "print('matplotlib' in sys.modules)\n") == "False\n"
    code = (
        "import sys; sys.modules['matplotlib'] = None\n"
        "from bderiv import BDerivative, plot\n"
        "from bderiv.examples import planar_table\n"
        "bd = BDerivative(*planar_table())\n"
        "rows = [{'n': 2, 'method': 'bderiv', 'seconds_per_query': 1e-8}]\n"
        "for draw, arg in ((plot.corner_field, bd), (plot.triangulation, bd),\n"
        "                  (plot.tangent_circle, bd), (plot.pieces, bd), (plot.scaling, rows)):\n"
        "    try:\n"
        "        draw(arg)\n"
        "    except ImportError as e:\n"
        "        print(draw.__name__, e)\n"
    )
    lines = _run(code).splitlines()
    names = ["corner_field", "triangulation", "tangent_circle", "pieces", "scaling"]
    assert [line.split()[0] for line in lines] == names
    for line in lines:
        assert "pip install 'bderiv[plot]'" in line


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
