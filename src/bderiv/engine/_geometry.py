"""Corner points, triangulation and dense table of a ``BDerivative`` (a mix-in).

What needs the 2**n regions as a whole rather than one query's chain: the corner points
(mathematics.md section 5), the triangulation built on them, and a corner model's dense table.
Each checks its size (and the rank of Dh) before building anything.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from .._limits import MAX_PIECES
from .._support import _tables
from .._support._format import format_region
from .._support._validate import check_memory
from .._support._validate_ints import check_pieces
from ..geometry.corners import check_table_size


def dh_rank(Dh) -> int:
    """The row rank of Dh, with each row first scaled by a power of two to a largest entry
    in [0.5, 1) (the rank does not change; NumPy's tolerance, relative to the largest
    singular value, would count rows 2**40 smaller than the others as zero)."""
    return int(np.linalg.matrix_rank(np.ldexp(Dh, -np.frexp(np.abs(Dh).max(axis=1))[1][:, None])))


class CornerPoints(NamedTuple):
    """The 2**n corner points: ``post[mask] = M(pre[mask])`` (mathematics.md section 5)."""

    pre: np.ndarray
    post: np.ndarray


class CornerGeometry:
    """``corner_points``, ``triangulation`` and ``to_dense`` of a ``BDerivative``."""

    def _require_full_rank(self, what: str) -> None:
        if not self.full_rank:
            rank = dh_rank(self.Dh)
            raise ValueError(
                f"{what} need Dh of full row rank n={self.n_events}, but rank(Dh) = {rank} "
                f"(more events than independent surfaces); apply, inverse, event_times and "
                f"piece still work"
            )

    def corner_points(self, memory_limit=None) -> CornerPoints:
        """The 2**n pre- and post-event corner points (mathematics.md section 5).

        Returns
        -------
        CornerPoints
            ``(pre, post)``, each of shape (2**n, d), with ``M(pre[mask]) == post[mask]``;
            ``pre[0] = post[0] = 0``, ``pre[-1] = F[0]``, ``post[-1] = F[-1]`` (for d > n up
            to a vector of ker Dh, on which M is the identity, or with resets their
            product; their derivation: ``_engines.resets.ResetEngine.corner_points``).
            Unpacks as ``pre, post = bd.corner_points()``.

        Raises
        ------
        ValueError
            If Dh is not of full row rank, or the points would exceed ``memory_limit``
            (default: the memory available).
        """
        self._require_full_rank("corner points")
        if self.model is not None:
            return self.to_dense("corner points", memory_limit).corner_points(memory_limit)
        need = _tables.corner_point_bytes(self.n_events, self.dim)
        check_memory(need, memory_limit, f"corner points for n={self.n_events}")
        return CornerPoints(*self._engine.corner_points())

    def triangulation(self, max_pieces: int = MAX_PIECES):
        """The PL homeomorphism as vertices and simplices (see :class:`Triangulation`).

        Raises
        ------
        ValueError
            If Dh is not of full row rank, n! exceeds ``max_pieces`` (checked before
            anything is built), or a reset is singular (no homeomorphism).
        """
        from ..geometry.triangulation import Triangulation

        self._require_full_rank("the triangulation")
        if self.resets is not None:  # a PL homeomorphism: refuses singular resets
            self._engine.inverse_resets("triangulation")
        if self.model is not None:  # the pieces are counted before a table is built
            check_table_size(self.n_events, self.dim, "the triangulation")
            check_pieces(self.n_events, max_pieces)
            return self.to_dense("the triangulation").triangulation(max_pieces)
        return Triangulation.from_bderivative(self, max_pieces=max_pieces)

    def to_dense(self, what: str = "the dense table", memory_limit=None):
        """This map with its corners as a dense (2**n, d) table.

        For a corner model the table is built (n <= ``corners.MAX_TABLE_EVENTS`` and within
        ``memory_limit``, default the memory available) and checked whole for
        transversality; a dense map returns itself.

        Raises
        ------
        ValueError
            For a corner model with too many events, or a table too large for memory.
        """
        if self.model is None:
            return self
        n, d = self.n_events, self.dim
        check_table_size(n, d, what)
        check_memory(_tables.dense_table_bytes(n, d), memory_limit,
                      f"{what} of a corner model with n={n} events in dimension d={d} "
                      f"(its dense table)")
        F = self._engine.dense_table()
        if not np.isfinite(F).all():
            mask = int(np.flatnonzero(~np.isfinite(F).all(axis=1))[0])
            raise ValueError(
                f"the corner model {self.model!r} gave a non-finite corner for "
                f"{format_region(mask, n)}: {F[mask]}"
            )
        return type(self)(self.Dh, F, fast_paths=self._fast_paths)
