"""Stability of a piecewise-linear map: multipliers of its pieces and its growth rate.

A piecewise-linear (PL), positively homogeneous map ``A`` (the B-derivative of a return
map at a fixed point) is stable when ``|A^k v|`` decays for every direction v. The
eigenvalues of its pieces do not decide this: a direction may visit several pieces in
turn, and the product of pieces that it meets can grow while every piece is a
contraction, or decay while a piece it visits has an eigenvalue above 1 in modulus. What
decides is the **growth rate**::

    lambda = sup_v  lim_k |A^k v|^(1/k),

which :func:`growth_rate` estimates by iterating A on a batch of directions at once
(one batched evaluation per iteration), renormalising every step and fitting the slope of
``log |A^k v|`` after a burn-in; the largest rate over the batch is the estimate.
``lambda < 1``: perturbations decay geometrically at that rate; ``lambda > 1``: some
grow.

Limits: a finite batch samples directions, so growth confined to a thin set of
directions that repels all others can be missed (it then concerns a set of measure zero,
but a perturbation placed exactly there would grow); a finite number of iterations
gives lambda to about ``exp(+-c / iterations)`` (the spread is reported: the two halves
of the window's difference, or the wobble of ``log |A^k v|`` about its line over the
window's length where larger, and never below the rounding of a step,
:data:`bderiv._limits.RATE_ROUNDING`), and a rate within that of 1 is undecided. The
verdict is about the linearisation: it predicts the decay of small perturbations of the
nonlinear system (checked against long simulations in tests/test_gaits.py), not the basin
of attraction.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from .._limits import RATE_ROUNDING
from .._support._progress import count_bar
from .._support._validate import check_matrix, check_memory
from ._arguments import check_burn_in, check_iterations

__all__ = ["Growth", "Stability", "growth_rate", "log_growth", "piece_multipliers"]


@dataclass(frozen=True, eq=False)
class Stability:
    """The stability verdict of a PL map, with its evidence.

    Attributes
    ----------
    growth_rate : float
        Estimated asymptotic growth rate of the map (the largest over the batch).
    stable : bool or None
        ``growth_rate < 1``; None when the estimate has not settled enough to say (its
        ``spread`` is not below ``|log growth_rate|``: the window's halves disagree about
        the side of 1, or the window is too short for its wobble; more iterations
        decide).
    rates : ndarray, shape (m,)
        Growth rate of each direction of the batch.
    spread : float
        The uncertainty of ``log growth_rate`` (:attr:`Growth.spread`, for the direction
        of the largest rate): the difference of the window's two halves, or the range of
        ``log |A^k v|`` about its fitted line over the window's length where larger.
    multipliers : dict
        ``{orders: eigenvalues}`` for the pieces met most often during the iteration
        (``PeriodicOrbit.stability`` reports a dozen); ``orders`` a
        tuple of one event order (tuple) per group, ``eigenvalues`` the (d - 1,) complex
        Floquet multipliers of the piece on the section, by decreasing modulus.
    visits : dict
        ``{orders: count}``: how often a direction of the batch was in each piece.
    iterations, burn_in : int
        Iterations of the map, of which the first ``burn_in`` are not averaged.
    floor : float
        The spread's floor: the rounding of a step (``RATE_ROUNDING``), or the map's own
        accuracy where it is known and larger
        (:attr:`bderiv.analysis.orbit.PeriodicOrbit.accuracy`); a rate
        undecided at the floor is 1 to within what the map can say (neutral).
    """

    growth_rate: float
    stable: bool
    rates: np.ndarray = field(repr=False)
    spread: float
    multipliers: dict
    visits: dict = field(repr=False)
    iterations: int
    burn_in: int
    floor: float = RATE_ROUNDING

    @property
    def verdict_word(self) -> str:
        """"stable", "unstable" or "undecided" (``stable`` None): :func:`verdict_word`."""
        return verdict_word(self.stable)

    def summary(self) -> str:
        """A few lines: the verdict, the rate, and the pieces with their multipliers."""
        verdict = self.verdict_word
        if self.stable is None and self.spread <= self.floor:
            within = "rounding" if self.floor <= RATE_ROUNDING else \
                f"the return map's accuracy ({self.floor:.2g}, from the integration's rtol)"
            verdict += (f": the rate is 1 to within {within} (neutral: perturbations neither "
                        f"grow nor decay at first order)")
        elif self.stable is None:
            verdict += (f": the estimate has not settled in {self.iterations} iterations, "
                        f"pass more")
        floored = " (its floor: the map's accuracy)" if self.floor > RATE_ROUNDING and \
            self.spread <= self.floor else ""
        lines = [f"growth rate {self.growth_rate:.6g} ({verdict}; spread of the estimate "
                 f"{self.spread:.2g}{floored}, {self.rates.size} directions, "
                 f"{self.iterations} iterations)"]
        if len(self.visits) > len(self.multipliers):
            lines.append(f"  {len(self.visits)} pieces met; the {len(self.multipliers)} met "
                         f"most often:")
        for orders, mult in sorted(self.multipliers.items(), key=lambda kv: -self.visits[kv[0]]):
            radius = np.abs(mult).max() if mult.size else 0.0
            lines.append(f"  piece {orders}: {self.visits[orders]} visits, |multipliers| "
                         f"{np.round(np.abs(mult), 6).tolist()} (radius {radius:.6g})")
        return "\n".join(lines)


class Growth(NamedTuple):
    """The growth rates of a PL map's iterates (:func:`growth_rate`).

    Attributes
    ----------
    rates : ndarray, shape (m,)
        Per direction, ``exp`` of the least-squares slope of ``log |A^k v|`` against k
        over the window (after the burn-in).
    spread : ndarray, shape (m,)
        The uncertainty of each log-rate: the absolute difference of the log-rates fitted
        on the two halves of the window, or, where larger, the range of ``log |A^k v|``
        about the fitted line over the window's length (the two halves of a short window
        can agree by chance).
    visits : dict
        ``{orders: count}`` (empty without ``fmap_orders``).
    """

    rates: np.ndarray
    spread: np.ndarray
    visits: dict


def verdict_word(stable) -> str:
    """``stable`` (True, False or None: :attr:`Stability.stable`) in a word: "stable",
    "unstable" or "undecided"."""
    return {True: "stable", False: "unstable"}.get(stable, "undecided")


def verdict(rate: float, spread: float) -> bool | None:
    """``rate < 1``, or None when the estimate's ``spread`` (of its log) is not below the
    distance of ``log rate`` from 0 (:attr:`Stability.stable`).

    Examples
    --------
    >>> verdict(0.78, 1e-4), verdict(3.7, 3.1), verdict(1.2, 0.01)
    (True, None, False)
    """
    if not spread < abs(np.log(rate)):
        return None
    return bool(rate < 1.0)


def growth_rate(fmap, V0, iterations=200, burn_in=None, fmap_orders=None) -> Growth:
    """Iterate a PL map on a batch of directions and estimate its growth rate.

    Parameters
    ----------
    fmap : callable
        ``fmap(V) -> (m, d)`` for ``V`` of shape (m, d): the map, positively homogeneous.
    V0 : array_like, shape (m, d)
        Start directions, no row zero.
    iterations : int
        Number of iterations, >= 2.
    burn_in : int, optional
        Iterations not averaged, in ``[0, iterations - 2]`` (default ``iterations // 4``).
    fmap_orders : callable, optional
        ``fmap_orders(V) -> (fmap(V), orders)``, ``orders`` a list of (m, n_g) arrays
        (``FlowBDerivative.apply_orders``): the map and the pieces of V in one pass, used
        after the burn-in to record the pieces visited.

    Returns
    -------
    Growth
        ``rates``, ``spread``, ``visits``.
    """
    iterations = check_iterations(iterations)
    burn_in = check_burn_in(burn_in, iterations)
    if np.ndim(V0) == 2:  # (else check_matrix names the shape)
        check_growth_memory(*np.shape(V0), iterations)
    logs, visits = log_growth(fmap, V0, iterations, fmap_orders=fmap_orders,
                              record_from=burn_in)
    window = logs[burn_in:]
    half = window.shape[0] // 2
    with np.errstate(invalid="ignore"):  # directions mapped to 0 (-inf) get rate 0
        slope = np.nan_to_num(_slope(window), nan=-np.inf)
        halves = np.abs(_slope(window[:half]) - _slope(window[half:]))
        spread = np.nan_to_num(np.maximum(halves, _wobble(window, slope)), nan=0.0)
    return Growth(np.exp(slope), np.maximum(spread, RATE_ROUNDING), visits)


def _wobble(logs, slope):
    """``(m,)``: per direction (``logs`` (w, m), the window's one-step log-growths;
    ``slope`` (m,), their fitted log-rates), how far ``log |A^k v|`` strays from the fitted
    line ``k log rate``
    over the window (its range), over the window's length: the rate's uncertainty from a
    window this short. ``log |A^k v| = k log rate + b_k`` with ``b_k`` bounded (complex
    multipliers make it oscillate): the two halves' slopes can agree by chance on a few
    iterations (the pronking map's one-step growth swings from 0.15 to 4.3, and two
    halves of two iterations put its rate 0.78 at 1.1), but no slope is known better than
    the range of ``b`` over the window's length."""
    k = np.arange(1, logs.shape[0] + 1, dtype=np.float64)[:, None]
    b = np.cumsum(logs, axis=0) - k * slope
    return (b.max(axis=0) - b.min(axis=0)) / logs.shape[0]


#: (m, d) float arrays alive at once in a growth-rate run: the start directions (on the
#: section and in the state), their checked copy, the iterate, its image and its
#: renormalised image, with room for the map's own temporaries.
GROWTH_ROW_ARRAYS = 8


def check_growth_memory(n_directions, dim, iterations, memory_limit=None) -> None:
    """Refuse a growth-rate run on ``n_directions`` directions before any array is made.

    It keeps :data:`GROWTH_ROW_ARRAYS` arrays (n_directions, dim) and the log-growth table
    (iterations, n_directions), all float64.

    Raises
    ------
    ValueError
        If they take more than ``memory_limit`` bytes (default: the memory available),
        naming the sizes.
    """
    m, d = int(n_directions), int(dim)
    iterations = check_iterations(iterations)
    check_memory(8 * m * (GROWTH_ROW_ARRAYS * d + iterations), memory_limit,
                 f"the growth rate of {m} directions in dimension {d} over {iterations} "
                 f"iterations (n_directions x (8 d + iterations) floats)")


def _slope(logs):
    """Least-squares slope of the cumulative log-growth, per direction: (m,).

    Steadier than the mean of the logs when the growth oscillates (complex
    multipliers): an oscillation of the cumulative sum moves it by O(1/k^2) per step of
    the window instead of O(1/k) at its ends.
    """
    k = np.arange(logs.shape[0], dtype=np.float64)
    if k.size == 1:
        return logs[0]
    k -= k.mean()
    cum = np.cumsum(logs, axis=0)
    return (k @ (cum - cum.mean(axis=0))) / (k @ k)


def log_growth(fmap, V0, iterations, *, fmap_orders=None, record_from=0):
    """``log(|A v_k| / |v_k|)`` of every step: shape (iterations, m), and the visits.

    The directions are renormalised after every step (no overflow or underflow, however
    long); a direction mapped to 0 gets ``-inf`` and keeps its last direction. The
    cumulative sum over the steps is ``log |A^k v_0| - log |v_0|``. ``fmap_orders`` and
    ``record_from``: count the pieces visited from that step on (see
    :func:`growth_rate`).
    """
    V = check_matrix(V0, "V0", (None, None))
    norms = np.linalg.norm(V, axis=1)
    if not np.all(norms > 0):
        raise ValueError(f"V0 must have no zero row, but row {int(np.argmin(norms))} is zero")
    V = V / norms[:, None]
    logs = np.empty((iterations, V.shape[0]))
    visits = _Visits()
    with count_bar(iterations, "growth rate", "iterations") as bar:  # long runs
        for k in range(iterations):
            if fmap_orders is not None and k >= record_from:
                W, orders = fmap_orders(V)
                visits.add(orders)
            else:
                W = fmap(V)
            norms = np.linalg.norm(W, axis=1)
            zero = norms == 0
            safe = np.where(zero, 1.0, norms)
            logs[k] = np.where(zero, -np.inf, np.log(safe))
            V = np.where(zero[:, None], V, W / safe[:, None])
            bar(k + 1)
    return logs, visits.result()


class _Visits:
    """A tally of the pieces (one order per group) of the batches added. A row's local
    indices (each below its group's size n_g) are read as the digits of one int64 code
    (a mixed radix; a sort of 200 codes is 4-6x cheaper than one of the rows, and the
    keys are made once per piece, not per batch); the rows are sorted themselves when
    ``prod n_g**n_g`` would not fit (2**62)."""

    def __init__(self):
        self.counts, self.rows, self.sizes, self.weights = {}, {}, None, None

    def add(self, orders_list):
        if not orders_list:
            self.counts[()] = self.counts.get((), 0) + 1
            return
        stacked = np.concatenate(orders_list, axis=-1)
        if self.sizes is None:
            self.sizes = [o.shape[-1] for o in orders_list]
            radix = np.repeat(np.asarray(self.sizes, dtype=np.int64), self.sizes)
            if np.sum(np.log2(np.maximum(radix, 1))) < 62:
                self.weights = np.cumprod(np.concatenate(([1], radix[:-1])))
        if self.weights is None:
            _, first, counts = np.unique(stacked, axis=0, return_index=True,
                                         return_counts=True)
            codes = [self._key(row) for row in stacked[first]]
        else:
            codes, first, counts = np.unique(stacked @ self.weights, return_index=True,
                                             return_counts=True)
            codes = codes.tolist()
        for code, i, count in zip(codes, first.tolist(), counts.tolist(), strict=True):
            if code not in self.counts:
                self.counts[code], self.rows[code] = 0, stacked[i]
            self.counts[code] += count

    def _key(self, row):
        parts = np.split(row, np.cumsum(self.sizes)[:-1])
        return tuple(tuple(int(k) for k in p) for p in parts)

    def result(self):
        """``{orders: count}``, orders a tuple of one order (tuple of int) per group."""
        return {(code if isinstance(code, tuple) else self._key(self.rows[code])): count
                for code, count in self.counts.items()}


def piece_multipliers(piece, basis):
    """Eigenvalues of a piece restricted to the section: shape (d - 1,), complex.

    ``basis`` (d, d - 1) is an orthonormal basis of the section's tangent space; at a
    fixed point the piece maps it into itself, so ``basis.T @ piece @ basis`` is the
    piece on the section (the flow direction, mapped to 0, is left out).
    """
    restricted = basis.T @ piece @ basis
    eig = np.linalg.eigvals(restricted)
    return eig[np.argsort(-np.abs(eig), kind="stable")]
