"""The numba kernels of a body with point contacts: the mass matrix solved in compiled code.

The field of ``M(q) q'' = b(x, s)`` (:mod:`bderiv.symbolic.contacts` builds ``b``) is
``(q', M^-1 b)``. Solving ``M a = b`` symbolically multiplies the expressions' size about
7-fold per coordinate: for the quadruped's mass matrix (:mod:`bderiv.examples.quadruped`,
380 operations in all) sympy's ``LUsolve`` of its leading k x k block has 643, 4116,
29651 and 216118 operations for k = 3, 4, 5, 6 (the last in 10 s), before the Jacobians
differentiate them. So the kernels fill ``M`` and ``b`` from their own cse'd expressions
and solve numerically (the factorization ``M = L D L^T``, O(m^3): a few hundred flops for
m = 7), which also checks at every evaluation that ``M`` is positive definite there (a
pivot of ``D`` <= 0 raises :data:`bderiv.symbolic._solve.NOT_DEFINITE`; the solve is the
library's, :mod:`bderiv.symbolic._solve`, imported by every model's module). Against
Gaussian elimination with partial pivoting (the solve before it) it took, per call of the
quadruped's field and field_jacobian, 256 and 837 ns instead of 313 and 1053, and 83 and
149 ns instead of 96 and 158 for a two-link arm (m = 2; min of 9 interleaved runs of
200000 calls).
The Jacobians stay exact through the implicit-function rule: from ``M a = b``,

    M da/dx_j = db/dx_j - (dM/dx_j) a,

whose right-hand side is printed as expressions in the state and the numbers ``a_i``
(symbols ``a_i``, filled after the first solve), then solved for all j at once. The
impact reset of contact k, ``v+ = v - (1 + e) w (J v) / (J w)`` with ``w = M^-1 J^T``
(``J = d phi_k / dq``, restitution ``e``; ``e = 0`` is plastic: the normal velocity
``J v`` is zeroed, ``-e J v`` otherwise), is differentiated the same way:
``M dw/dq_j = d J^T/dq_j - (dM/dq_j) w``. The kernels have the signatures of
:mod:`bderiv.symbolic._codegen` (the same compile and cache path), plus
``coupling(x) -> (n, n)``, ``J M^-1 J^T`` of all contacts.
"""

from __future__ import annotations

from . import _codegen
from ._inputs import require_sympy

#: bump when the generated source changes
MECHANICS_VERSION = 5

COUPLING_SIGNATURE = "float64[:, ::1](float64[::1])"

#: the generated module's import of the solve (:mod:`bderiv.symbolic._solve`: one compiled
#: copy for every model)
_SOLVE = "from bderiv.symbolic._solve import solve as _solve"


def _matrix_lines(printer, model, ind):
    """``M = np.empty((m, m))`` filled (both halves from one expression per pair)."""
    m = model.m
    outputs = [(f"M[{i}, {j}]", model.M[i][j], f"mass_matrix[{i}][{j}]")
               for i in range(m) for j in range(m)]
    return ([f"{ind}M = np.empty(({m}, {m}))"]
            + _codegen._block(printer, model, outputs, ind))


def _field_body(printer, model, jacobian: bool) -> list:
    sp = require_sympy()
    m, d, ind = model.m, model.dim, "    "
    outputs = [(f"M[{i}, {j}]", model.M[i][j], f"mass_matrix[{i}][{j}]")
               for i in range(m) for j in range(m)]
    outputs += [(f"b[{i}, 0]", model.b[i], f"the forces' row {i}") for i in range(m)]
    lines = [*_codegen._preamble(model, True, (d, d) if jacobian else d),
             f"{ind}M = np.empty(({m}, {m}))",
             f"{ind}b = np.empty(({m}, 1))", *_codegen._block(printer, model, outputs, ind)]
    if jacobian:
        lines.append(f"{ind}M2 = M.copy()")
    lines.append(f"{ind}_solve(M, b)")
    if not jacobian:
        return lines + [f"{ind}for i in range({m}):", f"{ind}    out[i] = x[{m} + i]",
                        f"{ind}    out[{m} + i] = b[i, 0]"]
    a = model.aux("a", m)
    lines += [f"{ind}a_{i} = b[{i}, 0]" for i in range(m)]
    outputs = []
    for i in range(m):
        for j, xj in enumerate(model.x):
            e = sp.diff(model.b[i], xj) - sum(sp.diff(model.M[i][k], xj) * a[k]
                                              for k in range(m))
            if e != 0:
                outputs.append((f"E[{i}, {j}]", e, f"the derivative of the forces' row {i} "
                                                   f"by {model.show(xj)}"))
    lines += [f"{ind}E = np.zeros(({m}, {d}))", *_codegen._block(printer, model, outputs, ind),
              f"{ind}_solve(M2, E)", f"{ind}for i in range({m}):",
              f"{ind}    out[i, {m} + i] = 1.0", f"{ind}    for j in range({d}):",
              f"{ind}        out[{m} + i, j] = E[i, j]"]
    return lines


def _contact_rows(printer, model, ind, hessian: bool) -> list:
    """One branch per contact k: ``J`` (m, 1) = d phi_k / dq, ``W = M^-1 J`` (``M`` kept),
    and with ``hessian`` ``H`` (m, m) the derivatives of ``J`` and ``K = H - (dM/dq) w``
    (``w_i`` the entries of ``W``), column j the right-hand side of dw/dq_j."""
    sp = require_sympy()
    m, lines = model.m, []
    w = model.aux("w", m)
    for k, grad in enumerate(model.J):
        lines.append(f"{ind}{'if' if k == 0 else 'elif'} k == {k}:")
        outputs = [(f"J[{i}, 0]", grad[i], f"the derivative of contacts[{k}] by "
                                          f"{model.show(model.x[i])}") for i in range(m)]
        lines += _codegen._block(printer, model, outputs, ind + "    ")
        # loops, not W[:, :] = J: an array into a slice compiles numba's shape error
        lines += [f"{ind}    for i in range({m}):", f"{ind}        W[i, 0] = J[i, 0]",
                  f"{ind}        for j in range({m}):", f"{ind}            M2[i, j] = M[i, j]",
                  f"{ind}    _solve(M2, W)"]
        if not hessian:
            continue
        lines += [f"{ind}    w_{i} = W[{i}, 0]" for i in range(m)]
        outputs = []
        for i in range(m):
            for j in range(m):
                h = sp.diff(grad[i], model.x[j])
                if h != 0:
                    outputs.append((f"H[{i}, {j}]", h, f"a second derivative of contacts[{k}]"))
                e = h - sum(sp.diff(model.M[i][r], model.x[j]) * w[r] for r in range(m))
                if e != 0:
                    outputs.append((f"K[{i}, {j}]", e, "the derivative of the impact "
                                                       f"direction of contacts[{k}]"))
        lines += _codegen._block(printer, model, outputs, ind + "    ")
    return lines


def _reset_body(printer, model, jacobian: bool) -> list:
    """``v+ = v - (1 + e) w g / c``, ``g = J v``, ``c = J w`` (module docstring)."""
    m, d, ind = model.m, model.dim, "    "
    lines = [*_codegen._preamble(model, True, (d, d) if jacobian else d)]
    lines += ([f"{ind}for i in range({d}):", f"{ind}    out[i, i] = 1.0"]
              if jacobian else [f"{ind}for i in range({d}):", f"{ind}    out[i] = x[i]"])
    lines += [f"{ind}if (mask >> k) & 1:  # a lift-off: no impact", f"{ind}    return out"]
    lines += _matrix_lines(printer, model, ind)
    lines += [f"{ind}J = np.zeros(({m}, 1))", f"{ind}W = np.zeros(({m}, 1))",
              f"{ind}M2 = np.empty(({m}, {m}))"]
    if jacobian:
        lines += [f"{ind}H = np.zeros(({m}, {m}))", f"{ind}K = np.zeros(({m}, {m}))"]
    lines += _contact_rows(printer, model, ind, jacobian)
    lines += _codegen._block(printer, model, [("e", model.restitution, "the restitution")],
                             ind)
    lines += [f"{ind}g = 0.0", f"{ind}c = 0.0", f"{ind}for i in range({m}):",
              f"{ind}    g += J[i, 0] * x[{m} + i]", f"{ind}    c += J[i, 0] * W[i, 0]"]
    if not jacobian:
        return lines + [f"{ind}for i in range({m}):",
                        f"{ind}    out[{m} + i] = x[{m} + i] - (1.0 + e) * W[i, 0] * g / c"]
    return lines + [
        f"{ind}_solve(M, K)  # K <- dw/dq: column j is M^-1 (dJ/dq_j - dM/dq_j w)",
        f"{ind}for j in range({m}):",
        f"{ind}    dg = 0.0",
        f"{ind}    dc = 0.0",
        f"{ind}    for i in range({m}):",
        f"{ind}        dg += H[i, j] * x[{m} + i]",
        f"{ind}        dc += H[i, j] * W[i, 0] + J[i, 0] * K[i, j]",
        f"{ind}    for i in range({m}):",
        f"{ind}        out[{m} + i, j] = -(1.0 + e) * (K[i, j] * g / c"
        f" + W[i, 0] * (dg * c - g * dc) / (c * c))",
        f"{ind}        out[{m} + i, {m} + j] -= (1.0 + e) * W[i, 0] * J[j, 0] / c",
    ]


def _coupling_body(printer, model) -> list:
    m, n, ind = model.m, model.n_events, "    "
    outputs = [(f"J[{i}, {k}]", model.J[k][i], f"the derivative of contacts[{k}] by "
                                               f"{model.show(model.x[i])}")
               for k in range(n) for i in range(m)]
    return [*_codegen._preamble(model, False, (n, n)), *_matrix_lines(printer, model, ind),
            f"{ind}J = np.empty(({m}, {n}))", *_codegen._block(printer, model, outputs, ind),
            f"{ind}W = J.copy()", f"{ind}_solve(M, W)",
            f"{ind}for k in range({n}):", f"{ind}    for j in range({n}):",
            f"{ind}        acc = 0.0", f"{ind}        for i in range({m}):",
            f"{ind}            acc += J[i, k] * W[i, j]", f"{ind}        out[k, j] = acc"]


def generate(model, key: str) -> str:
    """The source of the kernel module of ``model`` (a
    :class:`~bderiv.symbolic.contacts.ContactModel`)."""
    sp = require_sympy()
    printer = _codegen._printer()
    for label, e in model.labelled():  # name the user's expression that fails, if any
        _codegen.print_expr(printer, e, label, model.show(e))
    resets = model.restitution is not None
    lines = [f"# generated by bderiv.symbolic.contacts (version {MECHANICS_VERSION}, sympy "
             f"{sp.__version__}); key {key}",
             "# do not edit: delete this file (and __pycache__) to regenerate",
             "import math  # noqa: F401", "", "import numba", "import numpy as np", "",
             _SOLVE, "", f"DIM = {model.dim}", f"N_EVENTS = {model.n_events}",
             f"N_PARAMS = {len(model.p)}", f"HAS_RESETS = {resets}"]
    lines += _codegen._kernel("field", "x, mask", _field_body(printer, model, False))
    lines += _codegen._kernel("field_jacobian", "x, mask", _field_body(printer, model, True))
    events = [-phi for phi in model.contacts]
    d, n = model.dim, model.n_events
    lines += _codegen._kernel("events", "x", _codegen._preamble(model, False, n)
                              + _codegen._vector(printer, model, events, "events"))
    lines += _codegen._kernel("event_jacobian", "x", _codegen._preamble(model, False, (n, d))
                              + _codegen._jacobian(printer, model, events, "events"))
    lines += _codegen._kernel("corner_field", "x", _codegen.corner_body(model))
    if resets:
        lines += _codegen._kernel("reset", "x, mask, k", _reset_body(printer, model, False))
        lines += _codegen._kernel("reset_jacobian", "x, mask, k",
                                  _reset_body(printer, model, True))
    lines += _codegen._kernel("coupling", "x", _coupling_body(printer, model))
    return "\n".join(lines) + "\n"
