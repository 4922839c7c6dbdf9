"""``BDerivative``: the piecewise-linear B-derivative at a point where n events coincide."""

from __future__ import annotations

import math
import numbers
from collections.abc import Iterator
from functools import cached_property

import numpy as np

from . import _engines, _tables
from ._validate import check_matrix, check_order, check_out, check_points, check_positive_int
from .corners import CORNER_MODELS

#: batches smaller than this run on one thread (thread start-up costs more than it saves).
PARALLEL_MIN_QUERIES = _engines.PARALLEL_MIN_QUERIES

#: rows per chunk of ``apply``/``inverse`` when chunking is implied (a ``progress``
#: callback or a memmap input) and no ``chunk_size`` is given: 2**16 rows of d = 128 are
#: 64 MiB, and a chunk is long enough to keep two threads busy.
DEFAULT_CHUNK_ROWS = 1 << 16

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
    F : array_like, shape (2**n, d), or a corner model
        Corner table: ``F[mask]`` is the limit of the vector field of the region where the
        events whose bits are set in ``mask`` have happened (bit k set = event k happened).
        Or a :class:`~bderiv.StructuredCorners` / :class:`~bderiv.CornerFunction` model
        that gives the corners without storing 2**n rows (any n; transversality is then
        checked as described in :mod:`bderiv.corners`).
    transversality_tol : float, optional
        Rates ``G[mask, k] = F[mask] . Dh[k]`` must exceed
        ``transversality_tol * |F[mask]| * |Dh[k]|``; smaller positive rates are refused
        as grazing (event times would be ill-conditioned). Default 1e-9. Dense tables
        only: a corner model's rates are checked to be > 0 (see :mod:`bderiv.corners`).
    memory_limit : int, optional
        Bytes the dense tables may take; default: the memory currently available (dense
        tables only).
    fast_paths : bool, optional
        Use the fast paths when the tables allow them (default True; see ``fast_path``).

    Attributes
    ----------
    n_events : int
        n, the number of events.
    dim : int
        d, the state dimension.
    Dh : ndarray, shape (n, d)
        Read-only float64 copy of the event Jacobian.
    F : ndarray, shape (2**n, d), or None
        Read-only float64 copy of the corner table (None for a corner model).
    rates : ndarray, shape (2**n, n), or None
        Read-only event rates ``G = F @ Dh.T`` (None for a corner model).
    model : StructuredCorners or CornerFunction or None
        The corner model, None for a dense table.
    fast_path : {None, "own-rates", "linear"}
        The evaluation path chosen at construction. ``"own-rates"``: the rate of each event
        depends on no other event (``G[mask, k]`` depends only on bit k), so the event
        times are the first-order times and the order a sort. ``"linear"``: in addition
        the corners are additive (``F[mask] = F[0] + sum_{k in mask} A[k]``); then all
        n! pieces coincide and ``M(u) = u - A^T t = (I + A^T diag(1/G[0]) Dh) u``, one
        matrix product per query. None: the general selection with re-read rates.
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

    def __init__(self, Dh, F, *, transversality_tol: float = 1e-9, memory_limit=None,
                 fast_paths: bool = True):
        Dh = check_matrix(Dh, "Dh", (None, None))
        n, d = Dh.shape
        if n == 0 or d == 0:
            raise ValueError(f"Dh must have at least one event and one dimension, got {Dh.shape}")
        if isinstance(F, CORNER_MODELS):
            self._init_model(Dh, F, fast_paths)
            return
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
        if not (isinstance(transversality_tol, numbers.Real) and transversality_tol >= 0):
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
        self.model = None
        self._engine = _engines.DenseEngine(Dh, F, G, fast_paths=fast_paths)
        self.fast_path = self._engine.fast_path

    def _init_model(self, Dh, model, fast_paths: bool) -> None:
        n, d = Dh.shape
        want = (getattr(model, "n_events", n), getattr(model, "dim", d))
        if want != (n, d):
            raise ValueError(
                f"Dh has shape {Dh.shape} (n={n} events, dimension d={d}) but the corner "
                f"model {model!r} has n={want[0]} events in dimension d={want[1]}"
            )
        self._engine = model._engine(Dh, fast_paths)
        Dh.flags.writeable = False
        self.Dh, self.F, self.rates, self.model = Dh, None, None, model
        self.n_events, self.dim = n, d
        self.fast_path = self._engine.fast_path

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
        """Bytes held by the tables F and G (0 for a corner model)."""
        if self.F is None:
            return 0
        return self.F.nbytes + self.rates.nbytes

    # -- evaluation -------------------------------------------------------------------------

    def _map(self, V, out, inverse: bool, name: str, chunk_size=None, progress=None):
        if chunk_size is None and progress is None and not isinstance(V, np.memmap):
            flat, lead = check_points(V, self.dim, name)
            shape = lead + (self.dim,)
            result = np.empty(shape) if out is None else check_out(out, shape)
            self._engine.map(flat, result.reshape(-1, self.dim), inverse, name)
            return result
        return self._map_chunked(V, out, inverse, name, chunk_size, progress)

    def _map_chunked(self, V, out, inverse, name, chunk_size, progress):
        """Evaluate chunk by chunk: only one chunk of V is converted or held at a time."""
        if chunk_size is None:
            chunk_size = DEFAULT_CHUNK_ROWS
        chunk_size = check_positive_int(chunk_size, "chunk_size")
        if progress is not None and not callable(progress):
            from ._progress import resolve_progress

            progress = resolve_progress(progress, desc="BDerivative")
        if not isinstance(V, np.ndarray):
            V = np.asarray(V)
        if V.ndim == 0 or V.shape[-1] != self.dim:
            check_points(V, self.dim, name)  # raises the usual message
        lead = V.shape[:-1]
        rows = V.reshape(-1, self.dim)  # a view for contiguous (memmap) input
        shape = lead + (self.dim,)
        result = np.empty(shape) if out is None else check_out(out, shape)
        res = result.reshape(-1, self.dim)
        total = rows.shape[0]
        for start in range(0, total, chunk_size):
            stop = min(start + chunk_size, total)
            try:
                flat, _ = check_points(rows[start:stop], self.dim, name)
                self._engine.map(flat, res[start:stop], inverse, name)
            except ValueError as exc:
                raise ValueError(f"in rows {start}:{stop} of {name}: {exc}") from exc
            if progress is not None:
                progress(stop, total)
        if progress is not None and total == 0:
            progress(0, 0)
        return result

    def apply(self, V, out=None, *, chunk_size=None, progress=None) -> np.ndarray:
        """Evaluate the B-derivative on pre-event tangent vectors.

        Parameters
        ----------
        V : array_like, shape (..., d)
            Pre-event vectors (one vector ``(d,)`` or any batch; an ``np.memmap`` is read
            chunk by chunk).
        out : ndarray, shape (..., d), optional
            C-contiguous float64 array to write the result into (an ``np.memmap`` opened
            for writing works: batches larger than memory go from file to file).
        chunk_size : int, optional
            Evaluate ``chunk_size`` vectors at a time, so that only one chunk of ``V`` is
            converted to float64 and validated at once. Default: the whole batch at once,
            or ``DEFAULT_CHUNK_ROWS`` when ``V`` is a memmap or ``progress`` is given.
            Results do not depend on the chunking (bit for bit).
        progress : callable ``progress(done, total)``, or True, optional
            Called after each chunk with the number of vectors done and the total;
            ``True`` draws a tqdm bar (needs the ``progress`` extra).

        Raises
        ------
        ValueError
            On a wrong shape or non-finite vector; for a corner model, on a rate <= 0 met on
            a vector's chain (naming the vector, the event and the region; with chunking
            the rows of the chunk too; ``out`` may then be partly written).

        Returns
        -------
        ndarray, shape (..., d)
            Post-event vectors ``M(V)``.
        """
        if type(V).__module__.startswith("dask."):  # lazy, block-wise (see _dask.py)
            from ._dask import map_blocks

            return map_blocks(self.apply, V, self.dim, "V", out)
        return self._map(V, out, False, "V", chunk_size, progress)

    __call__ = apply

    def inverse(self, W, out=None, *, chunk_size=None, progress=None) -> np.ndarray:
        """Evaluate the exact inverse map (post-event vectors to pre-event vectors).

        Parameters
        ----------
        W : array_like, shape (..., d)
        out : ndarray, shape (..., d), optional
        chunk_size, progress : optional
            As for :meth:`apply`.

        Returns
        -------
        ndarray, shape (..., d)
            ``V`` with ``self(V) == W`` up to rounding.
        """
        if type(W).__module__.startswith("dask."):  # lazy, block-wise (see _dask.py)
            from ._dask import map_blocks

            return map_blocks(self.inverse, W, self.dim, "W", out)
        return self._map(W, out, True, "W", chunk_size, progress)

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
        self._engine.event_times(flat, times, order)
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
        return self._engine.piece(order)

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
            ``W[-1] = F[-1]`` (for d > n up to a vector of ker Dh, on which M is the
            identity).

        Raises
        ------
        ValueError
            If Dh is not of full row rank, or U and W would exceed ``memory_limit``.
        """
        self._require_full_rank("corner points")
        if self.model is not None:
            return self.to_dense("corner points").corner_points(memory_limit)
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
        if self.model is not None:
            return self.to_dense("the triangulation").triangulation(max_pieces)
        return Triangulation.from_bderivative(self, max_pieces=max_pieces)

    def to_dense(self, what: str = "the dense table") -> BDerivative:
        """This map with its corners as a dense (2**n, d) table.

        For a corner model the table is built (n <= ``corners.MAX_TABLE_EVENTS``, checked
        whole for transversality); a dense map returns itself.

        Raises
        ------
        ValueError
            For a corner model with too many events for a table of 2**n rows.
        """
        if self.model is None:
            return self
        from .corners import MAX_TABLE_EVENTS

        if self.n_events > MAX_TABLE_EVENTS:
            raise ValueError(
                f"{what} of a corner model with n={self.n_events} events need its dense "
                f"table of 2**{self.n_events} rows; this is refused for n > "
                f"{MAX_TABLE_EVENTS}. apply, inverse, event_times and piece work without it"
            )
        return BDerivative(self.Dh, self._engine.dense_table())
