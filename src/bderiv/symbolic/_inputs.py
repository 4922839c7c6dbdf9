"""Checks of :func:`~bderiv.symbolic.from_sympy`'s arguments and their canonical form.

The user's symbols are replaced by real symbols ``x_i`` (state), ``s_k`` (flags) and
``p_j`` (parameters, in the order of ``params``): the expressions then print as valid
Python whatever the user called the symbols, differentiate as real functions (``Abs``
gives ``sign``), and hash the same for the same model (:func:`canonical_text`).
"""

from __future__ import annotations

import numbers
from dataclasses import dataclass

import numpy as np

from .._support._validate import check_value


def require_sympy():
    """The ``sympy`` module, or an ImportError saying how to install it."""
    try:
        import sympy
    except ImportError:
        raise ImportError("bderiv.symbolic needs sympy: pip install 'bderiv[symbolic]' "
                          "(or pip install 'sympy>=1.12')") from None
    return sympy


@dataclass(frozen=True)
class Model:
    """A checked symbolic model over the canonical symbols.

    Attributes
    ----------
    field : tuple of sympy.Expr, length d
    events : tuple of sympy.Expr, length n
    resets : dict
        ``{k: tuple of d sympy.Expr}`` for the events that have a reset.
    x, s, p : tuple of sympy.Symbol
        The canonical state (d), flag (n) and parameter symbols.
    param_names : tuple of str
        The user's names of the parameters, in the order of ``p``.
    values : ndarray, shape (len(p),)
        The parameter values.
    original : dict
        Canonical symbol -> the user's symbol.
    """

    field: tuple
    events: tuple
    resets: dict
    x: tuple
    s: tuple
    p: tuple
    param_names: tuple
    values: np.ndarray
    original: dict

    def show(self, e):
        """``e`` in the user's symbols (for messages)."""
        return e.xreplace(self.original)

    @property
    def dim(self) -> int:
        return len(self.x)

    @property
    def n_events(self) -> int:
        return len(self.s)

    def labelled(self):
        """``(label, expression)`` of every user expression: ``field[i]``, ``events[k]``,
        ``resets[k][i]``."""
        yield from ((f"field[{i}]", e) for i, e in enumerate(self.field))
        yield from ((f"events[{k}]", e) for k, e in enumerate(self.events))
        for k in sorted(self.resets):
            yield from ((f"resets[{k}][{i}]", e) for i, e in enumerate(self.resets[k]))

    def canonical_text(self) -> list:
        """Strings that identify the model (not the parameter values): the cache key."""
        memo = {}
        return [f"d={self.dim} n={self.n_events} p={len(self.p)}",
                *(f"{label}={tree_text(e, memo)}" for label, e in self.labelled())]


def tree_text(e, memo: dict) -> str:
    """The expression tree of ``e`` as text: each node's class and its arguments' texts,
    the leaves (symbols with their assumptions, numbers with every bit) by
    :func:`sympy.srepr`. The information of ``srepr(e)`` at a fraction of its cost
    (docs/benchmarks.md, "Kernel design choices, measured"), a subtree met again taken
    from ``memo`` (keyed by class too: ``Float(1.0) == 1`` may hold)."""
    key = (type(e), e)
    text = memo.get(key)
    if text is None:
        if e.args:
            text = f"{type(e).__name__}({','.join(tree_text(a, memo) for a in e.args)})"
        else:
            try:
                text = require_sympy().srepr(e)
            except ValueError:  # a rational of more than 4300 digits: Python's str(int)
                text = f"{type(e).__name__}({e.p:#x}, {e.q:#x})"  # refuses it; hex is exact
        memo[key] = text
    return text


def _sequence(seq, name: str, what: str) -> list:
    """``list(seq)``, refusing a single sympy object, a string, a non-sequence or a matrix
    that is not a row or a column (``list`` would read it row by row)."""
    sp = require_sympy()
    if isinstance(seq, sp.Basic | str | bytes) and not isinstance(seq, sp.MatrixBase):
        raise TypeError(f"{name} must be a sequence of {what}, got one "
                        f"{type(seq).__name__} {seq!r}")
    if isinstance(seq, sp.MatrixBase) and min(seq.shape) > 1:
        raise ValueError(f"{name} must be a sequence of {what}, got a {seq.shape[0]} x "
                         f"{seq.shape[1]} Matrix (a row or a column of them: "
                         f"Matrix.reshape or .vec() says in which order)")
    try:
        return list(seq)
    except TypeError:
        raise TypeError(f"{name} must be a sequence of {what}, got "
                        f"{type(seq).__name__}") from None


#: assumptions that say more of a symbol than that it is real: sympy simplifies with them
#: as the expressions are made (``sqrt(k**2)`` is ``k`` for a positive k)
_NARROWING = ("positive", "negative", "nonnegative", "nonpositive", "zero", "nonzero",
              "integer", "rational", "even", "odd", "prime", "composite")


def _narrowed(symbol) -> list:
    """The narrowing assumptions ``symbol`` was made with (``positive``, ...)."""
    return [a for a in _NARROWING if symbol.assumptions0.get(a) is True]


def _symbols(seq, name: str) -> list:
    sp = require_sympy()
    items = _sequence(seq, name, "sympy Symbols")
    for i, s in enumerate(items):
        if not isinstance(s, sp.Symbol):
            raise TypeError(f"{name}[{i}] must be a sympy Symbol, got {type(s).__name__} "
                            f"{s!r}")
        if _narrowed(s):
            raise ValueError(f"{name}[{i}] = {s} is declared {_assumptions(s)}: sympy has "
                             f"simplified the expressions with that (sqrt({s}**2) is {s}), "
                             f"which is wrong wherever {s} takes another value, and a "
                             + ("flag takes the values 0 and 1" if name == "flags" else
                                "state coordinate takes any real value")
                             + ": make it with real=True (or no assumptions)")
    seen = {}
    for i, s in enumerate(items):
        if s in seen:
            raise ValueError(f"{name}[{i}] = {s} repeats {name}[{seen[s]}]")
        seen[s] = i
    return items


def _expressions(seq, name: str, length: int, length_text: str) -> list:
    sp = require_sympy()
    items = _sequence(seq, name, f"{length_text} sympy expressions")
    if len(items) != length:
        raise ValueError(f"{name} must have {length} expressions ({length_text}), got "
                         f"{len(items)}")
    out = []
    for i, e in enumerate(items):
        try:
            e = sp.sympify(e, strict=True)
        except (sp.SympifyError, TypeError):
            raise TypeError(f"{name}[{i}] must be a sympy expression or a number, got "
                            f"{type(e).__name__} {e!r}") from None
        if not isinstance(e, sp.Expr) or e.is_Matrix:  # a Matrix is an Expr too
            raise TypeError(f"{name}[{i}] must be a sympy expression (sympy.Expr), got "
                            f"{type(e).__name__} {e}")
        if e.has(sp.nan, sp.zoo, sp.oo, -sp.oo):  # (1/0 is zoo): no value anywhere
            raise ValueError(f"{name}[{i}] = {e} holds a non-finite constant (nan, zoo: "
                             f"a division by zero, or oo), so it has no finite value")
        out.append(e)
    return out


def _check_free(label: str, e, allowed: set, what: str) -> None:
    extra = e.free_symbols - allowed
    if extra:
        names = ", ".join(sorted(str(s) for s in extra))
        namesakes = {str(s): s for s in allowed}
        twins = [f"{s} ({_assumptions(s)}) is not the {s} of the model "
                 f"({_assumptions(namesakes[str(s)])}): a sympy Symbol is its name and its "
                 f"assumptions, so make both with the same ones"
                 for s in sorted(extra, key=str) if str(s) in namesakes]
        raise ValueError(f"{label} = {e} contains {names}, which {what}"
                         + "".join(f"; {t}" for t in twins))


def _assumptions(symbol) -> str:
    """The assumptions a Symbol was made with, as its constructor's keywords."""
    given = getattr(symbol, "_assumptions_orig", None)  # as given (sympy >= 1.12)
    if given is None:
        given = {k: v for k, v in symbol.assumptions0.items() if k != "commutative"}
    return ", ".join(f"{k}={v}" for k, v in sorted(given.items())) or "no assumptions"


def check_assumed(symbol, value: float, name: str) -> None:
    """Refuse a parameter ``value`` that breaks an assumption ``symbol`` was made with
    (sympy simplified the expressions with it: ``sqrt(k**2)`` is ``k`` for a positive k,
    so a k of -2 gave the field of 2)."""
    sp = require_sympy()
    for a in _narrowed(symbol):
        number = sp.Integer(int(value)) if float(value).is_integer() else sp.Float(value)
        if getattr(number, f"is_{a}") is not True:
            raise ValueError(f"{name} = {value!r}, but {symbol} is declared {a}=True: sympy "
                             f"has simplified the expressions with that, so they are wrong "
                             f"at this value; pass a value that is {a}, or make the symbol "
                             f"with real=True")


class AssumedParams:
    """A model's ``param_check`` (``with_params`` calls it) for parameters made with
    narrowing assumptions (``symbols``, in the model's order): :func:`check_assumed`."""

    def __init__(self, symbols):
        self.symbols = tuple(symbols)

    def __call__(self, values) -> None:
        for symbol, value in zip(self.symbols, values, strict=True):
            check_assumed(symbol, float(value), f"params[{symbol}]")


def assumed_params(symbols):
    """:class:`AssumedParams` of ``symbols``, or None when none is narrowed."""
    return AssumedParams(symbols) if any(map(_narrowed, symbols)) else None


def refuse_partial_piecewise(label: str, e, shown) -> None:
    """Refuse a ``Piecewise`` in ``e`` without an otherwise branch (a last condition
    ``True``): it has no value where none of its conditions holds (sympy's nan), so the
    model would be undefined there. ``label`` and ``shown`` (``e`` in the user's symbols)
    name it."""
    sp = require_sympy()
    for pw in e.atoms(sp.Piecewise):
        if pw.args[-1].cond is not sp.true:
            raise ValueError(f"{label} = {shown} has a Piecewise without an otherwise branch "
                             f"(its last condition is {pw.args[-1].cond}, not True), so it "
                             f"has no value where none of its conditions holds: end it with "
                             f"(value, True)")


def check_model(state, flags, field, events, resets, params) -> Model:
    """Check :func:`~bderiv.symbolic.from_sympy`'s arguments; the canonical model.

    Raises
    ------
    TypeError
        A symbol that is not a sympy Symbol, an expression that is not a sympy expression,
        a reset index that is not an integer, a parameter value that is not a real number.
    ValueError
        Wrong lengths, repeated symbols, flags in the events, free symbols that are neither
        state, flags nor parameters (named; a namesake of another's assumptions said so),
        non-finite parameter values, a Piecewise without an otherwise branch.
    """
    sp = require_sympy()
    state = _symbols(state, "state")
    flags = _symbols(flags, "flags")
    if not state:
        raise ValueError("state must have at least one symbol, got none")
    if not flags:
        raise ValueError("flags must have at least one symbol (one per event), got none")
    both = set(state) & set(flags)
    if both:
        raise ValueError(f"{', '.join(sorted(map(str, both)))} is both a state symbol and a "
                         f"flag")
    d, n = len(state), len(flags)
    field = _expressions(field, "field", d, f"one per state symbol, d = {d}")
    events = _expressions(events, "events", n, f"one per flag, n = {n}")
    if params is None:
        params = {}
    if not hasattr(params, "items"):
        raise TypeError(f"params must be a mapping symbol -> value, got "
                        f"{type(params).__name__}")
    names, values = [], []
    for sym, value in params.items():
        if not isinstance(sym, sp.Symbol):
            raise TypeError(f"params keys must be sympy Symbols, got {type(sym).__name__} "
                            f"{sym!r}")
        if sym in state or sym in flags:
            raise ValueError(f"params[{sym}]: {sym} is a {'state' if sym in state else 'flag'} "
                             f"symbol, not a parameter")
        names.append(sym)
        values.append(check_value(value, f"params[{sym}]"))
        check_assumed(sym, values[-1], f"params[{sym}]")
    if len({str(s) for s in names}) != len(names):
        raise ValueError("params has two symbols of the same name; with_params could not "
                         "tell them apart: rename one")
    allowed = set(state) | set(flags) | set(names)
    unknown = ("are neither state, flags nor parameters: add them to state or flags, or "
               "give them a value in params")
    for i, e in enumerate(field):
        _check_free(f"field[{i}]", e, allowed, unknown)
        refuse_partial_piecewise(f"field[{i}]", e, e)
    for k, e in enumerate(events):
        _check_free(f"events[{k}]", e, allowed, unknown)
        refuse_partial_piecewise(f"events[{k}]", e, e)
        _check_free(f"events[{k}]", e, allowed - set(flags),
                    "are flags: an event function depends on the state and the parameters "
                    "only (the flags say which events have happened; the surface cannot)")
    checked = {}
    if resets is not None:
        if not hasattr(resets, "items"):
            raise TypeError(f"resets must be a mapping event index -> d expressions, got "
                            f"{type(resets).__name__}")
        for k, exprs in resets.items():
            if isinstance(k, bool | np.bool_) or not isinstance(k, numbers.Integral):
                raise TypeError(f"resets keys must be event indices (int), got "
                                f"{type(k).__name__} {k!r}")
            if not 0 <= k < n:
                raise ValueError(f"resets key {k} is not an event index in [0, {n})")
            label = f"resets[{int(k)}]"
            exprs = _expressions(exprs, label, d, f"the state after event {k}, d = {d}")
            for i, e in enumerate(exprs):
                _check_free(f"{label}[{i}]", e, allowed, unknown)
                refuse_partial_piecewise(f"{label}[{i}]", e, e)
            checked[int(k)] = exprs
    x = tuple(sp.Symbol(f"x_{i}", real=True) for i in range(d))
    s = tuple(sp.Symbol(f"s_{k}", real=True) for k in range(n))
    p = tuple(sp.Symbol(f"p_{j}", real=True) for j in range(len(names)))
    to_canonical = dict(zip(state, x, strict=True))
    to_canonical.update(zip(flags, s, strict=True))
    to_canonical.update(zip(names, p, strict=True))

    def canon(exprs):
        return tuple(e.xreplace(to_canonical) for e in exprs)

    return Model(field=canon(field), events=canon(events),
                 resets={k: canon(v) for k, v in sorted(checked.items())},
                 x=x, s=s, p=p, param_names=tuple(str(s) for s in names),
                 values=np.array(values, dtype=np.float64),
                 original={v: k for k, v in to_canonical.items()})
