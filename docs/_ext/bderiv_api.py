"""The API reference of the documentation site, made from the package itself.

``.. bderiv-api::`` (in ``api.rst``) documents, with autodoc, the names of ``bderiv.__all__`` as
``bderiv.<name>`` and then every public module of the public sub-packages (``__all__``, or
the public names a module defines), each object once. The list follows the package: a
module moved or added needs no edit here.

Every Python cross-reference of the docstrings (``:func:``, ``:class:``, ``:mod:``, ...) is
checked: a name that Sphinx does not find among the documented objects is looked up in the
package (a module, then attributes); a documented object reached by another name (a
re-export, a module path) links to its entry, an existing object outside the reference
(an internal helper) is set as code, and a name that does not exist is a warning, an error
in the tests' build (``-W``).
"""

from __future__ import annotations

import importlib
import inspect
import pkgutil
import re
import types

from docutils import nodes
from docutils.statemachine import StringList
from sphinx.util.docutils import SphinxDirective
from sphinx.util.nodes import make_refnode, nested_parse_with_titles

#: sub-packages left out of the reference: the command line's internals and the model layer
#: (whose public names are the package's: ``bderiv.HybridSystem``, ``bderiv.SolverOptions``)
SKIP = ("bderiv.cli", "bderiv.models")
#: abbreviations the docstrings use for other packages
ALIASES = {"np": "numpy", "sp": "scipy"}


def public_modules(package):
    """The public modules below ``package``, sorted (a module path with no ``_`` part)."""
    names = [m.name for m in pkgutil.walk_packages(package.__path__, package.__name__ + ".")]
    return sorted(n for n in names if not any(p.startswith("_") for p in n.split("."))
                  and not n.startswith(tuple(s + "." for s in SKIP)) and n not in SKIP)


def module_names(module):
    """The public names of a module: its ``__all__``, else what it defines."""
    names = getattr(module, "__all__", None)
    if names is None:
        names = [n for n, v in vars(module).items() if not n.startswith("_")
                 and getattr(v, "__module__", None) == module.__name__]
    return [n for n in names if not isinstance(getattr(module, n, None), types.ModuleType)
            and not n.startswith("__")]


def directive_for(obj) -> str:
    if inspect.isclass(obj):
        return "autoclass"
    if callable(obj):
        return "autofunction"
    return "autodata"


class Reference:
    """What the reference documents: rST lines, and documented name by object."""

    def __init__(self):
        self.lines, self.name_of = [], {}

    def add(self, name, obj):
        self.name_of.setdefault(id(obj), name)
        options = ["   :members:", "   :inherited-members:"] if inspect.isclass(obj) else []
        self.lines += [f".. {directive_for(obj)}:: {name}", *options, ""]
        if inspect.isclass(obj):
            for member in dir(obj):
                if not member.startswith("_"):
                    try:
                        value = inspect.getattr_static(obj, member)
                    except AttributeError:
                        continue
                    self.name_of.setdefault(id(value), f"{name}.{member}")


def build_reference() -> Reference:
    import bderiv

    ref = Reference()
    ref.lines += ["The package", "-----------", "", ".. module:: bderiv", ""]
    for name in sorted(bderiv.__all__, key=str.lower):
        obj = getattr(bderiv, name)
        if not isinstance(obj, types.ModuleType) and not name.startswith("__"):
            ref.add(f"bderiv.{name}", obj)
    for modname in public_modules(bderiv):
        module = importlib.import_module(modname)
        names = [n for n in module_names(module) if id(getattr(module, n)) not in ref.name_of]
        ref.name_of.setdefault(id(module), modname)
        title = f"``{modname}``"
        parent, _, last = modname.rpartition(".")
        if getattr(importlib.import_module(parent), last) is module:
            ref.lines += [title, "-" * len(title), "", f".. automodule:: {modname}",
                          "   :no-members:", ""]
        else:  # the parent package's attribute of that name is a function (examples.chair)
            ref.lines += [title, "-" * len(title), "", f".. currentmodule:: {modname}", "",
                          *(module.__doc__ or "").splitlines(), ""]
        for name in names:
            ref.add(f"{modname}.{name}", getattr(module, name))
    return ref


class ApiDirective(SphinxDirective):
    def run(self):
        ref = build_reference()
        self.env.bderiv_names = ref.name_of  # the build's environment, read by resolve
        node = nodes.section()
        node.document = self.state.document
        nested_parse_with_titles(self.state, StringList(ref.lines, "<bderiv-api>"), node)
        return node.children


MISSING = object()


def lookup(path: str):
    """The object a dotted name points at (a module, then attributes), or ``MISSING``."""
    parts = path.split(".")
    parts[0] = ALIASES.get(parts[0], parts[0])
    for cut in range(len(parts), 0, -1):
        try:
            obj = importlib.import_module(".".join(parts[:cut]))
        except Exception:  # noqa: BLE001 (not a module: try a shorter prefix)
            continue
        for attr in parts[cut:]:
            obj = member(obj, attr)
            if obj is MISSING:
                break
        if obj is not MISSING:
            return obj
    builtin = getattr(__import__("builtins"), path, MISSING)
    return builtin


def member(obj, attr):
    """``obj.attr`` as stored (a property, not its value), with dataclass and named-tuple
    fields and annotated attributes counted as members; ``MISSING`` when absent."""
    try:
        return inspect.getattr_static(obj, attr)
    except AttributeError:
        pass
    if inspect.isclass(obj):
        for klass in obj.__mro__:
            if attr in getattr(klass, "__annotations__", {}):
                return ("field", klass, attr)
            try:  # an instance attribute: assigned as self.attr in the class's code
                source = inspect.getsource(klass)
            except (OSError, TypeError):
                continue
            if re.search(rf"self\.{re.escape(attr)}\b[^\n=]*=(?!=)", source):
                return ("instance attribute", klass, attr)
    return MISSING


def resolve(app, env, node, contnode):
    """Sphinx's ``missing-reference``: a Python name found in the package, or ``None``."""
    if node.get("refdomain") != "py":
        return None
    target = node["reftarget"].lstrip(".~")
    module, klass = node.get("py:module"), node.get("py:class")
    candidates = [target]
    if module and klass:
        candidates.append(f"{module}.{klass}.{target}")
    if module:
        candidates.append(f"{module}.{target}")
    # the scope the docstring is written in: "docstring of bderiv.analysis.system.X.f" looks
    # in X, then in bderiv.analysis.system, ... (a name imported or defined there)
    _, _, owner = (node.source or "").partition("docstring of ")
    parts = owner.split(".") if owner else []
    candidates += [".".join([*parts[:cut], target]) for cut in range(len(parts), 0, -1)]
    if not hasattr(env, "bderiv_names"):  # the reference page was not read in this build
        env.bderiv_names = build_reference().name_of
    names = env.bderiv_names
    objects = env.get_domain("py").objects
    for candidate in candidates:
        obj = lookup(candidate)
        if obj is MISSING:
            continue
        name = names.get(id(obj))
        if name in objects:
            entry = objects[name]
            return make_refnode(app.builder, node["refdoc"], entry.docname, entry.node_id,
                                contnode, name)
        return contnode
    return None


def setup(app):
    app.add_directive("bderiv-api", ApiDirective)
    app.connect("missing-reference", resolve)
    return {"parallel_read_safe": False, "parallel_write_safe": True}
