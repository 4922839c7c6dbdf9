"""Garcia et al.'s simplest walker written from their equations, an oracle independent of
bderiv for the compass-gait tests (tests/test_bounces.py, tests/test_compass_slopes.py):
Garcia, Chatterjee, Ruina & Coleman, "The simplest walking model: stability, complexity,
and scaling", ASME J. Biomech. Eng. 120(2), 1998."""

from __future__ import annotations

import numpy as np
from scipy.integrate import solve_ivp


def garcia_stride(z, gam=0.009):
    """Garcia et al.'s stride map on (theta, theta') just after heel strike, from their
    equations (g = l = 1, leg mass 0), by scipy: the heel strike is phi - 2 theta = 0
    crossed upward with phi < 0 (the scuff at mid-stance ignored)."""

    def f(_t, y):
        th, ph, thd, _ = y
        return [thd, y[3], np.sin(th - gam),
                np.sin(ph) * (thd**2 - np.cos(th - gam)) + np.sin(th - gam)]

    def strike(_t, y):
        return y[1] - 2 * y[0] if y[1] < 0 else -1.0

    strike.terminal, strike.direction = True, 1
    th, thd = z
    y0 = [th, 2 * th, thd, thd * (1 - np.cos(2 * th))]
    sol = solve_ivp(f, (0, 20), y0, events=strike, method="DOP853", rtol=1e-13, atol=1e-14)
    th, _, thd, _ = sol.y_events[0][0]
    return np.array([-th, np.cos(2 * th) * thd])


