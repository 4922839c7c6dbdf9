"""The argument checks of :func:`bderiv.symbolic.contacts.contact_system` that are its own:
the mass matrix, the stance laws, the impact law, one role per symbol, and the parameter
values the model cannot take (:class:`ParamCheck`, run at the build and by
``with_params``).
"""

from __future__ import annotations

import numbers

import numpy as np

from .._support._format import NOTES
from .._support._validate import check_value
from ._inputs import require_sympy

#: parameters of the default stance law ``stiffness * pen + damping * rate``, and values
DEFAULT_STANCE = {"contact_stiffness": 1.0e4, "contact_damping": 100.0}


def matrix(mass_matrix, m: int) -> list:
    """The mass matrix as m rows of m sympy expressions, checked square and symmetric."""
    sp = require_sympy()
    try:
        rows = sp.Matrix(mass_matrix)
    except Exception:
        raise TypeError(f"mass_matrix must be an m x m matrix (m = {m}) of sympy "
                        f"expressions, got {type(mass_matrix).__name__}") from None
    if rows.shape != (m, m):
        raise ValueError(f"mass_matrix must be {m} x {m} (one row and column per "
                         f"coordinate), got shape {rows.shape}")
    for i in range(m):
        for j in range(i + 1, m):
            gap = rows[i, j] - rows[j, i]
            if gap != 0 and sp.simplify(gap) != 0:
                raise ValueError(f"mass_matrix must be symmetric: entry [{i}][{j}] = "
                                 f"{rows[i, j]} and [{j}][{i}] = {rows[j, i]} differ")
    return [[rows[i, j] for j in range(m)] for i in range(m)]


def laws(stance, n: int, params: dict):
    """One callable ``law(pen, rate)`` per contact, and the parameters it adds."""
    sp = require_sympy()
    if stance is None:
        k, c = (sp.Symbol(name) for name in DEFAULT_STANCE)
        added = {s: v for s, v in zip((k, c), DEFAULT_STANCE.values(), strict=True)
                 if str(s) not in {str(p) for p in params}}
        taken = {str(p): p for p in params}
        k, c = taken.get(str(k), k), taken.get(str(c), c)
        return [lambda pen, rate: k * pen + c * rate] * n, added
    if callable(stance):
        return [stance] * n, {}
    given = list(stance) if isinstance(stance, list | tuple) else None
    if given is None or len(given) != n or not all(map(callable, given)):
        raise TypeError(f"stance must be None, a callable law(penetration, rate) -> force, or "
                        f"a list of {n} such callables (one per contact), got "
                        f"{type(stance).__name__}")
    return given, {}


def stance_force(law, k: int, pen, rate):
    """Contact k's normal force ``law(pen, rate)`` as a sympy expression; an exception of
    the law is noted with the law's name (Python 3.11+), a result that is not one
    expression refused naming the law."""
    sp = require_sympy()
    name = f"the stance law of contact {k} ({getattr(law, '__qualname__', repr(law))})"
    try:
        out = law(pen, rate)
    except Exception as exc:
        if NOTES:
            exc.add_note(f"bderiv: raised by {name}, called as law(penetration, rate) with "
                         f"two sympy symbols")
        raise
    try:
        force = sp.sympify(out, strict=True)
    except (sp.SympifyError, TypeError):
        force = None
    if not isinstance(force, sp.Expr) or force.is_Matrix:  # a Matrix is an Expr too
        raise TypeError(f"{name} must return one sympy expression (the normal force, in the "
                        f"penetration and its rate), got {type(out).__name__} {out!r}")
    return force


def restitution(impact, params: dict):
    """The restitution expression (None without impacts) and the parameter it adds."""
    sp = require_sympy()
    if impact is None:
        return None, {}
    if isinstance(impact, str):
        if impact != "plastic":
            raise ValueError(f"impact must be 'plastic', ('restitution', e), a number e in "
                             f"[0, 1] or None, got {impact!r}")
        return sp.Integer(0), {}
    if isinstance(impact, tuple) and len(impact) == 2 and impact[0] == "restitution":
        impact = impact[1]
    if isinstance(impact, sp.Expr) and not impact.is_number:
        return impact, {}  # an expression in the parameters (checked with the others)
    if isinstance(impact, bool) or not isinstance(impact, numbers.Real | sp.Expr):
        raise TypeError(f"impact must be 'plastic', ('restitution', e), a number e in [0, 1] "
                        f"or None, got {type(impact).__name__} {impact!r}")
    e = check_value(impact, "the restitution e")
    if not 0.0 <= e <= 1.0:
        raise ValueError(f"the restitution e must be in [0, 1], got {e!r}")
    sym = {str(p): p for p in params}.get("restitution", sp.Symbol("restitution"))
    return sym, ({} if sym in params else {sym: e})


def refuse_shared(roles) -> None:
    """Refuse a symbol in two roles: ``roles`` lists ``(role, {symbol: where})``, the
    role in words (``"a coordinate"``) and where each symbol is given (``"q[1]"``)."""
    for a, (role_a, given_a) in enumerate(roles):
        for role_b, given_b in roles[a + 1:]:
            for sym, where in given_a.items():
                if sym in given_b:
                    raise ValueError(
                        f"{sym} is both {role_a} ({where}) and {role_b} ({given_b[sym]}): "
                        f"a symbol takes one role (the state's coordinates and velocities, "
                        f"the flags and the parameters are distinct symbols); rename one")


class ParamCheck:
    """The parameter values a contact model cannot take, checked at its build and by
    ``with_params`` (:meth:`bderiv.symbolic.SymbolicSource.check_params`): a restitution
    outside [0, 1], and a mass matrix that is not positive definite where it does not
    depend on q (one state stands for all; where it does, the kernels check it at each
    evaluation). The expressions are over the canonical parameters ``p``; ``shown`` and
    ``names`` say them in the user's symbols."""

    def __init__(self, p, names, restitution=None, shown_restitution="", M=None,
                 assumed=None):
        self.p, self.names = tuple(p), tuple(names)
        self.assumed = assumed  # the parameters' own assumptions: AssumedParams or None
        self.restitution, self.shown_restitution = restitution, shown_restitution
        self.M = M  # None where it depends on q

    def _at(self, values, exprs) -> tuple:
        """The numbers of ``exprs`` at ``values``, and the parameters they use, in words."""
        sub = dict(zip(self.p, map(float, values), strict=True))
        used = set().union(*(e.free_symbols for e in exprs)) & set(self.p)
        words = ", ".join(f"{name} = {float(v)!r}" for name, s, v in
                          zip(self.names, self.p, values, strict=True) if s in used)
        return [float(e.xreplace(sub)) for e in exprs], words

    def __call__(self, values) -> None:
        """Refuse the parameter values ``values`` ((p,), in the model's order) where the
        restitution leaves [0, 1] or a constant mass matrix is not positive definite, or
        a value breaks its symbol's assumptions (``positive=True``, ...)."""
        if self.assumed is not None:
            self.assumed(values)
        if self.restitution is not None:
            (e,), words = self._at(values, [self.restitution])
            if not 0.0 <= e <= 1.0:
                at = (f" (the parameter {words})" if self.shown_restitution in self.names
                      else f" ({self.shown_restitution} at {words})")
                raise ValueError(f"the restitution e must be in [0, 1], got {e!r}{at}")
        if self.M is not None:
            flat, words = self._at(values, [e for row in self.M for e in row])
            M = np.array(flat).reshape(len(self.M), len(self.M))
            try:
                np.linalg.cholesky(M)
            except np.linalg.LinAlgError:
                at = f" at {words}" if words else ""
                raise ValueError(
                    f"mass_matrix must be positive definite, and it is not{at}: "
                    f"{M.tolist()}, eigenvalues {np.linalg.eigvalsh(M).tolist()} (it does "
                    f"not depend on q, so at no state)") from None
