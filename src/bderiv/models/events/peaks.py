"""The samples of a stretch and the peaks of its event values between them.

The screen for surfaces crossed and crossed back inside a step
(:mod:`bderiv.models.events.excursions`, steps 1 and 2 of its rule) reads the event values
at the step ends and the steps' midpoints (:func:`sample_times`); a sampled local maximum
that could reach the surface gives a bracket (:func:`peak_brackets`), and the maximum in a
bracket is searched on the dense output (:func:`peak_of`: bounded Brent, to a relative
time accuracy ``PEAK_XTOL``). Plain functions of arrays and of a callable, for any
integrator.
"""

from __future__ import annotations

import numpy as np

from ..._limits import PEAK_XTOL
from ..._numerics import REACH
from ..._support._validate import scratch
from ._python_rules import rules

__all__ = ["peak_brackets", "peak_of", "sample_times"]


def sample_times(ends: np.ndarray) -> np.ndarray:
    """The step ends and the midpoint of every step, in order: shape (2 m - 1,) for m ends.

    Examples
    --------
    >>> sample_times(np.array([0.0, 1.0, 3.0]))
    array([0. , 0.5, 1. , 2. , 3. ])
    """
    out = np.empty(2 * ends.size - 1)
    rules.sample_times(scratch(ends), out)
    return out


def peak_brackets(h: np.ndarray, tol: np.ndarray, *, stretch=False, reach=REACH) -> list:
    """Brackets of the sampled local maxima that could reach the surface.

    Parameters
    ----------
    h : ndarray, shape (m, n)
        Event values (local orientation: pending means ``h < 0``) at m sample times.
    tol : ndarray, shape (n,)
        How well each event's value is known.
    stretch : bool
        The samples span a whole stretch: an event at its surface (``h_k >= -tol_k``) at
        the first sample was just switched and leaves it, and one at the last sample is
        at the integrator's stop (located there, or switched with the located ones), so
        neither end is a peak to search there.
    reach : float
        How far above a sampled maximum a peak may rise, in units of its drop to the
        lower neighbour.

    Returns
    -------
    list of (k, lo, hi)
        Event k may peak between the samples lo < hi (indices), in order of lo.

    Examples
    --------
    A peak between samples 1 and 2 that the samples miss (-0.004 on both sides):

    >>> h = np.array([[-0.02], [-0.004], [-0.004], [-0.02]])
    >>> peak_brackets(h, np.array([1e-11]))
    [(0, 0, 2), (0, 1, 3)]
    >>> peak_brackets(h - 1.0, np.array([1e-11]))
    []
    """
    m = h.shape[0]
    if m < 2:
        return []
    rows = rules.peak_rows(scratch(h), scratch(tol), bool(stretch), float(reach))
    out = [(k, max(i - 1, 0), min(i + 1, m - 1)) for k, i in rows.tolist()]
    return sorted(out, key=lambda b: (b[1], b[0]))


def peak_of(value, t_lo: float, t_hi: float) -> tuple[float, float]:
    """The maximum of ``value(t)`` on ``[t_lo, t_hi]``: ``(t_peak, value(t_peak))``.

    Examples
    --------
    >>> t, v = peak_of(lambda t: np.cos(t) - 0.999, -0.3, 0.2)
    >>> abs(t) < 1e-8, round(v, 12)
    (True, 0.001)
    """
    from scipy.optimize import minimize_scalar  # here: a peak is rare, the import 0.1 s

    res = minimize_scalar(lambda s: -value(s), bounds=(t_lo, t_hi), method="bounded",
                          options={"xatol": PEAK_XTOL * (t_hi - t_lo)})
    candidates = [(float(res.x), -float(res.fun)), (t_lo, float(value(t_lo))),
                  (t_hi, float(value(t_hi)))]
    return max(candidates, key=lambda c: c[1])
