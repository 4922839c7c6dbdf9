"""Per-direction linearisation of a piecewise-linear map: ``jvp``, ``vjp``, ``piece_matrices``.

A continuous piecewise-linear map M (a :class:`~bderiv.BDerivative` or a
:class:`~bderiv.FlowBDerivative`) is linear on each piece; a direction ``v`` selects one,
``M_sigma(v)``, the piece of the event order(s) that ``v`` itself goes through. For a batch
of directions this mix-in gives that piece applied to a second vector (``jvp``), its
transpose applied to a co-vector (``vjp``: adjoints, gradients, covariance updates), or the
``(d, d)`` matrices themselves. No d x d matrix is built per row for ``jvp`` and ``vjp``:
the kernels run the saltation factors along each row's chain (backwards for ``vjp``).

On a boundary between pieces (a tie between event times) both neighbouring pieces are
linearisations of M; the one returned is the piece of the order ``orders(v)`` names: the
selection's, which takes the smaller event index when two computed times are equal. Near
a tie (and at a tie reached after events whose times are rounded) rounding decides which
neighbour that is; both agree on ``v`` itself, M being continuous.

A class using it provides ``dim`` and ``_tangent_rows(V, T, res, transpose, offset, name)``,
which writes ``M_sigma(v) t`` (or ``M_sigma(v)^T t``) for the rows v of ``V`` and t of
``T`` (C-contiguous float64, (m, d) each) into ``res`` (m, d).
"""

from __future__ import annotations

import math

import numpy as np

from .._kernels import scaling
from .._limits import PIECE_CHUNK_BYTES
from .._support._batch import evaluate, refuse_dask
from .._support._errors import QueryError
from .._support._validate import (
    FEWER_ROWS,
    batch_size,
    check_memory,
    check_points,
    check_real_array,
)


def unit_scale(rows: np.ndarray, exps=None) -> np.ndarray:
    """The rows (m, d) scaled by exact powers of two to largest entries in [0.5, 1)
    (``exps``: an int64 array (m,) that receives each row's exponent, the power of two
    that scales it back).

    The piece a direction selects depends on the direction only (M is positively
    homogeneous), but its event times scale with it: a row near the ends of the float64
    range would overflow (or underflow) them and select a wrong order. Scaling by powers
    of two is exact, so rows that are fine select what they selected before. One compiled
    pass on all threads (:func:`bderiv._kernels.scaling.scale_rows`).
    """
    out = np.empty_like(rows)
    scaling.scale_rows(rows, out, np.empty(rows.shape[0], np.int64) if exps is None else exps)
    return out


class Linearisation:
    """``jvp``, ``vjp`` and ``piece_matrices`` of a piecewise-linear map (mix-in)."""

    def jvp(self, V, T, out=None, *, chunk_size=None, progress=None) -> np.ndarray:
        """The piece that each direction selects, applied to a tangent vector.

        Parameters
        ----------
        V : array_like, shape (..., d)
            Directions; row q selects the piece ``M_sigma(q)`` (its event order(s)).
        T : array_like, shape (..., d)
            Vectors to push through that piece (same leading shape as V).
        out : ndarray, shape (..., d), optional
            C-contiguous float64 array for the result (may be V or T).
        chunk_size, progress : optional
            As for ``apply``; results do not depend on the chunking.

        Returns
        -------
        ndarray, shape (..., d)
            ``M_sigma(q) @ T[q]`` for every row q. ``jvp(V, V) == self(V)`` (positive
            homogeneity) up to rounding.
        """
        return self._pair(V, T, "T", out, False, chunk_size, progress)

    def vjp(self, V, W, out=None, *, chunk_size=None, progress=None) -> np.ndarray:
        """The transpose of the piece that each direction selects, applied to a co-vector.

        Parameters
        ----------
        V : array_like, shape (..., d)
            Directions; row q selects the piece ``M_sigma(q)``.
        W : array_like, shape (..., d)
            Co-vectors (gradients at the output; same leading shape as V).
        out, chunk_size, progress : optional
            As for :meth:`jvp`.

        Returns
        -------
        ndarray, shape (..., d)
            ``M_sigma(q).T @ W[q]`` for every row q: ``<W, jvp(V, T)> == <vjp(V, W), T>``
            row by row, to rounding.
        """
        return self._pair(V, W, "W", out, True, chunk_size, progress)

    def piece_matrices(self, V, *, memory_limit=None) -> np.ndarray:
        """The (d, d) matrix of the piece each direction selects.

        Parameters
        ----------
        V : array_like, shape (..., d)
        memory_limit : int, optional
            Bytes the result may take; default: the memory currently available.

        Returns
        -------
        ndarray, shape (..., d, d)
            ``P[q] @ t == jvp(V[q], t)`` for every t. Built from d ``jvp`` columns per row.

        Raises
        ------
        ValueError
            If the result would not fit in ``memory_limit`` (naming its size).
        """
        d = self.dim
        refuse_dask(V, what="piece_matrices takes")
        arr = check_real_array(V, "V")  # sized before check_points copies it (a wrong
        m = math.prod(arr.shape[:-1]) if arr.ndim and arr.shape[-1] == d else 0  # shape: there)
        # the result, the rows (a copy and its scaled copy) and one chunk's temporaries
        # (three arrays of d * d floats per row)
        check_memory(m * d * d * 8 + 2 * m * d * 8 + min(PIECE_CHUNK_BYTES, 3 * m * d * d * 8),
                     memory_limit, f"the piece matrices of {m} vectors in dimension {d}")
        flat, lead = check_points(arr, d)
        P = np.empty((m, d, d))
        eye = np.eye(d)
        step = max(1, PIECE_CHUNK_BYTES // (3 * d * d * 8))
        flat = unit_scale(flat)
        for s in range(0, m, step):
            e = min(s + step, m)
            cols = np.empty(((e - s) * d, d))
            try:
                self._tangent_rows(np.repeat(flat[s:e], d, axis=0), np.tile(eye, (e - s, 1)),
                                   cols, False, 0, "V")
            except QueryError as exc:  # rows repeated d times: name the caller's row
                raise exc.at(row=s + exc.row // d, shape=lead) from None
            P[s:e] = cols.reshape(e - s, d, d).transpose(0, 2, 1)  # [q, i, :] = M e_i
        return P.reshape(lead + (d, d))

    def _pair(self, V, T, t_name, out, transpose, chunk_size, progress):
        """Validate V and T and evaluate ``_tangent_rows`` on V's rows (chunks of V carry
        their offset; the rows of T are taken at the same offset)."""
        d = self.dim
        refuse_dask(V, T, what="jvp/vjp take", how=f" (V and {t_name} chunked alike)")
        T, m, copy = batch_size(T, d, t_name)  # sized before check_points copies T
        held = ([] if out is not None else ["its result"]) + (
            [f"{t_name}'s float64 copy"] if copy else [])
        if held:
            check_memory(copy + (0 if out is not None else 8 * m * d), None,
                         f"the {'vjp' if transpose else 'jvp'} of {m} vectors "
                         f"({' and '.join(held)}) would",
                         f"pass out=, a writeable np.memmap of {t_name}'s shape, to write "
                         f"the result to a file, and {t_name} as a C-contiguous float64 "
                         f"array; or {FEWER_ROWS}")
        flat_t, lead_t = check_points(T, d, t_name)
        lead_v = np.shape(V)[:-1]
        if lead_v != lead_t:
            raise ValueError(
                f"V and {t_name} must have the same shape, got {np.shape(V)} and "
                f"{lead_t + (d,)}"
            )
        if out is not None and np.may_share_memory(out, flat_t):
            flat_t = flat_t.copy()  # out may be T itself (V is copied by evaluate)

        def kernel(rows, res, offset):
            self._tangent_rows(unit_scale(rows), flat_t[offset : offset + rows.shape[0]], res,
                               transpose, offset, t_name)

        return evaluate(kernel, V, d, name="V", out=out, chunk_size=chunk_size,
                        progress=progress, desc=type(self).__name__)
