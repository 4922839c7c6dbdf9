"""The stop rules the Python stop logic calls: numba's where this machine has them, else
the same code run as Python.

:mod:`bderiv.models.compiled.rules` holds the numbers the event logic decides by, in one
copy for both integrators. The compiled run compiles them into itself; the Python stop
logic calls them from Python, and compiling them there took about 1.8 s of a fresh
machine's first answer (a Python model's, or a compiled one's while the integrator
compiles). :data:`rules` gives each rule compiled where this machine has it (compiled in
this process, or in numba's disk cache: :func:`bderiv.models.readiness.machine_has`,
looked at most once a second per rule until then), else its Python twin: the same file run
with ``njit`` as the identity, so that a rule calling another calls the twin too. Nothing
here compiles a rule: the background compilation of the integrator does
(:func:`compile_for_python`), once per machine.

The rules are loops over scalars of float64 arrays. CPython's floats are the same IEEE
doubles, each operation rounded once, and numba compiles without fast-math (nothing fused
or reordered), so a twin returns the bits of its compiled rule on the same arrays (a NaN's
sign aside, which no comparison sees; ``tests/test_python_rules.py`` compares every
rule), with NumPy's floating-point warnings off as the compiled rules have none, and a run
may use either at any stop. Masks are the exception: compiled, a mask is an int64, so the
rules that read one go to their twins for a model of more than ``MAX_EVENTS`` events.
The twins are slower (the chair's Python flow map about 12 % slower with every rule a
twin); they serve until the compiled rules are on the machine.
"""

from __future__ import annotations

import functools
import pathlib
import time
import types

import numpy as np

from ..compiled import machine_has
from ..compiled import rules as _compiled
from ..compiled.stretch import MAX_EVENTS

#: the rules that read a region's mask bit by bit: compiled, an int64 mask holds
#: MAX_EVENTS events, so a model of more (the Python integrator's masks are Python ints)
#: calls their twins (compiled, bit k >= 64 read bit k - 64: a crossing refused as an
#: internal error once the machine had the compiled rules; a review)
_MASK_RULES = frozenset(("wrong_side", "reads_across", "carried_across", "first_sent_back"))

#: seconds between two looks at the disk cache for a rule still run as Python
POLL_SECONDS = 1.0
#: the import the file's text must hold once, and what runs in its place
_NJIT_IMPORT = "from numba import njit\n"
_IDENTITY = ("def njit(*args, **options):  # the rules as Python (events/_python_rules.py)\n"
             "    return args[0] if args and callable(args[0]) else (lambda fn: fn)\n")


def _twin() -> types.ModuleType:
    """:mod:`bderiv.models.compiled.rules` run as Python."""
    source = pathlib.Path(_compiled.__file__).read_text(encoding="utf-8")
    if source.count(_NJIT_IMPORT) != 1:
        raise RuntimeError(f"{_compiled.__file__} no longer imports njit as "
                           f"{_NJIT_IMPORT.strip()!r}: its Python twin cannot be made")
    module = types.ModuleType(__name__ + ".twin")
    module.__file__ = _compiled.__file__
    module.__package__ = _compiled.__package__  # its relative imports resolve as the file's
    exec(compile(source.replace(_NJIT_IMPORT, _IDENTITY), _compiled.__file__, "exec"),
         module.__dict__)
    return module


TWIN = _twin()


def _quiet(twin):
    """``twin`` with NumPy's floating-point warnings off, as its compiled rule runs (an
    overflow to inf, a NaN: IEEE's results, no warning: under warnings as errors the twin
    raised where the compiled rule returned)."""

    @functools.wraps(twin)
    def run(*args):
        with np.errstate(all="ignore"):
            return twin(*args)

    return run


def _by_events(name, compiled_rule):
    """Rule ``name`` (of :data:`_MASK_RULES`) compiled for models of at most
    :data:`MAX_EVENTS` events (its first argument has one entry per event), its twin
    for more."""
    twin = _quiet(getattr(TWIN, name))

    @functools.wraps(compiled_rule)
    def run(*args):
        return (compiled_rule if args[0].size <= MAX_EVENTS else twin)(*args)

    return run


class _Rules:
    """Each rule of :mod:`bderiv.models.compiled.rules`: compiled where the machine has it,
    else its twin (looked again at most every :data:`POLL_SECONDS`); constants as they
    are."""

    def __init__(self):
        self._chosen = {}  # name -> (function, compiled, monotonic time of the look)
        self.compiled_only = False  # compile_for_python: every rule compiled at its call

    def __getattr__(self, name):
        if name.startswith("_"):
            raise AttributeError(name)
        chosen = self._chosen.get(name)
        if chosen is not None and (chosen[1] or time.monotonic() - chosen[2] < POLL_SECONDS):
            return chosen[0]
        compiled = getattr(_compiled, name)
        if not hasattr(compiled, "py_func"):  # a constant
            return compiled
        here = self.compiled_only or machine_has(compiled)
        rule = (_by_events(name, compiled) if name in _MASK_RULES else compiled) if here \
            else _quiet(getattr(TWIN, name))
        self._chosen[name] = (rule, here, time.monotonic())
        return rule


#: the rules as the Python stop logic calls them
rules = _Rules()


def compile_for_python(run) -> None:
    """Call ``run()`` (a workload of the Python integrator) with every rule compiled at its
    call, for the disk cache: the background compilation of the integrator runs this first
    (:func:`bderiv.cli.warmup.compile_family`), so later processes find them."""
    rules.compiled_only = True
    rules._chosen.clear()
    try:
        run()
    finally:
        rules.compiled_only = False
        rules._chosen.clear()  # looked again at the next calls
