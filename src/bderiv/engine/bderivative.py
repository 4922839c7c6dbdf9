"""``BDerivative``: the piecewise-linear B-derivative at a point where n events coincide."""

from __future__ import annotations

from collections.abc import Iterator
from functools import cached_property

import numpy as np

from .._kernels import scaling
from .._kernels._core import read_only
from .._limits import MAX_PIECES, RESET_TOL
from .._numerics import GRAZING_RTOL
from .._support._batch import evaluate, refuse_dask
from .._support._errors import QueryError
from .._support._validate import (
    AS_ROWS,
    FEWER_ROWS,
    batch_size,
    check_bool,
    check_finite_result,
    check_matrix,
    check_memory,
    check_points,
)
from .._support._validate_ints import check_order, check_pieces
from ._engines import DenseEngine
from ._engines.resets import LowRankResets, ResetEngine  # noqa: F401 (re-exported)
from ._geometry import (  # noqa: F401 (re-exported)
    CornerGeometry,
    CornerPoints,
    dh_rank,
)
from ._linearise import Linearisation, unit_scale
from ._representation import build_engine


class BDerivative(Linearisation, CornerGeometry):
    """B-derivative of an event-selected piecewise-smooth flow at an n-event point.

    The map ``M`` sends a pre-event tangent vector to the post-event tangent vector of the
    sampled (corner-limit) system (mathematics.md section 2). It is continuous and piecewise
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
        checked as described in :mod:`bderiv.geometry.corners`).
    transversality_tol : float, optional
        Default 1e-9 (0: no test). A dense table is refused when a rate
        ``G[mask, k] = F[mask] . Dh[k]`` is at most ``tol * |F[mask]| |Dh[k]|`` (grazing),
        or when one event's rates over the regions where it is pending differ by more than
        ``1 / tol`` (ill-conditioned). Accepted tables give M(u) to about
        ``n * eps * rate_spread`` of its scale, ties included (docs/mathematics.md,
        "Conditioning"). Corner models: rates > 0 only (see :mod:`bderiv.geometry.corners`).
    memory_limit : int, optional
        Bytes the dense tables may take; default: the memory currently available (dense
        tables only).
    fast_paths : bool, optional
        Use the fast paths when the tables allow them (default True; see ``fast_path``).
    resets : array_like of shape (2**n, n, d, d), or LowRankResets, optional
        Reset Jacobians at the events (impacts; dense tables only; mathematics.md section 9):
        ``resets[mask, k]`` for event k crossed from region ``mask``, or ``I + U V^T``
        (:class:`~bderiv.engine._engines.resets.LowRankResets`). Refused (ValueError naming the
        region and the events) when the flow has no B-derivative with them.
    reset_tol : float, optional
        Relative tolerance of that check, and ``1 / reset_tol`` the largest condition
        number of a reset that ``inverse`` accepts (default 1e-9).

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
    rate_spread : float or None
        Dense tables: the largest ratio of one event's rates over the regions where it is
        pending, the factor by which rounding in event times can grow. None for a model.
    resets : ndarray or LowRankResets or None
        The checked read-only reset Jacobians (unused entries zeroed), None without resets.
    full_rank : bool
        Whether Dh has row rank n (needed for corner points and the triangulation).
    transversality : {"table", "proved", "per-query"}
        How transversality was established: every region of the dense table checked at
        construction; proved for all regions of a structured model by its rate bound; or
        checked on every region a query visits (the kernels then test each rate).

    Raises
    ------
    TypeError
        If Dh or F is not real-valued (bool, complex, object or string dtypes).
    ValueError
        On wrong shapes, non-finite entries, a transversality violation, a grazing rate
        or ill-conditioned event times (naming the masks and the event), or tables larger
        than ``memory_limit``.

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

    def __init__(self, Dh, F, *, transversality_tol: float = GRAZING_RTOL, memory_limit=None,
                 fast_paths: bool = True, resets=None, reset_tol: float = RESET_TOL):
        # validate
        Dh = check_matrix(Dh, "Dh", (None, None))
        if Dh.shape[0] == 0 or Dh.shape[1] == 0:
            raise ValueError(f"Dh must have at least one event and one dimension, got {Dh.shape}")
        fast_paths = self._fast_paths = check_bool(fast_paths, "fast_paths")
        # choose the representation and build its engine (which validates its own tables)
        engine, model = build_engine(Dh, F, resets, transversality_tol, memory_limit,
                                     fast_paths, reset_tol)
        self._adopt(Dh, engine, model)

    @classmethod
    def _from_checked(cls, Dh, F, *, resets=None, reset_tol: float = RESET_TOL):
        """The map ``BDerivative(Dh, F, resets=resets, reset_tol=reset_tol)`` gives, from
        tables its caller made and checked (:func:`bderiv.analysis.assembly.group_bderivative`
        samples them from a model's checked outputs): Dh (n, d), n and d >= 1, a
        C-contiguous float64 array the map keeps (made read-only), F (2**n, d) float64,
        both finite; resets (2**n, n, d, d) or None. Only the checks of these arguments are
        skipped: the size, transversality, rate spread and reset checks of the tables run
        as in ``__init__``."""
        bd = cls.__new__(cls)
        bd._fast_paths = True
        if resets is None:
            engine = DenseEngine.build(Dh, F, GRAZING_RTOL, None, checked=True)
        else:
            engine = ResetEngine.build(Dh, F, resets, GRAZING_RTOL, reset_tol, None,
                                       checked=True)
        bd._adopt(Dh, engine, None)
        return bd

    def _adopt(self, Dh, engine, model) -> None:
        """The attributes of a map from its engine (``model``: None for a dense table)."""
        self.n_events, self.dim = Dh.shape
        self.Dh, self.model, self._engine = Dh, model, engine
        self.fast_path = engine.fast_path
        self.resets = getattr(engine, "resets", None)
        Dh.flags.writeable = False
        if model is None:
            self.F, self.rates = engine.caller_tables()
            for a in (engine.R, self.F, self.rates):
                a.flags.writeable = False
            self.rate_spread = engine.rate_spread
            self.transversality = "table"
        else:
            self.F = self.rates = self.rate_spread = None
            self.transversality = "proved" if engine.transversal_proved else "per-query"

    def __repr__(self) -> str:
        return f"BDerivative(n_events={self.n_events}, dim={self.dim})"

    def __getstate__(self) -> dict:
        state = self.__dict__.copy()
        if self.model is None:  # views of the engine's arrays: linked again on unpickling
            state.pop("F"), state.pop("rates"), state.pop("resets", None)
        return state

    def __setstate__(self, state: dict) -> None:
        # unpickled arrays come back writeable; keep the tables read-only as built
        self.__dict__.update(state)
        self.resets = getattr(self._engine, "resets", None)
        if self.model is None:
            self.F, self.rates = self._engine.caller_tables()
            self._engine.R.flags.writeable = False
        for arr in (self.Dh, self.F, self.rates):
            if isinstance(arr, np.ndarray):
                arr.flags.writeable = False

    @cached_property
    def full_rank(self) -> bool:
        return dh_rank(self.Dh) == self.n_events

    @property
    def table_bytes(self) -> int:
        """Bytes held by the region records, which hold F and G (0 for a corner model)."""
        if self.F is None:
            return 0
        return self._engine.R.nbytes if self.resets is None else self._engine.table_bytes

    # -- evaluation -------------------------------------------------------------------------

    def _map(self, V, out, inverse: bool, chunk_size, progress, method):
        name = "W" if inverse else "V"

        def kernel(rows, res, offset):
            if self._engine.map(rows, res, inverse, name, offset):
                check_finite_result(res, name, offset)

        return evaluate(kernel, V, self.dim, name=name, out=out, chunk_size=chunk_size,
                        progress=progress, desc="BDerivative", method=method)

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
            or, when ``V`` is a memmap, ``progress`` is given or ``V`` has more than
            ``IMPLICIT_CHUNK_ROWS`` (2**20) vectors, chunks of at most
            ``DEFAULT_CHUNK_ROWS`` (2**16) vectors sized to about half a second each by
            the last one's time (Ctrl-C is then seen between chunks).
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
        return self._map(V, out, False, chunk_size, progress, self.apply)

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
        return self._map(W, out, True, chunk_size, progress, self.inverse)

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

        Raises
        ------
        ValueError
            If a nonzero time is beyond the normal float64 range (``V`` near the ends of
            the range: times scale with it, ``times(c v) = c times(v)``), naming the
            vector and the event; ``apply``, ``inverse`` and ``orders`` still work there.
        """
        return self._event_times(V, True)

    def orders(self, V) -> np.ndarray:
        """The event order (piece) of each vector: ``event_times(V)[1]``, shape (..., n)
        (given also where the times themselves are beyond float64)."""
        return self._event_times(V, False)[1]

    def _event_times(self, V, exact: bool):
        refuse_dask(V, what="event_times and orders take")
        n = self.n_events
        V, m, copy = batch_size(V, self.dim)  # sized before check_points copies V
        check_memory(2 * m * n * 8 + copy, None, f"the event times and orders of {m} vectors "
                     f"({n} events){AS_ROWS if copy else ''}", FEWER_ROWS)
        flat, lead = check_points(V, self.dim)
        times = np.empty((flat.shape[0], n))
        order = np.empty((flat.shape[0], n), dtype=np.int64)
        try:
            if self._engine.event_times(flat, times, order, exact=exact) and exact:
                check_finite_result(times, "V", 0, "event times")
        except QueryError as exc:  # named by its full index in a batch of several axes
            raise exc.at(shape=lead) from None
        return times.reshape(lead + (n,)), order.reshape(lead + (n,))

    def _tangent_rows(self, V, T, res, transpose: bool, offset: int, name: str) -> None:
        """The kernel of ``jvp``/``vjp`` (:class:`~bderiv.engine._linearise.Linearisation`);
        ``name``: T's in the caller's errors. The piece is linear: when a row of T is
        beyond ``_numerics.QUERY_BAND``, the rows run scaled by powers of two, as the queries
        of :meth:`apply` do, so that their products along the chain under- or overflow
        only where the result does (a read-only pass otherwise: scaling every batch cost
        jvp 1.2x)."""
        exps = np.empty(T.shape[0], dtype=np.int64)
        if not scaling.outside_band(T, exps):  # T read-only, as kernels take what they read
            bad = self._engine.tangents(V, read_only(T), res, transpose, offset)
        else:
            self._engine.tangents(V, read_only(unit_scale(T, exps)), res, transpose, offset)
            bad = scaling.unscale_rows(res, exps, 0)
        if bad:
            check_finite_result(res, name, offset)

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
        check_pieces(self.n_events, max_pieces)
        return self._iter_pieces()

    def _iter_pieces(self):
        from itertools import permutations

        for order in permutations(range(self.n_events)):
            order = np.array(order, dtype=np.int64)
            yield order, self.piece(order)
