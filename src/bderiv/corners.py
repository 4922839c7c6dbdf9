"""Corner models: the corner values ``F[mask]`` without the (2**n, d) table.

Pass a model instead of the dense table to :class:`~bderiv.BDerivative`; every query then
visits only the n + 1 regions of its own chain, so n is no longer capped by memory
(n = 128 events is routine). Regions of a model are named by a **happened array**: a
uint8 array of n flags, ``happened[k] = 1`` iff event k has happened (the bits of the dense
table's mask, without the 64-bit limit). Error messages print it as ``0b...`` with event 0
rightmost, like masks of dense tables.

Transversality cannot be checked on all 2**n regions of a model. What is checked:

- :class:`StructuredCorners` at construction of the ``BDerivative``: the lower bound
  ``G[mask, k] >= Dh[k].F0 + sum_i min(0, Dh[k].A[i]) + sum_p min(0, Dh[k].B[p])``.
  Without pairs the bound is attained, so the check is exact: a violation is refused up
  front, naming the region. With pairs a failed bound is inconclusive and the check falls
  to the queries (next point).
- every model, at every query: each rate of each region on the query's chain must be > 0,
  else the call raises ``ValueError`` naming the query, the event and the region. A wrong
  answer or NaN is never returned (``out`` may be partly written when the call raises).
"""

from __future__ import annotations

import numpy as np

from . import _corner_kernels, _tables
from ._validate import check_finite, check_matrix, check_real_array

#: the largest n for which a model's dense table (2**n rows) is built on request
#: (``corner_points``, ``triangulation``, ``table``).
MAX_TABLE_EVENTS = 20

#: transversality of structured corners counts as proved when the lower bound on every rate
#: exceeds this fraction of the sum of the magnitudes it adds up.
PROOF_MARGIN = 1e-9


def _check_table_size(n: int, d: int) -> None:
    if n > MAX_TABLE_EVENTS:
        raise ValueError(
            f"the dense table of a corner model with n={n} events has 2**{n} rows "
            f"({_tables.human_bytes(_tables.dense_table_bytes(n, d))}); it is built only "
            f"for n <= {MAX_TABLE_EVENTS}. apply, inverse, event_times and piece work "
            f"for any n without it"
        )


def happened_rows(masks: np.ndarray, n: int) -> np.ndarray:
    """uint8 (len(masks), n) flags of integer masks: row i, column k = bit k of masks[i]."""
    return ((masks[:, None] >> np.arange(n)) & 1).astype(np.uint8)


class StructuredCorners:
    """Contact-like corners: ``F[mask] = F0 + sum_{k in mask} A[k] + sum_{p: pairs[p] in
    mask} B[p]``.

    Event k adds the jump ``A[k]`` to the field; pair p adds ``B[p]`` once both of its
    events have happened (sparse interactions). The rates ``G[mask] = Dh @ F[mask]`` are
    updated incrementally along each query's chain: O(n^2 + p n + n d + p d) per query and
    O(n^2 + p (n + d)) memory, nothing of size 2**n.

    With ``Dh[j] . A[k] = 0`` for j != k and ``Dh @ B[p] = 0`` (the rate of an event changes
    only when it happens itself) the event order is a plain sort; without pairs the map is
    then linear (see ``BDerivative.fast_path``).

    Parameters
    ----------
    F0 : array_like, shape (d,)
        The pre-event field ``F[0]``.
    A : array_like, shape (n, d)
        ``A[k]``: the jump of the field when event k happens.
    pairs : array_like of int, shape (p, 2), optional
        Pairs of distinct events ``(j, k)`` that interact.
    B : array_like, shape (p, d), optional
        ``B[p]``: the extra jump once both events of ``pairs[p]`` have happened.

    Raises
    ------
    TypeError, ValueError
        On non-real or non-finite arrays, inconsistent shapes, or pairs that are out of
        range or join an event with itself.

    Examples
    --------
    >>> import numpy as np
    >>> from bderiv import BDerivative, StructuredCorners
    >>> model = StructuredCorners(F0=[1.0, 1.0], A=[[1.0, 0.0], [0.0, 0.0]])
    >>> bd = BDerivative(np.eye(2), model)   # the same map as the 4-row table [[1,1],
    >>> bd([-1.0, -2.0])                     # [2,1],[1,1],[2,1]]
    array([-2., -2.])
    """

    def __init__(self, F0, A, pairs=None, B=None):
        F0 = np.asarray(check_real_array(F0, "F0"), dtype=np.float64)
        if F0.ndim != 1 or F0.size == 0:
            raise ValueError(f"F0 must have shape (d,) with d >= 1, got shape {F0.shape}")
        check_finite(F0, "F0")
        d = F0.shape[0]
        A = check_matrix(A, "A", (None, d))
        n = A.shape[0]
        if n == 0:
            raise ValueError("A must have at least one row (one jump per event), got 0")
        if (pairs is None) != (B is None):
            raise ValueError("pairs and B go together: pass both or neither")
        if pairs is None:
            pairs = np.empty((0, 2), dtype=np.int64)
            B = np.empty((0, d))
        else:
            pairs = np.asarray(pairs)
            if pairs.size == 0:
                pairs = pairs.reshape(0, 2)
            if pairs.dtype.kind not in "iu":
                raise TypeError(f"pairs must hold integers, got dtype {pairs.dtype}")
            if pairs.ndim != 2 or pairs.shape[1] != 2:
                raise ValueError(f"pairs must have shape (p, 2), got {pairs.shape}")
            pairs = np.ascontiguousarray(pairs, dtype=np.int64)
            if pairs.size and (pairs.min() < 0 or pairs.max() >= n):
                raise ValueError(
                    f"pairs must name events 0..{n - 1} (n={n} from A's rows), got events "
                    f"from {pairs.min()} to {pairs.max()}"
                )
            same = np.flatnonzero(pairs[:, 0] == pairs[:, 1])
            if same.size:
                raise ValueError(
                    f"pairs[{same[0]}] = {pairs[same[0]].tolist()} joins an event with itself; "
                    f"put that jump into A"
                )
            B = check_matrix(B, "B", (pairs.shape[0], d))
        for arr in (F0, A, pairs, B):
            arr.flags.writeable = False
        self.F0, self.A, self.pairs, self.B = F0, A, pairs, B
        self.n_events, self.dim = n, d

    def __repr__(self) -> str:
        return (
            f"StructuredCorners(n_events={self.n_events}, dim={self.dim}, "
            f"pairs={self.pairs.shape[0]})"
        )

    def corners(self, happened) -> np.ndarray:
        """``F`` on regions given as 0/1 flags.

        Parameters
        ----------
        happened : array_like, shape (..., n)
            ``happened[..., k]`` true iff event k has happened.

        Returns
        -------
        ndarray, shape (..., d)
        """
        h = np.asarray(happened).astype(np.float64)
        both = h[..., self.pairs[:, 0]] * h[..., self.pairs[:, 1]]
        return self.F0 + h @ self.A + both @ self.B

    def chain_corners(self, order) -> np.ndarray:
        """``F[B_j]`` on the n + 1 regions of an event order, shape (n + 1, d)."""
        h = np.zeros((self.n_events + 1, self.n_events))
        for j, k in enumerate(order):
            h[j + 1 :, k] = 1.0
        return self.corners(h)

    def table(self) -> np.ndarray:
        """The dense (2**n, d) table (n <= ``MAX_TABLE_EVENTS``), e.g. for comparisons."""
        _check_table_size(self.n_events, self.dim)
        n = self.n_events
        F = np.empty((1 << n, self.dim))
        for rows in _tables.blocks(F.shape[0]):
            masks = np.arange(rows.start, rows.stop, dtype=np.int64)
            F[rows] = self.corners(happened_rows(masks, n))
        return F

    def _check_transversal(self, Dh, engine) -> bool:
        """Refuse a provable violation; return True when transversality is proved."""
        g0, a, bDh = engine.g0, engine.a, engine.bDh
        lower = g0 + np.minimum(a, 0).sum(axis=0) + np.minimum(bDh, 0).sum(axis=0)
        # margin: rates are updated along the chain by n + p additions, whose rounding is
        # ~ (n + p) eps (|g0| + sum |jumps|), far below this
        size = np.abs(g0) + np.abs(a).sum(axis=0) + np.abs(bDh).sum(axis=0)
        if (lower > PROOF_MARGIN * size).all():
            return True
        if self.pairs.shape[0] == 0 and not (lower > 0).all():  # bound attained: violated
            k = int(np.flatnonzero(~(lower > 0))[0])
            hap = (a[:, k] < 0).astype(np.uint8)
            from ._engines import format_happened

            raise ValueError(
                f"transversality violated at event {k} in region mask "
                f"{format_happened(hap)} (bit k set = event k happened): rate "
                f"Dh[{k}] . (F0 + sum of A over the region) = {lower[k]:.3g}, expected > 0; "
                f"the flow must cross every event surface from h_k < 0 to h_k > 0 in "
                f"every region"
            )
        for name, rates in (("0 (no event yet)", g0), ("full (all events)", engine.gfull)):
            if not (rates > 0).all():
                k = int(np.flatnonzero(~(rates > 0))[0])
                raise ValueError(
                    f"transversality violated at event {k} in region {name}: rate "
                    f"{rates[k]:.3g}, expected > 0"
                )
        return False

    def _engine(self, Dh, fast_paths: bool):
        from ._engines import StructuredEngine

        engine = StructuredEngine(Dh, self, fast_paths)
        engine.transversal_proved = self._check_transversal(Dh, engine)
        return engine


class CornerFunction:
    """Corners computed by a numba-compiled function on each region a query visits.

    Parameters
    ----------
    func : numba njit function ``func(happened, out) -> None``
        ``happened`` is a uint8 array of n flags (``happened[k] == 1`` iff event k has
        happened); ``func`` writes ``F[happened]`` into ``out``, a float64 array of shape
        (d,). It is called n + 1 times per query, from several threads at once: it must be
        pure (no shared state). A plain Python function is compiled with ``numba.njit``.
        Masks are arrays, not integers, so n is not limited to 62 events.

    Notes
    -----
    Each query costs n + 1 calls of ``func`` plus O(n^2 d) for its rates ``Dh @ F``. The
    kernels are compiled once per function and per process (first call takes seconds).
    Transversality is checked on every region a query visits (see the module notes).

    Examples
    --------
    >>> import numba, numpy as np
    >>> from bderiv import BDerivative, CornerFunction
    >>> @numba.njit
    ... def field(happened, out):
    ...     out[0] = 1.0 + happened[0]
    ...     out[1] = 1.0
    >>> bd = BDerivative(np.eye(2), CornerFunction(field))
    >>> bd([-1.0, -2.0])
    array([-2., -2.])
    """

    def __init__(self, func):
        from numba.core.registry import CPUDispatcher

        if not callable(func):
            raise TypeError(f"func must be a function func(happened, out), got {func!r}")
        if not isinstance(func, CPUDispatcher):
            import numba

            func = numba.njit(func)
        self.func = func

    def __repr__(self) -> str:
        name = getattr(self.func, "__name__", repr(self.func))
        return f"CornerFunction({name})"

    def corners(self, happened, dim: int) -> np.ndarray:
        """``F`` on the regions ``happened`` (shape (m, n), 0/1), shape (m, dim)."""
        h = np.ascontiguousarray(np.asarray(happened), dtype=np.uint8)
        if h.ndim != 2:
            raise ValueError(f"happened must have shape (m, n), got {h.shape}")
        out = np.full((h.shape[0], dim), np.nan)
        try:
            _corner_kernels.function_corners(self.func, h, out)
        except Exception as exc:  # numba typing errors come in many classes
            if isinstance(exc, ValueError | TypeError) and "func" in str(exc):
                raise
            raise TypeError(
                f"the corner function {self!r} could not be called as func(happened, out) "
                f"with happened a uint8 array of {h.shape[1]} flags and out a float64 array "
                f"of shape ({dim},): {type(exc).__name__}: {exc}"
            ) from exc
        return out

    def chain_corners(self, order, dim: int) -> np.ndarray:
        n = len(order)
        h = np.zeros((n + 1, n), dtype=np.uint8)
        for j, k in enumerate(order):
            h[j + 1 :, k] = 1
        return self.corners(h, dim)

    def table(self, n: int, dim: int) -> np.ndarray:
        """The dense (2**n, dim) table (n <= ``MAX_TABLE_EVENTS``)."""
        _check_table_size(n, dim)
        F = np.empty((1 << n, dim))
        for rows in _tables.blocks(F.shape[0]):
            masks = np.arange(rows.start, rows.stop, dtype=np.int64)
            F[rows] = self.corners(happened_rows(masks, n), dim)
        return F

    def _engine(self, Dh, fast_paths: bool):
        from ._engines import FunctionEngine

        n, d = Dh.shape
        # the first and the last region: checks that func runs and writes finite values
        ends = self.corners(np.array([np.zeros(n), np.ones(n)], dtype=np.uint8), d)
        if not np.isfinite(ends).all():
            raise ValueError(
                f"the corner function {self!r} must write all {d} entries of out with finite "
                f"values; on the region with no event it gave {ends[0]}, with all events "
                f"{ends[1]}"
            )
        engine = FunctionEngine(Dh, self, fast_paths)
        engine.transversal_proved = False
        return engine


CORNER_MODELS = (StructuredCorners, CornerFunction)
