"""Monte Carlo consistency of filters through a simultaneous touchdown: the NEES table.

The scenario (docs/estimation.md): the true start ``x ~ N(x0, P0)`` around an example's
start ``x0``, whose trajectory meets its events simultaneously at ``t_event``; a filter
predicts to ``t_event / 2`` (no event), updates with a measurement of the positions (the
first half of the state), and predicts through the touchdown to ``t_final``. There its
normalised estimation error squared ``(x - m)^T P^-1 (x - m)`` of each run is drawn from a
chi-square with d degrees of freedom if the filter is consistent: the mean over N runs
lies in ``[chi2.ppf(0.025, N d) / N, chi2.ppf(0.975, N d) / N]`` 95 % of the time.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from .._support._progress import count_bar
from .kalman import HybridKalmanFilter

#: the filters compared: name -> HybridKalmanFilter keywords
FILTERS = {
    "mixture": {"method": "mixture"},
    "sigma": {"method": "sigma"},
    "salted, mean's order": {"method": "piece"},
    "salted, order (0, 1)": {"method": "piece", "priority": (0, 1)},
    "salted, order (1, 0)": {"method": "piece", "priority": (1, 0)},
}


class Consistency(NamedTuple):
    """NEES of each filter over the runs.

    Attributes
    ----------
    nees : dict
        Filter name -> ndarray (runs,) of the NEES at ``t_final``.
    band : tuple of float
        The 95 % band of the mean NEES of a consistent filter.
    orders : ndarray, shape (runs, 2)
        The event order each true run took at the touchdown.
    dim : int
    """

    nees: dict
    band: tuple
    orders: np.ndarray
    dim: int

    def table(self) -> str:
        """The table as text: filter, mean NEES, in the band or not."""
        lo, hi = self.band
        n = len(self.orders)
        first = np.mean(self.orders[:, 0] == 0)
        lines = [f"{n} runs, d = {self.dim}; event 0 first in {first:.0%} of them; "
                 f"95 % band of the mean NEES: [{lo:.3f}, {hi:.3f}]",
                 f"{'filter':24s} {'mean NEES':>10s}  verdict"]
        for name, v in self.nees.items():
            m = float(np.mean(v))
            verdict = "consistent" if lo <= m <= hi else ("overconfident" if m > hi
                                                          else "underconfident")
            lines.append(f"{name:24s} {m:10.3f}  {verdict}")
        return "\n".join(lines)


def consistency(example, runs, *, prior_sd=1e-4, seed=0, window=None, filters=None):
    """The NEES of each filter over ``runs`` Monte Carlo runs (module docstring).

    Parameters
    ----------
    example : Example
        With ``system``, ``x0``, ``t_event``, ``t_final`` (e.g. ``examples.chair()``).
    runs : int
        Number of runs, >= 1.
    prior_sd : float
        Standard deviation of each coordinate of the prior (P0 = prior_sd^2 I); the
        measurement noise has half of it. Small enough that the flow is linear to well
        within it away from the events.
    seed : int
    window : float, optional
        The filters' window; default: their own (derived at each step from the prior).
    filters : dict, optional
        Name -> HybridKalmanFilter keywords (default :data:`FILTERS`).

    Returns
    -------
    Consistency
    """
    model, d = example.system, example.system.dim
    filters = FILTERS if filters is None else filters
    given = {} if window is None else {"window": window}
    rng = np.random.default_rng(seed)
    P0 = prior_sd**2 * np.eye(d)
    H = np.eye(d)[: d // 2]
    R = (prior_sd / 2) ** 2 * np.eye(d // 2)
    t1, T = example.t_event / 2, example.t_final
    X0 = example.x0 + prior_sd * rng.standard_normal((runs, d))
    X1 = model.simulate_many(X0, t1).x_final  # (bars of their own once they last)
    truth = model.simulate_many(X1, T - t1)
    orders = np.array([[k for g in run.groups for k in g.events][:2] for run in truth])
    Z = X1 @ H.T + (prior_sd / 2) * rng.standard_normal((runs, d // 2))
    first = {name: HybridKalmanFilter(model, example.x0, P0, **given, **kw)
             for name, kw in filters.items()}
    for f in first.values():
        f.predict(t1)  # the same prior for every run: one step for all
    nees = {name: np.empty(runs) for name in filters}
    with count_bar(runs, "consistency", "runs") as bar:  # long runs
        for i in range(runs):
            for name, kw in filters.items():
                f = HybridKalmanFilter(model, first[name].mean, first[name].cov, **given,
                                       **kw)
                f.update(Z[i], R, H=H)
                f.predict(T - t1)
                nees[name][i] = f.nees(truth.x_final[i])
            bar(i + 1)
    from scipy.stats import chi2  # here: scipy.stats imports in 0.6 s

    lo, hi = chi2.ppf([0.025, 0.975], runs * d) / runs
    return Consistency(nees, (float(lo), float(hi)), orders, d)
