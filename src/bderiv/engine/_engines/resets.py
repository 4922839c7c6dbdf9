"""The engine of a dense corner table with reset maps at the events (mathematics.md section 9).

A crossing of event k from region ``mask`` makes the state jump; near the event point its
Jacobian ``R[mask, k]`` (d, d) enters the update of the virtual position. The resets are
given densely, shape (2**n, n, d, d), or as :class:`LowRankResets` (``I + U V^T``, a
velocity stopped at an impact is rank one). At construction the table is validated and
the two conditions under which the B-derivative exists are checked for every region and
pair of pending events; the inverse resets are built when the inverse is first asked for.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import scipy.linalg

from ..._kernels import resets as kernels
from ..._kernels._core import frozen_tables
from ..._limits import CHECK_ROWS
from ..._support._format import format_mask, format_region
from ..._support._tables import blocks, dense_table_bytes
from ..._support._validate import check_finite, check_memory, check_number, check_real_array
from .base import Engine
from .dense import DenseEngine


class LowRankResets(NamedTuple):
    """Reset Jacobians of low rank: ``R[mask, k] = I + U[mask, k] @ V[mask, k].T``.

    Attributes
    ----------
    U, V : array_like, shape (2**n, n, d, r)
        For a crossing of event k from region ``mask`` (bit k clear); entries with bit k
        set are not used. A velocity ``v_i`` set to zero at an impact is
        ``U = -e_i, V = e_i`` (r = 1).
    """

    U: object
    V: object


def reset_matrices(P, Q, low: int, masks, k: int) -> np.ndarray:
    """Dense ``R[masks, k]``, shape (len(masks), d, d)."""
    if not low:
        return P[masks, k]
    d = P.shape[2]
    return np.eye(d) + P[masks, k] @ Q[masks, k].transpose(0, 2, 1)


def _check_resets(resets, n: int, d: int, memory_limit):
    """(P, Q, low): the user's resets checked (type, shape, finite where used), copied as
    C-contiguous float64 with the unused entries zeroed; size checked before the copy."""
    low = isinstance(resets, LowRankResets)
    parts = (("resets.U", resets.U), ("resets.V", resets.V)) if low else (("resets", resets),)
    arrays = [check_real_array(a, name) for name, a in parts]
    want = (1 << n, n, d, arrays[0].shape[-1] if low and arrays[0].ndim == 4 else d)
    for (name, _), arr in zip(parts, arrays, strict=True):
        if arr.shape != want:
            shape = "(2**n, n, d, r), r the rank" if low else "(2**n, n, d, d)"
            raise ValueError(
                f"{name} must have shape {shape} = {want} for n={n} events in dimension "
                f"d={d} (entry [mask, k]: the crossing of event k from region mask), got "
                f"{arr.shape}"
            )
    check_memory(len(arrays) * int(np.prod(want)) * 8 + dense_table_bytes(n, d), memory_limit,
                 f"reset tables for n={n} events in dimension d={d} (with the corner table)")
    used = ((np.arange(1 << n)[:, None] >> np.arange(n)) & 1) == 0
    out = []
    for (name, _), arr in zip(parts, arrays, strict=True):
        copy = _transposed(np.empty(want[:2] + want[:1:-1]))  # the kernels' layout
        copy[...] = arr
        copy[~used] = 0.0
        check_finite(copy, name)
        out.append(copy)
    Q = out[1] if low else np.zeros((1, 1, 1, 1))
    return out[0], Q, int(low)


def _transposed(A):
    """A with its last two axes swapped (a view): the kernels' layout of a table and back."""
    return A.transpose(0, 1, 3, 2)


def check_existence(Dh, P, Q, low: int, tol: float) -> None:
    """Refuse resets under which the flow is not continuous at the event point.

    For every region b and pair j < k of pending events, on y in ker Dh_j ∩ ker Dh_k
    (mathematics.md section 9): ``R[b|j, k] R[b, j] y = R[b|k, j] R[b, k] y`` (the two ways
    through the tie agree) and ``Dh_k R[b, j] y = 0 = Dh_j R[b, k] y`` (a reset does not
    move the other surface). Mismatches are relative to the norms of the factors, and
    computed on factors scaled by powers of two (:func:`_unit`): at entries of 1e200 the
    products would overflow.
    """
    n, d = Dh.shape
    masks = np.arange(1 << n)
    Dh = _unit(Dh[:, None, :])[0][:, 0]  # each row scaled: the same surfaces
    dh = np.linalg.norm(Dh, axis=1)
    for j in range(n):
        for k in range(j + 1, n):
            N = scipy.linalg.null_space(Dh[[j, k]])
            if N.shape[1] == 0:
                continue
            free = masks[((masks >> j) & 1 == 0) & ((masks >> k) & 1 == 0)]
            for rows in blocks(free.size, CHECK_ROWS):
                b = free[rows]
                (Rj, ej), (Rk, ek) = (_unit(reset_matrices(P, Q, low, b, i)) for i in (j, k))
                Rjk, ejk = _unit(reset_matrices(P, Q, low, b | (1 << j), k))
                Rkj, ekj = _unit(reset_matrices(P, Q, low, b | (1 << k), j))
                RjN, RkN = Rj @ N, Rk @ N
                # the two ways' scales 2**(ejk + ej) and 2**(ekj + ek), over the larger
                top = np.maximum(ejk + ej, ekj + ek)
                a, c = (np.ldexp(1.0, e - top)[:, None, None] for e in (ejk + ej, ekj + ek))
                gap = _norms(a * (Rjk @ RjN) - c * (Rkj @ RkN)) / (
                    _norms(a * Rjk) * _norms(Rj) + _norms(c * Rkj) * _norms(Rk))
                move_k = np.abs(Dh[k] @ RjN).max(axis=1) / (dh[k] * _norms(Rj))
                move_j = np.abs(Dh[j] @ RkN).max(axis=1) / (dh[j] * _norms(Rk))
                _refuse(gap, move_k, move_j, b, j, k, n, tol)


def _norms(A) -> np.ndarray:
    """Frobenius norms of a stack of matrices (m, p, q) -> (m,)."""
    return np.linalg.norm(A, axis=(1, 2))


def _unit(A):
    """A stack of matrices (m, p, q) scaled by powers of two (exact) so that each one's
    largest entry is in [0.5, 1), and the exponents (m,) that undo it (0 for a zero one)."""
    e = np.frexp(np.abs(A).max(axis=(1, 2)))[1]
    return np.ldexp(A, -e[:, None, None]), e


def _refuse(gap, move_k, move_j, b, j, k, n, tol) -> None:
    """Raise for the first region of a block where a condition of existence fails."""
    bad = np.flatnonzero(~((gap <= tol) & (move_k <= tol) & (move_j <= tol)))
    if not bad.size:
        return
    i = int(bad[0])
    region = format_region(int(b[i]), n)
    for a, c, move in ((j, k, move_k[i]), (k, j, move_j[i])):
        if not move <= tol:
            raise ValueError(
                f"the reset of event {a} from {region} moves the surface of event {c}, "
                f"still pending, by {move:.3g} (relative; tolerance {tol:g}): events "
                f"{a} and {c} happening together would not stay together, so the flow "
                f"is not continuous at the event point and has no B-derivative "
                f"(Dh_{c} R[b, {a}] y != 0 for y with Dh_{a} y = Dh_{c} y = 0)"
            )
    raise ValueError(
        f"the resets of events {j} and {k} from {region} do not commute on the "
        f"common tangent space of their surfaces: crossing {j} then {k} and {k} "
        f"then {j} differ by {gap[i]:.3g} (relative; tolerance {tol:g}), so the "
        f"flow is not continuous at the event point and has no B-derivative "
        f"(R[b|{j}, {k}] R[b, {j}] y != R[b|{k}, {j}] R[b, {k}] y for y with "
        f"Dh_{j} y = Dh_{k} y = 0)"
    )


class ResetEngine(Engine):
    """Corners and rates of a :class:`DenseEngine` (``table``: its validation, its
    records) and the reset tables: ``P`` (2**n, n, d, d) the Jacobians (``low == 0``), or
    ``P``, ``Q`` (2**n, n, d, r) their factors U, V (``low == 1``), as views of arrays in
    the transposed layout of ``_kernels/resets`` (C-contiguous there)."""

    def __init__(self, table: DenseEngine, P, Q, low: int, reset_tol: float):
        self.table, self.P, self.Q, self.low = table, P, Q, low
        self.Dh, self.n, self.d = table.Dh, table.n, table.d
        self.R, self.F, self.G = table.R, table.F, table.G
        self.rate_spread, self.reset_tol = table.rate_spread, reset_tol
        # contiguous copies for the kernels (F and G are strided views of the records)
        self._DhT, self._F, self._G = (np.ascontiguousarray(a) for a in (self.Dh.T, self.F,
                                                                          self.G))
        self._forward = self._kernel_tables(P, Q)
        self._inverse = None
        self.resets = LowRankResets(P, Q) if low else P

    def __getstate__(self):
        state = self.__dict__.copy()
        for name in ("F", "G", "R", "resets", "_forward", "_inverse"):  # rebuilt
            state.pop(name)
        state["P"], state["Q"] = _transposed(self.P), _transposed(self.Q)  # contiguous
        return state

    def __setstate__(self, state):
        for name in ("P", "Q"):  # unpickled arrays come back writeable: read-only as built
            state[name].flags.writeable = False
            state[name] = _transposed(state[name])
        self.__dict__.update(state)
        self.R, self.F, self.G = self.table.R, self.table.F, self.table.G
        self._forward, self._inverse = self._kernel_tables(self.P, self.Q), None
        self.resets = LowRankResets(self.P, self.Q) if self.low else self.P

    def _kernel_tables(self, P, Q):
        """The tables of ``_kernels/resets`` for resets P, Q in this engine's form."""
        DhP = (np.ascontiguousarray(_transposed(self.Dh @ P)) if self.low
               else np.zeros((1, 1, 1, 1)))
        return frozen_tables(kernels.ResetTables(self._DhT, self._F, self._G, _transposed(P),
                                          _transposed(Q), DhP, self.low))

    @classmethod
    def build(cls, Dh, F, resets, transversality_tol, reset_tol, memory_limit,
              checked: bool = False):
        """Validate F (as a dense table, ``checked`` as for :meth:`DenseEngine.build`), the
        resets and the conditions of existence."""
        n, d = Dh.shape
        reset_tol = check_number(reset_tol, "reset_tol")
        P, Q, low = _check_resets(resets, n, d, memory_limit)
        # rates of events that happened may have either sign (a bounce: section 9)
        table = DenseEngine.build(Dh, F, transversality_tol, memory_limit, fast_paths=False,
                                  scale=False, pending_only=True, checked=checked)
        check_existence(Dh, P, Q, low, reset_tol)
        for a in (P, Q):
            a.flags.writeable = False
        return cls(table, P, Q, low, reset_tol)

    @property
    def table_bytes(self) -> int:
        return self.R.nbytes + self._F.nbytes + self._G.nbytes + self.P.nbytes + self.Q.nbytes

    def _tables(self, inverse: bool = False):
        return self.inverse_resets() if inverse else self._forward

    def inverse_resets(self, what: str = "inverse"):
        """The kernel tables of the inverse resets, built once; refuses a singular reset
        (``what`` names what needs the homeomorphism)."""
        if self._inverse is None:
            self._check_invertible_order(what)
            n, d = self.n, self.d
            Pi = _transposed(np.zeros_like(_transposed(self.P)))
            for k in range(n):
                b = np.flatnonzero((np.arange(1 << n) >> k) & 1 == 0)
                # I + U V^T is invertible iff I + V^T U is (Woodbury)
                K = (self.Q[b, k].transpose(0, 2, 1) @ self.P[b, k] + np.eye(self.P.shape[3])
                     if self.low else self.P[b, k])
                cond = np.linalg.cond(K) if K.shape[-1] else np.ones(b.size)
                bad = np.flatnonzero(~(cond * self.reset_tol < 1.0))
                if bad.size:
                    i = int(bad[0])
                    raise ValueError(
                        f"the reset Jacobian R[{b[i]}, {k}] of event {k} crossed from region "
                        f"mask {format_mask(int(b[i]), n)} is singular (condition number "
                        f"{cond[i]:.3g}, above 1 / reset_tol = {1 / self.reset_tol:.3g}): the "
                        f"B-derivative is not a homeomorphism and has no {what} (an impact "
                        f"that stops a velocity forgets it); apply, event_times, piece, jvp "
                        f"and vjp still work"
                    )
                if self.low:
                    Pi[b, k] = -self.P[b, k] @ np.linalg.inv(K)
                elif d:
                    Pi[b, k] = np.linalg.inv(K)
            self._inverse = self._kernel_tables(Pi, self.Q)
        return self._inverse

    def _check_invertible_order(self, what: str) -> None:
        """Refuse an inverse that running time backwards cannot find (mathematics.md
        section 9, "The inverse"): each event's rate after it happened must have one sign
        in every region (positive: crossed; negative: a bounce) away from zero, and its
        reset must map the surface's tangent space into itself (``Dh_k R[b, k]`` parallel to
        ``Dh_k``), so that ``-(Dh_k x) / G[B, k]`` is the time it happened."""
        n, tol = self.n, self.reset_tol
        masks = np.arange(1 << n)
        for k in range(n):
            after = masks[(masks >> k) & 1 == 1]
            rate = self.G[after, k]
            # |rate| / (|F| |Dh_k|) as a quotient of norms that neither overflow nor
            # underflow (np.hypot): their product did, for tables of 1e155 or 1e-160,
            # and read as a vanishing rate
            unit = np.hypot.reduce(self.Dh[k])
            relative = np.abs(rate) / np.hypot.reduce(self.F[after], axis=1) / unit
            sides = np.sign(rate) * (relative > tol)
            if not (np.all(sides > 0) or np.all(sides < 0)):
                i = int(np.argmin(relative))
                raise ValueError(
                    f"no {what}: the rate of event {k} after it happened changes sign or "
                    f"vanishes over the regions (G[{after[i]}, {k}] = {rate[i]:.3g} in region "
                    f"mask {format_mask(int(after[i]), n)}), so the time it happened cannot be "
                    f"read back from the state after; apply, event_times, piece, jvp and vjp "
                    f"still work"
                )
            before = masks[(masks >> k) & 1 == 0]
            u = self.Dh[k] / unit  # Dh_k's direction (its rows R: the same test, unscaled)
            DhR = u @ reset_matrices(self.P, self.Q, self.low, before, k)  # (m, d)
            off = np.hypot.reduce(DhR - (DhR @ u)[:, None] * u, axis=1)
            bad = np.flatnonzero(~(off <= tol * np.hypot.reduce(DhR, axis=1) + 1e-300))
            if bad.size:
                b = int(before[bad[0]])
                raise ValueError(
                    f"no {what}: the reset of event {k} from region mask {format_mask(b, n)} "
                    f"does not map the surface of event {k} to itself to first order "
                    f"(Dh_{k} R[{b}, {k}] is not parallel to Dh_{k}: off by {off[bad[0]]:.3g}), "
                    f"so the time it happened cannot be read back from the state after; "
                    f"apply, event_times, piece, jvp and vjp still work"
                )

    def _map(self, V, out, inverse: bool, name: str, offset: int) -> int:
        return kernels.apply(self._tables(inverse), V, (out,), inverse, launch=self.launch)

    def _times(self, V, times, orders, offset: int) -> int:
        return kernels.event_times(self._tables(), V, (times, orders), launch=self.launch)

    def tangents(self, V, T, out, transpose: bool, offset: int = 0) -> int:
        return kernels.tangents(self._tables(), V, (out, T), transpose, launch=self.launch)

    def corners(self, happened) -> np.ndarray:
        bits = np.asarray(happened, dtype=np.int64)
        return self.F[bits @ (1 << np.arange(self.n, dtype=np.int64))]

    def dense_table(self) -> np.ndarray:
        return self.F

    def piece(self, order) -> np.ndarray:
        """S_n ... S_1 with S_j = R + (F[B_j] - R F[B_{j-1}]) Dh[k_j]^T / G[B_{j-1}, k_j]."""
        M = np.eye(self.d)
        b = 0
        for k in (int(k) for k in order):
            a = b | (1 << k)
            R = reset_matrices(self.P, self.Q, self.low, np.array([b]), k)[0]
            M = (R + np.outer(self.F[a] - R @ self.F[b], self.Dh[k] / self.G[b, k])) @ M
            b = a
        return M

    def reset_product(self) -> np.ndarray:
        """R_full: the resets of all events in ascending order, (d, d) (M on ker Dh)."""
        M = np.eye(self.d)
        for k in range(self.n):
            M = reset_matrices(self.P, self.Q, self.low, np.array([(1 << k) - 1]), k)[0] @ M
        return M

    def corner_points(self):
        """(U, W), each (2**n, d): U[S] the pre-event vector whose events in S happen
        together at time -1 and the rest at time 0, W[S] = M(U[S]).

        At time -1 the position y = U[S] - F[0] lies on the surfaces of S; the resets of S
        (ascending, R_S) take it to R_S y, which reaches the other surfaces at time 0 in
        region S: ``Dh_S y = 0`` and ``Dh_k R_S y = -G[S, k]`` for k not in S (minimum-norm
        solution). Needs that (n, d) system to have rank n.
        """
        n, d = self.n, self.d
        RS = np.empty((1 << n, d, d))
        RS[0] = np.eye(d)
        U = np.zeros((1 << n, d))  # U[0] = W[0] = 0: the apex
        for S in range(1, 1 << n):
            top = S.bit_length() - 1
            rest = S & ~(1 << top)
            RS[S] = reset_matrices(self.P, self.Q, self.low, np.array([rest]), top)[0] @ RS[rest]
        for S in range(1, 1 << n):
            inside = (S >> np.arange(n)) & 1 == 1
            A = np.where(inside[:, None], self.Dh, self.Dh @ RS[S])
            rhs = np.where(inside, 0.0, -self.G[S])
            if np.linalg.matrix_rank(A) < n:
                raise ValueError(
                    f"the corner point of region mask {format_mask(S, n)} is not defined: "
                    f"the resets of its events make the surfaces still pending dependent "
                    f"(rank of [Dh_S; Dh_rest R_S] below n={n})"
                )
            U[S] = np.linalg.lstsq(A, rhs, rcond=None)[0] + self.F[0]
        W = np.empty_like(U)
        self.map(U, W, False)
        return U, W
