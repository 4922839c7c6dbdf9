"""The numbers compiled into kernels live in ``bderiv._numerics``, the one module of numbers
whose file keys the kernels' disk caches; ``bderiv._limits`` (Python-only defaults) keys
none, so editing a default of the command line or of a figure compiles nothing again
(issue 36).

The guard: no njit function of the package reads a value that comes from ``_limits``, be
it imported from it (directly or through another module), read as ``_limits.NAME``, or a
module-level constant computed from one. Checked on the functions' bytecode (the global
names each compiled function, and every function nested in it, reads), against the
names each module takes from ``_limits`` (found in its source).
"""

from __future__ import annotations

import ast
import gc
import importlib
import importlib.util
import pathlib
import pkgutil
import shutil
import sys
import types

import numba
from numba.core.dispatcher import Dispatcher

import bderiv
from bderiv import _limits, _numerics
from bderiv._kernels import _core
from bderiv._kernels._cache import sources_digest
from bderiv.models.compiled import _cached

LIMITS = "bderiv._limits"


def _assigned(tree) -> set:
    """Names assigned at the top level of a module."""
    names = set()
    for node in tree.body:
        targets = node.targets if isinstance(node, ast.Assign) else (
            [node.target] if isinstance(node, ast.AnnAssign) else [])
        for target in targets:
            names.update(n.id for n in ast.walk(target) if isinstance(n, ast.Name))
    return names


#: the names ``_limits`` defines
PYTHON_ONLY = _assigned(ast.parse(pathlib.Path(_limits.__file__).read_text()))


def tainted(modules) -> dict:
    """``{module name: (names, aliases)}``: the module's globals whose values come from
    ``_limits``'s own names (imported from it or from a module that has them, or assigned
    from an expression that reads one), and its names of the ``_limits`` module itself."""
    trees = {name: ast.parse(pathlib.Path(m.__file__).read_text())
             for name, m in modules.items() if getattr(m, "__file__", "").endswith(".py")}
    out = {name: (set(), set()) for name in trees}
    out[LIMITS] = (set(PYTHON_ONLY), set())
    changed = True
    while changed:
        changed = False
        for name, tree in trees.items():
            if name == LIMITS:
                continue
            names, aliases = out[name]
            before = len(names) + len(aliases)
            package = name if hasattr(modules[name], "__path__") else name.rpartition(".")[0]
            for node in ast.walk(tree):
                if isinstance(node, ast.ImportFrom):
                    source = importlib.util.resolve_name(
                        "." * node.level + (node.module or ""), package)
                    for a in node.names:
                        if f"{source}.{a.name}" == LIMITS:
                            aliases.add(a.asname or a.name)
                        elif a.name in out.get(source, ((), ()))[0]:
                            names.add(a.asname or a.name)
            for node in tree.body:  # constants computed from a tainted value
                if isinstance(node, ast.Assign | ast.AnnAssign) and node.value is not None:
                    read = {n.id for n in ast.walk(node.value) if isinstance(n, ast.Name)}
                    attrs = {(n.value.id, n.attr) for n in ast.walk(node.value)
                             if isinstance(n, ast.Attribute) and isinstance(n.value, ast.Name)}
                    if read & names or any(b in aliases and x in PYTHON_ONLY
                                           for b, x in attrs):
                        names |= _assigned(ast.Module(body=[node], type_ignores=[]))
            changed |= len(names) + len(aliases) != before
    return out


def _codes(code):
    yield code
    for const in code.co_consts:
        if isinstance(const, types.CodeType):
            yield from _codes(const)


def violations(dispatchers, taint) -> list:
    """``(function, name)`` for each njit function that reads a value of ``_limits``."""
    found = []
    for d in dispatchers:
        module = d.py_func.__globals__.get("__name__", "")
        names, aliases = taint.get(module, ((), ()))
        for code in _codes(d.py_func.__code__):
            read = set(code.co_names)
            bad = read & set(names)
            if read & set(aliases):
                bad |= read & PYTHON_ONLY
            found += [(f"{module}:{d.py_func.__qualname__}", n) for n in sorted(bad)]
    return found


def _package_dispatchers():
    # gc.get_objects() leaves out frozen objects: the suite freezes what each file leaves
    # alive (tests/conftest.py), so thaw them first (the next file's end freezes them again)
    gc.unfreeze()
    # type(), not isinstance: a dead weak proxy among gc's objects raises on __class__
    return [o for o in gc.get_objects() if issubclass(type(o), Dispatcher)
            and (o.py_func.__module__ or "").startswith("bderiv")]


def _import_all() -> dict:
    for info in pkgutil.walk_packages(bderiv.__path__, "bderiv."):
        try:
            importlib.import_module(info.name)
        except ImportError:  # an optional extra that is not installed: its kernels too
            pass
    return {n: m for n, m in sys.modules.items()
            if m is not None and (n == "bderiv" or n.startswith("bderiv."))}


def test_no_kernel_reads_a_python_only_number():
    modules = _import_all()
    dispatchers = _package_dispatchers()
    from bderiv.models import readiness

    assert all(any(d is o for o in dispatchers) for d in readiness.DISPATCHERS)  # all found
    found = violations(dispatchers, tainted(modules))
    assert not found, (f"njit code reads values of bderiv._limits (Python-only: its file keys "
                       f"no cache): {found}; move them to bderiv._numerics")


def test_the_guard_sees_a_number_of_limits_in_njit_code(tmp_path):
    """The check itself: a kernel that reads a default of ``_limits`` (imported, through
    the module, or through a constant computed from it) is found."""
    source = tmp_path / "probe.py"
    source.write_text(
        "import numba\n"
        "from bderiv import _limits\n"
        "from bderiv._limits import DEFAULT_RTOL\n"
        "from bderiv._numerics import MIN_RTOL\n"
        "TWICE = 2 * DEFAULT_RTOL\n"
        "@numba.njit\n"
        "def direct():\n    return DEFAULT_RTOL + MIN_RTOL\n"
        "@numba.njit\n"
        "def derived():\n    return TWICE\n"
        "@numba.njit\n"
        "def attribute():\n    return _limits.DEFAULT_ATOL\n"
        "@numba.njit\n"
        "def clean():\n    return MIN_RTOL\n")
    spec = importlib.util.spec_from_file_location("bderiv._probe_numerics", source)
    probe = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(probe)
    taint = tainted({"bderiv._probe_numerics": probe, LIMITS: _limits})
    found = violations([probe.direct, probe.derived, probe.attribute, probe.clean], taint)
    assert sorted(found) == [("bderiv._probe_numerics:attribute", "DEFAULT_ATOL"),
                             ("bderiv._probe_numerics:derived", "TWICE"),
                             ("bderiv._probe_numerics:direct", "DEFAULT_RTOL")]
    assert isinstance(probe.clean, numba.core.registry.CPUDispatcher)


def test_the_caches_are_keyed_by_the_numerics_not_the_defaults():
    kernels = pathlib.Path(_core.__file__).parent
    assert _core.SOURCES == sources_digest(kernels, _numerics.__file__)
    # the integrator's key also covers the pointer call compiled into its run
    from bderiv._kernels import _pointer

    assert _cached.sources_key() == sources_digest(pathlib.Path(_cached.__file__).parent,
                                                   _numerics.__file__, _pointer.__file__,
                                                   skip=_cached.PYTHON_ONLY)
    assert not PYTHON_ONLY & set(vars(_numerics))


def test_the_integrators_key_leaves_out_only_files_no_compiled_code_reads(tmp_path):
    """``_cached.PYTHON_ONLY`` (the files of ``models/compiled/`` outside the integrator's
    key, so that an edit of them compiles nothing again) define no numba function, and no
    other file of the folder imports them: what they hold never reaches compiled code."""
    folder = pathlib.Path(_cached.__file__).parent
    package = _cached.__package__
    names = {path.stem for path in folder.glob("*.py")}
    skipped = {name[:-3] for name in _cached.PYTHON_ONLY}
    assert skipped <= names and "__init__" in skipped
    out = {f"{package}.{stem}" for stem in skipped - {"__init__"}} | {package}
    for stem in sorted(names - skipped):
        tree = ast.parse((folder / f"{stem}.py").read_text(encoding="utf-8"))
        for node in ast.walk(tree):  # every import, relative or absolute, made absolute
            if isinstance(node, ast.Import):
                read = {a.name for a in node.names}
            elif isinstance(node, ast.ImportFrom):
                base = importlib.util.resolve_name("." * node.level + (node.module or ""),
                                                   package) if node.level else node.module
                read = ({f"{base}.{a.name}" if a.name in names else base for a in node.names}
                        if base == package else {base})  # a submodule, or __init__'s name
            else:
                continue
            assert not read & out, f"{stem}.py imports {read & out}, out of the key"
    # numba's ways of making compiled code, in the skipped files' code (not their text)
    makers = {"njit", "jit", "intrinsic", "overload", "overload_method", "register_jitable",
              "jitclass", "structref", "generated_jit", "cfunc", "checked_njit", "eager"}
    for stem in sorted(skipped):
        tree = ast.parse((folder / f"{stem}.py").read_text(encoding="utf-8"))
        used = {node.id for node in ast.walk(tree) if isinstance(node, ast.Name)} | \
            {node.attr for node in ast.walk(tree) if isinstance(node, ast.Attribute)}
        assert not used & makers, f"{stem}.py uses {used & makers}: its edits must key it"
        if stem != "__init__":
            module = importlib.import_module(f"{package}.{stem}")
            assert not [value for value in vars(module).values()
                        if isinstance(value, Dispatcher)
                        and value.py_func.__module__ == module.__name__], stem
    # an edit of a skipped file leaves the key as it was; an edit of a kept one changes it
    copy = tmp_path / "compiled"
    shutil.copytree(folder, copy, ignore=shutil.ignore_patterns("__pycache__"))

    def key():
        return sources_digest(copy, skip=_cached.PYTHON_ONLY)

    first = key()
    with open(copy / "model.py", "a", encoding="utf-8") as fh:
        fh.write("# an edit\n")
    assert key() == first
    with open(copy / "_run.py", "a", encoding="utf-8") as fh:
        fh.write("# an edit\n")
    assert key() != first


def _callees(fn, seen=None):
    """The dispatchers ``fn``'s code names (globals, and attributes of global modules, in
    its nested code too), and those of the uncached helpers of its own file it calls
    (compiled into it)."""
    seen = set() if seen is None else seen
    names = {name for code in _codes(fn.__code__) for name in code.co_names}
    for name in names:
        value = fn.__globals__.get(name)
        found = ([getattr(value, attr) for attr in names
                  if isinstance(getattr(value, attr, None), Dispatcher)]
                 if isinstance(value, types.ModuleType)
                 else [value] if isinstance(value, Dispatcher) else [])
        for callee in found:
            if id(callee) in seen:
                continue
            seen.add(id(callee))
            yield callee
            if (callee.py_func.__module__ == fn.__module__
                    and callee.stats.cache_path is None):
                yield from _callees(callee.py_func, seen)


def test_a_kernel_cached_under_its_own_name_calls_kernels_of_its_own_file_only():
    """Numba invalidates a cached kernel when its own file changes, not when a callee's
    file does (the callee is compiled into it): a cached kernel of bderiv that calls a
    kernel of another file must be cached under a digest of both (``.k<digest>``), else an
    edit of the callee's file leaves the caller's stale entry in use."""
    for name, module in _import_all().items():
        for value in list(vars(module).values()):
            if (not isinstance(value, Dispatcher) or value.py_func.__module__ != name
                    or value.stats.cache_path is None
                    or ".k" in value.py_func.__qualname__):
                continue
            for callee in _callees(value.py_func):
                assert callee.py_func.__module__ == name, (
                    f"{name}.{value.py_func.__qualname__} is cached under its own "
                    f"name and calls {callee.py_func.__module__}."
                    f"{callee.py_func.__qualname__}")
