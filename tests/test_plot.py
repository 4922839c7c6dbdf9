"""Figures build with the Agg backend (matplotlib, the extra ``plot``)."""

from __future__ import annotations

import io
import sys

import numpy as np
import pytest

from bderiv import BDerivative, plot
from bderiv.cli import planar_table, three_event_table

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
    assert ax.get_title() == "corner-limit field (n=2 events)"
    # 2 event lines and the sampled trajectories are drawn
    assert len(ax.lines) >= 2 + 7
    png_bytes(fig)


def test_triangulation(planar, tmp_path):
    fig = plot.triangulation(planar)
    left, right = fig.axes[:2]
    assert len(left.patches) == len(right.patches) == 4  # 2 * 2! simplices
    assert "pre-event" in left.get_title() and "post-event" in right.get_title()
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
    png_bytes(fig)


def test_pieces_all_and_sampled():
    fig = plot.pieces(BDerivative(*three_event_table()))
    assert len(fig.axes[0].patches) == 6
    png_bytes(fig)
    rng = np.random.default_rng(3)
    F = rng.uniform(0.5, 1.5, (32, 5))  # n = 5: 120 pieces, too many to show all
    fig = plot.pieces(BDerivative(np.eye(5), F), max_pieces=10, n_samples=500)
    assert len(fig.axes[0].patches) == 10
    assert "most visited" in fig._suptitle.get_text()
    png_bytes(fig)


def test_scaling():
    rows = [
        {"n": n, "d": n, "m": 10, "method": m, "seconds_per_query": s * n}
        for n in (2, 4, 8)
        for m, s in (("bderiv", 1e-8), ("numpy", 1e-7))
    ]
    fig = plot.scaling(rows)
    assert len(fig.axes[0].lines) == 2
    png_bytes(fig)
    with pytest.raises(ValueError, match="no benchmark rows"):
        plot.scaling(rows, batch=5)


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


def test_matplotlib_imported_lazily():
    import subprocess

    code = (
        "import sys; sys.modules['matplotlib'] = None\n"
        "import bderiv.plot as p, numpy as np\n"
        "from bderiv import BDerivative\n"
        "try:\n"
        "    p.pieces(BDerivative(np.eye(1), np.ones((2, 1))))\n"
        "except ImportError as e:\n"
        "    print(e)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout
    assert "bderiv[plot]" in out
