"""docs/design.md is true to the code: its modules exist and imports point down its layers."""

from __future__ import annotations

import ast
import pathlib
import re

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1]
PKG = ROOT / "src" / "bderiv"

#: the layers of docs/design.md, top to bottom: each a set of the package's folders (the
#: model side one level down) and modules; a module may import its own unit, the other
#: units of its layer and the layers below, never one above.
LAYERS = [
    {"cli", "__main__"},  # the command line (warmup: `bderiv compile`; sweep: `bderiv bench`)
    {"control"},  # trajectory optimisation through contact, on examples and the models
    {"examples"},  # ready models: on the analysis, symbolic (quadruped) and plot
    {"plot", "symbolic", "jax", "estimate", "robots"},  # the front ends over the analysis
    {"analysis"},  # flow maps, return maps, orbits, stability, checks; HybridSystem
    {"models", "models/calls", "models/user_functions", "models/section",
     "models/python_first", "models/numerical_jacobians"},  # a run's needs
    {"models/integrate", "models/readiness"},  # the run, over both integrators
    {"models/events"},  # the event logic at a stop, for both integrators
    {"models/compiled"},  # the compiled integrator
    {"engine"},  # BDerivative, its engines, linearisation and corner geometry
    {"geometry"},  # corner models, triangulations and their files
    {"_kernels"},  # numba kernels
]
#: helpers any layer may use; they import only each other and the foundation.
HELPERS = {"_support"}
#: the numbers (tolerances, sizes, limits): every module may import them, the kernels and
#: the helpers included; they import nothing of the package but each other (``_numerics``:
#: those compiled into kernels; ``_limits``: the Python-only ones; neither imports the other).
FOUNDATION = {"_limits", "_numerics"}
#: the modules that lie flat in the package: the face, ``python -m`` and the foundation
FLAT = {"__init__", "__main__", *FOUNDATION}


def _unit(parts) -> str:
    """The unit of a module path: ``cli/render`` -> ``cli``; in the model side's
    sub-package one level down: ``models/events/locate`` -> ``models/events``."""
    if parts[0] == "models" and len(parts) > 1 and parts[1] != "__init__":
        return "models/" + parts[1]
    return parts[0]


def _top(path: pathlib.Path) -> str:
    """The unit of a module file: ``cli/render.py`` -> ``cli``."""
    return _unit(path.relative_to(PKG).with_suffix("").parts)


def _imported(path: pathlib.Path):
    """The package's module paths a module imports, as parts (relative imports resolved;
    ``from pkg import name`` gives ``pkg/name`` where that is a module, else ``pkg``)."""
    depth = len(path.relative_to(PKG).parts) - 1  # 0 for a module at the package root
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            for alias in node.names:
                parts = alias.name.split(".")
                if parts[0] == "bderiv" and len(parts) > 1:
                    yield parts[1:]
            continue
        if not isinstance(node, ast.ImportFrom):
            continue
        if node.level == 0:
            if not node.module or node.module.split(".")[0] != "bderiv":
                continue
            parts = node.module.split(".")[1:]
        else:
            up = node.level - 1  # levels above the module's own package
            if up > depth:
                continue
            parts = list(path.relative_to(PKG).parts[: depth - up])
            parts += node.module.split(".") if node.module else []
        for alias in node.names:
            module = [*parts, alias.name]
            if (PKG.joinpath(*module).with_suffix(".py").exists()
                    or (PKG.joinpath(*module) / "__init__.py").exists()):
                yield module
            elif parts:
                yield parts
            else:  # a name of the package's face: ``from bderiv import __version__``
                yield ["__init__"]


def _imported_units(path: pathlib.Path):
    """The units a module imports."""
    for parts in _imported(path):
        yield _unit(parts)


def _layer(unit: str):
    if unit in HELPERS or unit in FOUNDATION:
        return None
    for i, layer in enumerate(LAYERS):
        if unit in layer:
            return i
    raise AssertionError(f"module {unit!r} is in no layer of docs/design.md")


MODULES = sorted(p for p in PKG.rglob("*.py") if p != PKG / "__init__.py")  # the public face


#: folders whose modules design.md describes as a group, not one by one
GROUPS = ("cli", "control", "examples", "plot", "symbolic", "jax", "estimate",
          "models/compiled")


def test_every_module_is_placed_and_named_in_the_design():
    """Every unit is in a layer; design.md names each folder (``name/``) and each module
    outside the folders it describes as a group (``name.py``)."""
    design = (ROOT / "docs" / "design.md").read_text()
    for path in MODULES:
        unit = _top(path)
        _layer(unit)
        parts = path.relative_to(PKG).parts
        for k, folder in enumerate(parts[:-1]):
            assert f"{folder}/" in design, f"folder {'/'.join(parts[:k + 1])}"
        if path.name not in ("__init__.py", "__main__.py") and not unit.startswith(GROUPS):
            assert path.name in design, f"module {path.relative_to(PKG)}"


def test_few_modules_lie_flat():
    """The package's root holds the face, ``python -m`` and the foundation; every other
    module lives in the folder of its layer."""
    flat = {p.stem for p in PKG.glob("*.py")}
    assert flat <= FLAT, f"modules flat in src/bderiv that belong in a folder: {flat - FLAT}"


@pytest.mark.parametrize("path", MODULES, ids=lambda p: str(p.relative_to(PKG)))
def test_imports_point_down(path):
    unit = _top(path)
    mine = _layer(unit)
    for other in _imported_units(path):
        if other in ("__init__", unit) or other in FOUNDATION:
            continue
        theirs = _layer(other)
        if mine is None:
            assert theirs is None, f"helper {unit} imports {other} (layer {theirs})"
        elif theirs is not None:
            assert theirs >= mine, f"{path.relative_to(PKG)} imports {other}, a layer above"


def _module(parts) -> str:
    """The module a path of parts names: ``["engine", "_engines"]`` ->
    ``engine/_engines/__init__``."""
    return "/".join(parts) + ("/__init__" if PKG.joinpath(*parts).is_dir() else "")


def test_no_modules_import_each_other_in_a_loop():
    """Inside a folder too, no module reaches itself through the imports (those made at
    the first call of a function included)."""
    arrows = {_module(p.relative_to(PKG).with_suffix("").parts):
              {_module(parts) for parts in _imported(p)} for p in MODULES}
    done, path = set(), []

    def visit(module):
        assert module not in path, "a loop of imports: " + " -> ".join(
            [*path[path.index(module):], module])
        if module in done:
            return
        path.append(module)
        for other in sorted(arrows.get(module, ())):
            visit(other)
        path.pop()
        done.add(module)

    for module in sorted(arrows):
        visit(module)


def test_kernels_import_nothing_of_the_package():
    for path in (PKG / "_kernels").glob("*.py"):
        others = set(_imported_units(path)) - {"_kernels", "__init__"} - FOUNDATION
        assert not others, f"{path.name} imports {others}"


def test_the_foundation_imports_nothing_of_the_package():
    assert not set(_imported_units(PKG / "_numerics.py"))
    assert not set(_imported_units(PKG / "_limits.py"))


@pytest.mark.parametrize("unit", sorted(FOUNDATION))
def test_every_number_is_explained_and_used(unit):
    """Each name of ``_limits`` and ``_numerics`` has its own ``#:`` line above it (or
    shares the block of the names defined with it) and is imported by some module of the
    package."""
    lines = (PKG / f"{unit}.py").read_text().splitlines()
    names = [(i, line.split("=")[0].strip()) for i, line in enumerate(lines)
             if line[:1].isupper() and "=" in line]
    assert names
    sources = [p.read_text() for p in MODULES if p.name not in ("_limits.py", "_numerics.py")]
    for i, name in names:
        j = i - 1
        while j >= 0 and lines[j][:1].isupper() and "=" in lines[j]:
            j -= 1  # a name defined in the same block as the one above
        assert lines[j].startswith("#:"), f"{name} has no #: line"
        assert any(re.search(rf"\b{name}\b", text) for text in sources), f"{name} is unused"
