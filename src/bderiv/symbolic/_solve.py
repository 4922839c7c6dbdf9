"""The mass matrix's solve in the kernels of :func:`bderiv.symbolic.contact_system`.

Each generated module of a contact model imports :func:`solve` (``from
bderiv.symbolic._solve import solve as _solve``) instead of carrying a copy of its own: a
copy was typed and compiled again for every model, 0.5 s of the 6.5 s of CPU that a
two-link arm's kernels took to compile (2026-11-30). This one is compiled once on a
machine and kept in bderiv's checked numba cache; numba's cache of a generated kernel
does not watch this file, so the models' cache key holds its digest
(:data:`SOLVE_DIGEST`, ``contacts.contact_system``).
"""

from __future__ import annotations

from .._kernels._cache import checked_njit, sources_digest

#: what :func:`solve` raises where the mass matrix is not positive definite (a constant:
#: the message of an exception raised in compiled code)
NOT_DEFINITE = ("the mass matrix M(q) is not positive definite at this state (singular or "
                "indefinite: a pivot of its factorization L D L^T is <= 0)")

#: the digest of this file, in the cache key of every contact model's generated module
SOLVE_DIGEST = sources_digest(None, __file__)


@checked_njit()
def solve(A, B):
    """B <- A^-1 B for A (m, m) symmetric positive definite (its lower triangle is read)
    and B (m, r), by the factorization A = L D L^T (A is overwritten by L below its
    diagonal and D on it): a pivot of D <= 0, an A singular or not positive definite,
    raises the mass matrix's ValueError."""
    m, r = A.shape[0], B.shape[1]
    for c in range(m):
        for k in range(c):
            t = A[c, k]
            for i in range(k):
                t -= A[c, i] * A[k, i] * A[i, i]
            A[c, k] = t / A[k, k]
        d = A[c, c]
        for i in range(c):
            d -= A[c, i] * A[c, i] * A[i, i]
        if d <= 0.0:
            raise ValueError(NOT_DEFINITE)
        A[c, c] = d
    if r == 1:  # L y = b, then D L^T x = y: dot products (a field's solve)
        for c in range(m):
            acc = B[c, 0]
            for k in range(c):
                acc -= A[c, k] * B[k, 0]
            B[c, 0] = acc
        for c in range(m - 1, -1, -1):
            acc = B[c, 0] / A[c, c]
            for k in range(c + 1, m):
                acc -= A[k, c] * B[k, 0]
            B[c, 0] = acc
        return
    for c in range(m):  # the same by rows of B (contiguous: a Jacobian's solve)
        for k in range(c):
            f = A[c, k]
            for j in range(r):
                B[c, j] -= f * B[k, j]
    for c in range(m - 1, -1, -1):
        for j in range(r):
            B[c, j] /= A[c, c]
        for k in range(c + 1, m):
            f = A[k, c]
            for j in range(r):
                B[c, j] -= f * B[k, j]
