"""The engine of :class:`~bderiv.StructuredCorners`: rates updated along each chain."""

from __future__ import annotations

import numpy as np

from ..._kernels import structured as kernels
from ..._kernels._core import frozen_tables
from ..._limits import PROOF_MARGIN
from ..._support._format import format_happened
from ..._support._tables import padded
from ...geometry.corners import StructuredCorners
from . import fastpath
from .base import Engine, tabulate
from .dense import table_exponents


class StructuredEngine(Engine):
    """Rate jumps ``a = A @ Dh.T``, ``bDh = B @ Dh.T`` and the pairs of each event (CSR).

    At construction the lower bound ``Dh[k].F0 + sum_i min(0, a[i, k]) + sum_p min(0,
    bDh[p, k])`` of every rate is checked: above a margin, transversality is proved and
    the kernels skip their per-region checks; without pairs the bound is attained, so a
    bound <= 0 is a violation, refused here naming the region.

    As a dense table's (:func:`.dense.table_exponents`), the kernels' tables are made
    from Dh's rows and the corners (F0, A, B) scaled by powers of two where they are far
    from 1: the map is the same, the event times ``2**time_shift`` the caller's, and a
    model whose rates fit float64 runs whatever the scale of its vectors (Dh and F of
    1e200 each, rates 1e400, were refused as "transversality violated": rate nan).
    ``Dh`` and ``model`` are the scaled ones (the tangents and pieces read them: ratios,
    unchanged), ``caller`` the caller's model (its dense table).
    """

    def __init__(self, Dh, model, fast_paths: bool = True):
        self.caller = model
        self.n, self.d = Dh.shape
        F0, A, pairs, B = model.F0, model.A, model.pairs, model.B
        f_big = max(float(np.abs(M).max(initial=0.0)) for M in (F0, A, B))
        dh_exps, f_exp = table_exponents(np.abs(Dh).max(axis=1).tolist(), f_big)
        self.time_shift, self._rate_exps = f_exp, f_exp + dh_exps
        if f_exp or np.count_nonzero(dh_exps):
            Dh = np.ldexp(Dh, -dh_exps[:, None])
            F0, A, B = (np.ldexp(M, -f_exp) for M in (F0, A, B))
            model = StructuredCorners(F0, A, pairs, B)  # (the kernels read these alone)
        self.Dh, self.model = Dh, model
        DhT = np.ascontiguousarray(Dh.T)
        g0 = Dh @ F0
        a = np.ascontiguousarray(A @ Dh.T)  # a[i, k] = Dh[k] . A[i]
        bDh = np.ascontiguousarray(B @ Dh.T)  # (p, n)
        gfull = g0 + a.sum(axis=0) + bDh.sum(axis=0)
        self.transversal_proved = self._check_transversal(g0, gfull, a, bDh, pairs.shape[0])
        self._tables = _kernel_tables(DhT, g0, gfull, a, bDh, pairs, A, B,
                                      not self.transversal_proved)
        self.fast = fastpath.structured(Dh, g0, a, bDh, A, B) if fast_paths else None
        self._own = None  # the own-rates fast path's tables, forwards and backwards
        if self.fast is not None and self.fast.kind == "own-rates":
            self._own = tuple(frozen_tables(kernels.StructuredOwnTables(DhT, rate, pairs, A, B))
                              for rate in (self.fast.rate0, self.fast.ratef))

    def _check_transversal(self, g0, gfull, a, bDh, n_pairs) -> bool:
        """Refuse a provable violation; return True when transversality is proved."""
        lower = g0 + np.minimum(a, 0).sum(axis=0) + np.minimum(bDh, 0).sum(axis=0)
        size = np.abs(g0) + np.abs(a).sum(axis=0) + np.abs(bDh).sum(axis=0)
        if (lower > PROOF_MARGIN * size).all():
            return True
        if n_pairs == 0 and not (lower > 0).all():  # bound attained: violated
            k = int(np.flatnonzero(~(lower > 0))[0])
            hap = (a[:, k] < 0).astype(np.uint8)
            raise ValueError(
                f"transversality violated at event {k} in region mask "
                f"{format_happened(hap)} (bit k set = event k happened): rate "
                f"Dh[{k}] . (F0 + sum of A over the region) = "
                f"{np.ldexp(lower[k], self._rate_exps[k]):.3g}, expected > 0; "
                f"the flow must cross every event surface from h_k < 0 to h_k > 0 in "
                f"every region"
            )
        for name, rates in (("0 (no event yet)", g0), ("full (all events)", gfull)):
            if not (rates > 0).all():
                k = int(np.flatnonzero(~(rates > 0))[0])
                raise ValueError(
                    f"transversality violated at event {k} in region {name}: rate "
                    f"{np.ldexp(rates[k], self._rate_exps[k]):.3g}, expected > 0"
                )
        return False

    def _apply(self, V, out, inverse, name, offset) -> int:
        return self._run_checked(kernels.apply, V, (out,), inverse, name, offset)

    def _apply_own_rates(self, V, out, inverse) -> int:
        return kernels.apply_own_rates(self._own[inverse], V, (out,), inverse,
                                       launch=self.launch)

    def _event_times(self, V, times, orders, offset) -> int:
        return self._run_checked(kernels.event_times, V, (times, orders), False, "V", offset)

    def _diagnose(self, u, inverse, hap, r):
        return kernels.diagnose(self._tables, u[None], inverse, hap, r)

    def corners(self, happened) -> np.ndarray:
        return self.model.corners(happened)

    def dense_table(self) -> np.ndarray:
        return tabulate(self.caller.corners, self.n, self.d)


def _kernel_tables(DhT, g0, gfull, a, bDh, pairs, A, B, check):
    """The tables of ``_kernels.structured`` (see its docstring): rows padded to multiples
    of 8, the pairs of each event as CSR."""
    (d, n), p = DhT.shape, pairs.shape[0]
    nc, dc = -(-n // 8), -(-d // 8)
    ev = np.concatenate([pairs[:, 0], pairs[:, 1]])
    partner = np.concatenate([pairs[:, 1], pairs[:, 0]])
    pid = np.concatenate([np.arange(p), np.arange(p)])
    srt = np.argsort(ev, kind="stable")
    counts = np.bincount(ev, minlength=n)
    ptr = np.zeros(n + 1, dtype=np.int64)
    np.cumsum(counts, out=ptr[1:])
    return frozen_tables(kernels.StructuredTables(
        padded(DhT, 8 * nc), padded(np.stack([g0, gfull]), 8 * nc, 1.0),
        padded(a, 8 * nc), padded(bDh, 8 * nc), ptr,
        np.ascontiguousarray(partner[srt], dtype=np.int64),
        np.ascontiguousarray(pid[srt], dtype=np.int64),
        padded(np.vstack([A, B]), 8 * dc), padded(np.arange(n)[None], 8 * nc, np.inf),
        n, d, nc, dc, p, int(counts.max(initial=0)), int(check)))
