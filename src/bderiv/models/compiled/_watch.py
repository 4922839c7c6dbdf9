"""Event watching: which events crossed in a step, and where, on the dense output.

Event k is watched in the direction that flips its bit of the region mask: upward when the
bit is clear, downward when it is set. A step from ``g`` to ``g_new`` crossed it when
``g <= 0 <= g_new`` (upward) or ``g >= 0 >= g_new`` (downward): scipy's
``find_active_events``, so a value leaving zero counts, as in ``solve_ivp``. The crossing
time is the root of ``events(x(t))[k]`` on the step's dense output, found by Brent's method
with scipy's ``brentq`` algorithm and its tolerances in ``solve_ivp`` (``xtol = rtol =
4 eps``).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from ..._numerics import EVENT_MAX_ITER, EVENT_RTOL, EVENT_XTOL
from ._dop853 import dense_eval
from ._rhs import OK, call_events


@njit(cache=True, inline="always")
def crossed(g, g_new, mask, active):
    """``active[k]`` = event k crossed in the direction that flips bit k of ``mask``;
    returns whether any did."""
    found = False
    for k in range(g.size):
        if mask >> k & 1:
            hit = g[k] >= 0.0 and g_new[k] <= 0.0
        else:
            hit = g[k] <= 0.0 and g_new[k] >= 0.0
        active[k] = hit
        found = found or hit
    return found


@njit(cache=True)
def _event_at(model, with_section, k, F, y_old, t_old, h, t, x, g, bad):
    """``(status, events(x(t))[k])`` on the dense output ``F``."""
    dense_eval(F, y_old, t_old, h, t, x.size, x)
    status = call_events(model, with_section, x, g.size, g, bad)
    return status, g[k]


@njit(cache=True)
def locate(model, with_section, k, g_old, F, y_old, t_old, t_new, x, g, bad):
    """``(status, t)``: the root of event k in ``[t_old, t_new]`` on the dense output,
    ``g_old`` its watched value at ``t_old``: the event at ``y_old`` (which the dense output
    gives at ``t_old`` exactly), or at a run's stretch's start the side a 0 reads
    (``on_side`` of :func:`._integrate.drive_stretch`), as solve_ivp's ``brentq`` reads
    the event function there.

    scipy's ``brentq`` (``Zeros/brentq.c``): inverse quadratic interpolation or secant
    steps kept inside the bracket, bisection otherwise, to ``xtol + rtol |t|``. The ends
    must bracket a root (``crossed`` guarantees a sign change or a zero end).
    """
    h = t_new - t_old
    xpre, xcur, fpre = t_old, t_new, g_old
    status, fcur = _event_at(model, with_section, k, F, y_old, t_old, h, xcur, x, g, bad)
    if status != OK:
        return status, xcur
    if fpre == 0.0:
        return OK, xpre
    if fcur == 0.0 or np.signbit(fpre) == np.signbit(fcur):
        # no sign change left: the dense output's end differs from the step's end state
        # by rounding, and the crossing is at the end
        return OK, xcur
    xblk = fblk = spre = scur = 0.0
    for _ in range(EVENT_MAX_ITER):
        if fpre != 0.0 and fcur != 0.0 and (np.signbit(fpre) != np.signbit(fcur)):
            xblk, fblk = xpre, fpre
            spre = scur = xcur - xpre
        if abs(fblk) < abs(fcur):
            xpre, xcur, xblk = xcur, xblk, xcur
            fpre, fcur, fblk = fcur, fblk, fcur
        delta = (EVENT_XTOL + EVENT_RTOL * abs(xcur)) / 2.0
        sbis = (xblk - xcur) / 2.0
        if fcur == 0.0 or abs(sbis) < delta:
            return OK, xcur
        if abs(spre) > delta and abs(fcur) < abs(fpre):
            if xpre == xblk:  # interpolate
                stry = -fcur * (xcur - xpre) / (fcur - fpre)
            else:  # extrapolate
                dpre = (fpre - fcur) / (xpre - xcur)
                dblk = (fblk - fcur) / (xblk - xcur)
                stry = -fcur * (fblk * dblk - fpre * dpre) / (dblk * dpre * (fblk - fpre))
            if 2.0 * abs(stry) < min(abs(spre), 3.0 * abs(sbis) - delta):
                spre, scur = scur, stry  # good short step
            else:
                spre = scur = sbis
        else:
            spre = scur = sbis
        xpre, fpre = xcur, fcur
        xcur += scur if abs(scur) > delta else (delta if sbis > 0.0 else -delta)
        status, fcur = _event_at(model, with_section, k, F, y_old, t_old, h, xcur, x, g, bad)
        if status != OK:
            return status, xcur
    return OK, xcur
