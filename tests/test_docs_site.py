"""The documentation site builds: Sphinx over docs/ and the public API's docstrings, with
warnings as errors (a broken cross-reference, a docstring docutils cannot parse, a link to
a missing page or heading fails the test). Skipped where the ``docs`` extra is missing."""

from __future__ import annotations

import pathlib
import subprocess
import sys

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1]


def test_site_builds_without_warnings(tmp_path):
    for name in ("sphinx", "myst_parser", "numpydoc", "pydata_sphinx_theme"):
        pytest.importorskip(name)
    command = [sys.executable, "-m", "sphinx", "-W", "--keep-going", "-E", "-q", "-b", "html",
               "-d", str(tmp_path / "doctrees"), str(ROOT / "docs"), str(tmp_path / "html")]
    out = subprocess.run(command, capture_output=True, text=True, timeout=900)
    assert out.returncode == 0, out.stdout[-4000:] + out.stderr[-8000:]
    api = (tmp_path / "html" / "api.html").read_text(encoding="utf-8")
    for name in ("bderiv.BDerivative", "bderiv.HybridSystem", "bderiv.FlowBDerivative"):
        assert f'id="{name}"' in api, f"the API reference does not document {name}"


def test_a_broken_reference_fails_the_build(tmp_path):
    """The build's check is live: a docstring naming an object that does not exist fails."""
    for name in ("sphinx", "myst_parser", "numpydoc", "pydata_sphinx_theme"):
        pytest.importorskip(name)
    src = tmp_path / "src"
    src.mkdir()
    (src / "conf.py").write_text(
        "import sys\n"
        f"sys.path[:0] = [{str(ROOT / 'docs' / '_ext')!r}, {str(ROOT / 'src')!r}]\n"
        "extensions = ['sphinx.ext.autodoc', 'numpydoc', 'bderiv_api']\n"
        "nitpicky = True\nnumpydoc_show_class_members = False\n")
    (src / "index.rst").write_text(
        "Probe\n=====\n\n"
        "A name that exists, by another path: :func:`bderiv.engine.bderivative.BDerivative`.\n\n"
        "One that does not: :func:`bderiv.no_such_function`.\n")
    command = [sys.executable, "-m", "sphinx", "-W", "--keep-going", "-E", "-q", "-b", "html",
               str(src), str(tmp_path / "html")]
    out = subprocess.run(command, capture_output=True, text=True, timeout=300)
    assert out.returncode != 0
    assert "bderiv.no_such_function" in out.stderr
    assert "BDerivative" not in out.stderr
