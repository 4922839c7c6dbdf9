"""``bderiv plot`` on a gait: the figures orbit and growth of the pronking orbit, and the
usage errors they share with the other figures; ``plot`` and ``export`` on the impact
example landing."""

from __future__ import annotations

import json

import numpy as np
import pytest
from test_cli import run

pytest.importorskip("matplotlib")
Image = pytest.importorskip("PIL.Image")


def has_colour(path, hex_colour, at_least=20):
    """Whether the image at ``path`` has ``at_least`` pixels of exactly ``hex_colour``."""
    rgb = np.asarray(Image.open(path).convert("RGB")).reshape(-1, 3)
    want = [int(hex_colour[i:i + 2], 16) for i in (1, 3, 5)]
    return int(np.all(rgb == want, axis=1).sum()) >= at_least


def test_all_figures_of_pronking(capsys, tmp_path):
    """``--figure all`` on pronking draws the two gait figures, as PNGs of the figures' size
    at --dpi, and names each B-derivative figure that does not apply."""
    code, out, err = run(["plot", "--example", "pronking", "--figure", "all", "--dpi", "50",
                          "--out", str(tmp_path)], capsys)
    assert code == 0, err
    assert out.startswith("bderiv plot: pronking (n = 2, d = 4)")
    # the seconds of work are announced as they start (users' fourth pass, item 2)
    assert "bderiv plot: finding the pronking orbit by Newton's method" in err
    assert "bderiv plot: simulating 40 strides from 4 perturbed starts" in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["growth.png", "orbit.png"]
    for name in ("orbit", "growth"):
        assert f"wrote {tmp_path / name}.png" in out
    for name in ("field", "triangulation", "circle", "note", "pieces"):
        assert (f"not drawn: {name}, which draws a B-derivative at an event point, not a "
                f"gait's orbit") in out
    assert "not drawn: scaling, which needs --bench-json" in out
    # 10 x 7.6 inches (four time panels beside the phase plane) and 6 x 4.5 inches at 50 dpi
    sizes = {"orbit": (500, 380), "growth": (300, 225)}
    for name, size in sizes.items():
        with Image.open(tmp_path / f"{name}.png") as im:
            assert (im.format, im.size) == ("PNG", size)
            im.load()  # decodes the whole file: a truncated PNG fails here
    # what each draws: the fixed point's star (orbit); the simulated strides' dots beside
    # the return map's lines (growth), so the decay check against simulation is there
    assert has_colour(tmp_path / "orbit.png", "#AA3377")
    assert has_colour(tmp_path / "growth.png", "#EE6677")
    assert has_colour(tmp_path / "growth.png", "#4477AA")


@pytest.mark.parametrize("fmt, magic", [("pdf", b"%PDF-"), ("svg", b"<?xml")])
def test_orbit_in_other_formats(capsys, tmp_path, fmt, magic):
    code, out, err = run(["plot", "--example", "pronking", "--figure", "orbit", "--format",
                          fmt, "--out", str(tmp_path), "--json"], capsys)
    assert code == 0, err
    summary = json.loads(out)
    path = tmp_path / f"orbit.{fmt}"
    assert summary["files"] == [str(path)] and summary["skipped"] == {}
    assert (summary["example"], summary["dim"], summary["n_events"]) == ("pronking", 4, 2)
    data = path.read_bytes()
    assert data.startswith(magic) and len(data) > 5000
    if fmt == "svg":
        assert b"<svg" in data[:1000]


def test_all_on_planar_names_the_gait_figures(capsys, tmp_path):
    """And the other way round: ``--figure all`` on a B-derivative leaves out orbit and
    growth, with the reason; in JSON as PDF, in words as SVG (each format's one drawing of
    the five figures in the suite; PNG: test_cli.py::test_plot_default_and_chair)."""
    code, out, err = run(["plot", "--example", "planar", "--figure", "all", "--dpi", "30",
                          "--format", "pdf", "--out", str(tmp_path / "pdf"), "--json"],
                         capsys)
    assert code == 0, err
    summary = json.loads(out)
    names = ("field", "triangulation", "circle", "note", "pieces")
    assert summary["files"] == [str(tmp_path / "pdf" / f"{name}.pdf") for name in names]
    assert summary["skipped"] == {"orbit": "needs a gait's periodic orbit",
                                  "growth": "needs a gait's periodic orbit",
                                  "scaling": "needs --bench-json"}
    for name in names:
        data = (tmp_path / "pdf" / f"{name}.pdf").read_bytes()
        assert data.startswith(b"%PDF-") and len(data) > 1000
    code, out, err = run(["plot", "--example", "planar", "--figure", "all", "--dpi", "30",
                          "--format", "svg", "--out", str(tmp_path / "svg")], capsys)
    assert code == 0, err
    assert "wrote" in out
    assert ("not drawn: orbit, which needs a gait's periodic orbit (try --example pronking)"
            in out)
    assert "not drawn: scaling, which needs --bench-json\n" in out
    for name in names:
        assert f"wrote {tmp_path / 'svg' / name}.svg" in out
        data = (tmp_path / "svg" / f"{name}.svg").read_bytes()
        assert data.startswith(b"<?xml") and len(data) > 1000


BAD = [
    (["--figure", "orbit"],
     "figure orbit needs a gait's periodic orbit, but planar is not a gait: use --example "
     "pronking, or a figure of planar: field, triangulation, circle, note, pieces (or "
     "scaling, with --bench-json)"),
    (["--example", "chair", "--figure", "pieces", "growth"],
     "figure growth needs a gait's periodic orbit, but chair is not a gait"),
    (["--example", "pronking", "--figure", "orbit", "field"],
     "figure field draws a B-derivative at an event point, not a gait's orbit: use "
     "--example planar, or a figure of pronking: orbit, growth (or scaling, with "
     "--bench-json)"),
    (["--example", "pronking", "--n", "3"], "--n applies to --example network only"),
    (["--example", "pronking", "--extended"], "--extended applies to --example network"),
    (["--example", "landing", "--figure", "field"],
     "figure field draws the plane (needs d = 2), but landing has n = 2, d = 10: use "
     "--example planar, or a figure of landing: pieces (or scaling, with --bench-json)"),
    (["--example", "landing", "--figure", "orbit"],
     "figure orbit needs a gait's periodic orbit, but landing is not a gait"),
    (["--example", "landing", "--n", "3"], "--n applies to --example network only"),
    (["--example", "pronking", "--figure", "gait"], "invalid choice: 'gait'"),
    (["--example", "pronking", "--figure", "growth", "scaling"], "pass --bench-json"),
    (["--example", "pronking", "--figure", "orbit", "--format", "jpg"], "invalid choice"),
    (["--example", "pronking", "--figure", "orbit", "--dpi", "0"], "an integer >= 10"),
    (["--example", "pronking", "--figure", "orbit", "--dpi", "100000"],
     "--dpi 100000 makes the figure orbit 1000000 x 760000 pixels"),
]


@pytest.mark.parametrize("argv, message", BAD, ids=lambda v: " ".join(v) if isinstance(
    v, list) else None)
def test_usage_errors(capsys, tmp_path, argv, message):
    """One error line on stderr (after the work it took to find it, announced), exit status
    2, nothing written (not even the directory)."""
    out_dir = tmp_path / "figs"
    code, out, err = run(["plot", *argv, "--out", str(out_dir)], capsys)
    assert (code, out) == (2, "")
    *said, last = err.splitlines()
    assert last.startswith("bderiv plot: error: "), err
    assert all(line.startswith("bderiv plot: finding the pronking orbit") for line in said), err
    assert message in err
    assert not out_dir.exists()


def test_unwritable_out(capsys, tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("")
    code, out, err = run(["plot", "--example", "pronking", "--figure", "orbit", "--out",
                          str(blocker / "figs")], capsys)
    assert (code, out) == (2, "") and err.count("\n") == 1
    assert "--out: cannot make the directory" in err and "not writable" in err


def test_help_lists_the_gait_figures(capsys):
    code, out, _ = run(["plot", "--help"], capsys)
    assert code == 0
    text = " ".join(out.split())
    assert "pieces, scaling, orbit, growth, all" in text
    assert "orbit and growth (--example pronking only)" in text
    assert "as long as `bderiv demo --example pronking`" in text  # it takes seconds
    assert "the gait pronking" in text
    assert "the impact landing (resets at a simultaneous touchdown)" in text


# -- the orbit figure, as a reader sees it ---------------------------------------------------


@pytest.fixture(scope="module")
def pronking():
    from bderiv.cli.systems import load_orbit

    return load_orbit("pronking")


def _span(patch):
    """(start, end) in time of a shaded stretch (an axvspan)."""
    x = np.asarray(patch.get_xy() if not hasattr(patch, "get_width") else
                   [[patch.get_x(), 0], [patch.get_x() + patch.get_width(), 0]])[:, 0]
    return x.min(), x.max()


def test_orbit_figure_components_units_and_stance(pronking):
    """Each state component in a panel of its own with its unit (z and vz no longer share
    an axis; the pitch is there), time in seconds, and the stance shaded: where both feet
    are on the ground, found in the test from the model's own geometry (foot k at body
    frame point (a_k, -leg): height z + a_k sin(theta) - leg cos(theta), a = -+0.4,
    leg = 0.5), to within the sampling step."""
    from bderiv import plot
    from bderiv.cli.systems import ORBIT_EXAMPLES

    ex, orbit = pronking
    named = ORBIT_EXAMPLES["pronking"]
    fig = plot.gait_orbit(orbit, **named)
    *panels, phase = fig.axes
    assert [ax.get_ylabel() for ax in panels] == list(named["labels"]) == [
        "height $z$ (m)", "pitch $\\theta$ (rad)", "vertical velocity $v_z$ (m/s)",
        "pitch rate $\\omega$ (rad/s)"]
    assert panels[-1].get_xlabel() == "time (s)"
    assert (phase.get_xlabel(), phase.get_ylabel()) == (named["labels"][0], named["labels"][2])
    traj = orbit.sample()
    a, leg = np.array([-0.4, 0.4]), 0.5
    z, theta = traj.x[:, :1], traj.x[:, 1:2]
    feet = z + a * np.sin(theta) - leg * np.cos(theta)
    down = traj.t[(feet <= 0).all(axis=1)]
    step = 1.01 * orbit.period / 400  # the sampling's largest step (and rounding)
    for ax in panels:
        (stance,) = [p for p in ax.patches]
        start, end = _span(stance)
        assert abs(start - down.min()) < step and abs(end - down.max()) < step
    (legend,) = [ax.get_legend() for ax in panels if ax.get_legend()]
    assert [t.get_text() for t in legend.get_texts()] == ["stance: both feet on the ground"]
    # the symmetric orbit has no pitch: theta and omega are 0 (to rounding), drawn flat
    for ax, k in ((panels[1], 1), (panels[3], 3)):
        assert np.abs(traj.x[:, k]).max() < 1e-9
        assert ax.get_ylim() == pytest.approx((-1.0, 1.0), abs=1e-9)
        assert [t.get_text() for t in ax.texts][0].startswith("constant to rounding")
    assert not panels[0].texts and not panels[2].texts


def test_orbit_figure_refuses_bad_components(pronking):
    from bderiv import plot

    _, orbit = pronking
    with pytest.raises(ValueError, match=r"components must be state indices in \[0, 4\), "
                                         r"got \[0, 7\]"):
        plot.gait_orbit(orbit, components=(0, 7))
    for phase in ((0, -1), (0, 1, 2)):
        with pytest.raises(ValueError, match=r"phase must be two state indices in \[0, 4\)"):
            plot.gait_orbit(orbit, phase=phase)


# -- the impact example landing: plot and export ---------------------------------------------


def test_plot_landing(capsys, tmp_path):
    """landing (d = 10, n = 2): the figure that applies is pieces; the plane's figures and
    the gait's are named as not drawn. Its two pieces pass through the plastic stop of a
    foot's sliding (u_k -> 0), so every piece is singular: det 0, said in the title."""
    code, out, err = run(["plot", "--example", "landing", "--dpi", "40", "--out",
                          str(tmp_path), "--json"], capsys)
    assert code == 0, err
    summary = json.loads(out)
    assert (summary["example"], summary["dim"], summary["n_events"]) == ("landing", 10, 2)
    assert summary["files"] == [str(tmp_path / "pieces.png")]
    assert summary["skipped"] == {**{f: "draws the plane (needs d = 2)"
                                     for f in ("field", "triangulation", "circle", "note")},
                                  "orbit": "needs a gait's periodic orbit",
                                  "growth": "needs a gait's periodic orbit",
                                  "scaling": "needs --bench-json"}
    with Image.open(tmp_path / "pieces.png") as im:
        im.load()
    from bderiv import plot
    from bderiv.cli.systems import load_example

    _, bd = load_example("landing")
    # each touchdown from region 0b00 stops one foot's sliding: a reset of rank d - 1
    assert [np.linalg.matrix_rank(bd.resets[0, k]) for k in range(2)] == [9, 9]
    fig = plot.pieces(bd)
    assert [p.get_height() for p in fig.axes[0].patches] == [0.0]
    assert "every piece singular" in fig.axes[0].get_title()


@pytest.mark.parametrize("which", ["event", "flow"])
def test_export_landing_says_why_there_is_no_triangulation(capsys, tmp_path, which):
    """The stop of a foot's sliding is a singular reset: no homeomorphism, so no
    triangulation, at the event point or along the flow; a usage error says so and
    nothing is written."""
    code, out, err = run(["export", "--example", "landing", "--map", which, "--out",
                          str(tmp_path / "tri")], capsys)
    assert (code, out) == (2, "") and err.count("\n") == 1
    assert err.startswith("bderiv export: error: landing has no triangulation (nor has its "
                          "flow map, which contains the same resets): the reset Jacobian "
                          "R[0, 0] of event 0 crossed from region mask 0b00 is singular")
    assert "not a homeomorphism" in err
    assert list(tmp_path.iterdir()) == []
