"""``BDerivative``: the piecewise-linear B-derivative at a point where n events coincide."""

from __future__ import annotations

import math
from collections.abc import Iterator
from functools import cached_property

import numpy as np

from . import _kernels, _tables
from ._validate import check_matrix, check_order, check_out, check_points, check_positive_int

#: batches smaller than this run on one thread (thread start-up costs more than it saves).
PARALLEL_MIN_QUERIES = 1024

#: default cap on the number of pieces ``pieces()`` and ``triangulation()`` will build.
MAX_PIECES = 40320  # 8!


class BDerivative:
    """B-derivative of an event-selected piecewise-smooth flow at an n-event point.

    The map ``M`` sends a pre-event tangent vector to the post-event tangent vector of the
    sampled (corner-limit) system (MATH.md section 2). It is continuous and piecewise
    linear with one linear piece per event order (n! pieces), none of which is built
    unless asked for: each query finds its own event order and event times.

    Parameters
    ----------
    Dh : array_like, shape (n, d)
        Event Jacobian: row k is the gradient of the event function h_k at the event point.
    F : array_like, shape (2**n, d)
        Corner table: ``F[mask]`` is the limit of the vector field of the region where the
        events whose bits are set in ``mask`` have happened (bit k set = event k happened).
    transversality_tol : float, optional
        Rates ``G[mask, k] = F[mask] . Dh[k]`` must exceed
        ``transversality_tol * |F[mask]| * |Dh[k]|``; smaller positive rates are refused
        as grazing (event times would be ill-conditioned). Default 1e-9.
    memory_limit : int, optional
        Bytes the dense tables may take; default: the memory currently available.

    Attributes
    ----------
    n_events : int
        n, the number of events.
    dim : int
        d, the state dimension.
    Dh : ndarray, shape (n, d)
        Read-only float64 copy of the event Jacobian.
    F : ndarray, shape (2**n, d)
        Read-only float64 copy of the corner table.
    rates : ndarray, shape (2**n, n)
        Read-only event rates ``G = F @ Dh.T``.
    full_rank : bool
        Whether Dh has row rank n (needed for corner points and the triangulation).

    Raises
    ------
    TypeError
        If Dh or F is not real-valued (bool, complex, object or string dtypes).
    ValueError
        On wrong shapes, non-finite entries, a transversality violation or grazing rate
        (naming the mask and the event), or tables larger than ``memory_limit``.

    Examples
    --------
    Two events in the plane; the field speeds up in x after event 0:

    >>> import numpy as np
    >>> from bderiv import BDerivative
    >>> Dh = np.eye(2)
    >>> F = np.array([[1.0, 1.0], [2.0, 1.0], [1.0, 1.0], [2.0, 1.0]])
    >>> bd = BDerivative(Dh, F)
    >>> bd([-1.0, -2.0])          # event 0 at t=1, event 1 at t=2
    array([-2., -2.])
    >>> bd.event_times([-1.0, -2.0])
    (array([1., 2.]), array([0, 1]))
    >>> bd.inverse(bd([0.3, -0.7]))
    array([ 0.3, -0.7])
    """

    def __init__(self, Dh, F, *, transversality_tol: float = 1e-9, memory_limit=None):
        Dh = check_matrix(Dh, "Dh", (None, None))
        n, d = Dh.shape
        if n == 0 or d == 0:
            raise ValueError(f"Dh must have at least one event and one dimension, got {Dh.shape}")
        limit = _tables.available_memory() if memory_limit is None else int(memory_limit)
        need = _tables.dense_table_bytes(n, d)
        if n > 40 or need > limit:
            raise ValueError(
                f"dense corner tables for n={n} events in dimension d={d} need 2**{n} rows, "
                f"{_tables.human_bytes(need)}, more than the memory limit of "
                f"{_tables.human_bytes(limit)}; use fewer simultaneous events or a corner "
                f"model that does not store 2**n rows"
            )
        F = check_matrix(F, "F", (None, d))
        if F.shape[0] != 1 << n:
            raise ValueError(
                f"F must have 2**n = {1 << n} rows (one per mask of n={n} events, n from "
                f"Dh's {n} rows), got {F.shape[0]} rows"
            )
        if not (isinstance(transversality_tol, int | float) and transversality_tol >= 0):
            raise ValueError(
                f"transversality_tol must be a number >= 0, got {transversality_tol!r}"
            )

        G = _tables.event_rates(F, Dh)
        bad = _tables.find_transversality_violation(G, F, Dh, transversality_tol)
        if bad is not None:
            mask, k, kind, scale = bad
            where = (
                f"event {k} in region mask {_tables.format_mask(mask, n)} (bit k set = event "
                f"k happened): rate G[{mask}, {k}] = F[{mask}] . Dh[{k}] = {G[mask, k]:.3g}"
            )
            if kind == "violated":
                raise ValueError(
                    f"transversality violated at {where}, expected > 0: the flow must cross "
                    f"every event surface from h_k < 0 to h_k > 0 in every region"
                )
            raise ValueError(
                f"grazing rate at {where}, tiny relative to |F[{mask}]| |Dh[{k}]| = "
                f"{scale:.3g} (transversality_tol={transversality_tol:g}); the surface is "
                f"nearly tangent to the flow"
            )
        for a in (Dh, F, G):
            a.flags.writeable = False
        self.Dh, self.F, self.rates = Dh, F, G
        self.n_events, self.dim = n, d

    def __repr__(self) -> str:
        return f"BDerivative(n_events={self.n_events}, dim={self.dim})"

    def __setstate__(self, state: dict) -> None:
        # unpickled arrays come back writeable; keep the tables read-only as built
        self.__dict__.update(state)
        for name in ("Dh", "F", "rates"):
            arr = state.get(name)
            if isinstance(arr, np.ndarray):
                arr.flags.writeable = False

    @cached_property
    def full_rank(self) -> bool:
        return bool(np.linalg.matrix_rank(self.Dh) == self.n_events)

    @property
    def table_bytes(self) -> int:
        """Bytes held by the tables F and G."""
        return self.F.nbytes + self.rates.nbytes

    # -- evaluation -------------------------------------------------------------------------

    def _map(self, V, out, inverse: bool, name: str):
        flat, lead = check_points(V, self.dim, name)
        shape = lead + (self.dim,)
        if out is None:
            result = np.empty(shape)
        else:
            result = check_out(out, shape)
        kernel = (
            _kernels.map_parallel if flat.shape[0] >= PARALLEL_MIN_QUERIES else _kernels.map_serial
        )
        kernel(self.Dh, self.F, self.rates, flat, result.reshape(-1, self.dim), inverse)
        return result

    def apply(self, V, out=None) -> np.ndarray:
        """Evaluate the B-derivative on pre-event tangent vectors.

        Parameters
        ----------
        V : array_like, shape (..., d)
            Pre-event vectors (one vector ``(d,)`` or any batch).
        out : ndarray, shape (..., d), optional
            C-contiguous float64 array to write the result into.

        Returns
        -------
        ndarray, shape (..., d)
            Post-event vectors ``M(V)``.
        """
        if type(V).__module__.startswith("dask."):  # lazy, block-wise (see _dask.py)
            from ._dask import map_blocks

            return map_blocks(self.apply, V, self.dim, "V", out)
        return self._map(V, out, inverse=False, name="V")

    __call__ = apply

    def inverse(self, W, out=None) -> np.ndarray:
        """Evaluate the exact inverse map (post-event vectors to pre-event vectors).

        Parameters
        ----------
        W : array_like, shape (..., d)
        out : ndarray, shape (..., d), optional

        Returns
        -------
        ndarray, shape (..., d)
            ``V`` with ``self(V) == W`` up to rounding.
        """
        if type(W).__module__.startswith("dask."):  # lazy, block-wise (see _dask.py)
            from ._dask import map_blocks

            return map_blocks(self.inverse, W, self.dim, "W", out)
        return self._map(W, out, inverse=True, name="W")

    def event_times(self, V) -> tuple[np.ndarray, np.ndarray]:
        """Event times and event order of the sampled trajectory of each vector.

        Parameters
        ----------
        V : array_like, shape (..., d)
            Pre-event vectors: the virtual positions at time 0 of the pre-event flow.

        Returns
        -------
        times : ndarray, shape (..., n)
            ``times[..., k]`` is the time at which event k happens.
        order : ndarray of int64, shape (..., n)
            ``order[..., j]`` is the j-th event to happen (the piece's event order).
        """
        flat, lead = check_points(V, self.dim)
        n = self.n_events
        times = np.empty((flat.shape[0], n))
        order = np.empty((flat.shape[0], n), dtype=np.int64)
        _kernels.event_times_batch(self.Dh, self.rates, flat, times, order)
        return times.reshape(lead + (n,)), order.reshape(lead + (n,))

    # -- pieces -----------------------------------------------------------------------------

    def piece(self, order) -> np.ndarray:
        """The (d, d) matrix of the linear piece of one event order.

        Parameters
        ----------
        order : sequence of int, length n
            A permutation of ``0..n-1``: ``order[j]`` is the j-th event to happen.

        Returns
        -------
        ndarray, shape (d, d)
            ``S_n ... S_1``, the product of the saltation matrices along the order.
        """
        order = check_order(order, self.n_events)
        out = np.empty((self.dim, self.dim))
        _kernels.piece_matrix(self.Dh, self.F, self.rates, order, out)
        return out

    def pieces(self, max_pieces: int = MAX_PIECES) -> Iterator[tuple[np.ndarray, np.ndarray]]:
        """Iterate over all n! ``(order, matrix)`` pairs, orders in lexicographic order.

        Raises
        ------
        ValueError
            If n! exceeds ``max_pieces`` (raise the limit to go on anyway).
        """
        check_positive_int(max_pieces, "max_pieces")
        count = math.factorial(self.n_events)
        if count > max_pieces:
            raise ValueError(
                f"{self.n_events} events have {self.n_events}! = {count} pieces, more than "
                f"max_pieces={max_pieces}; pass a larger max_pieces, or use piece(order) for "
                f"the orders you need"
            )
        return self._iter_pieces()

    def _iter_pieces(self):
        from itertools import permutations

        for order in permutations(range(self.n_events)):
            order = np.array(order, dtype=np.int64)
            yield order, self.piece(order)

    # -- corner points and triangulation ------------------------------------------------------

    def _require_full_rank(self, what: str) -> None:
        if not self.full_rank:
            rank = np.linalg.matrix_rank(self.Dh)
            raise ValueError(
                f"{what} need Dh of full row rank n={self.n_events}, but rank(Dh) = {rank} "
                f"(more events than independent surfaces); apply, inverse, event_times and "
                f"piece still work"
            )

    def corner_points(self, memory_limit=None) -> tuple[np.ndarray, np.ndarray]:
        """The 2**n pre- and post-event corner points (MATH.md section 5).

        Returns
        -------
        U, W : ndarray, shape (2**n, d) each
            ``M(U[mask]) == W[mask]``; ``U[0] = W[0] = 0``, ``U[-1] = F[0]``,
            ``W[-1] = F[-1]``.

        Raises
        ------
        ValueError
            If Dh is not of full row rank, or U and W would exceed ``memory_limit``.
        """
        self._require_full_rank("corner points")
        need = _tables.corner_point_bytes(self.n_events, self.dim)
        limit = _tables.available_memory() if memory_limit is None else int(memory_limit)
        if need > limit:
            raise ValueError(
                f"corner points for n={self.n_events} take {_tables.human_bytes(need)}, more "
                f"than the memory limit of {_tables.human_bytes(limit)}"
            )
        return _tables.corner_points(self.F, self.Dh, self.rates)

    def triangulation(self, max_pieces: int = MAX_PIECES):
        """The PL homeomorphism as vertices and simplices (see :class:`Triangulation`)."""
        from .triangulation import Triangulation

        self._require_full_rank("the triangulation")
        return Triangulation.from_bderivative(self, max_pieces=max_pieces)
