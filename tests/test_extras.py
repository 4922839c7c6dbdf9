"""The optional extras (matplotlib, tqdm, dask, jax, diffrax, pinocchio, sympy, ...): no
module of the package imports one, and a function that needs a missing one says which
extra to install.

One fresh process answers every check (a Python interpreter and the package's import cost
about 1.5 s of CPU each; these checks took four): it imports every module of the package
with the extras installed and reports which extras got imported, then makes each extra
missing (``sys.modules[name] = None``: an import of it raises ``ImportError``, as when it
is not installed) and calls one function of each kind that needs one. An import that does
not touch an extra cannot fail when it is missing, so the first check covers a machine
without them."""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap

import pytest

#: the optional extras of pyproject.toml, by the names they are imported as
EXTRAS = ("matplotlib", "PIL", "tqdm", "dask", "distributed", "jax", "jaxlib", "diffrax",
          "pinocchio", "example_robot_data", "sympy", "hybrid_tools", "sphinx")

_PROBE = textwrap.dedent("""
    import importlib, json, pkgutil, sys
    extras = {extras!r}
    import bderiv
    names = [m.name for m in pkgutil.walk_packages(bderiv.__path__, "bderiv.")]
    for name in names:
        if name != "bderiv.__main__":  # it runs the command line
            importlib.import_module(name)
    report = {{"modules": len(names),
               "imported": [name for name in extras if name in sys.modules]}}
    for name in extras:
        sys.modules[name] = None

    def refusal(call):
        try:
            call()
        except ImportError as exc:
            return str(exc)
        return None

    from bderiv import BDerivative, plot
    from bderiv.examples import chair, planar_table
    import bderiv.jax, bderiv.robots
    bd = BDerivative(*planar_table())
    rows = [{{"n": 2, "method": "bderiv", "seconds_per_query": 1e-8}}]
    report["plot"] = {{draw.__name__: refusal(lambda: draw(arg)) for draw, arg in (
        (plot.corner_field, bd), (plot.triangulation, bd), (plot.tangent_circle, bd),
        (plot.pieces, bd), (plot.scaling, rows))}}
    report["jax"] = refusal(lambda: bderiv.jax.flow(chair().system, 1.0))
    report["robots"] = refusal(bderiv.robots.quadruped)
    print(json.dumps(report))
""").format(extras=EXTRAS)


@pytest.fixture(scope="module")
def report():
    out = subprocess.run([sys.executable, "-c", _PROBE], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    return json.loads(out.stdout)


def test_no_module_imports_an_extra(report):
    """Every module of the package (the doctests import them all) imports none of the
    extras, installed or not; ``bderiv.plot``, ``bderiv.jax`` and ``bderiv.robots``
    import theirs inside the functions that need them."""
    assert report["modules"] >= 100
    assert report["imported"] == []


def test_the_figures_ask_for_matplotlib(report):
    assert list(report["plot"]) == ["corner_field", "triangulation", "tangent_circle",
                                    "pieces", "scaling"]
    for name, message in report["plot"].items():
        assert message is not None and "pip install 'bderiv[plot]'" in message, name


def test_the_jax_functions_ask_for_jax(report):
    assert report["jax"].startswith("bderiv.jax needs jax: pip install 'bderiv[jax]'")


def test_the_robots_ask_for_pinocchio(report):
    assert "pip install 'bderiv[robots]'" in report["robots"]
