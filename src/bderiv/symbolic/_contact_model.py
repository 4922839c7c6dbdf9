"""The checked contact model of :func:`bderiv.symbolic.contacts.contact_system` over
canonical symbols (:class:`ContactModel`): the user's expressions, the cache key, and the
right-hand side ``b`` of ``M(q) q'' = b`` (forces, Coriolis terms, stance forces) derived
when the code generator (:mod:`bderiv.symbolic._mechanics`) first asks for it."""

from __future__ import annotations

import functools

from ._inputs import require_sympy, tree_text

__all__ = ["ContactModel"]


class ContactModel:
    """A checked contact model over canonical symbols (``x_i``: q then q', ``s_k``,
    ``p_j``), what :mod:`bderiv.symbolic._mechanics` prints.

    It holds the user's expressions (the cache key, :meth:`canonical_text`, is theirs: a
    cached model is neither derived nor compiled); the right-hand side ``b`` and the
    gradients ``J`` are derived when first asked for (by the code generator).

    Attributes
    ----------
    M : tuple of tuples, (m, m)
        The mass matrix.
    forces : tuple, (m,)
    contacts : tuple, (n,)
        The gaps phi_k.
    laws : tuple, (n,)
        Each contact's normal force in the symbols ``pen[k]`` and ``rate[k]``.
    restitution : sympy.Expr or None
        ``e`` (in the parameters), None without impacts.
    coriolis : bool
    x, s, p : tuple of sympy.Symbol
        The state (q then q'), flags and parameters.
    """

    def __init__(self, *, M, forces, contacts, laws, restitution, coriolis, x, s, p, pen,
                 rate, param_names, values, original, names):
        self.M, self.forces, self.contacts, self.laws = M, forces, contacts, laws
        self.restitution, self.coriolis = restitution, coriolis
        self.x, self.s, self.p, self.pen, self.rate = x, s, p, pen, rate
        self.param_names, self.values, self.original = param_names, values, original
        self.names = names  # the contacts as the user wrote them (for messages)

    @property
    def m(self) -> int:
        return len(self.M)

    @property
    def dim(self) -> int:
        return len(self.x)

    @property
    def n_events(self) -> int:
        return len(self.s)

    def show(self, e):
        return e.xreplace(self.original)

    def aux(self, name: str, count: int) -> tuple:
        """Symbols ``name_0 ...`` the kernels fill with numbers (solves' results)."""
        sp = require_sympy()
        return tuple(sp.Symbol(f"{name}_{i}", real=True) for i in range(count))

    @functools.cached_property
    def J(self) -> tuple:
        """(n, m): the gradients d phi_k / dq."""
        sp = require_sympy()
        return tuple(tuple(sp.diff(phi, q) for q in self.x[:self.m]) for phi in self.contacts)

    def stance_force(self, k: int):
        """Contact k's normal force in the state: the law at ``-phi_k``, ``-J_k q'``."""
        rate = -sum(g * v for g, v in zip(self.J[k], self.x[self.m:], strict=True))
        return self.laws[k].xreplace({self.pen[k]: -self.contacts[k], self.rate[k]: rate})

    @functools.cached_property
    def b(self) -> tuple:
        """(m,): forces, Coriolis terms, stance forces ``s_k J_k^T lambda_k``."""
        m = self.m
        rhs = list(self.forces)
        if self.coriolis:
            rhs = [a + c for a, c in zip(rhs, _coriolis(self.M, self.x[:m], self.x[m:]),
                                         strict=True)]
        for k in range(self.n_events):
            lam = self.stance_force(k)
            rhs = [r + self.s[k] * self.J[k][i] * lam for i, r in enumerate(rhs)]
        return tuple(rhs)

    def labelled(self):
        """``(label, expression)`` of the user's expressions (the stance laws in the
        state)."""
        m = self.m
        yield from ((f"mass_matrix[{i}][{j}]", self.M[i][j]) for i in range(m)
                    for j in range(m))
        yield from ((f"forces[{i}]", e) for i, e in enumerate(self.forces))
        yield from ((f"contacts[{k}]", e) for k, e in enumerate(self.contacts))
        yield from ((f"the stance force of contact {k}", self.stance_force(k))
                    for k in range(self.n_events))
        if self.restitution is not None:
            yield "restitution", self.restitution

    def canonical_text(self) -> list:
        """Strings that identify the model (not the parameter values): the cache key."""
        memo = {}
        return [f"m={self.m} n={self.n_events} p={len(self.p)} coriolis={self.coriolis}",
                *(f"{label}={tree_text(e, memo)}" for label, e in self.labelled())]


def _coriolis(M, q, v) -> list:
    """``-C(q, v) v``: ``-sum_jk (dM_ij/dq_k - dM_jk/dq_i / 2) v_j v_k``."""
    sp = require_sympy()
    m = len(q)
    dM = [[[sp.diff(M[i][j], q[k]) for k in range(m)] for j in range(m)] for i in range(m)]
    return [-sp.Add(*(v[j] * v[k] * (dM[i][j][k] - dM[j][k][i] / 2)
                      for j in range(m) for k in range(m)
                      if dM[i][j][k] != 0 or dM[j][k][i] != 0)) for i in range(m)]
