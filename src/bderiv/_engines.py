"""Evaluation engines behind :class:`~bderiv.BDerivative`.

``BDerivative`` validates arguments and reshapes queries; an engine owns the tables of one
corner representation and runs the kernels on clean ``(m, d)`` C-contiguous float64
batches. Every engine has the same methods:

- ``map(V, out, inverse)``: ``out = M(V)`` or ``M^-1(V)``; raises ``ValueError`` if a
  query's chain meets a rate <= 0 (models only: dense tables are checked whole up front);
- ``event_times(V, times, orders)``;
- ``chain_corners(order)``: ``F`` on the n + 1 regions of an order, shape (n + 1, d);
- ``dense_table()``: the (2**n, d) table (models: only for small n).

``fast_path`` names the path chosen at construction (MATH.md sections 3 and 4):

- ``"own-rates"``: ``G[mask, k]`` depends only on bit k of ``mask`` (the rate of an event
  changes at most when that event itself happens). Pending rates never change, so the event
  times are the first-order times ``-(Dh u)_k / G[0, k]`` and the order is a sort.
- ``"linear"``: own rates and additive corners ``F[mask] = F0 + sum_{k in mask} A[k]``.
  Then the saltation factors ``S_k = I + A[k] Dh[k]^T / G[0, k]`` commute (``Dh[j] . A[k]
  = 0`` for j != k), every piece is the same matrix and
  ``M(u) = u - A^T t = (I + A^T diag(1 / G[0]) Dh) u``: a matrix product per query.
"""

from __future__ import annotations

import numpy as np

from . import _corner_kernels as ck
from . import _kernels, _tables

#: batches smaller than this run on one thread.
PARALLEL_MIN_QUERIES = 1024

#: relative tolerance of the fast-path detection: an entry that should vanish may be up to
#: FAST_RTOL * max|F| * |Dh[k]| (rounding of tables built in floating point is ~1e-16 of
#: that; the deviation this admits changes results by far less than the test RTOL 1e-9).
FAST_RTOL = 1e-12


def format_happened(hap) -> str:
    """``0b...`` string of a 0/1 flag array; the rightmost bit is event 0."""
    return "0b" + "".join("1" if h else "0" for h in np.asarray(hap)[::-1])


def raise_violation(query: int, k: int, hap, rate: float, inverse: bool, name: str):
    raise ValueError(
        f"transversality violated on the chain of {name}[{query}]"
        f"{' (inverse map)' if inverse else ''}: event {k} has rate {rate:.3g} <= 0 in "
        f"region mask {format_happened(hap)} (bit k set = event k happened); the flow must "
        f"cross every event surface from h_k < 0 to h_k > 0 in every region"
    )


def _pick(m: int, serial, parallel):
    return parallel if m >= PARALLEL_MIN_QUERIES else serial


# ----------------------------------------------------------------------------------------
# fast-path detection for dense tables (NumPy, block by block, stops at the first misfit)
# ----------------------------------------------------------------------------------------
def _abs_max(F: np.ndarray) -> float:
    """max |F| without a temporary of F's size."""
    return float(max(F.max(), -F.min()))


def own_rates(F: np.ndarray, G: np.ndarray, Dh: np.ndarray, rtol: float = FAST_RTOL):
    """``(G[0], G[-1])`` if ``G[mask, k]`` is ``G[0, k]`` or ``G[-1, k]`` by bit k, else None."""
    n = Dh.shape[0]
    g0, gf = G[0].copy(), G[-1].copy()
    tol = rtol * _abs_max(F) * np.linalg.norm(Dh, axis=1)
    for rows in _tables.blocks(G.shape[0]):
        bits = _tables.mask_bits(np.arange(rows.start, rows.stop, dtype=np.int64), n)
        ref = g0 + bits * (gf - g0)
        if (np.abs(G[rows] - ref) > tol).any():
            return None
    return g0, gf


def additive(F: np.ndarray, rtol: float = FAST_RTOL):
    """``(F0, A)`` with ``F[mask] = F0 + sum_{k in mask} A[k]`` (to tolerance), else None."""
    n = (F.shape[0] - 1).bit_length()
    F0 = F[0].copy()
    A = F[1 << np.arange(n)] - F0
    tol = rtol * max(_abs_max(F), np.finfo(float).tiny)
    for rows in _tables.blocks(F.shape[0]):
        bits = _tables.mask_bits(np.arange(rows.start, rows.stop, dtype=np.int64), n)
        if (np.abs(F[rows] - (F0 + bits @ A)) > tol).any():
            return None
    return F0, A


def linear_matrices(Dh, A, g0, gf):
    """(M, M^-1) of the linear fast path: I + A^T diag(1/g0) Dh, I - A^T diag(1/gf) Dh."""
    eye = np.eye(Dh.shape[1])
    M = eye + A.T @ (Dh / g0[:, None])
    Minv = eye - A.T @ (Dh / gf[:, None])
    return M, Minv


def _transposed(*mats):
    return tuple(np.ascontiguousarray(m.T) for m in mats)


def piece_from_chain(Dh, Fc, order):
    """S_n ... S_1 (MATH.md section 4) from the corners ``Fc[j] = F[B_j]`` of an order."""
    d = Dh.shape[1]
    M = np.eye(d)
    for j, k in enumerate(order):
        rate = Dh[k] @ Fc[j]
        M += np.outer(Fc[j + 1] - Fc[j], (Dh[k] @ M) / rate)
    return M


# ----------------------------------------------------------------------------------------
# dense tables
# ----------------------------------------------------------------------------------------
class DenseEngine:
    """The (2**n, d) table F and rates G; general kernels of ``_kernels`` or a fast path."""

    def __init__(self, Dh, F, G, fast_paths: bool = True):
        self.Dh, self.F, self.G = Dh, F, G
        self.DhT = np.ascontiguousarray(Dh.T)
        self.n, self.d = Dh.shape
        self.fast_path = None
        if fast_paths:
            split = own_rates(F, G, Dh)
            if split is not None:
                self.rate0, self.ratef = split
                self.fast_path = "own-rates"
                add = additive(F)
                if add is not None:
                    self.M, self.Minv = linear_matrices(Dh, add[1], *split)
                    self.MT, self.MinvT = _transposed(self.M, self.Minv)
                    self.fast_path = "linear"

    def map(self, V, out, inverse: bool, name: str = "V") -> None:
        m = V.shape[0]
        if self.fast_path == "linear":
            kernel = _pick(m, ck.linear_map_serial, ck.linear_map_parallel)
            kernel(self.MinvT if inverse else self.MT, V, out)
        elif self.fast_path == "own-rates":
            kernel = _pick(m, ck.dense_sorted_map_serial, ck.dense_sorted_map_parallel)
            kernel(self.DhT, self.F, self.ratef if inverse else self.rate0, V, out, inverse)
        else:
            kernel = _pick(m, _kernels.map_serial, _kernels.map_parallel)
            kernel(self.Dh, self.F, self.G, V, out, inverse)

    def event_times(self, V, times, orders) -> None:
        if self.fast_path is None:
            _kernels.event_times_batch(self.Dh, self.G, V, times, orders)
        else:
            ck.own_rate_times(self.DhT, self.rate0, V, times, orders)

    def piece(self, order) -> np.ndarray:
        out = np.empty((self.d, self.d))
        _kernels.piece_matrix(self.Dh, self.F, self.G, order, out)
        return out

    def dense_table(self) -> np.ndarray:
        return self.F


# ----------------------------------------------------------------------------------------
# corner models
# ----------------------------------------------------------------------------------------
class _ModelEngine:
    """Shared parts of the model engines: pieces from the corners along a chain."""

    Dh: np.ndarray

    def piece(self, order) -> np.ndarray:
        Fc = self.chain_corners(order)
        rates = Fc @ self.Dh.T
        if not (rates > 0).all():
            j, k = np.argwhere(~(rates > 0))[0]
            hap = np.zeros(self.n, dtype=np.uint8)
            hap[order[:j]] = 1
            raise_violation(0, int(k), hap, float(rates[j, k]), False, "order")
        return piece_from_chain(self.Dh, Fc, order)

    def _check(self, status, V, inverse, name, offset=0):
        bad = np.flatnonzero(status >= 0)
        if bad.size:
            q = int(bad[0])
            hap = np.empty(self.n, dtype=np.uint8)
            r = np.empty(self.n)
            k = self._diagnose(V[q], inverse, hap, r)
            raise_violation(q + offset, int(k), hap, float(r[k]), inverse, name)


class StructuredEngine(_ModelEngine):
    """Rates updated incrementally along each chain (see ``_corner_kernels``).

    ``transversal_proved`` (set by the model): all rates of all regions are > 0, so the
    kernels skip the per-region checks.
    """

    transversal_proved = False

    def __init__(self, Dh, model, fast_paths: bool = True):
        self.Dh, self.model = Dh, model
        self.DhT = np.ascontiguousarray(Dh.T)
        self.n, self.d = Dh.shape
        F0, A, pairs, B = model.F0, model.A, model.pairs, model.B
        self.A, self.B, self.pairs = A, B, pairs
        self.g0 = Dh @ F0
        self.a = np.ascontiguousarray(A @ Dh.T)  # a[i, k] = Dh[k] . A[i]
        self.bDh = np.ascontiguousarray(B @ Dh.T)  # (p, n)
        self.gfull = self.g0 + self.a.sum(axis=0) + self.bDh.sum(axis=0)
        # pairs touching each event, as CSR: pidx[ptr[i]:ptr[i+1]] with partner other[...]
        p = pairs.shape[0]
        ev = np.concatenate([pairs[:, 0], pairs[:, 1]])
        partner = np.concatenate([pairs[:, 1], pairs[:, 0]])
        pid = np.concatenate([np.arange(p), np.arange(p)])
        srt = np.argsort(ev, kind="stable")
        self.other = np.ascontiguousarray(partner[srt], dtype=np.int64)
        self.pidx = np.ascontiguousarray(pid[srt], dtype=np.int64)
        self.ptr = np.zeros(self.n + 1, dtype=np.int64)
        np.cumsum(np.bincount(ev, minlength=self.n), out=self.ptr[1:])
        self.fast_path = None
        if fast_paths:
            scale = max(np.linalg.norm(F0), np.linalg.norm(A, axis=1).max(initial=0.0),
                        np.linalg.norm(B, axis=1).max(initial=0.0))
            tol = FAST_RTOL * scale * np.linalg.norm(Dh, axis=1)
            off = self.a - np.diag(np.diag(self.a))
            if (np.abs(off) <= tol).all() and (np.abs(self.bDh) <= tol).all():
                self.rate0 = self.g0.copy()
                self.ratef = self.g0 + np.diag(self.a)
                self.fast_path = "own-rates"
                if p == 0 or not B.any():
                    self.M, self.Minv = linear_matrices(Dh, A, self.rate0, self.ratef)
                    self.MT, self.MinvT = _transposed(self.M, self.Minv)
                    self.fast_path = "linear"

    def _args(self):
        return (self.DhT, self.g0, self.gfull, self.a, self.bDh, self.ptr, self.other,
                self.pidx)

    def map(self, V, out, inverse: bool, name: str = "V") -> None:
        m = V.shape[0]
        if self.fast_path == "linear":
            kernel = _pick(m, ck.linear_map_serial, ck.linear_map_parallel)
            kernel(self.MinvT if inverse else self.MT, V, out)
        elif self.fast_path == "own-rates":
            kernel = _pick(m, ck.structured_own_map_serial, ck.structured_own_map_parallel)
            kernel(self.DhT, self.ratef if inverse else self.rate0, self.pairs, self.A, self.B,
                   V, out, inverse)
        else:
            status = np.empty(m, dtype=np.int64)
            kernel = _pick(m, ck.structured_map_serial, ck.structured_map_parallel)
            kernel(*self._args(), self.A, self.B, V, out, status, inverse,
                   not self.transversal_proved)
            self._check(status, V, inverse, name)

    def event_times(self, V, times, orders) -> None:
        if self.fast_path is not None:
            ck.own_rate_times(self.DhT, self.rate0, V, times, orders)
            return
        status = np.empty(V.shape[0], dtype=np.int64)
        ck.structured_times(*self._args(), self.pairs.shape[0], V, times, orders, status,
                            not self.transversal_proved)
        self._check(status, V, False, "V")

    def _diagnose(self, u, inverse, hap, r):
        return ck.structured_diagnose(*self._args(), self.pairs.shape[0], u, inverse, hap, r)

    def chain_corners(self, order) -> np.ndarray:
        return self.model.chain_corners(order)

    def dense_table(self) -> np.ndarray:
        return self.model.table()


class FunctionEngine(_ModelEngine):
    """Corners from a user njit function, evaluated on each query's chain."""

    def __init__(self, Dh, model, fast_paths: bool = True):
        self.Dh, self.model = Dh, model
        self.DhT = np.ascontiguousarray(Dh.T)
        self.n, self.d = Dh.shape
        self.func = model.func
        self.fast_path = None
        self._none = np.empty((0, self.d))
        self._none_t = np.empty((0, self.n))
        self._none_o = np.empty((0, self.n), dtype=np.int64)

    def map(self, V, out, inverse: bool, name: str = "V") -> None:
        m = V.shape[0]
        status = np.empty(m, dtype=np.int64)
        kernel = _pick(m, ck.function_map_serial, ck.function_map_parallel)
        kernel(self.func, self.DhT, V, out, self._none_t, self._none_o, status, inverse)
        self._check(status, V, inverse, name)

    def event_times(self, V, times, orders) -> None:
        status = np.empty(V.shape[0], dtype=np.int64)
        kernel = _pick(V.shape[0], ck.function_map_serial, ck.function_map_parallel)
        kernel(self.func, self.DhT, V, self._none, times, orders, status, False)
        self._check(status, V, False, "V")

    def _diagnose(self, u, inverse, hap, r):
        return ck.function_diagnose(self.func, self.DhT, u, inverse, hap, r)

    def chain_corners(self, order) -> np.ndarray:
        return self.model.chain_corners(order, self.d)

    def dense_table(self) -> np.ndarray:
        return self.model.table(self.n, self.d)
