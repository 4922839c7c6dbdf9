"""``bderiv plot`` on a gait: the figures orbit and growth of the pronking orbit, and the
usage errors they share with the other figures."""

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
    assert sorted(p.name for p in tmp_path.iterdir()) == ["growth.png", "orbit.png"]
    for name in ("orbit", "growth"):
        assert f"wrote {tmp_path / name}.png" in out
    for name in ("field", "triangulation", "circle", "note", "pieces"):
        assert (f"not drawn: {name}, which draws a B-derivative at an event point, not a "
                f"gait's orbit") in out
    assert "not drawn: scaling, which needs --bench-json" in out
    # 10 x 4.2 inches (two panels) and 6 x 4.5 inches at 50 dpi
    sizes = {"orbit": (500, 210), "growth": (300, 225)}
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
    growth, with the reason."""
    code, out, err = run(["plot", "--example", "planar", "--figure", "all", "--dpi", "30",
                          "--out", str(tmp_path), "--json"], capsys)
    assert code == 0, err
    summary = json.loads(out)
    assert [p.rsplit("/", 1)[-1] for p in summary["files"]] == [
        "field.png", "triangulation.png", "circle.png", "note.png", "pieces.png"]
    assert summary["skipped"] == {"orbit": "needs a gait's periodic orbit",
                                  "growth": "needs a gait's periodic orbit",
                                  "scaling": "needs --bench-json"}
    code, out, err = run(["plot", "--example", "planar", "--figure", "all", "--dpi", "30",
                          "--out", str(tmp_path)], capsys)
    assert code == 0, err
    assert ("not drawn: orbit, which needs a gait's periodic orbit (try --example pronking)"
            in out)
    assert "not drawn: scaling, which needs --bench-json\n" in out


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
    (["--example", "landing"], "invalid choice: 'landing'"),
    (["--example", "pronking", "--figure", "gait"], "invalid choice: 'gait'"),
    (["--example", "pronking", "--figure", "growth", "scaling"], "pass --bench-json"),
    (["--example", "pronking", "--figure", "orbit", "--format", "jpg"], "invalid choice"),
    (["--example", "pronking", "--figure", "orbit", "--dpi", "0"], "positive integer"),
    (["--example", "pronking", "--figure", "orbit", "--dpi", "100000"],
     "--dpi 100000 makes the figure orbit 1000000 x 420000 pixels"),
]


@pytest.mark.parametrize("argv, message", BAD, ids=lambda v: " ".join(v) if isinstance(
    v, list) else None)
def test_usage_errors(capsys, tmp_path, argv, message):
    """One line on stderr, exit status 2, nothing written (not even the directory)."""
    out_dir = tmp_path / "figs"
    code, out, err = run(["plot", *argv, "--out", str(out_dir)], capsys)
    assert (code, out) == (2, "")
    assert err.count("\n") == 1 and err.startswith("bderiv plot: error: "), err
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
    assert "the gait pronking" in text and "landing" not in text
