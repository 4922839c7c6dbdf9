"""The optional dependencies (the extras and the test and docs tools of pyproject.toml): no
module of the package imports one, and a function that needs a missing extra says which
extra to install. The same process also reports the package's cached kernels that would
read numba's unchecked cache files.

One fresh process answers every check (a Python interpreter and the package's import cost
about 1.5 s of CPU each; these checks took five): it imports every module of the package
with all of them installed and reports which got imported; then, one extra at a time, it
makes that extra missing (``sys.modules[name] = None``: an import of it raises
``ImportError``, as when it is not installed), calls the functions that need it, and puts
it back. An import that does not touch an optional dependency cannot fail where it is
missing (the package looks for its data files and versions inside functions only:
``importlib.metadata`` in ``robots._files``), so the first check covers a machine without
them.

Under ``--dist worksteal`` the other worker may take some of these tests: the fixture then
runs once in each worker."""

from __future__ import annotations

import json
import pathlib
import re
import subprocess
import sys
import textwrap

import numpy as np
import pytest

import bderiv

#: every distribution of pyproject.toml's optional dependencies, by the names it is
#: imported as (example-robot-data is data only: found through ``importlib.metadata``)
IMPORT_NAMES = {
    "matplotlib": ("matplotlib", "mpl_toolkits"),
    "tqdm": ("tqdm",),
    "dask": ("dask",),
    "distributed": ("distributed",),
    "sympy": ("sympy",),
    "jax": ("jax",),
    "diffrax": ("diffrax",),
    "pin": ("pinocchio",),
    "example-robot-data": (),
    "hybrid-tools": ("hybrid_tools",),
    "pytest": ("pytest", "_pytest"),
    "pytest-xdist": ("xdist",),
    "hypothesis": ("hypothesis",),
    "pytest-benchmark": ("pytest_benchmark",),
    "ruff": ("ruff",),
    "sphinx": ("sphinx",),
    "myst-parser": ("myst_parser",),
    "numpydoc": ("numpydoc",),
    "pydata-sphinx-theme": ("pydata_sphinx_theme",),
}

_PROBE = textwrap.dedent("""
    import importlib, json, pkgutil, sys
    import bderiv
    names = [m.name for m in pkgutil.walk_packages(bderiv.__path__, "bderiv.")]
    for name in names:
        if name != "bderiv.__main__":  # it runs the command line
            importlib.import_module(name)
    report = {{"modules": len(names),
               "imported": [name for name in {optional!r} if name in sys.modules],
               "scipy": [name for name in ("scipy.integrate", "scipy.optimize",
                                           "scipy.stats") if name in sys.modules]}}
    from numba.core.dispatcher import Dispatcher
    from bderiv._kernels._cache import hardened
    report["unchecked"] = sorted(
        name + "." + value.py_func.__qualname__
        for name, module in list(sys.modules.items())
        if name.split(".")[0] == "bderiv" and module is not None
        for value in vars(module).values()
        if isinstance(value, Dispatcher) and value.stats.cache_path is not None
        and not hardened(value))

    def refusals(extra, calls):
        sys.modules[extra] = None
        try:
            said = {{}}
            for name, call in calls:
                try:
                    call()
                except ImportError as exc:
                    said[name] = str(exc)
                else:
                    said[name] = None
            return said
        finally:
            del sys.modules[extra]

    from bderiv import BDerivative, plot
    from bderiv.examples import chair, planar_table
    import bderiv.jax, bderiv.robots
    bd = BDerivative(*planar_table())
    rows = [{{"n": 2, "method": "bderiv", "seconds_per_query": 1e-8}}]
    report["plot"] = refusals("matplotlib", [(draw.__name__, lambda draw=draw, arg=arg: draw(arg))
                                             for draw, arg in (
        (plot.corner_field, bd), (plot.triangulation, bd), (plot.tangent_circle, bd),
        (plot.pieces, bd), (plot.scaling, rows))])
    report["jax"] = refusals("jax", [("flow", lambda: bderiv.jax.flow(chair().system, 1.0))])
    report["robots"] = refusals("pinocchio", [("quadruped", bderiv.robots.quadruped)])
    print(json.dumps(report))
""")


def optional_distributions():
    """The distributions named in pyproject.toml's optional dependencies (not bderiv's own
    extras), lower case."""
    tomllib = pytest.importorskip("tomllib")
    root = pathlib.Path(__file__).resolve().parents[1]
    with open(root / "pyproject.toml", "rb") as fh:
        extras = tomllib.load(fh)["project"]["optional-dependencies"]
    names = {re.match(r"[A-Za-z0-9_.\-]+", r).group(0).lower().replace("_", "-")
             for reqs in extras.values() for r in reqs}
    return {name for name in names if name != "bderiv"}


@pytest.fixture(scope="module")
def report():
    optional = [name for names in IMPORT_NAMES.values() for name in names]
    out = subprocess.run([sys.executable, "-c", _PROBE.format(optional=optional)],
                         capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    return json.loads(out.stdout)


def test_every_optional_dependency_is_listed():
    assert optional_distributions() == set(IMPORT_NAMES)


def test_no_module_imports_an_optional_dependency(report):
    """Every module of the package (the doctests import them all) imports none of them,
    installed or not; ``bderiv.plot``, ``bderiv.jax`` and ``bderiv.robots`` import
    theirs inside the functions that need them."""
    files = list(pathlib.Path(bderiv.__file__).parent.rglob("*.py"))
    assert report["modules"] == len(files) - 1  # all but bderiv/__init__.py: none skipped
    assert report["imported"] == []


def test_no_module_imports_scipys_integrators_optimizers_or_statistics(report):
    """They cost a process 0.35 s (scipy.integrate, with scipy.special and
    scipy.optimize) to 0.6 s (scipy.stats) at import: the functions that call them import
    them, so that the compiled path, which never does, is spared them. The DOP853 tableau
    of the compiled integrator is read from scipy's file without its package
    (``test_the_compiled_integrators_tableau_is_scipys``)."""
    assert report["scipy"] == []


def test_the_compiled_integrators_tableau_is_scipys(monkeypatch):
    """Read from scipy's file on its own where scipy.integrate was not imported: the same
    numbers as the module solve_ivp uses, bit for bit."""
    from scipy.integrate._ivp import dop853_coefficients as scipys

    from bderiv.models.compiled import _dop853

    monkeypatch.delitem(sys.modules, "scipy.integrate")
    alone = _dop853._scipys_tableau()
    assert alone is not scipys
    for name in ("A", "B", "C", "E3", "E5", "D", "N_STAGES", "N_STAGES_EXTENDED",
                 "INTERPOLATOR_POWER"):
        ours, theirs = np.asarray(getattr(alone, name)), np.asarray(getattr(scipys, name))
        assert ours.dtype == theirs.dtype and ours.shape == theirs.shape, name
        assert ours.tobytes() == theirs.tobytes(), name
    # an install without scipy's sources (bytecode only): imported as a module
    monkeypatch.setattr(_dop853.scipy, "__file__", "/nonexistent/scipy/__init__.py")
    assert _dop853._scipys_tableau() is scipys


def test_every_cached_kernel_reads_checked_files_however_its_module_is_imported(report):
    """Every module imported directly (not through ``bderiv``'s names, which harden what
    is imported so far): each cached top-level kernel of the package reads bderiv's checked
    cache files, so a damaged entry is compiled again (robots' ``_lie`` read numba's plain
    files, and one flipped bit broke every later process)."""
    assert report["unchecked"] == []


def test_the_figures_ask_for_matplotlib(report):
    assert list(report["plot"]) == ["corner_field", "triangulation", "tangent_circle",
                                    "pieces", "scaling"]
    for name, message in report["plot"].items():
        assert message is not None and "pip install 'bderiv[plot]'" in message, name


def test_the_jax_functions_ask_for_jax(report):
    message = report["jax"]["flow"]
    assert message is not None
    assert message.startswith("bderiv.jax needs jax: pip install 'bderiv[jax]'")


def test_the_robots_ask_for_pinocchio(report):
    message = report["robots"]["quadruped"]
    assert message is not None
    assert message.startswith("bderiv.robots needs Pinocchio: pip install 'bderiv[robots]'")
