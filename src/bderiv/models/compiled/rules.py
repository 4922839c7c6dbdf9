"""The rules at a stop of the integrator, in compiled code: one copy for both integrators.

These are the numbers the event logic decides by (docs/mathematics.md, section 11): the
state's error bound, the events' rates and windows, the classes of the events at a stop,
the transversality of a crossing, a return across a surface, the sampled peaks of an
excursion. They are plain loops over arrays. The Python stop logic
(:mod:`bderiv.models.events`) calls them on the values a solve_ivp run evaluated, and the
compiled run (:mod:`._run`) on the values its model evaluated in compiled code; both get
the same bits from the same arrays, so a run may pass from one to the other at any stop.
The rules' meaning is documented where the Python side names them
(:func:`bderiv.models.events.locate.windows`, :func:`~bderiv.models.events.locate.classify`,
:func:`bderiv.models.events.crossings.switch`, :mod:`bderiv.models.events.excursions`).

Arrays are C-contiguous float64 (event flags: bool); results go into ``out`` arrays.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from ..._numerics import GLOBAL_ERROR_FACTOR, GRAZING_RTOL

#: the codes of :func:`classify`: switched with the group; within ``simultaneity_tol`` of
#: crossing but not at the stop (switched at its own time, later); at the stop with a time
#: known worse than the tolerance
GROUP, NEAR, UNDECIDED = 1, 2, 4


@njit(cache=True)
def state_error(atol, rtol, scale, carried, out):
    """``out = max(carried, GLOBAL_ERROR_FACTOR (atol + rtol scale))`` per component."""
    for i in range(scale.size):
        out[i] = max(carried[i], GLOBAL_ERROR_FACTOR * (atol + rtol * scale[i]))


@njit(cache=True)
def local_rates(sign, J, F, Dh, rate):
    """The gradients in the local orientation, ``Dh = sign J`` (n, d), and the rates
    ``rate = Dh F`` (n,)."""
    n, d = J.shape
    for k in range(n):
        r = 0.0
        for i in range(d):
            Dh[k, i] = sign[k] * J[k, i]
            r += Dh[k, i] * F[i]
        rate[k] = r


@njit(cache=True)
def tolerances(Dh, err, out):
    """``out = |Dh| err`` (n,): how well each event's value is known."""
    n, d = Dh.shape
    for k in range(n):
        s = 0.0
        for i in range(d):
            s += abs(Dh[k, i]) * err[i]
        out[k] = s


@njit(cache=True)
def windows(Dh, rate, err, fired, window):
    """``window = sigma + |rate| u`` (n,) with ``sigma = |Dh| err``; returns ``u``, the
    largest ``sigma_j / rate_j`` over the ``fired`` events (bool, (n,)) with a positive
    rate (0 if none)."""
    tolerances(Dh, err, window)
    u = 0.0
    for j in range(rate.size):
        if fired[j] and rate[j] > 0.0:
            u = max(u, window[j] / rate[j])
    for k in range(rate.size):
        window[k] = window[k] + abs(rate[k]) * u
    return u


@njit(cache=True)
def classify(h, rate, window, fired, simultaneity_tol, out):
    """``out[k]`` (int64, (n,)): the bits ``GROUP``, ``NEAR``, ``UNDECIDED`` of event k."""
    for k in range(h.size):
        code = 0
        if fired[k] or h[k] > window[k]:
            code = GROUP
        elif not rate[k] > 0.0:
            code = 0
        elif abs(h[k]) <= window[k]:
            code = GROUP
            if window[k] / rate[k] > simultaneity_tol:
                code |= UNDECIDED
        elif -h[k] / rate[k] <= simultaneity_tol:
            code = NEAR
        out[k] = code


@njit(cache=True)
def clearly_positive(dh, F):
    """Whether the rate ``dh . F`` is positive beyond ``GRAZING_RTOL |dh| |F|``."""
    r, a, b = 0.0, 0.0, 0.0
    for i in range(F.size):
        r += dh[i] * F[i]
        a += dh[i] * dh[i]
        b += F[i] * F[i]
    return r > GRAZING_RTOL * np.sqrt(a) * np.sqrt(b)


@njit(cache=True)
def same_flow(F0, F1, J0, J1):
    """Whether two regions' fields at a state, ``F0``, ``F1`` (d,), and their Jacobians
    there, ``J0``, ``J1`` (d, d), are the same to ``GRAZING_RTOL`` (a difference too small
    to tell, relative to the largest entry; max norms): the flow is the same on both sides
    of a surface near the state (:func:`bderiv.models.events.crossings.landing`)."""
    return _close(F0.ravel(), F1.ravel()) and _close(J0.ravel(), J1.ravel())


@njit(cache=True)
def _close(a, b):
    """Whether ``max |a - b| <= GRAZING_RTOL max(|a|, |b|)`` (1-d arrays; all zero: equal)."""
    gap, size = 0.0, 0.0
    for i in range(a.size):
        gap = max(gap, abs(a[i] - b[i]))
        size = max(size, abs(a[i]), abs(b[i]))
    return gap <= GRAZING_RTOL * size


@njit(cache=True)
def first_grazing(group, Dh, F):
    """The first event of ``group`` (bool, (n,)) whose crossing is not clearly transversal
    in the field ``F`` (:func:`clearly_positive` of its row of ``Dh``); -1 if none."""
    for k in range(group.size):
        if group[k] and not clearly_positive(Dh[k], F):
            return k
    return -1


@njit(cache=True)
def wrong_side(h, mask, window):
    """The first event k whose value ``h[k]`` (n,) is not on the side of its surface that
    bit k of ``mask`` says (set: ``h_k > 0``; clear: ``h_k < 0``) and is further from it
    than ``window[k]``; -1 if none: the invariant of the region after every stop
    (:func:`bderiv.models.events.sides.check_sides`)."""
    for k in range(h.size):
        side = 1.0 if mask >> k & 1 else -1.0
        if not side * h[k] > 0.0 and not abs(h[k]) <= window[k]:
            return k
    return -1


@njit(cache=True)
def reads_across(h, mask, window, skip):
    """Whether an event not in ``skip`` (bits) reads a rounding across its surface after a
    stop: ``h[k]`` (n,) strictly on the other side than bit k of ``mask`` says, within
    ``window[k]`` (:func:`carried_across` then looks at its rate)."""
    for k in range(h.size):
        side = 1.0 if mask >> k & 1 else -1.0
        if not (skip >> k) & 1 and side * h[k] < 0.0 and abs(h[k]) <= window[k]:
            return True
    return False


@njit(cache=True)
def carried_across(h, mask, window, skip, J, F):
    """The first event k of :func:`reads_across` that the field ``F`` (d,) of region
    ``mask`` carries further across (``J[k] . F``, J (n, d) the event Jacobian, clearly of
    that side); -1 if none. Its crossing is at once and unseen: the integrator reads it
    across at both ends of every step (:func:`bderiv.models.events.sides.check_carried`)."""
    for k in range(h.size):
        side = 1.0 if mask >> k & 1 else -1.0
        if (skip >> k) & 1 or not side * h[k] < 0.0 or abs(h[k]) > window[k]:
            continue
        if clearly_positive(-side * J[k], F):
            return k
    return -1


@njit(cache=True)
def first_sent_back(group, h, window, kept, Dh, F):
    """After a group's resets, the first event of ``group`` (bool, (n,)) on its surface
    (``|h_k| <= window_k``, local orientation) that the field ``F`` of the region the state
    goes on in sends back across: a flipped one whose rate ``Dh_k . F`` is clearly
    negative, a kept one (``kept``: the bits of the bounced events) whose rate is clearly
    positive; -1 if none."""
    for k in range(h.size):
        if not group[k] or abs(h[k]) > window[k]:
            continue
        if (kept >> k) & 1:
            if clearly_positive(Dh[k], F):
                return k
        elif clearly_positive(-Dh[k], F):
            return k
    return -1


@njit(cache=True)
def return_sample(h, tol):
    """The earliest sample ``i >= 1`` with ``h[i, k] < 0`` of an event across its surface,
    ``h[j, k] > tol_k``, at a later sample j (the first such j), the lowest of those
    before j; -1 if none (:func:`bderiv.models.events.excursions._return`)."""
    m, n = h.shape
    first = -1
    for k in range(n):
        j = -1
        for i in range(1, m):
            if h[i, k] > tol[k]:
                j = i
                break
        if j <= 1:
            continue
        low, i_low = h[1, k], 1
        for i in range(2, j):
            if h[i, k] < low:
                low, i_low = h[i, k], i
        if low < 0.0 and (first < 0 or i_low < first):
            first = i_low
    return first


@njit(cache=True)
def start_dip_steps(h):
    """``(k, j)`` rows (B, 2): event k is across its surface at the first sample
    (``h[0, k] > 0``: a located crossing's rounding, or an event switched with it on its
    way to its side) and at every sample up to step j (samples ``2 j .. 2 j + 2``), where
    it first rises above the step's start value: it may have gone below the surface and
    come back inside that step, unseen (the first such step of each event;
    :func:`bderiv.models.events.excursions._start_dip`)."""
    m, n = h.shape
    out = np.empty((n, 2), dtype=np.int64)
    count = 0
    for k in range(n):
        if not h[0, k] > 0.0:
            continue
        for j in range((m - 1) // 2):
            start, middle, end = h[2 * j, k], h[2 * j + 1, k], h[2 * j + 2, k]
            if not (middle > 0.0 and end > 0.0):
                break
            if middle > start or end > start:
                out[count, 0] = k
                out[count, 1] = j
                count += 1
                break
    return out[:count]


@njit(cache=True)
def sample_times(ends, out):
    """``out`` (2 m - 1,): the step ends (m,) and the midpoint of every step, in order."""
    m = ends.size
    for i in range(m):
        out[2 * i] = ends[i]
    for i in range(m - 1):
        out[2 * i + 1] = 0.5 * (ends[i] + ends[i + 1])


@njit(cache=True)
def linspace(start, stop, out):
    """``out`` (num >= 2,): ``num`` evenly spaced times from ``start`` to ``stop``, as
    ``np.linspace`` computes them (``i * step + start``, the last ``stop``)."""
    div = out.size - 1
    delta = stop - start
    step = delta / div
    for i in range(out.size):
        out[i] = (i / div * delta if step == 0.0 else i * step) + start
    out[div] = stop


@njit(cache=True)
def peak_rows(h, tol, stretch, reach):
    """``(k, i)`` rows (B, 2) of the samples ``h[i, k]`` (m >= 2 samples, n events) not lower
    than their neighbours with ``h + reach (h - lower neighbour) >= -tol_k`` (with
    ``stretch``, the first and last sample only where ``h < -tol_k``): event by event,
    samples in order (:func:`bderiv.models.events.excursions.peak_brackets`)."""
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
