"""Corner models: the corner values ``F[mask]`` without the (2**n, d) table.

Pass a model instead of the dense table to :class:`~bderiv.BDerivative`; every query then
visits only the n + 1 regions of its own chain, so n is no longer capped by memory
(n = 128 events is routine). Regions of a model are named by a **happened array**: a
uint8 array of n flags, ``happened[k] = 1`` iff event k has happened (the bits of the dense
table's mask, without the 64-bit limit). Error messages print it as ``0b...`` with event 0
rightmost, like masks of dense tables.

**The corner-model protocol** (:class:`CornerModel`) is what ``BDerivative`` asks of a
model, and all it asks: ``n_events`` and ``dim`` (or None: taken from ``Dh``),
``corners(happened)`` (NumPy, any batch of regions) and ``corner_function()`` (a numba
function ``func(happened, out)`` that the compiled kernels call on each region of each
chain). :class:`StructuredCorners` also has an engine of its own that updates the rates
incrementally; :class:`CornerFunction` wraps a function; any other class with these
members is a corner model too (the tutorial shows one).

Transversality cannot be checked on all 2**n regions of a model. What is checked:

- :class:`StructuredCorners` at construction of the ``BDerivative``: the lower bound
  ``G[mask, k] >= Dh[k].F0 + sum_i min(0, Dh[k].A[i]) + sum_p min(0, Dh[k].B[p])``.
  Without pairs the bound is attained, so the check is exact: a violation is refused up
  front, naming the region. With pairs a failed bound is inconclusive and the check falls
  to the queries (next point).
- every model, at every query: each rate of each region on the query's chain must be > 0
  and each corner finite, else the call raises ``ValueError`` naming the query, the event
  and the region. A wrong answer or NaN is never returned (``out`` may be partly written
  when the call raises).
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import numpy as np

from .._limits import MAX_TABLE_EVENTS
from .._support import _tables
from .._support._format import error_text
from .._support._validate import check_finite, check_matrix, check_memory, check_real_array

__all__ = ["CornerFunction", "CornerModel", "StructuredCorners"]


@runtime_checkable
class CornerModel(Protocol):
    """What :class:`~bderiv.BDerivative` needs of a corner model.

    Attributes
    ----------
    n_events : int or None
        n; None when the model fits any n (then taken from ``Dh``).
    dim : int or None
        d; None when the model fits any d.

    Methods
    -------
    corners(happened) -> ndarray, shape (..., d)
        The corners of a batch of regions given as 0/1 flags of shape (..., n).
    corner_function() -> numba function ``func(happened, out)``
        Writes the corner of one region (``happened``: uint8 array of n flags) into
        ``out`` (float64, shape (d,)); called from several threads at once, so it must be
        pure. A plain Python function is compiled with ``numba.njit``.
    """

    n_events: int | None
    dim: int | None

    def corners(self, happened) -> np.ndarray: ...

    def corner_function(self): ...


def check_table_size(n: int, d: int, what: str = "the dense table") -> None:
    """Refuse ``what`` (something that needs a model's dense table) above
    ``MAX_TABLE_EVENTS`` events."""
    if n > MAX_TABLE_EVENTS:
        raise ValueError(
            f"{what} of a corner model with n={n} events needs its dense table of 2**{n} "
            f"rows ({_tables.human_bytes(_tables.dense_table_bytes(n, d))}); this is refused "
            f"for n > {MAX_TABLE_EVENTS}. apply, inverse, event_times and piece work for any "
            f"n without it"
        )


def _check_corners_memory(lead, d) -> None:
    """Refuse the corners of regions of leading shape ``lead`` beyond what the process may
    take (their (..., d) float64 result and a copy of that size)."""
    m = int(np.prod(lead, dtype=object))
    check_memory(2 * m * d * 8, None, f"the corners of {m} regions in R^{d}")


class _Tabulated:
    """``chain_corners`` and ``table`` of a model with sizes, from its ``corners``."""

    n_events: int | None
    dim: int | None

    def _sizes(self, what: str) -> tuple[int, int]:
        if self.n_events is None or self.dim is None:
            raise ValueError(
                f"{what} of {self!r} needs its size: pass n_events= and dim= when you "
                f"create it (inside a BDerivative the size comes from Dh)"
            )
        return self.n_events, self.dim

    def chain_corners(self, order) -> np.ndarray:
        """``F[B_j]`` on the n + 1 regions of an event order, shape (n + 1, d)."""
        n, _ = self._sizes("chain_corners")
        return self.corners(_tables.chain_regions(order, n))

    def table(self) -> np.ndarray:
        """The dense (2**n, d) table (n <= ``MAX_TABLE_EVENTS``), e.g. for comparisons."""
        n, d = self._sizes("the dense table")
        check_table_size(n, d)
        check_memory((1 << n) * d * 8, None,
                     f"the dense table of a corner model ({n} events in R^{d}: 2**{n} rows of "
                     f"{d} float64)")
        return _tables.tabulate(self.corners, n, d)


class StructuredCorners(_Tabulated):
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
        h = np.asarray(happened)
        if h.ndim == 0 or h.shape[-1] != self.n_events:
            raise ValueError(f"happened must have shape (..., {self.n_events}), got {h.shape}")
        if h.dtype.kind not in "biu" or ((h != 0) & (h != 1)).any():
            raise ValueError("happened must hold 0/1 flags (bool or integers)")
        _check_corners_memory(h.shape[:-1], self.dim)
        h = h.astype(np.float64)
        both = h[..., self.pairs[:, 0]] * h[..., self.pairs[:, 1]]
        return self.F0 + h @ self.A + both @ self.B

    def corner_function(self):
        """``func(happened, out)`` computing :meth:`corners` of one region (compiled)."""
        from .._kernels.structured import corner_function

        return corner_function(self.F0, self.A, self.pairs, self.B)


class CornerFunction(_Tabulated):
    """Corners computed by a numba-compiled function on each region a query visits.

    Parameters
    ----------
    func : numba njit function ``func(happened, out) -> None``
        ``happened`` is a uint8 array of n flags (``happened[k] == 1`` iff event k has
        happened); ``func`` writes ``F[happened]`` into ``out``, a float64 array of shape
        (d,). It is called n + 1 times per query, from several threads at once: it must be
        pure (no shared state). A plain Python function is compiled with ``numba.njit``.
        Masks are arrays, not integers, so n is not limited to 62 events.
    n_events, dim : int, optional
        The size, when ``func`` is written for one; needed only to use :meth:`corners` or
        :meth:`table` on their own (inside a ``BDerivative`` the size comes from ``Dh``).

    Notes
    -----
    Each query costs n + 1 calls of ``func`` plus O(n d) for the rates ``Dh @ F`` of each
    region. The kernels call ``func`` through its address: they are compiled once and
    kept on disk, and a new function compiles only itself (under a second, where the
    kernels compiled again per function took about 5 s). Every region a query visits is
    checked: rates > 0, and every entry of
    ``out`` written and finite (``out`` is NaN-filled before each call). No fast path is
    looked for (that would need all 2**n corners).

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
    >>> CornerFunction(field, n_events=2, dim=2).table()
    array([[1., 1.],
           [2., 1.],
           [1., 1.],
           [2., 1.]])
    """

    def __init__(self, func, *, n_events=None, dim=None):
        from numba.core.registry import CPUDispatcher

        from .._support._validate_ints import check_positive_int

        if not callable(func):
            raise TypeError(f"func must be a function func(happened, out), got {func!r}")
        if not isinstance(func, CPUDispatcher):
            import numba

            func = numba.njit(func)
        self.func = func
        self.n_events = None if n_events is None else check_positive_int(n_events, "n_events")
        self.dim = None if dim is None else check_positive_int(dim, "dim")

    def __repr__(self) -> str:
        name = getattr(self.func, "__name__", repr(self.func))
        return f"CornerFunction({name})"

    def corner_function(self):
        return self.func

    def corners(self, happened) -> np.ndarray:
        """``F`` on the regions ``happened`` (shape (..., n), 0/1), shape (..., d)."""
        from .._kernels.function import corners

        n, d = self._sizes("corners")
        h = np.asarray(happened)
        if h.ndim == 0 or h.shape[-1] != n:
            raise ValueError(f"happened must have shape (..., {n}), got {h.shape}")
        _check_corners_memory(h.shape[:-1], d)
        flat = h.reshape(-1, n)  # corners gives func its own uint8 copy
        out = np.full((flat.shape[0], d), np.nan)  # an entry left unwritten stays NaN
        try:
            corners(self.func, flat, out)
        except Exception as exc:  # numba's typing errors come in many classes
            raise TypeError(f"func could not be called as func(happened, out) with happened "
                            f"a uint8 array of {n} flags and out a float64 array of shape "
                            f"({d},): {error_text(exc)}") from None
        bad = ~np.isfinite(out).all(axis=1)
        if bad.any():
            i = int(np.argmax(bad))
            raise ValueError(f"func must write all {d} entries of out with finite values; on "
                             f"the region happened = {flat[i].tolist()} it gave {out[i]} (NaN: "
                             f"an entry left unwritten)")
        return out.reshape(h.shape[:-1] + (d,))
