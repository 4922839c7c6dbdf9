"""The sampled local maxima of the event values that could reach their surfaces, compiled.

:func:`peak_rows` is the screen of :func:`.excursions.peak_brackets` in one loop (the rule
is written there): it runs on every stretch of a run, for both integrators, where NumPy's
dozen array operations on a few dozen samples cost more than a compiled stretch.
"""

from __future__ import annotations

import numpy as np
from numba import njit, types

_SIGNATURE = types.int64[:, ::1](types.float64[:, ::1], types.float64[::1], types.boolean,
                                 types.float64)


@njit(_SIGNATURE, cache=True)
def peak_rows(h, tol, stretch, reach):
    """``(k, i)`` rows (B, 2) of the samples ``h[i, k]`` (m >= 2 samples, n events) not lower
    than their neighbours with ``h + reach (h - lower neighbour) >= -tol_k`` (with
    ``stretch``, the first and last sample only where ``h < -tol_k``): event by event,
    samples in order."""
    m, n = h.shape
    out = np.empty((m * n, 2), dtype=np.int64)
    count = 0
    for k in range(n):
        for i in range(m):
            v = h[i, k]
            if i > 0 and not v >= h[i - 1, k]:
                continue
            if i < m - 1 and not v >= h[i + 1, k]:
                continue
            if i == 0:
                low = h[1, k]
            elif i == m - 1:
                low = h[m - 2, k]
            else:
                low = min(h[i - 1, k], h[i + 1, k])
            if not v + reach * (v - low) >= -tol[k]:
                continue
            if stretch and (i == 0 or i == m - 1) and not v < -tol[k]:
                continue
            out[count, 0] = k
            out[count, 1] = i
            count += 1
    return out[:count]
