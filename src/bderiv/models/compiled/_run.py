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
function). What this function records is then exactly what the Python loop would have,
the samples at given times (``t_eval``) included: each on the dense output of the stretch
that holds it.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from ..._numerics import (
    MIN_RTOL,
    REFINE_FACTOR,
    RESET_MISMATCH,
)
from ._dop853 import dense_rows, step_starts
from ._integrate import EVENT, FINISHED, N_STEPS, room
from ._model import drive_at
from ._rhs import (
    OK,
    call_events,
    checked_field,
)
from ._stops import after_resets, event_jacobian, landing, plain_screen
from .rules import (
    GROUP,
    NEAR,
    UNDECIDED,
    carried_across,
    classify,
    first_grazing,
    local_rates,
    reads_across,
    state_error,
    windows,
    wrong_side,
)

#: the run ended (final time or the section) / the next stretch is the Python loop's
ENDED = 0
HANDOFF = 1
@njit(cache=True)
def _integrated(model, jac_mode, event_jac_mode, variational, with_section, n, d, t, x, mask,
                sign, scale, err, t_final, rtol, atol, max_step, simultaneity_tol, budget):
    """A stretch from ``(t, x)`` in region ``mask`` at these tolerances (``atol`` (m,): the
    driver's), screened, and its stop examined (:func:`bderiv.models.events.locate.settle`'s
    ``decide``): ``(ok, status, steps, t_end, y_end, ts, ys, J, grown, err, first, h, F,
    Dh, rate, window, codes, dense, Fd)``, ``first`` the located crossing (the lowest index
    of the earliest root; ``n`` the section, -1 none), the stop's values (local
    orientation) when it is an event's, the driver's dense record (its steps' start times
    and sizes, their coefficients) last. Not ok: the
    stretch is the Python loop's."""
    m = d * (d + 1) if variational else d
    h, F, rate, window = np.zeros(n), np.zeros(d), np.zeros(n), np.zeros(n)
    Dh, codes = np.zeros((n, d)), np.zeros(n, dtype=np.int64)
    y0 = np.zeros(m)
    for i in range(d):
        y0[i] = x[i]
    if variational:
        for i in range(d):
            y0[d + i * d + i] = 1.0
    forced = n if with_section and t == 0.0 else -1
    # the driver through its address (:func:`._model.drive_at`: its code not linked in
    # here), with the types it is compiled for from Python
    status, t_end, y_end, ts, ys, steps, Fd, _, roots, counts, _, _, _, gs = drive_at(
        model.driver, (model, jac_mode, variational, with_section, n + with_section, mask, d,
                       t, y0, t_final, rtol, atol, max_step, np.float64(0.0), forced,
                       np.bool_(True), budget, np.bool_(True)))
    grown, err_new, first = scale.copy(), np.empty(d), -1
    fail = (False, status, counts[N_STEPS], t_end, y_end, ts, ys, Dh, grown, err_new, first,
            h, F, Dh, rate, window, codes, steps, Fd)
    if status != EVENT and status != FINISHED:
        return fail
    x_end = y_end[:d].copy()
    ok, J = event_jacobian(model, event_jac_mode, x_end, n, d)
    if not ok or not plain_screen(model, event_jac_mode, sign, mask, n, d, ts, ys, gs, steps,
                                   Fd, J, atol[0], rtol):
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
            F, Dh, rate, window, codes, steps, Fd)


@njit(cache=True)
def _differ(a, b, bits):
    """Whether some entries of ``a`` and ``b`` (int64 codes) differ in a bit of ``bits``
    (``b`` = 0: some entry of ``a`` has one set). Element loops in the compiled run: each
    array expression compiles a kernel of its own."""
    for k in range(a.size):
        if (a[k] ^ b[k]) & bits:
            return True
    return False


@njit(cache=True)
def _holds(masks, mask):
    """Whether ``mask`` is one of ``masks``."""
    for k in range(masks.size):
        if masks[k] == mask:
            return True
    return False


@njit(cache=True)
def start_region(model, x, n, d):
    """The region of a run's start ``x``: bit k set where ``events(x)[k] > 0``; -1 when
    ``x`` is on a surface or the events fail their check (the Python loop says which)."""
    h = np.empty(n)
    if call_events(model, np.bool_(False), x, n, h, np.empty(d)) != OK:
        return np.int64(-1)
    mask = np.int64(0)
    for k in range(n):
        if h[k] == 0.0:
            return np.int64(-1)
        if h[k] > 0.0:
            mask |= np.int64(1) << k
    return mask


@njit(cache=True)
def _carried(model, event_jac_mode, x, mask, h, window, skip, n, d):
    """Whether :func:`.rules.carried_across` finds an event at ``x`` in region ``mask`` (or
    a call fails: the Python loop says why)."""
    ok, J = event_jacobian(model, event_jac_mode, x, n, d)
    status, F = checked_field(model, x, mask, d)
    return not ok or status != OK or carried_across(h, mask, window, skip, J, F) >= 0


@njit(cache=True)
def _sample(times, taken, sampled, end, last, dense, Fd, ys, d, mask, S, SM):
    """The next of ``times`` on a recorded stretch (before its ``end``; up to it when
    ``last``), on its dense output, into rows ``sampled``... of ``S`` and ``SM``: the rows
    now filled."""
    first = taken + sampled
    stop = first
    while stop < times.size and (times[stop] < end or (last and times[stop] == end)):
        stop += 1
    if stop > first:
        t_old, h, y_old = step_starts(dense, ys, d)
        dense_rows(t_old, h, Fd, y_old, times[first:stop], S[sampled:sampled + stop - first])
        for i in range(sampled, sampled + stop - first):
            SM[i] = mask
    return sampled + stop - first


@njit(cache=True, nogil=True)
def run_stretches(model, jac_mode, event_jac_mode, variational, with_section, with_resets,
                  n, d, t, x, mask, scale, err,
                  t_final, rtol, atol, max_step, simultaneity_tol, all_checked, checked,
                  groups_left, budget, times, times_taken):
    """The run's stretches from ``(t, x)`` in region ``mask`` while the stops are plain
    (the event Jacobian by ``event_jac_mode``, not ``EVENT_JAC_NONE``).

    ``mask`` -1: the run's start, its region from the signs of the events
    (:func:`start_region`; still -1 when the Python loop must say why not);
    ``scale``, ``err`` (d,): the largest ``|x_i|`` so far and the error bound carried into
    the stretch; ``atol`` (m,): the driver's, one per integrated component; ``checked``
    (int64 masks): the regions whose field Jacobian is checked (``variational``, unless
    ``all_checked``; a region outside them is handed back); ``groups_left``: the groups
    the run may still switch; ``budget``: accepted steps before handing back (Ctrl-C);
    ``times`` (ascending; empty: none), ``times_taken``: the times to sample and how many of
    them are sampled already (each on the dense output of the recorded stretch that holds
    it, as :meth:`bderiv.models.integrate.record.RunLog.sample` takes them).

    Returns
    -------
    code : int
        ``ENDED`` or ``HANDOFF``.
    returned : bool
        The run ended at the section.
    t, mask : float, int
        The run's time and region after the recorded stretches.
    now : ndarray, shape (3, d)
        Its state, ``scale`` and ``err`` there.
    T, X, M : ndarray, shapes (N,), (N, d), (N,)
        Their samples and masks (as ``Trajectory``'s).
    L : ndarray, shape (S, d, d)
        Their sensitivities at their ends (``variational``).
    group_t : ndarray, shape (G,)
        Their event groups' times.
    group_masks : ndarray, shape (G, 3), int64
        Each group's events (bits), mask before and mask after.
    group_x : ndarray, shape (G, 2, d)
        Each group's state, and after its resets (``with_resets``: the model's ``reset``).
    group_J : ndarray, shape (G, n, d)
        The event Jacobian at each group's state (``variational``).
    S, SM : ndarray, shapes (k,  d), (k,)
        The states at the next ``k`` of ``times`` and their masks.
    steps : int
        Accepted steps taken, the stretch handed back included.
    """
    T = np.empty(64)
    X = np.empty((64, d))
    M = np.empty(64, dtype=np.int64)
    left = times.size - times_taken
    S, SM, sampled = np.empty((left, d)), np.empty(left, dtype=np.int64), np.int64(0)
    L = np.empty((8 if variational else 0, d, d))
    group_t = np.empty(8)
    group_masks = np.empty((8, 3), dtype=np.int64)
    group_x = np.empty((8, 2, d))
    group_J = np.empty((8 if variational else 0, n, d))
    count, stretches, groups, steps = np.int64(0), np.int64(0), np.int64(0), np.int64(0)
    sign, none = np.empty(n), np.zeros(n, dtype=np.int64)
    code, returned = HANDOFF, False
    if mask < 0:
        mask = start_region(model, x, n, d)
    while mask >= 0:
        if variational and not all_checked and not _holds(checked, mask):
            break
        for k in range(n):
            sign[k] = -1.0 if mask >> k & 1 else 1.0
        ok, status, taken, t_end, y_end, ts, ys, J, grown, err_new, first, h, F, Dh, rate, \
            window, codes, dense, Fd = _integrated(model, jac_mode, event_jac_mode, variational,
                                        with_section, n, d, t, x, mask, sign, scale, err,
                                        t_final, rtol, atol, max_step, simultaneity_tol,
                                        budget - steps)
        steps += taken
        if not ok:
            break
        event = 0 <= first < n
        if event and variational and _differ(codes, none, np.int64(UNDECIDED)):
            # locate.settle: the state alone integrated again, tighter, until the events
            # at the stop are decided or rtol is at its floor; the stretch integrated once
            # more at those tolerances when that changed the group
            f_rtol, f_atol, decided, now = rtol, atol[0], True, codes
            while ok and decided and _differ(now, none, np.int64(UNDECIDED)) and \
                    f_rtol > MIN_RTOL:
                f_rtol, f_atol = max(f_rtol / REFINE_FACTOR, MIN_RTOL), f_atol / REFINE_FACTOR
                ok, _, taken, _, _, _, _, _, _, _, at, _, _, _, _, _, now, _, _ = _integrated(
                    model, jac_mode, event_jac_mode, np.bool_(False), with_section, n, d, t, x,
                    mask, sign, scale, err, t_final, f_rtol, np.full(d, f_atol), max_step,
                    simultaneity_tol, budget - steps)
                steps += taken
                decided = 0 <= at < n
            if not ok:
                break
            if not (decided and not _differ(now, codes, np.int64(GROUP | NEAR))):
                ok, status, taken, t_end, y_end, ts, ys, J, grown, err_new, first, h, F, Dh, \
                    rate, window, codes, dense, Fd = _integrated(
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
            group, events, size = np.zeros(n, dtype=np.bool_), np.empty(n, dtype=np.int64), 0
            for k in range(n):  # the group's flags, bits and events (ascending)
                if codes[k] & GROUP:
                    group[k], events[size] = True, k
                    bits |= np.int64(1) << k
                    size += 1
            if first_grazing(group, Dh, F) >= 0:
                break
            new, x_after = mask ^ bits, x_end
            if with_resets:
                largest = err_new[0]
                for i in range(d):
                    largest = max(largest, err_new[i])
                ok, x_after = after_resets(model, events[:size], mask, x_end, d,
                                            RESET_MISMATCH * largest)
                if ok:
                    ok, new = landing(model, jac_mode, event_jac_mode, sign, group, mask,
                                      new, x_after, window, n, d)
            else:  # every event lands on the far side, and must move on
                fs, F_new = checked_field(model, x_end, new, d)
                ok = fs == OK and first_grazing(group, Dh, F_new) < 0
            if not ok or groups >= groups_left:
                break
            # every event on the side its bit says, or within its window of the surface
            # (sides.check_sides): else the Python loop words the broken invariant
            h_after = np.empty(n)
            if with_resets:
                ok = call_events(model, np.bool_(False), x_after, n, h_after,
                                 np.empty(d)) == OK
            else:
                for k in range(n):
                    h_after[k] = sign[k] * h[k]  # exact: the values at x_end
            if not ok or wrong_side(h_after, new, window) >= 0:
                break
            # an event a rounding across, carried further across at once: the Python loop
            # refuses it (sides.check_carried)
            if reads_across(h_after, new, window, bits) and _carried(
                    model, event_jac_mode, x_after, new, h_after, window, bits, n, d):
                break
        # the stretch is the Python loop's too: recorded
        need = count + ts.size
        T, X, M = room(T, need), room(X, need), room(M, need)
        for r in range(ts.size):
            T[count + r] = ts[r]
            for i in range(d):
                X[count + r, i] = ys[r, i]
            M[count + r] = mask
        count += ts.size
        if sampled < left:
            # the section's return and the final time end the run: their time is sampled
            last = not event or (status == EVENT and first == n)
            sampled = _sample(times, times_taken, sampled, t_end, last, dense, Fd, ys, d, mask,
                              S, SM)
        if variational:
            L = room(L, stretches + 1)
            for i in range(d):
                for j in range(d):
                    L[stretches, i, j] = ys[ts.size - 1, d + i * d + j]
        stretches += 1
        t, x, scale, err = t_end, x_end, grown, err_new
        if status == EVENT and first == n:  # the return to the section
            code, returned = ENDED, True
            break
        if not event:
            code = ENDED
            break
        group_t, group_masks = room(group_t, groups + 1), room(group_masks, groups + 1)
        group_x = room(group_x, groups + 1)
        group_t[groups] = t
        group_masks[groups, 0], group_masks[groups, 1], group_masks[groups, 2] = \
            bits, mask, new
        for i in range(d):
            group_x[groups, 0, i], group_x[groups, 1, i] = x[i], x_after[i]
        if variational:
            group_J = room(group_J, groups + 1)
            for k in range(n):
                for i in range(d):
                    group_J[groups, k, i] = J[k, i]
        groups += 1
        mask, x = new, x_after
        if t >= t_final:
            code = ENDED
            break
    now = np.empty((3, d))  # few arrays: boxing each costs Python about 0.6 us
    for i in range(d):
        now[0, i], now[1, i], now[2, i] = x[i], scale[i], err[i]
    return (code, returned, t, mask, now, T[:count], X[:count], M[:count], L[:stretches],
            group_t[:groups], group_masks[:groups], group_x[:groups], group_J[:groups],
            S[:sampled], SM[:sampled], steps)
