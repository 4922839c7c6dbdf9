"""docs/design.md is true to the code: its modules exist and imports point down its layers."""

from __future__ import annotations

import ast
import pathlib
import re

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1]
PKG = ROOT / "src" / "bderiv"

#: the layers of docs/design.md, top to bottom; a module may import its own layer and the
#: layers below, never one above.
LAYERS = [
    {"cli", "__main__"},
    {"control"},  # trajectory optimisation through contact, on examples and the models
    {"plot", "examples", "_bench", "symbolic", "jax", "warmup", "estimate", "robots"},
    # _bench: `bderiv bench`'s sweep; warmup: `bderiv compile`; estimate: the Kalman
    # filter; robots: models from URDFs
    {"models", "models/system", "models/calls", "models/user_functions", "models/section",
     "orbit", "jacobians", "_numdiff", "stability_map"},
    {"checks", "models/assembly"},  # assembly: the model's B-derivatives, group by group
    {"models/integrate", "models/readiness", "flowmap", "returnmap", "stability"},
    {"models/events"},  # the event logic at a stop, for both integrators
    {"models/compiled"},  # the compiled integrator
    {"bderivative", "_geometry", "triangulation", "_triangulation_io"},
    {"corners", "_engines", "_linearise"},  # _linearise scales rows with a kernel
    {"_kernels"},
]
#: helpers any layer may use; they import only each other and the foundation.
HELPERS = {"_batch", "_validate", "_format", "_tables", "_dask", "_progress", "_baselines",
           "_cyclic", "_safefiles", "_errors", "_compiling"}
#: the numbers (tolerances, sizes, limits): every module may import them, the kernels and
#: the helpers included; they import nothing of the package but each other (``_numerics``:
#: those compiled into kernels; ``_limits``: the Python-only ones; neither imports the other).
FOUNDATION = {"_limits", "_numerics"}


def _unit(parts) -> str:
    """The unit of a module path: ``cli/render`` -> ``cli``; in the model side's
    sub-package one level down: ``models/events/locate`` -> ``models/events``."""
    if parts[0] == "models" and len(parts) > 1 and parts[1] != "__init__":
        return "models/" + parts[1]
    return parts[0]


def _top(path: pathlib.Path) -> str:
    """The unit of a module file: ``cli/render.py`` -> ``cli``."""
    return _unit(path.relative_to(PKG).with_suffix("").parts)


def _imported_units(path: pathlib.Path):
    """Top-level package units imported by a module (relative imports resolved)."""
    depth = len(path.relative_to(PKG).parts) - 1  # 0 for a module at the package root
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            for alias in node.names:
                parts = alias.name.split(".")
                if parts[0] == "bderiv" and len(parts) > 1:
                    yield _unit(parts[1:])
        elif isinstance(node, ast.ImportFrom):
            if node.level == 0:
                if node.module and node.module.split(".")[0] == "bderiv":
                    parts = node.module.split(".")[1:]
                    yield from ([_unit(parts)] if parts else [a.name for a in node.names])
                continue
            up = node.level - 1  # levels above the module's own package
            if up > depth:
                continue
            base = list(path.relative_to(PKG).parts[: depth - up])
            parts = base + (node.module.split(".") if node.module else [])
            if parts == ["models"] and not node.module:  # from . import x (in models)
                yield from ("models/" + a.name for a in node.names)
            elif parts:
                yield _unit(parts)
            else:  # from . import x (at the package root)
                yield from (a.name for a in node.names)


def _layer(unit: str):
    if unit in HELPERS or unit in FOUNDATION:
        return None
    for i, layer in enumerate(LAYERS):
        if unit in layer:
            return i
    raise AssertionError(f"module {unit!r} is in no layer of docs/design.md")


MODULES = sorted(p for p in PKG.rglob("*.py") if p != PKG / "__init__.py")  # the public face


def test_every_module_is_placed_and_named_in_the_design():
    design = (ROOT / "docs" / "design.md").read_text()
    for unit in {_top(p) for p in MODULES}:
        _layer(unit)
        assert unit.removesuffix(".py") in design or unit == "__main__", unit


@pytest.mark.parametrize("path", MODULES, ids=lambda p: str(p.relative_to(PKG)))
def test_imports_point_down(path):
    unit = _top(path)
    mine = _layer(unit)
    for other in _imported_units(path):
        if other in ("__init__", unit) or other == "__version__" or other in FOUNDATION:
            continue
        theirs = _layer(other)
        if mine is None:
            assert theirs is None, f"helper {unit} imports {other} (layer {theirs})"
        elif theirs is not None:
            assert theirs >= mine, f"{path.relative_to(PKG)} imports {other}, a layer above"


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
