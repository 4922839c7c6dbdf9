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
    assert "mask 0b01" in [t.get_text() for t in ax.texts]
    # 2 event lines and the sampled trajectories are drawn
    assert len(ax.lines) >= 2 + 7
    png_bytes(fig)


def test_triangulation(planar, tmp_path):
    fig = plot.triangulation(planar)
    left, right = fig.axes[:2]
    assert len(left.patches) == len(right.patches) == 4  # 2 * 2! simplices
    assert "pre-event" in left.get_title() and "post-event" in right.get_title()
    assert "B-derivative at the event point" in fig.get_suptitle()
    assert "U[0b01]" in [t.get_text() for t in left.texts]
    png_bytes(fig)
    tri = planar.triangulation()
    path = tri.save(tmp_path / "tri.json")
    from bderiv import load_triangulation

    fig2 = plot.triangulation(None, tri=load_triangulation(path))
    png_bytes(fig2)


def test_tangent_circle(planar):
    fig = plot.tangent_circle(planar, n_vectors=90)
    labels = [t.get_text() for t in fig.axes[0].get_legend().get_texts()]
    assert "order (0,1)" in labels and "order (1,0)" in labels
    assert "B-derivative at the event point" in fig.axes[0].get_title()
    png_bytes(fig)


def test_pieces_all_and_sampled():
    fig = plot.pieces(BDerivative(*three_event_table()))
    assert len(fig.axes[0].patches) == 6
    png_bytes(fig)
    rng = np.random.default_rng(3)
    F = rng.uniform(0.5, 1.5, (32, 5))  # n = 5: 120 pieces, too many to show all
    fig = plot.pieces(BDerivative(np.eye(5), F), max_pieces=10, n_samples=500)
    assert len(fig.axes[0].patches) == 10
    assert "most visited" in fig.get_suptitle()
    png_bytes(fig)


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
