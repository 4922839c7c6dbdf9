"""Python models of more than 63 events: their region masks are Python ints, which an
int64 does not hold (bit 63 is its sign). Runs, flow maps, bounces and the functions that
take masks from the caller read them whole; numba functions, which take an int64 mask,
are refused for such a model when it is made. Oracles: closed forms, and the same model
with its inactive events left out."""

from __future__ import annotations

import numpy as np
import pytest


def test_events_beyond_bit_63_cross_and_their_flow_map_is_the_closed_form():
    """Events 64 and 65 at once, then 66, of a Python model of 70 events: the run
    recorded its masks as int64 and raised a raw OverflowError at the first of them (and
    the group's masks too). Closed form: s' = 1 crosses the levels, y' = 1 + the number
    of those three events that happened, so that at T = 2 from (0, 0)
    y = 0.5 * 1 + 0.5 * 3 + 1 * 4 = 6, and the flow's derivative is [[1, 0], [4 - 1, 1]]
    (each crossing earlier by ds: dy = (a_before - a_after) * -ds, summed)."""
    from bderiv import HybridSystem

    n = 70
    levels = np.full(n, 10.0)
    levels[[64, 65, 66]] = [0.5, 0.5, 1.0]

    def field(x, mask):
        return np.array([1.0, 1.0 + bin(int(mask) >> 64).count("1")])

    model = HybridSystem(field, lambda x: x[0] - levels, n_events=n, dim=2,
                         event_jacobian=lambda x: np.outer(np.ones(n), [1.0, 0.0]),
                         field_jacobian=lambda x, mask: np.zeros((2, 2)))
    run = model.simulate(np.zeros(2), 2.0)
    final = (1 << 64) | (1 << 65) | (1 << 66)
    assert run.mask_final == final
    assert run.masks.dtype == object and run.masks[0] == 0 and run.masks[-1] == final
    assert run.x_final == pytest.approx([2.0, 6.0], rel=1e-9)
    assert [g.events for g in run.groups] == [(64, 65), (66,)]
    D = model.flow_bderivative(np.zeros(2), 2.0)
    assert D(np.eye(2)) == pytest.approx(np.array([[1.0, 3.0], [0.0, 1.0]]), abs=1e-8)
    many = model.simulate_many(np.zeros((2, 2)), 2.0)
    assert many.mask_final.tolist() == [final, final]


def test_a_bounce_on_event_66_is_the_one_event_balls():
    """A bounce keeps its event's bit (the state is sent back): its mask went to a rule
    as an int64 and overflowed for bit 66. The ball with the floor as its event 66 (the
    other 69 far below) runs as the ball of one event: the same state, region and flow
    map."""
    from bderiv import HybridSystem
    from bderiv.examples import bouncing_ball

    n, floor = 70, 66
    one = bouncing_ball(e=0.8).system
    below = np.full(n, 100.0)
    below[floor] = 0.0
    wide = HybridSystem(
        one.field, lambda x: -x[0] - below, n_events=n, dim=2,
        event_jacobian=lambda x: np.outer(np.ones(n), [-1.0, 0.0]),
        field_jacobian=lambda x, mask: np.array([[0.0, 1.0], [0.0, 0.0]]),
        reset=lambda x, mask, k: np.array([x[0], -0.8 * x[1]]),
        reset_jacobian=lambda x, mask, k: np.array([[1.0, 0.0], [0.0, -0.8]]))
    x0, t = np.array([1.0, 0.0]), 0.55
    a, b = one.simulate(x0, t), wide.simulate(x0, t)
    assert [g.events for g in b.groups] == [(floor,)]
    assert (b.mask_final, a.mask_final) == (0, 0)  # the bounce kept both bits clear
    assert b.x_final == pytest.approx(a.x_final, rel=1e-12)
    V = np.eye(2)
    assert wide.flow_bderivative(x0, t)(V) == pytest.approx(
        one.flow_bderivative(x0, t)(V), rel=1e-9)


def _wide_model(n=70):
    """A Python model of ``n`` events whose field reads bits 63, 64 and 65 of the mask."""
    from bderiv import HybridSystem

    def field(x, mask):
        mask = int(mask)
        rate = 1.0 + (mask >> 64 & 1) + 10 * (mask >> 65 & 1) + 100 * (mask >> 63 & 1)
        return np.array([1.0, rate])

    return HybridSystem(field, lambda x: x[0] - np.full(n, 10.0), n_events=n, dim=2,
                        field_jacobian=lambda x, mask: np.zeros((2, 2)))


def test_masks_beyond_bit_63_given_by_the_caller_are_read_whole():
    """check_jacobians(masks=) and sample_corners cast the masks to int64 first: an
    OverflowError for a Python int beyond 2**63, and a uint64 mask with bit 63 set read
    as negative, every bit from 63 up set (a silent wrong field; a review)."""
    import bderiv

    model, x = _wide_model(), np.zeros(2)
    top = (1 << 63) | 1
    F = model.calls.sample_corners(x, np.array([top], dtype=np.uint64))
    assert F.tolist() == [[1.0, 101.0]]
    assert model.calls.sample_corners(x, [1 << 64, 1 << 65, 0]).tolist() == [
        [1.0, 2.0], [1.0, 11.0], [1.0, 1.0]]
    assert bderiv.check_jacobians(model, x, masks=[1 << 64, top]).passed
    for bad in ([1 << 70], [-1]):
        with pytest.raises(ValueError, match=r"mask.* must be in \[0, 2\*\*70\)"):
            model.calls.sample_corners(x, bad)
        with pytest.raises(ValueError, match=r"mask.* must be in \[0, 2\*\*70\)"):
            bderiv.check_jacobians(model, x, masks=bad)
    with pytest.raises(TypeError, match=r"masks\[0\] must be an integer, got float"):
        model.calls.sample_corners(x, [1.5])
    with pytest.raises(ValueError, match=r"the fields of all 2\*\*70 regions .*pass masks="):
        model.calls.sample_corners(x)


def test_all_events_at_once_beyond_memory_are_refused_by_name():
    """bderivative(rho) of 64 events needs the fields of 2**64 regions: numpy's "Maximum
    allowed dimension exceeded" before (and a MemoryError at n = 30)."""
    from bderiv import HybridSystem

    n = 64
    model = HybridSystem(lambda x, mask: np.array([1.0, 1.0]),
                         lambda x: x[0] - np.full(n, 0.5), n_events=n, dim=2,
                         event_jacobian=lambda x: np.outer(np.ones(n), [1.0, 0.0]),
                         field_jacobian=lambda x, mask: np.zeros((2, 2)))
    with pytest.raises(ValueError, match=r"corner tables of 64 events at once .* more than "
                                         r"the memory limit"):
        model.bderivative(np.array([0.5, 0.0]))


def test_numba_functions_of_more_than_63_events_are_refused_when_the_model_is_made():
    """Their first second on Python ran them (the compiled integrator refused the model
    later), and with use_compiled=False numba raised a raw OverflowError at the first
    crossing of event 63 (a review)."""
    from numba import njit

    from bderiv import HybridSystem

    levels = np.full(70, 1000.0)

    @njit
    def field(x, mask):
        return np.array([1.0, 1.0 + ((mask >> 62) & 1)])

    @njit
    def events(x):
        return x[0] - levels

    for use_compiled in (True, False):
        with pytest.raises(ValueError, match=r"n_events=70, but field is numba-compiled.*"
                                             r"int64, which holds 63 events"):
            HybridSystem(field, events, n_events=70, dim=2, use_compiled=use_compiled)
    HybridSystem(field, events, n_events=63, dim=2)  # 63 fit


def test_masks_mixed_of_signed_and_unsigned_integers_are_integers():
    """numpy makes a list of int64 and uint64 values float64: each mask was then refused
    as a float (a review)."""
    from bderiv import HybridSystem

    small = HybridSystem(lambda x, mask: np.array([1.0, 1.0 + mask]), lambda x: x[:1],
                         n_events=2, dim=2, field_jacobian=lambda x, mask: np.zeros((2, 2)))
    x = np.zeros(2)
    assert small.calls.sample_corners(x, [np.uint64(1), 2]).tolist() == [[1.0, 2.0],
                                                                          [1.0, 3.0]]
    wide = _wide_model()
    assert wide.calls.sample_corners(x, [np.uint64(1 << 63), 5]).tolist() == [
        [1.0, 101.0], [1.0, 1.0]]
    with pytest.raises(ValueError, match=r"^masks\[1\] must be in \[0, 2\*\*70\), got -1"):
        wide.calls.sample_corners(x, [0, -1])
    with pytest.raises(TypeError, match=r"^masks\[0\] must be an integer, got float"):
        small.calls.sample_corners(x, [1.0])


def test_a_numba_reset_guard_is_refused_too():
    """reset_guard(x, mask, k) takes the mask as well: a numba one passed the check and
    raised numba's "Int value is too large" at the first bounce (a review)."""
    from numba import njit

    from bderiv import HybridSystem

    @njit
    def guard(x, mask, k):
        return None

    n = 70
    with pytest.raises(ValueError, match=r"n_events=70, but reset_guard is numba-compiled"):
        HybridSystem(lambda x, mask: np.array([x[1], -9.81]), lambda x: -x[0] - np.zeros(n),
                     n_events=n, dim=2, reset=lambda x, mask, k: np.array([x[0], -x[1]]),
                     reset_guard=guard)

