"""A run's stretches and stops in compiled code, as long as every stop is a plain one.

:func:`run_stretches` repeats, in one compiled call, what the run loop of
:func:`bderiv.models.integrate.run.run` does for each stretch of a compiled model: the
driver integrates the region to the final time or the first crossing, the excursion
screen samples the dense output, the stop is examined (state error, rates, windows,
classes; undecided events of a derivative settled by integrating again, tighter, as
:func:`bderiv.models.events.locate.settle` does) and the group switched after its
transversality checks (compiled resets applied, where they land decided), all by the
rules of :mod:`.rules` that the Python stop logic calls too, on the same values, so the
bits are the same. A stop that needs more is handed back: the function returns the run's
state before that stretch, and the Python loop integrates the stretch and decides its stop
(a peak to search inside a step, a return across a surface, a refusal to word, a region
whose field Jacobian is not yet checked, a full step budget, a failed check of a user
function). What this function records is then exactly what the Python loop would have.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from ..._limits import (
    COMPLEX_STEP,
    FINE_REACH,
    FINE_SAMPLES,
    MIN_RTOL,
    ORDERS_CHECKED,
    REACH,
    REFINE_FACTOR,
    RESET_MISMATCH,
)
from ._dop853 import dense_rows
from ._integrate import EVENT, FINISHED, N_STEPS, drive_stretch, room
from ._rhs import (
    OK,
    all_finite,
    argument,
    call_events,
    checked_field,
    coordinate_scale,
    events_rows,
    finite_vector,
)
from .rules import (
    GROUP,
    NEAR,
    UNDECIDED,
    classify,
    clearly_positive,
    first_grazing,
    linspace,
    local_rates,
    peak_rows,
    return_sample,
    sample_times,
    state_error,
    tolerances,
    windows,
)

#: the run ended (final time or the section) / the next stretch is the Python loop's
ENDED = 0
HANDOFF = 1
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
        J = model.event_jacobian(argument(model, x))
        if J.shape[0] != n or J.shape[1] != d:
            return False, np.zeros((n, d))
        J = np.ascontiguousarray(J).copy()
    else:
        base = argument(model, x)
        z = np.empty(base.size, dtype=np.complex128)
        J = np.empty((n, d))
        for j in range(d):
            h = COMPLEX_STEP * coordinate_scale(x[j])
            z[:] = base
            z[j] = complex(x[j], h)
            v = model.cevents(z)
            if v.size != n:
                return False, J
            for k in range(n):
                J[k, j] = v[k].imag / h
    return all_finite(J), J


@njit(cache=True)
def _plain_screen(model, event_jac_mode, sign, mask, n, d, ts, ys, steps, Fd, J, atol, rtol):
    """Whether the excursion screen finds nothing to search on the stretch
    (:func:`bderiv.models.events.excursions._earliest_lost` up to its search: no sampled
    peak that could reach a surface once its bracket is sampled finer and its ends decided
    by the rates there, no return across a surface); False also on a failed check."""
    count, last = ts.size, 2 * ts.size - 2
    times = np.empty(last + 1)
    sample_times(ts, times)
    t_old, h_step = np.ascontiguousarray(steps[:, 0]), np.ascontiguousarray(steps[:, 1])
    y_old = np.ascontiguousarray(ys[:-1, :d])
    states = np.empty((times.size, d))
    dense_rows(t_old, h_step, Fd, y_old, times, states)
    H = np.empty((times.size, n))
    if events_rows(model, states, n, H, np.zeros(d)) != OK:
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
    if return_sample(H, tol) >= 0:
        return False
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
    fine, X = np.empty(FINE_SAMPLES), np.empty((FINE_SAMPLES, d))
    V, G = np.empty((FINE_SAMPLES, 1)), np.empty((FINE_SAMPLES, n))
    for b in range(rows.shape[0]):
        k, i = rows[b, 0], rows[b, 1]
        lo, hi = max(i - 1, 0), min(i + 1, last)
        linspace(times[lo], times[hi], fine)
        dense_rows(t_old, h_step, Fd, y_old, fine, X)
        if events_rows(model, X, n, G, np.zeros(d)) != OK:
            return False
        for r in range(FINE_SAMPLES):
            V[r, 0] = sign[k] * G[r, k]
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
        y = model.reset(argument(model, y), b, k)
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
    a[i + 1:] = a[i + 1:][::-1].copy()
    return True


@njit(cache=True)
def _after_resets(model, events, mask, x, d, accuracy):
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
        if not ok or not np.abs(y - first).max() <= accuracy:
            return False, x
        more = events.size <= ORDERS_CHECKED and _next_order(order)
    return True, first


@njit(cache=True)
def _landing(model, event_jac_mode, sign, group, mask, new, x_after, window, n, d):
    """``(ok, mask after)``: where the group's events landed after their resets
    (:func:`bderiv.models.events.crossings.landing`, and its refusal of a jump across
    another surface); not ok for a refusal or a failed check."""
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
        dh = -Dh[k]
        if h[k] >= -window[k]:  # on the surface: the flow after the reset decides
            if not clearly_positive(dh, F):
                continue
            fs, back = checked_field(model, x_after, new ^ (np.int64(1) << k), d)
            if fs != OK or not clearly_positive(dh, back):
                return False, new
        kept |= np.int64(1) << k
    return True, new ^ kept


@njit(cache=True)
def _integrated(model, jac_mode, event_jac_mode, variational, with_section, n, d, t, x, mask,
                sign, scale, err, t_final, rtol, atol, max_step, simultaneity_tol, budget):
    """A stretch from ``(t, x)`` in region ``mask`` at these tolerances (``atol`` (m,): the
    driver's), screened, and its stop examined (:func:`bderiv.models.events.locate.settle`'s
    ``decide``): ``(ok, status, steps, t_end, y_end, ts, ys, J, grown, err, first, h, F,
    Dh, rate, window, codes)``, ``first`` the located crossing (the lowest index of the
    earliest root; ``n`` the section, -1 none), the stop's values (local orientation) when
    it is an event's. Not ok: the stretch is the Python loop's."""
    m = d * (d + 1) if variational else d
    h, F, rate, window = np.zeros(n), np.zeros(d), np.zeros(n), np.zeros(n)
    Dh, codes = np.zeros((n, d)), np.zeros(n, dtype=np.int64)
    y0 = np.zeros(m)
    y0[:d] = x
    if variational:
        for i in range(d):
            y0[d + i * d + i] = 1.0
    forced = n if with_section and t == 0.0 else -1
    # no literal arguments: a callee is compiled again for each literal type it meets
    status, t_end, y_end, ts, ys, steps, Fd, _, roots, counts, _, _, _ = \
        drive_stretch(model, jac_mode, variational, with_section, n + with_section, mask, d, t,
                      y0, t_final, rtol, atol, max_step, np.float64(0.0), forced, budget,
                      np.bool_(True))
    grown, err_new, first = scale.copy(), np.empty(d), -1
    fail = (False, status, counts[N_STEPS], t_end, y_end, ts, ys, Dh, grown, err_new, first,
            h, F, Dh, rate, window, codes)
    if status != EVENT and status != FINISHED:
        return fail
    x_end = y_end[:d].copy()
    ok, J = event_jacobian(model, event_jac_mode, x_end, n, d)
    if not ok or not _plain_screen(model, event_jac_mode, sign, mask, n, d, ts, ys, steps, Fd,
                                   J, atol[0], rtol):
        return fail
    for r in range(ts.size):
        for i in range(d):
            grown[i] = max(grown[i], abs(ys[r, i]))
    state_error(atol[0], rtol, grown, err, err_new)
    if status == EVENT:
        for k in range(n + with_section):
            if roots[k] == t_end:
                first = k
                break
    if 0 <= first < n:
        if call_events(model, np.bool_(False), x_end, n, h, np.empty(d)) != OK:
            return fail
        fs, F = checked_field(model, x_end, mask, d)
        if fs != OK:
            return fail
        local_rates(sign, J, F, Dh, rate)
        for k in range(n):
            h[k] *= sign[k]
        fired = np.zeros(n, dtype=np.bool_)
        fired[first] = True
        windows(Dh, rate, err_new, fired, window)
        classify(h, rate, window, fired, simultaneity_tol, codes)
    return (True, status, counts[N_STEPS], t_end, y_end, ts, ys, J, grown, err_new, first, h,
            F, Dh, rate, window, codes)


@njit(cache=True, nogil=True)
def run_stretches(model, jac_mode, event_jac_mode, variational, with_section, with_resets,
                  n, d, t, x, mask, scale, err,
                  t_final, rtol, atol, max_step, simultaneity_tol, all_checked, checked,
                  groups_left, budget):
    """The run's stretches from ``(t, x)`` in region ``mask`` while the stops are plain
    (the event Jacobian by ``event_jac_mode``, not ``EVENT_JAC_NONE``).

    ``scale``, ``err`` (d,): the largest ``|x_i|`` so far and the error bound carried into
    the stretch; ``atol`` (m,): the driver's, one per integrated component; ``checked``
    (int64 masks): the regions whose field Jacobian is checked (``variational``, unless
    ``all_checked``; a region outside them is handed back); ``groups_left``: the groups
    the run may still switch; ``budget``: accepted steps before handing back (Ctrl-C).

    Returns
    -------
    code : int
        ``ENDED`` or ``HANDOFF``.
    returned : bool
        The run ended at the section.
    t, x, mask, scale, err
        The run's state after the recorded stretches.
    T, X, M : ndarray, shapes (N,), (N, d), (N,)
        Their samples and masks (as ``Trajectory``'s).
    L : ndarray, shape (S, d, d)
        Their sensitivities at their ends (``variational``).
    group_t, group_bits, mask_before, mask_after : ndarray, shape (G,)
        Their event groups: time, events (bits), masks.
    group_x, group_x_after : ndarray, shape (G, d)
        Each group's state, and after its resets (``with_resets``: the model's ``reset``).
    group_J : ndarray, shape (G, n, d)
        The event Jacobian at each group's state (``variational``).
    steps : int
        Accepted steps taken, the stretch handed back included.
    """
    T = np.empty(64)
    X = np.empty((64, d))
    M = np.empty(64, dtype=np.int64)
    L = np.empty((8 if variational else 0, d, d))
    group_t = np.empty(8)
    group_bits = np.empty(8, dtype=np.int64)
    mask_before = np.empty(8, dtype=np.int64)
    mask_after = np.empty(8, dtype=np.int64)
    group_x = np.empty((8, d))
    group_x_after = np.empty((8, d))
    group_J = np.empty((8 if variational else 0, n, d))
    count, stretches, groups, steps = np.int64(0), np.int64(0), np.int64(0), np.int64(0)
    sign = np.empty(n)
    code, returned = HANDOFF, False
    while True:
        if variational and not all_checked and not (checked == mask).any():
            break
        for k in range(n):
            sign[k] = -1.0 if mask >> k & 1 else 1.0
        ok, status, taken, t_end, y_end, ts, ys, J, grown, err_new, first, h, F, Dh, rate, \
            window, codes = _integrated(model, jac_mode, event_jac_mode, variational,
                                        with_section, n, d, t, x, mask, sign, scale, err,
                                        t_final, rtol, atol, max_step, simultaneity_tol,
                                        budget - steps)
        steps += taken
        if not ok:
            break
        event = 0 <= first < n
        if event and variational and (codes & UNDECIDED).any():
            # locate.settle: the state alone integrated again, tighter, until the events
            # at the stop are decided or rtol is at its floor; the stretch integrated once
            # more at those tolerances when that changed the group
            f_rtol, f_atol, decided, now = rtol, atol[0], True, codes
            while ok and decided and (now & UNDECIDED).any() and f_rtol > MIN_RTOL:
                f_rtol, f_atol = max(f_rtol / REFINE_FACTOR, MIN_RTOL), f_atol / REFINE_FACTOR
                ok, _, taken, _, _, _, _, _, _, _, at, _, _, _, _, _, now = _integrated(
                    model, jac_mode, event_jac_mode, np.bool_(False), with_section, n, d, t, x,
                    mask, sign, scale, err, t_final, f_rtol, np.full(d, f_atol), max_step,
                    simultaneity_tol, budget - steps)
                steps += taken
                decided = 0 <= at < n
            if not ok:
                break
            kept = (GROUP | NEAR)
            if not (decided and ((now & kept) == (codes & kept)).all()):
                ok, status, taken, t_end, y_end, ts, ys, J, grown, err_new, first, h, F, Dh, \
                    rate, window, codes = _integrated(
                        model, jac_mode, event_jac_mode, variational, with_section, n, d, t, x,
                        mask, sign, scale, err, t_final, f_rtol, np.full(atol.size, f_atol),
                        max_step, simultaneity_tol, budget - steps)
                steps += taken
                if not ok:
                    break
                event = 0 <= first < n
        x_end = y_end[:d].copy()
        new, x_after, bits = mask, x_end, np.int64(0)
        if event:
            if (codes & NEAR).any():
                break
            group = (codes & GROUP) != 0
            if first_grazing(group, Dh, F) >= 0:
                break
            for k in range(n):
                if group[k]:
                    bits |= np.int64(1) << k
            new, x_after = mask ^ bits, x_end
            if with_resets:
                events = np.flatnonzero(group)
                ok, x_after = _after_resets(model, events, mask, x_end, d,
                                            RESET_MISMATCH * err_new.max())
                if ok:
                    ok, new = _landing(model, event_jac_mode, sign, group, mask, new,
                                       x_after, window, n, d)
            else:  # every event lands on the far side, and must move on
                fs, F_new = checked_field(model, x_end, new, d)
                ok = fs == OK and first_grazing(group, Dh, F_new) < 0
            if not ok or groups >= groups_left:
                break
        # the stretch is the Python loop's too: recorded
        need = count + ts.size
        T, X, M = room(T, need), room(X, need), room(M, need)
        for r in range(ts.size):
            T[count + r] = ts[r]
            X[count + r] = ys[r, :d]
            M[count + r] = mask
        count += ts.size
        if variational:
            L = room(L, stretches + 1)
            L[stretches] = ys[-1, d:].reshape((d, d))
        stretches += 1
        t, x, scale, err = t_end, x_end, grown, err_new
        if status == EVENT and first == n:  # the return to the section
            code, returned = ENDED, True
            break
        if not event:
            code = ENDED
            break
        group_t, group_bits = room(group_t, groups + 1), room(group_bits, groups + 1)
        mask_before, mask_after = room(mask_before, groups + 1), room(mask_after, groups + 1)
        group_x, group_x_after = room(group_x, groups + 1), room(group_x_after, groups + 1)
        group_t[groups], group_bits[groups] = t, bits
        mask_before[groups], mask_after[groups] = mask, new
        group_x[groups], group_x_after[groups] = x, x_after
        if variational:
            group_J = room(group_J, groups + 1)
            group_J[groups] = J
        groups += 1
        mask, x = new, x_after
        if t >= t_final:
            code = ENDED
            break
    return (code, returned, t, x, mask, scale, err, T[:count], X[:count], M[:count],
            L[:stretches], group_t[:groups], group_bits[:groups], mask_before[:groups],
            mask_after[:groups], group_x[:groups], group_x_after[:groups], group_J[:groups],
            steps)
