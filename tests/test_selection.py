"""The selection's steps (``_kernels/selection.py``), on hand-made rows: the tie rule, the
direction, retired events, and the move of g."""

from __future__ import annotations

import numpy as np

from bderiv._kernels.selection import advance, earliest, exclude, pending_times, retire


def test_earliest_breaks_ties_to_the_smaller_event_both_ways():
    tau = np.array([[3.0, 1.0, 2.0, 1.0, 5.0],
                    [3.0, 1.0, 5.0, 2.0, 5.0]])
    assert earliest(tau, 0, False) == (1, 1.0)  # events 1 and 3 tie: 1
    assert earliest(tau, 1, True) == (2, 5.0)  # going backwards the latest, 2 before 4


def test_a_retired_event_is_never_selected_again():
    g = np.array([[-1.0, -1.0, -1.0]])
    rates = np.array([[1.0, 2.0, 4.0]])
    tau = np.empty((1, 3))
    order = []
    for _ in range(3):  # forwards: times 1, 0.5, 0.25 -> events 2, 1, 0
        pending_times(g, 0, rates, 0, tau)
        k, t = earliest(tau, 0, False)
        retire(g, 0, k, False)
        order.append((k, t))
    assert order == [(2, 0.25), (1, 0.5), (0, 1.0)]
    g[0] = [2.0, 1.0, 3.0]
    for k in range(3):
        retire(g, 0, k, True)
    pending_times(g, 0, rates, 0, tau)
    assert (tau == -np.inf).all()  # backwards a retired event's time is -inf


def test_advance_moves_g_by_the_time_times_the_rate_jump():
    g = np.array([[0.0, -1.0], [5.0, 5.0]])
    rates = np.array([[1.0, 2.0], [3.0, 0.5]])
    advance(g, 0, 0.5, rates, 0, 1)
    np.testing.assert_array_equal(g, [[0.5 * (1.0 - 3.0), -1.0 + 0.5 * (2.0 - 0.5)],
                                      [5.0, 5.0]])


def test_an_excluded_event_is_not_selected_whatever_the_sign_of_its_rate():
    """After a bounce the rate of an event that happened may be negative: excluding its
    time (not its g) keeps it out of the selection both ways."""
    g = np.array([[-1.0, 1.0, -1.0]])
    rates = np.array([[1.0, -0.5, 2.0]])  # event 1 happened and bounced
    tau = np.empty((1, 3))
    pending_times(g, 0, rates, 0, tau)
    assert tau[0, 1] == 2.0  # would be the latest backwards, were it a candidate
    exclude(tau, 0, 1, True)
    assert earliest(tau, 0, True) == (0, 1.0)
    pending_times(g, 0, rates, 0, tau)
    tau[0, 1] = -tau[0, 1]  # the earliest forwards, were it a candidate
    exclude(tau, 0, 1, False)
    assert earliest(tau, 0, False) == (2, 0.5)
