"""``Triangulation``: the B-derivative as a PL homeomorphism given by vertices and simplices.

This is the representation of the source note (mathematics.md section 5): pre-event vertices
``pre``, their post-event images ``post``, and the simplicial cones of the fan around
F[0]. It holds everything needed to rebuild the map (and its inverse) elsewhere, without
the event machinery. Its files are saved and loaded by ``_triangulation_files`` (their
formats parsed and written by ``_triangulation_io``); files and direct construction alike
are checked completely by ``_triangulation_fields`` before anything is trusted.
"""

from __future__ import annotations

import math
from itertools import permutations

import numpy as np
import scipy.linalg

from .._support._batch import evaluate
from .._support._errors import QueryError
from .._support._progress import count_bar
from .._support._validate import (
    all_finite,
    check_finite_result,
    check_matrix,
    singular_condition,
)
from .._support._validate_ints import check_positive_int
from ._triangulation_fields import FIELDS, DegenerateCones, check_fields
from ._triangulation_files import TriangulationFiles, save_files

__all__ = ["Triangulation", "load_triangulation", "save_files"]


class Triangulation(TriangulationFiles):
    """A continuous piecewise-linear map given by a fan of simplicial cones.

    Parameters
    ----------
    pre : array_like, shape (n_vertices, d)
        Pre-event vertices. Vertex 0 is the origin (the apex of every cone).
    post : array_like, shape (n_vertices, d)
        Their images under the map (``post[0]`` is the origin too).
    simplices : array_like of int, shape (n_simplices, n + 1)
        Vertex indices, 1 <= n <= d; column 0 is the apex 0. The cone of a simplex is
        spanned by its other n vertices (non-negative weights) plus the kernel basis (any
        weights). Every vertex is used.
    kernel : array_like, shape (d, d - n)
        Basis of the subspace (ker Dh) that no event sees (empty when d = n; orthonormal
        when built by :meth:`from_bderivative`).
    kernel_post : array_like, shape (d, d - n), optional
        Images of the ``kernel`` columns under the map; default ``kernel`` (the map at an
        event point is the identity there). The cones of ``post`` are spanned with it.

    Raises
    ------
    ValueError
        On a wrong shape, a non-finite entry, an index out of range, an unused vertex or a
        degenerate simplex (its cone, before or after the map, does not span R^d).
    TypeError
        On a non-real dtype, or simplices that are not integers.

    Notes
    -----
    Built by :meth:`BDerivative.triangulation`: vertices ``0 .. 2**n - 1`` are the corner
    points ``pre[mask] -> post[mask]`` of :meth:`BDerivative.corner_points` and vertex
    ``2**n`` is ``-F[0] -> -F[full]``. The order sigma with chain ``B_0 = 0, ..., B_n =
    full`` owns two simplices, ``[0, B_1, ..., B_{n-1}, full]`` and ``[0, B_1, ...,
    B_{n-1}, 2**n]``, the halves of its cone before and after the flow direction.

    The map is a homeomorphism: the ``post`` cones are a fan too, so :meth:`inverse` is the
    same evaluation with ``pre``, ``kernel`` and ``post``, ``kernel_post`` swapped (mathematics.md
    section 6). :meth:`composed` carries the fan through linear maps before and after (the
    triangulation of a flow map with one event group). Evaluation is brute force over all
    simplices: meant for checking, and for small n.

    Save it with :meth:`save` (``.npz`` or ``.json``) and read it back with :meth:`load`
    (or :func:`bderiv.load_triangulation`): the file holds the whole map. The arrays are
    read-only.

    Examples
    --------
    >>> import numpy as np
    >>> from bderiv import BDerivative
    >>> F = np.array([[1.0, 1.0], [2.0, 1.0], [1.0, 1.0], [2.0, 1.0]])
    >>> tri = BDerivative(np.eye(2), F).triangulation()
    >>> tri
    Triangulation(n_events=2, dim=2, vertices=5, simplices=4)
    >>> tri([-1.0, -2.0])
    array([-2., -2.])
    >>> tri.inverse([-2.0, -2.0])
    array([-1., -2.])
    """

    def __init__(self, pre, post, simplices, kernel, kernel_post=None):
        fields = dict(pre=pre, post=post, simplices=simplices, kernel=kernel,
                      kernel_post=kernel_post)
        self._set(check_fields(fields, "Triangulation"))

    def _set(self, fields: dict) -> None:
        for name in FIELDS:
            fields[name].flags.writeable = False
            setattr(self, name, fields[name])
        self.dim = self.pre.shape[1]
        self.n_events = self.simplices.shape[1] - 1

    def __setstate__(self, state: dict) -> None:
        # unpickled arrays come back writeable; keep them read-only as validated
        self.__dict__.update(state)
        if "kernel_post" not in state:  # pickled before kernel_post existed: the identity
            self.kernel_post = self.kernel.copy()
        for name in FIELDS:
            getattr(self, name).flags.writeable = False

    @classmethod
    def from_bderivative(cls, bd, max_pieces: int) -> Triangulation:
        """Build the fan of ``bd`` (2 n! simplices); refuses when n! > ``max_pieces``."""
        check_positive_int(max_pieces, "max_pieces")
        n = bd.n_events
        if math.factorial(n) > max_pieces:
            raise ValueError(
                f"the triangulation of {n} events has 2 * {n}! = {2 * math.factorial(n)} "
                f"simplices, more than 2 * max_pieces={max_pieces}; pass a larger max_pieces"
            )
        pre, post = bd.corner_points()
        full = (1 << n) - 1
        pre = np.vstack([pre, -bd.F[0]])
        post = np.vstack([post, -bd.F[full]])
        orders = np.array(list(permutations(range(n))), dtype=np.int64).reshape(-1, n)
        # chain[:, j] = mask after j events; cumulative OR of the order's bits
        chain = np.cumsum(1 << orders, axis=1)
        inner = chain[:, :-1]
        apex = np.zeros((len(orders), 1), dtype=np.int64)
        plus = np.hstack([apex, inner, np.full((len(orders), 1), full)])
        minus = np.hstack([apex, inner, np.full((len(orders), 1), full + 1)])
        simplices = np.stack([plus, minus], axis=1).reshape(-1, n + 1)
        kernel = scipy.linalg.null_space(bd.Dh).reshape(bd.dim, bd.dim - n)
        # with resets M moves ker Dh (by the product of the resets, mathematics.md section 9)
        moved = getattr(bd, "resets", None) is not None and kernel.shape[1]
        try:
            return cls(pre, post, simplices, kernel, bd(kernel.T).T if moved else None)
        except DegenerateCones as exc:  # the map's own fan, flat in float64
            raise ValueError(
                f"this map's fan is too ill-conditioned to triangulate in float64 (its "
                f"rates or corners span many orders of magnitude, so a cone's rays are "
                f"numerically dependent; {exc}); the map itself evaluates (bd(V), "
                f"bd.inverse(W)), only its fan of simplices cannot be built") from None

    def composed(self, before, after) -> Triangulation:
        """The triangulation of ``v -> after @ self(before @ v)``, same simplices.

        The pre-event vertices and the kernel basis are pulled back by ``before``, the
        post-event vertices and the kernel images pushed forward by ``after``: for a flow
        map ``L_1 . M . L_0`` with one event group of map ``M``, ``before = L_0`` carries the
        fan's pre-event points back to the start point and ``after = L_1`` its post-event
        points to the final time.

        Parameters
        ----------
        before, after : array_like, shape (d, d)
            Invertible real matrices.

        Returns
        -------
        Triangulation

        Raises
        ------
        ValueError
            On a wrong shape, a non-finite entry, or a matrix singular to working
            precision (naming it).

        Examples
        --------
        >>> import numpy as np
        >>> from bderiv import BDerivative
        >>> F = np.array([[1.0, 1.0], [2.0, 1.0], [1.0, 1.0], [2.0, 1.0]])
        >>> tri = BDerivative(np.eye(2), F).triangulation()
        >>> A, B = np.diag([2.0, 1.0]), np.diag([1.0, 3.0])
        >>> tri.composed(A, B)([-0.5, -2.0])     # B @ tri(A @ v) = B @ [-2, -2]
        array([-2., -6.])
        """
        d = self.dim
        mats = {}
        for name, value in (("before", before), ("after", after)):
            mat = check_matrix(value, name, (d, d))
            cond = singular_condition(mat)
            if cond is not None:
                raise ValueError(
                    f"{name} must be invertible, but it is singular to working precision "
                    f"(condition number {cond:.3g})"
                )
            mats[name] = mat
        pulled = np.linalg.solve(mats["before"], np.hstack([self.pre.T, self.kernel]))
        n_vertices = self.pre.shape[0]
        return Triangulation(pulled[:, :n_vertices].T, self.post @ mats["after"].T,
                             self.simplices, pulled[:, n_vertices:],
                             mats["after"] @ self.kernel_post)

    def __repr__(self) -> str:
        return (
            f"Triangulation(n_events={self.n_events}, dim={self.dim}, "
            f"vertices={self.pre.shape[0]}, simplices={self.simplices.shape[0]})"
        )

    def apply(self, V, out=None, *, chunk_size=None, progress=None) -> np.ndarray:
        """Evaluate the map by locating each vector in its cone (barycentric weights).

        Parameters
        ----------
        V : array_like, shape (..., d), or a dask array
            Pre-event vectors (a dask array gives a lazy dask array).
        out : ndarray, shape (..., d), optional
            C-contiguous float64 array to write the result into (may be ``V`` itself).
        chunk_size : int, optional
            Evaluate ``chunk_size`` vectors at a time (results do not depend on it).
        progress : callable ``progress(done, total)``, or True, optional
            Called after each chunk; ``True`` draws a tqdm bar.

        Returns
        -------
        ndarray, shape (..., d)
            Post-event vectors.

        Raises
        ------
        ValueError, TypeError
            On a wrong shape, dtype or non-finite vector (the messages of
            :meth:`BDerivative.apply`).
        """
        return evaluate(self._forward, V, self.dim, name="V", out=out, chunk_size=chunk_size,
                        progress=progress, desc="Triangulation", method=self.apply)

    __call__ = apply

    def inverse(self, W, out=None, *, chunk_size=None, progress=None) -> np.ndarray:
        """Evaluate the exact inverse map: locate each vector in a ``post`` cone.

        Parameters
        ----------
        W : array_like, shape (..., d), or a dask array
            Post-event vectors.
        out, chunk_size, progress : optional
            As for :meth:`apply`.

        Returns
        -------
        ndarray, shape (..., d)
            ``V`` with ``self(V) == W`` up to rounding.
        """
        return evaluate(self._backward, W, self.dim, name="W", out=out, chunk_size=chunk_size,
                        progress=progress, desc="Triangulation.inverse", method=self.inverse)

    def _forward(self, rows, res, offset) -> None:
        outside = _fan_map(self.pre, self.post, self.simplices, self.kernel,
                           self.kernel_post, rows, res)
        _check_covered(outside, "V", "pre", offset)
        if not all_finite(res):
            check_finite_result(res, "V", offset)

    def _backward(self, rows, res, offset) -> None:
        outside = _fan_map(self.post, self.pre, self.simplices, self.kernel_post,
                           self.kernel, rows, res)
        _check_covered(outside, "W", "post", offset)
        if not all_finite(res):
            check_finite_result(res, "W", offset)


def load_triangulation(path, format: str | None = None, *,
                       memory_limit=None) -> Triangulation:
    """Read a triangulation saved by :meth:`Triangulation.save` or ``bderiv export``.

    Same as :meth:`Triangulation.load` (the file is checked completely, its size before
    it is read, its digest before its fields); the result is callable, ``tri(V)`` with V
    of shape ``(..., d)``, and has ``tri.inverse(W)``.
    """
    return Triangulation.load(path, format, memory_limit=memory_limit)


# -- evaluation -------------------------------------------------------------------------------


#: entries of the (cones, rows, d) weights that :func:`_fan_map` computes at once (8 MiB)
FAN_BLOCK = 1 << 20
#: a row whose best cone's least barycentric weight is below this, relative to its
#: largest, lies in no cone (rounding on a shared face is some eps times the cone's
#: condition number)
OUTSIDE_WEIGHT = -1e-8


def _check_covered(outside, name: str, side: str, offset: int) -> None:
    """Refuse the first row of ``outside`` (indices of rows in no cone): a
    :class:`~bderiv._support._errors.QueryError` naming it."""
    if outside.size:
        raise QueryError(
            f"{{query}} lies in no cone of the triangulation's {side} fan (its best cone's "
            f"weights reach below {OUTSIDE_WEIGHT:g} of their size): the cones do not "
            f"cover R^d, so the map is not known there. A triangulation made by "
            f"BDerivative.triangulation() covers R^d; was this one built by hand from a "
            f"subset of its simplices, or read from a file edited without its digest?",
            int(outside[0]) + offset, name)


def _fan_map(src, dst, simplices, ksrc, kdst, rows, res) -> np.ndarray:
    """Write into ``res`` (m, d) the PL map of ``rows`` (m, d) from ``src`` to ``dst`` cones;
    returns the indices of the rows that lie in no cone (:data:`OUTSIDE_WEIGHT`).

    Each row is located in the cone of ``src`` (with the kernel basis ``ksrc``) whose
    barycentric weights are least negative (relative to their size: robust on shared
    faces; the first such cone on a tie) and rebuilt from ``dst`` (with ``kdst``) with the
    same weights. ``pre, post, kernel, kernel_post`` is the map, ``post, pre, kernel_post,
    kernel`` its inverse. Row by row the arithmetic does not depend on the other rows (an
    explicit inverse and einsum, where a multi-right-hand-side solve would not be), so
    results are independent of chunking. The cones are taken in blocks (their inverses
    at once: one call per cone cost 0.2 ms, 125 s at n = 9), with a bar once it lasts.
    """
    m, d = rows.shape
    n = simplices.shape[1] - 1
    best_weight = np.full(m, -np.inf)
    best = np.zeros((m, d))  # the weights in the best cone so far
    which = np.full(m, -1)  # that cone
    block = max(1, FAN_BLOCK // max(1, m * d))
    everyone = np.arange(m)
    with np.errstate(over="ignore", invalid="ignore"), \
            count_bar(len(simplices), "Triangulation", "cones") as bar:
        for start in range(0, len(simplices), block):
            cones = simplices[start:start + block, 1:]
            P = np.concatenate((src[cones].transpose(0, 2, 1),
                                np.broadcast_to(ksrc, (len(cones),) + ksrc.shape)), axis=2)
            weights = np.einsum("bij,mj->bmi", np.linalg.inv(P), rows)  # (b, m, d)
            lam = weights[:, :, :n]
            min_weight = lam.min(axis=2) / (np.abs(lam).max(axis=2) + 1e-300)
            min_weight[np.isnan(min_weight)] = -np.inf  # overflow: never a best cone
            first = np.argmax(min_weight, axis=0)  # the block's best, the first on a tie
            top = min_weight[first, everyone]
            better = np.flatnonzero(top > best_weight)
            best_weight[better] = top[better]
            which[better] = start + first[better]
            best[better] = weights[first[better], better]
            bar(start + len(cones))
        res.fill(np.nan)  # a row no cone takes (weights overflowing) stays NaN, not garbage
        found = np.flatnonzero(which >= 0)
        Q = np.concatenate((dst[simplices[which[found], 1:]].transpose(0, 2, 1),
                            np.broadcast_to(kdst, (found.size,) + kdst.shape)), axis=2)
        res[found] = np.einsum("mij,mj->mi", Q, best[found])
    return np.flatnonzero((which >= 0) & (best_weight < OUTSIDE_WEIGHT))
