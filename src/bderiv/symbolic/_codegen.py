"""The Python source of a symbolic model's numba kernels: derivation, cse and printing.

:func:`generate` differentiates the model's expressions (exact Jacobians by
:func:`sympy.diff`), shares their common subexpressions (:func:`sympy.cse`, one pass per
kernel) and prints one module of ``@numba.njit(cache=True)`` kernels, compiled (or loaded
from the cache) for the signatures :data:`SIGNATURES` by
:func:`bderiv.symbolic._model.compile_kernels` (in ``KERNELS`` order: ``corner_field``
calls ``field``). The kernels have the signatures of a compiled model
(:class:`bderiv.models.compiled.CompiledModel` with ``params``): their ``x`` (d + m,) is
the state then the m parameter values (another length is refused: a ValueError, whose
message names the length, before any entry is read), and each returns a new array:

=====================================================  =====================
kernel                                                 returns
=====================================================  =====================
``field(x, mask)``                                     (d,)
``field_jacobian(x, mask)``                            (d, d), by the state
``events(x)``                                          (n,)
``event_jacobian(x)``                                  (n, d)
``corner_field(x)``                                    (2**n, d), all masks
``reset(x, mask, k)`` (models with resets)             (d,)
``reset_jacobian(x, mask, k)``                         (d, d)
=====================================================  =====================

so the compiled integrator calls ``field``, ``events`` and ``field_jacobian`` directly
(no Python per step) and a parameter change is another array, not another compilation.
Flag k is bit k of ``mask`` (as a float); an event without a reset expression is the
identity in ``reset``. sympy is used through its module attributes (``sympy.diff``,
``sympy.cse``) at call time.
"""

from __future__ import annotations

import contextlib
import math
import re

from ._inputs import require_sympy

#: bump when the generated source changes: old cache files are then no longer used
CODEGEN_VERSION = 4

#: the kernels of every model, then those of models with resets
KERNELS = ("field", "field_jacobian", "events", "event_jacobian", "corner_field")
RESET_KERNELS = ("reset", "reset_jacobian")

_X1 = "float64[::1]"
_X2 = "float64[:, ::1]"
SIGNATURES = {
    "field": f"{_X1}({_X1}, int64)",
    "field_jacobian": f"{_X2}({_X1}, int64)",
    "events": f"{_X1}({_X1})",
    "event_jacobian": f"{_X2}({_X1})",
    "corner_field": f"{_X2}({_X1})",
    "reset": f"{_X1}({_X1}, int64, int64)",
    "reset_jacobian": f"{_X2}({_X1}, int64, int64)",
}


class CoefficientOverflow(ArithmeticError):
    """A number of an expression beyond the range of a double (raised by the printer)."""


#: characters of an expression a :class:`CodegenError` shows as it is; a longer one (a
#: 400-digit coefficient) is shown with its numbers to 4 digits, and cut if still longer
SHOWN_CHARS = 200


class CodegenError(ValueError):
    """An expression that cannot be printed as Python (an undefined function, a
    derivative sympy cannot evaluate, ...): ``label`` names it."""

    def __init__(self, label, expr, reason):
        self.label = label
        super().__init__(f"{label} = {_shown(expr)} does not compile: {reason}")


def _shown(expr) -> str:
    """``expr`` as a message shows it (:data:`SHOWN_CHARS`): its numbers to 4 digits
    where it is longer (inside functions and conditions too: sympy's ``N`` leaves
    ``sin(10**400*x)`` as it is; integers below 10**15 kept, so that ``x**2`` stays), cut
    where it is still longer. Whatever the expression holds, the message is made (an
    integer of more than 4300 digits does not even print)."""
    text = None
    with contextlib.suppress(Exception):
        text = str(expr)
    if text is None or len(text) > SHOWN_CHARS:
        with contextlib.suppress(Exception):  # sympy's N of whatever the model holds
            sympy = require_sympy()
            rounded = {n: n.evalf(4) for n in expr.atoms(sympy.Number)
                       if not n.is_Integer or abs(n) >= 10**15}
            text = str(sympy.N(expr.xreplace(rounded), 4))
    text = type(expr).__name__ if text is None else text
    return text if len(text) <= SHOWN_CHARS else f"{text[:SHOWN_CHARS - 4]} ..."


def _reason(exc) -> str:
    """The first line of a printer's exception, without the printer's class."""
    first = str(exc).strip().splitlines()[0] if str(exc).strip() else ""
    first = re.sub(r"^Unsupported by <class '[^']*'>: ", "", first)
    return f"{type(exc).__name__}: {first}"


def _printer():
    sympy = require_sympy()
    from sympy.printing.pycode import PythonCodePrinter

    def double(expr) -> str:
        value = float(expr)
        if not math.isfinite(value):  # repr would print inf, an undefined name
            raise CoefficientOverflow(f"the coefficient {sympy.N(expr, 3)} overflows a "
                                      f"double (float64 ends near 1.8e308)")
        return repr(value)

    class Printer(PythonCodePrinter):
        def _print_Float(self, expr):  # every bit of the double, not 15 digits
            return double(expr)

        def _print_Integer(self, expr):  # beyond 2**53 an int64 literal could overflow
            return str(expr.p) if abs(expr.p) <= 2**53 else double(expr)

        def _print_Rational(self, expr):  # p/q correctly rounded, whatever their size
            return double(expr)

    try:
        printer = Printer({"fully_qualified_modules": True, "strict": True})
    except TypeError:  # sympy < 1.13 has no "strict": checked through _not_supported
        printer = Printer({"fully_qualified_modules": True})
    return printer


def print_expr(printer, expr, label: str, shown=None) -> str:
    """``expr`` as Python source, or a :class:`CodegenError` naming ``label`` and
    ``shown`` (the expression in the user's symbols; default ``expr``)."""
    shown = expr if shown is None else shown
    # a DiracDelta is the derivative of a jump (sign, Heaviside) in the state
    jumps = (" (a DiracDelta: the derivative of a jump in the state, as of sign or "
             "Heaviside; a switch in the state is an event: write it as one, the two sides' "
             "expressions chosen by its flag)"
             if expr.has(require_sympy().DiracDelta) else "")
    printer._not_supported = set()
    try:
        text = printer.doprint(expr)
    except CoefficientOverflow as exc:
        raise CodegenError(label, shown, str(exc)) from None
    except Exception as exc:  # sympy raises PrintMethodNotImplementedError and others
        raise CodegenError(label, shown, f"sympy cannot print it as Python ({_reason(exc)})"
                                         f"{jumps}") from None
    if printer._not_supported:
        what = ", ".join(sorted(map(str, printer._not_supported)))
        raise CodegenError(label, shown, f"not supported in Python: {what}{jumps}")
    return text


def _block(printer, model, outputs, indent: str) -> list:
    """Lines computing ``outputs`` [(target, expr, label)], subexpressions shared.

    A failure of the shared print is located by printing each output alone.
    """
    sp = require_sympy()
    exprs = [e for _, e, _ in outputs]
    temps, reduced = sp.cse(exprs, symbols=sp.numbered_symbols("c_"), order="none")
    try:
        lines = [f"{indent}{t} = {print_expr(printer, e, '')}" for t, e in temps]
        lines += [f"{indent}{target} = {print_expr(printer, e, '')}"
                  for (target, _, _), e in zip(outputs, reduced, strict=True)]
    except CodegenError:
        for _, e, label in outputs:
            print_expr(printer, e, label, model.show(e))
        raise
    return lines


def length_check(model) -> list:
    """A kernel's first lines: ``x`` of another length than the state's and the
    parameters' is refused (a ValueError with a constant message: compiled code reads no
    further than it is told, so a short ``x`` would be read past its end)."""
    d, m = model.dim, len(model.p)
    after = (f"then the {m} parameter values in the order of param_names" if m else
             "(the model has no parameters)")
    return [f"    if x.shape[0] != {d + m}:",
            f'        raise ValueError("x must have {d + m} entries: the state ({d}) {after}")']


def _preamble(model, mask: bool, out=None, check=True) -> list:
    """The length check (:func:`length_check`, unless ``check`` is False), the state,
    flags and parameters as locals (the parameters after the state in ``x``), and ``out``
    when its shape is given: ``np.empty`` for a vector (every entry is written),
    ``np.zeros`` for a matrix (a Jacobian writes its nonzero entries only). (Not
    ``out[:, :] = 0.0``: numba's slice assignment costs a few tenths of a second of
    compiling per kernel.)"""
    d = model.dim
    lines = length_check(model) if check else []
    lines += [f"    x_{i} = x[{i}]" for i in range(d)]
    if mask:
        lines += [f"    s_{k} = float((mask >> {k}) & 1)" for k in range(model.n_events)]
    lines += [f"    p_{j} = x[{d + j}]" for j in range(len(model.p))]
    if out is not None:
        lines.append(f"    out = np.{'zeros' if isinstance(out, tuple) else 'empty'}({out})")
    return lines


def _kernel(name, args, body) -> list:
    """A kernel returning ``out`` (its body allocates and fills it)."""
    return ["", "@numba.njit(cache=True)", f"def {name}({args}):", *body, "    return out"]


def _vector(printer, model, exprs, label, indent="    "):
    outputs = [(f"out[{i}]", e, f"{label}[{i}]") for i, e in enumerate(exprs)]
    return _block(printer, model, outputs, indent)


def _jacobian(printer, model, exprs, label, indent="    "):
    """Lines writing the nonzero derivatives of ``exprs`` by ``x`` into ``out``
    (len(exprs), d), zeros (:func:`_preamble`)."""
    sp = require_sympy()
    outputs = []
    for i, e in enumerate(exprs):
        for j, xj in enumerate(model.x):
            de = sp.diff(e, xj)
            if de != 0:
                outputs.append((f"out[{i}, {j}]", de, f"the derivative of {label}[{i}] by "
                                                      f"{model.show(xj)}"))
    return _block(printer, model, outputs, indent)


def _resets(printer, model, jacobian: bool) -> list:
    """The body of ``reset`` / ``reset_jacobian``: one branch per event with a reset,
    the identity for the others."""
    body = []
    for branch, (k, exprs) in enumerate(model.resets.items()):
        body.append(f"    {'if' if branch == 0 else 'elif'} k == {k}:")
        label = f"resets[{k}]"
        body += (_jacobian(printer, model, exprs, label, "        ") if jacobian
                 else _vector(printer, model, exprs, label, "        "))
    body.append("    else:")
    if jacobian:
        body += [f"        for i in range({model.dim}):",
                 "            out[i, i] = 1.0"]
    else:
        body += [f"        for i in range({model.dim}):", "            out[i] = x[i]"]
    return body


def generate(model, key: str) -> str:
    """The source of the kernel module of ``model`` (a :class:`~._inputs.Model`).

    Raises
    ------
    CodegenError
        If an expression or a derivative cannot be printed as Python (named).
    """
    sp = require_sympy()
    printer = _printer()
    for label, e in model.labelled():  # name the user's expression that fails, if any
        print_expr(printer, e, label, model.show(e))
    d, n = model.dim, model.n_events
    lines = [f"# generated by bderiv.symbolic (codegen version {CODEGEN_VERSION}, sympy "
             f"{sp.__version__}); key {key}",
             "# do not edit: delete this file (and __pycache__) to regenerate",
             "import math  # noqa: F401",
             "", "import numba", "import numpy as np", "",
             f"DIM = {d}", f"N_EVENTS = {n}",
             f"N_PARAMS = {len(model.p)}", f"HAS_RESETS = {bool(model.resets)}"]
    lines += _kernel("field", "x, mask", _preamble(model, True, d)
                     + _vector(printer, model, model.field, "field"))
    lines += _kernel("field_jacobian", "x, mask", _preamble(model, True, (d, d))
                     + _jacobian(printer, model, model.field, "field"))
    lines += _kernel("events", "x", _preamble(model, False, n)
                     + _vector(printer, model, model.events, "events"))
    lines += _kernel("event_jacobian", "x", _preamble(model, False, (n, d))
                     + _jacobian(printer, model, model.events, "events"))
    lines += _kernel("corner_field", "x", corner_body(model))
    if model.resets:
        lines += _kernel("reset", "x, mask, k", _preamble(model, True, d)
                         + _resets(printer, model, False))
        lines += _kernel("reset_jacobian", "x, mask, k", _preamble(model, True, (d, d))
                         + _resets(printer, model, True))
    return "\n".join(lines) + "\n"


def corner_body(model) -> list:
    """The body of ``corner_field``: ``field`` at every mask, copied entry by entry
    (``out[mask] = row``, numba's array-into-slice assignment, took 2 s of compiling
    against 0.3 s)."""
    return [*length_check(model), f"    out = np.empty(({1 << model.n_events}, {model.dim}))",
            "    for mask in range(out.shape[0]):",
            "        row = field(x, mask)",
            f"        for i in range({model.dim}):",
            "            out[mask, i] = row[i]"]


def probe_source(model) -> str:
    """A module with one kernel per user expression, ``probe_<i>(x, mask) -> float``
    in the order of ``model.labelled()``: compiled one by one to find the expression that
    numba refuses when the model's module does not compile."""
    printer = _printer()
    lines = ["import math  # noqa: F401", "", "import numba"]
    for i, (label, e) in enumerate(model.labelled()):
        lines += ["", f"def probe_{i}(x, mask):  # {label}",
                  *_preamble(model, True, check=False),
                  f"    return {print_expr(printer, e, label, model.show(e))}"]
    return "\n".join(lines) + "\n"
