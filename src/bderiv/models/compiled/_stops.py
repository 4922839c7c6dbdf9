"""The compiled run's rules at a stop that need the model: the event Jacobian, the
excursion screen, and the resets of a group with where they land.

Each repeats a decision of the Python stop logic (named in its docstring) on values the
model gives in compiled code, by the arithmetic of :mod:`.rules`; a decision it cannot
make (a bracket to search, a refusal) is False, and the compiled run (:mod:`._run`) hands
the stretch back to the Python loop.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from ..._numerics import COMPLEX_STEP, FINE_REACH, FINE_SAMPLES, ORDERS_CHECKED, REACH
from ._dop853 import dense_rows, step_starts
from ._rhs import (
    OK,
    all_finite,
    argument,
    call_events,
    checked_field,
    coordinate_scale,
    events_rows,
    finite_vector,
    jacobian,
)
from .rules import (
    clearly_positive,
    first_sent_back,
    linspace,
    local_rates,
    peak_rows,
    return_sample,
    same_flow,
    sample_times,
    start_dip_steps,
    state_error,
    tolerances,
)

#: how the event Jacobian is had in compiled code: the given ``event_jacobian``, complex step
#: of ``events``; none (the Python loop's: a Python or numerical one)
EVENT_JAC_GIVEN = 0
EVENT_JAC_COMPLEX_STEP = 1
EVENT_JAC_NONE = 2


@njit(cache=True)
def event_jacobian(model, mode, x, n, d):
    """The event Jacobian at ``x`` by ``mode``: ``(ok, J)``, J (n, d) checked (shape,
    finite). Complex step: column j is ``Im events(x + i h e_j) / h``, h as the field's."""
    if mode == EVENT_JAC_GIVEN:
        try:
            J = model.event_jacobian(argument(model, x))
        except Exception:  # noqa: BLE001 - the Python loop calls it again and says what
            return False, np.zeros((n, d))
        if J.shape[0] != n or J.shape[1] != d:
            return False, np.zeros((n, d))
        J = np.ascontiguousarray(J).copy()
    else:
        base = argument(model, x)
        z = np.empty(base.size, dtype=np.complex128)
        J = np.empty((n, d))
        for j in range(d):
            h = COMPLEX_STEP * coordinate_scale(x[j])
            for i in range(base.size):
                z[i] = base[i]
            z[j] = complex(x[j], h)
            try:
                v = model.cevents(z)
            except Exception:  # noqa: BLE001
                return False, J
            if v.size != n:
                return False, J
            for k in range(n):
                J[k, j] = v[k].imag / h
    return all_finite(J), J


@njit(cache=True)
def plain_screen(model, event_jac_mode, sign, mask, n, d, ts, ys, gs, steps, Fd, J, atol,
                 rtol):
    """Whether the excursion screen finds nothing to search on the stretch
    (:func:`bderiv.models.events.excursions._earliest_lost` up to its search: no sampled
    peak that could reach a surface once its bracket is sampled finer and its ends decided
    by the rates there, no return across a surface, no step to search for one from a start
    across); False also on a failed check.

    The samples at the step ends are the record's states ``ys``, and their events the
    driver's own values ``gs`` (NaN at a stop inside a step: evaluated here), the same bits
    as a call there; the midpoints' are evaluated on the dense output."""
    count, last = ts.size, 2 * ts.size - 2
    times = np.empty(last + 1)
    sample_times(ts, times)
    t_old, h_step, y_old = step_starts(steps, ys, d)
    mids = np.empty(count - 1)
    for i in range(count - 1):
        mids[i] = times[2 * i + 1]
    middle = np.empty((count - 1, d))
    dense_rows(t_old, h_step, Fd, y_old, mids, middle)
    states = np.empty((times.size, d))
    for i in range(count):
        for j in range(d):
            states[2 * i, j] = ys[i, j]
    for i in range(count - 1):
        for j in range(d):
            states[2 * i + 1, j] = middle[i, j]
    H = np.empty((times.size, n))
    bad = np.zeros(d)
    for r in range(times.size):
        if r % 2 == 0 and gs.shape[1] > 0 and not np.isnan(gs[r // 2, 0]):
            for k in range(n):
                H[r, k] = gs[r // 2, k]
        elif call_events(model, np.bool_(False), states[r], n, H[r], bad) != OK:
            return False
    scale = np.zeros(d)
    for r in range(times.size):
        for k in range(n):
            H[r, k] *= sign[k]
        for i in range(d):
            scale[i] = max(scale[i], abs(states[r, i]))
    err = np.empty(d)
    state_error(atol, rtol, scale, np.zeros(d), err)
    tol = np.empty(n)
    tolerances(J, err, tol)
    if return_sample(H, tol) >= 0 or start_dip_steps(H).shape[0] > 0:
        return False  # a return across a surface, or a step to search for one
    rows = peak_rows(H, tol, np.bool_(True), REACH)
    if rows.shape[0] == 0:
        return True
    # the rates at the stretch's ends, where a bracket there that the event leaves from, or
    # rises into, peaks (excursions' end rule)
    x_start, x_end = ys[0, :d].copy(), ys[count - 1, :d].copy()
    ok, J_start = event_jacobian(model, event_jac_mode, x_start, n, d)
    start_status, F_start = checked_field(model, x_start, mask, d)
    end_status, F_end = checked_field(model, x_end, mask, d)
    if not ok or start_status != OK or end_status != OK:
        return False
    rate_start, rate_end, Dh = np.empty(n), np.empty(n), np.empty((n, d))
    local_rates(sign, J_start, F_start, Dh, rate_start)
    local_rates(sign, J, F_end, Dh, rate_end)
    # the events on a bracket's fine samples, once per bracket (the events peaking at the
    # same sample share it)
    slot = np.full(last + 1, -1)
    brackets = 0
    for b in range(rows.shape[0]):
        if slot[rows[b, 1]] < 0:
            slot[rows[b, 1]] = brackets
            brackets += 1
    fine, X = np.empty(FINE_SAMPLES), np.empty((FINE_SAMPLES, d))
    V, G = np.empty((FINE_SAMPLES, 1)), np.empty((brackets, FINE_SAMPLES, n))
    done = np.zeros(brackets, dtype=np.bool_)
    for b in range(rows.shape[0]):
        k, i = rows[b, 0], rows[b, 1]
        lo, hi = max(i - 1, 0), min(i + 1, last)
        if not done[slot[i]]:
            linspace(times[lo], times[hi], fine)
            dense_rows(t_old, h_step, Fd, y_old, fine, X)
            if events_rows(model, X, n, G[slot[i]], np.zeros(d)) != OK:
                return False
            done[slot[i]] = True
        for r in range(FINE_SAMPLES):
            V[r, 0] = sign[k] * G[slot[i], r, k]
        sub = peak_rows(V, tol[k:k + 1].copy(), np.bool_(False), FINE_REACH)
        for c in range(sub.shape[0]):
            a, z = max(sub[c, 1] - 1, 0), min(sub[c, 1] + 1, FINE_SAMPLES - 1)
            if not (lo == 0 and a == 0 and rate_start[k] < 0.0) and \
                    not (hi == last and z == FINE_SAMPLES - 1 and rate_end[k] > 0.0):
                return False  # a bracket to search
    return True


@njit(cache=True)
def _reset_in_order(model, order, mask, x, d):
    """``(ok, y)``: ``x`` moved by the resets of the events ``order`` one after the other,
    each called with the mask before its own crossing; checked (shape, finite)."""
    y, b = x, mask
    for k in order:
        try:
            y = model.reset(argument(model, y), b, k)
        except Exception:  # noqa: BLE001 - the Python loop calls it again and says what
            return False, x
        if y.size != d or not finite_vector(y):
            return False, x
        y = np.ascontiguousarray(y).copy()
        b ^= np.int64(1) << k
    return True, y


@njit(cache=True)
def _next_order(a):
    """The next permutation of ``a`` in lexicographic order, in place; False after the
    last (``itertools.permutations``' order from ascending)."""
    i = a.size - 2
    while i >= 0 and a[i] >= a[i + 1]:
        i -= 1
    if i < 0:
        return False
    j = a.size - 1
    while a[j] <= a[i]:
        j -= 1
    a[i], a[j] = a[j], a[i]
    lo, hi = i + 1, a.size - 1
    while lo < hi:  # a[i + 1:] reversed
        a[lo], a[hi] = a[hi], a[lo]
        lo, hi = lo + 1, hi - 1
    return True


@njit(cache=True)
def after_resets(model, events, mask, x, d, accuracy):
    """``(ok, x_after)``: the resets of ``events`` (ascending) from ``x``, and that every
    order of them (groups of up to ``ORDERS_CHECKED``; else also descending) gives a
    state within ``accuracy`` (max norm) of it
    (:func:`bderiv.models.events.crossings.apply_resets`)."""
    ok, first = _reset_in_order(model, events, mask, x, d)
    if not ok:
        return False, x
    order = events.copy()
    more = _next_order(order) if events.size <= ORDERS_CHECKED else events.size > 1
    if events.size > ORDERS_CHECKED:
        order = events[::-1].copy()
    while more:
        ok, y = _reset_in_order(model, order, mask, x, d)
        if not ok:
            return False, x
        gap = 0.0  # max |y - first| (both finite: checked)
        for i in range(d):
            gap = max(gap, abs(y[i] - first[i]))
        if not gap <= accuracy:
            return False, x
        more = events.size <= ORDERS_CHECKED and _next_order(order)
    return True, first


@njit(cache=True)
def landing(model, jac_mode, event_jac_mode, sign, group, mask, new, x_after, window, n, d):
    """``(ok, mask after)``: where the group's events landed after their resets
    (:func:`bderiv.models.events.crossings.landing`, and its refusal of a jump across
    another surface); not ok for a refusal or a failed check (``jac_mode``: how the field
    Jacobian is had, for a plastic landing's :func:`_held`)."""
    h = np.empty(n)
    if call_events(model, np.bool_(False), x_after, n, h, np.empty(d)) != OK:
        return False, new
    for k in range(n):
        h[k] *= sign[k]
        if not group[k] and h[k] > window[k]:
            return False, new
    ok, J = event_jacobian(model, event_jac_mode, x_after, n, d)
    if not ok:
        return False, new
    fs, F = checked_field(model, x_after, new, d)
    if fs != OK:
        return False, new
    Dh, rate = np.empty((n, d)), np.empty(n)
    local_rates(sign, J, F, Dh, rate)
    kept = np.int64(0)
    for k in range(n):
        if not group[k] or h[k] > window[k]:
            continue
        bit = np.int64(1) << k
        if h[k] >= -window[k]:  # on the surface: the flow after the reset decides
            if clearly_positive(Dh[k], F):  # moves on: contact continues
                continue
            fs, back = checked_field(model, x_after, new ^ bit, d)
            if fs != OK:
                return False, new
            if not clearly_positive(-Dh[k], F):  # stops on the surface (plastic)
                if not _held(model, jac_mode, x_after, new, new ^ bit, F, back, d):
                    return False, new
                continue
            if not clearly_positive(-Dh[k], back):
                return False, new
        kept |= bit
    if kept:  # some bounced: checked in the region the state goes on in
        fs, F = checked_field(model, x_after, new ^ kept, d)
        if fs != OK or first_sent_back(group, h, window, kept, Dh, F) >= 0:
            return False, new  # handed back: the Python loop words the refusal
    return True, new ^ kept


@njit(cache=True)
def _held(model, jac_mode, x, far, near, F_far, F_near, d):
    """Whether region ``far`` holds a state ``x`` stopped on a surface
    (:func:`bderiv.models.events.crossings.holds`); False also on a failed check."""
    J_far, J_near = np.empty((d, d)), np.empty((d, d))
    if jacobian(model, jac_mode, x, far, d, J_far) != OK or \
            jacobian(model, jac_mode, x, near, d, J_near) != OK:
        return False
    return not same_flow(F_near, F_far, J_near, J_far)
