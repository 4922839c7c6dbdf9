"""The documentation site builds: Sphinx over docs/ and the public API's docstrings, with
warnings as errors (a broken cross-reference, a docstring docutils cannot parse, a link to
a missing page or heading fails the test). Skipped where the ``docs`` extra is missing.

Sphinx runs in the test's process (``build_main``, the function behind ``python -m
sphinx``): as a subprocess it spent a third of its 15 s of CPU importing numpy, scipy,
numba and the package, which this process has imported already."""

from __future__ import annotations

import pathlib
import sys
import warnings

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1]


def build_site(args, capsys, monkeypatch):
    """``(status, stderr)`` of ``python -m sphinx -W --keep-going -E -q -b html *args``,
    run here, ``sys.path`` kept as it was (a ``conf.py`` inserts folders). Python's
    warnings as a fresh process filters them (the suite's filters turn the package's
    warnings into errors, not those of Sphinx's extensions), but a warning raised for the
    site's own extension (``docs/_ext/bderiv_api.py``), a deprecated API it uses, is an
    error."""
    for name in ("sphinx", "myst_parser", "numpydoc", "pydata_sphinx_theme"):
        pytest.importorskip(name)
    from sphinx.cmd.build import build_main

    monkeypatch.setattr(sys, "path", list(sys.path))
    capsys.readouterr()
    with warnings.catch_warnings():
        warnings.resetwarnings()
        warnings.simplefilter("ignore", DeprecationWarning)
        warnings.simplefilter("ignore", PendingDeprecationWarning)
        warnings.filterwarnings("error", module="bderiv_api")
        status = build_main(["-W", "--keep-going", "-E", "-q", "-b", "html", *map(str, args)])
    return status, capsys.readouterr().err


def test_site_builds_without_warnings(tmp_path, capsys, monkeypatch):
    status, err = build_site(["-d", tmp_path / "doctrees", ROOT / "docs", tmp_path / "html"],
                             capsys, monkeypatch)
    assert status == 0, err[-8000:]
    api = (tmp_path / "html" / "api.html").read_text(encoding="utf-8")
    for name in ("bderiv.BDerivative", "bderiv.HybridSystem", "bderiv.FlowBDerivative"):
        assert f'id="{name}"' in api, f"the API reference does not document {name}"


def test_a_broken_reference_fails_the_build(tmp_path, capsys, monkeypatch):
    """The build's check is live: a docstring naming an object that does not exist fails."""
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
    status, err = build_site([src, tmp_path / "html"], capsys, monkeypatch)
    assert status != 0
    assert "bderiv.no_such_function" in err
    assert "BDerivative" not in err
