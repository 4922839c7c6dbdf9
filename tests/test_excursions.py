"""Surfaces crossed and crossed back inside one solver step (issue 27 item 7a).

The model: an oscillator ``q'' = -q`` of amplitude 1 that grazes ``q = C`` (C = 0.999);
while ``q > C`` a force -2 acts. Each excursion above the surface lasts about 0.03, less
than one DOP853 step at the default tolerances, so an integrator that compares signs at
step ends sees none of them. The oracle is the closed-form flow: in either region the
motion is a rotation at unit angular speed about ``(c, 0)`` in the ``(q, p)`` plane
(c = 0 before the surface, c = -2 beyond it), and the crossing times solve
``c + R cos(t - psi) = C``.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from bderiv import HybridSystem
from bderiv.examples import pronking
from bderiv.models.events import excursions
from bderiv.models.events.excursions import REACH, peak_brackets, peak_of, sample_times

C = 0.999
T = 30.0
X0 = np.array([0.0, 1.0, 0.0])


def oscillator(level=C, flipped=False):
    """The model; ``flipped`` writes the event as ``C - q`` (the excursion is then a
    downward crossing and back, bit set before it)."""
    s = -1.0 if flipped else 1.0

    def field(x, mask):
        beyond = bool(mask & 1) != flipped  # q > level
        return np.array([x[1], -x[0] - (2.0 if beyond else 0.0), 1.0])

    return HybridSystem(
        field,
        lambda x: np.array([s * (x[0] - level)]),
        n_events=1,
        dim=3,
        field_jacobian=lambda x, mask: np.array([[0.0, 1, 0], [-1, 0, 0], [0, 0, 0]]),
        event_jacobian=lambda x: np.array([[s, 0.0, 0.0]]),
    )


def _rotate(q, p, c, t):
    """The flow of ``q'' = -(q - c)`` for time t."""
    u = q - c
    return c + u * math.cos(t) + p * math.sin(t), -u * math.sin(t) + p * math.cos(t)


def _next_crossing(q, p, c, upward):
    """The first time > 0 at which the rotation about (c, 0) from (q, p) meets q = C
    going up (p > 0) or down (p < 0); inf if it never does."""
    u = q - c
    R = math.hypot(u, p)
    if R <= abs(C - c):
        return math.inf
    psi = math.atan2(p, u)
    alpha = math.acos((C - c) / R)
    times = []
    for base in (psi + alpha, psi - alpha):
        t = base % (2 * math.pi)
        pt = -u * math.sin(t) + p * math.cos(t)
        if t > 1e-12 and (pt > 0) == upward:
            times.append(t)
    return min(times, default=math.inf)


def closed_form(x0, t_final):
    """The exact flow ``(q, p, z)`` at t_final, and the crossing times."""
    q, p, z = (float(v) for v in x0)
    t, beyond, log = 0.0, q > C, []
    while True:
        c = -2.0 if beyond else 0.0
        dt = _next_crossing(q, p, c, upward=not beyond)
        if t + dt >= t_final:
            q, p = _rotate(q, p, c, t_final - t)
            return np.array([q, p, z + t_final]), log
        q, p = _rotate(q, p, c, dt)
        q = C  # exactly on the surface (rounding of the rotation)
        t += dt
        log.append(t)
        beyond = not beyond


def test_the_oracle_is_the_flow():
    # the closed form against a tightly stepped integration of the same field (the
    # excursions resolved by max_step): the oracle itself is right
    x, log = closed_form(X0, T)
    traj = oscillator().simulate(X0, T, max_step=0.005)
    assert len(log) == len(traj.events) == 10
    np.testing.assert_allclose([r.time for r in traj.events], log, atol=1e-8)
    np.testing.assert_allclose(traj.x_final, x, atol=1e-8)


@pytest.mark.parametrize("flipped", [False, True])
def test_simulate_finds_every_excursion(flipped):
    x, log = closed_form(X0, T)
    traj = oscillator(flipped=flipped).simulate(X0, T)
    times = [r.time for r in traj.events]
    assert len(times) == 10, times
    np.testing.assert_allclose(times, log, atol=1e-8)
    np.testing.assert_allclose(traj.x_final, x, atol=1e-8)
    up = -1 if flipped else 1  # the first crossing of each pair enters q > C
    assert [r.direction for r in traj.events] == [up, -up] * 5


def test_flow_bderivative_converges_to_the_closed_form():
    D = oscillator().flow_bderivative(X0, T)
    assert D.n_groups == 10
    V = np.eye(3)
    DV = D(V)
    base, _ = closed_form(X0, T)
    errors = []
    for eps in (1e-5, 1e-6):
        fd = np.array([(closed_form(X0 + eps * v, T)[0] - base) / eps for v in V])
        errors.append(np.abs(DV - fd).max() / np.abs(fd).max())
    # one-sided differences of the exact flow: error proportional to eps
    assert errors[1] < 2e-3, errors
    assert errors[1] < 0.2 * errors[0], errors


def test_a_graze_within_the_accuracy_is_refused():
    # the oscillator's top is the surface itself: whether it crosses is undecidable
    with pytest.raises(ValueError, match=r"event 0 comes within the integration accuracy .*"
                                         r"cannot be decided"):
        oscillator(level=1.0).simulate(X0, 3.0)


def test_a_peak_clearly_below_the_surface_is_no_event():
    traj = oscillator(level=1.0 + 1e-6).simulate(X0, T)
    assert traj.events == ()
    np.testing.assert_allclose(traj.x_final[:2], [math.sin(T), math.cos(T)], atol=1e-8)


def test_sample_times_interleave_midpoints():
    np.testing.assert_array_equal(sample_times(np.array([0.0, 2.0, 3.0])),
                                  [0.0, 1.0, 2.0, 2.5, 3.0])


def test_peak_brackets():
    tol = np.array([1e-9, 1e-9])
    t = np.linspace(-0.5, 0.5, 7)
    h = np.column_stack((np.cos(t) - 0.999, -np.ones(7)))  # the top at sample 3
    assert peak_brackets(h, tol) == [(0, 2, 4)]
    # the far one (-1 everywhere) is flat: each sample is a local maximum, none reaches 0
    # within REACH times its spread; shifted to -tol it does
    assert peak_brackets(np.column_stack((h[:, 0] - 1.0, h[:, 1])), tol) == []
    flat = np.full((3, 1), -1e-9)
    assert peak_brackets(flat, tol[:1]) == [(0, 0, 1), (0, 0, 2), (0, 1, 2)]
    # a peak that rises above its neighbours by less than the reach is still searched
    spread = 1e-3
    top = -REACH * spread + spread / 2  # could rise by REACH * spread: to spread / 2 > 0
    v = np.array([[top - spread], [top], [top - spread]])
    assert peak_brackets(v, np.zeros(1)) == [(0, 0, 2)]
    assert peak_brackets(v - spread, np.zeros(1)) == []
    assert peak_brackets(v, np.zeros(1), reach=0.4) == []  # the finer screen's reach
    # an end of the samples is a candidate (its neighbour is lower) ...
    ends = np.array([[0.0], [-1e-3], [-2e-3], [-1e-3], [-1e-13]])
    assert peak_brackets(ends, np.array([1e-12])) == [(0, 0, 1), (0, 3, 4)]
    # ... but not at the surface when they span a stretch: the switch and the stop
    assert peak_brackets(ends, np.array([1e-12]), stretch=True) == []
    assert peak_brackets(ends - 1e-9, np.array([1e-12]), stretch=True) == [(0, 0, 1),
                                                                           (0, 3, 4)]


def numpy_peak_brackets(h, tol, stretch=False, reach=REACH):
    """The screen's rule in array operations (the oracle of the compiled loop): a sample
    not lower than its neighbours whose value plus ``reach`` times its drop to the lower
    neighbour reaches ``-tol``; with ``stretch`` the ends only below ``-tol``."""
    m, n = h.shape
    if m < 2:
        return []
    edge = np.full((1, n), -np.inf)
    left, right = np.concatenate((edge, h[:-1])), np.concatenate((h[1:], edge))
    low = np.minimum(np.where(np.isfinite(left), left, right),
                     np.where(np.isfinite(right), right, left))
    peak = (h >= left) & (h >= right) & (h + reach * (h - low) >= -tol)
    if stretch:
        peak[[0, -1]] &= h[[0, -1]] < -tol
    ks, rows = np.nonzero(peak.T)
    out = [(int(k), max(int(i) - 1, 0), min(int(i) + 1, m - 1))
           for k, i in zip(ks, rows, strict=True)]
    return sorted(out, key=lambda b: (b[1], b[0]))


@pytest.mark.parametrize("seed", range(6))
def test_peak_brackets_follow_the_rule_on_random_samples(seed):
    rng = np.random.default_rng(seed)
    m, n = rng.integers(2, 40), rng.integers(1, 6)
    h = -np.abs(rng.standard_normal((m, n))) * 10.0 ** rng.integers(-9, 1, size=n)
    h[rng.random((m, n)) < 0.2] = 0.0  # samples on a surface, ties between neighbours
    h[:, 0] = np.round(h[:, 0], 1)  # flat stretches
    tol = 10.0 ** rng.integers(-12, -2, size=n)
    for stretch in (False, True):
        for reach in (REACH, 1.0, 0.0):
            assert peak_brackets(h, tol, stretch=stretch, reach=reach) == \
                numpy_peak_brackets(h, tol, stretch, reach)
    assert peak_brackets(h[:1], tol) == []


def test_peak_of_finds_the_top_and_the_ends():
    t, v = peak_of(lambda s: math.cos(s) - 0.999, -0.3, 0.2)
    assert abs(t) < 1e-7 and v == pytest.approx(0.001, abs=1e-14)
    assert peak_of(lambda s: s, 0.0, 1.0) == (1.0, 1.0)  # monotone: the end


# --- brackets at the ends of a stretch ---------------------------------------------------
# The screen leaves a bracket at an end of a stretch unsearched when the event rises into
# the end (or leaves the start): its one peak is that end. These check that a crossing lost
# right at an end is still found (the rate points the other way), and that the rule saves
# the searches that found nothing.

STOP, T_END = 1.0, 1.1


def clock_model(a, w, scale, push=1.0):
    """``z' = 1``, ``y' = V`` while event 1's bit is set; event 0 is ``z = STOP``, event 1
    is ``(w^2 - (z - a)^2) / scale^2 + push y``: along the clock it rises above 0 at
    ``a - w`` and, without the push of ``y``, falls back at ``a + w``: an excursion of
    width ``2 w``. With the push it stays across (``V`` exceeds its fall rate until
    ``T_END``), so the closed form is: event 1 at ``a - w``, event 0 at STOP, ``y(T_END) =
    V (T_END - a + w)``; without (``V = 1``), event 1 at ``a -+ w`` and ``y(T_END) = 2 w``."""
    K = 1.0 / scale**2
    V = 2.0 * K * (T_END - a) + 1.0 if push else 1.0

    def field(x, mask):
        return np.array([1.0, V if mask >> 1 & 1 else 0.0])

    return HybridSystem(
        field,
        lambda x: np.array([x[0] - STOP, K * (w * w - (x[0] - a) ** 2) + push * x[1]]),
        n_events=2,
        dim=2,
        field_jacobian=lambda x, mask: np.zeros((2, 2)),
        event_jacobian=lambda x: np.array([[1.0, 0.0], [-2.0 * K * (x[0] - a), push]]),
    ), V


def steps_around_the_stop():
    """The step ends just before and just after the stop at STOP (the solver's steps do
    not depend on the events: the same in every run of :func:`clock_model`)."""
    far, _ = clock_model(-10.0, 1.0, 1.0)
    traj = far.simulate(np.zeros(2), T_END, simultaneity_tol=1e-12)
    t_stop = traj.events[0].time
    return traj.t[traj.t < t_stop][-1], t_stop, traj.t[traj.t > t_stop][0]


@pytest.mark.parametrize("end", ["stop", "start"])
def test_an_excursion_next_to_an_end_of_a_stretch_is_found(end):
    # the excursion lies inside the finer screen's bracket at the end of the stretch that
    # the stop ends ("stop"; the event falls into the stop) or at the start of the next
    # one ("start"; it rises from the start): the sampled maximum is that end, and the
    # peak is inside the bracket, invisible to the samples and the step ends
    before, t_stop, after = steps_around_the_stop()
    if end == "stop":
        delta = 0.5 * (t_stop - before) / 16  # the finer screen's spacing
        a = t_stop - 0.3 * delta
    else:
        delta = 0.5 * (after - t_stop) / 16
        a = t_stop + 0.3 * delta
    w = 0.2 * delta
    system, V = clock_model(a, w, delta)
    traj = system.simulate(np.zeros(2), T_END, simultaneity_tol=1e-12)
    expected = sorted([(a - w, 1), (STOP, 0)])
    assert [r.event for r in traj.events] == [k for _, k in expected]
    np.testing.assert_allclose([r.time for r in traj.events], [t for t, _ in expected],
                               rtol=0, atol=1e-9)
    np.testing.assert_allclose(traj.x_final, [T_END, V * (T_END - a + w)], rtol=1e-9)


def test_a_return_within_the_first_step_after_a_found_crossing_is_found():
    # the excursion of the "stop" case above, falling back before the stop: once its
    # crossing is located, the next stretch starts on the surface and its first step
    # spans the return. The located root may sit a rounding on the side it came from
    # (here it does: the bit says across, the value not), so both ends of that step read
    # across and the return showed only as the event across at the stop, switched there
    # 2.4e-3 late (y 25 % off); the samples show it below the surface in between
    before, t_stop, _ = steps_around_the_stop()
    delta = 0.5 * (t_stop - before) / 16
    a, w = t_stop - 0.3 * delta, 0.2 * delta
    system, V = clock_model(a, w, delta, push=0.0)
    traj = system.simulate(np.zeros(2), T_END, simultaneity_tol=1e-12)
    assert [(r.event, r.direction) for r in traj.events] == [(1, 1), (1, -1), (0, 1)]
    np.testing.assert_allclose([r.time for r in traj.events], [a - w, a + w, STOP],
                               rtol=0, atol=1e-9)
    assert V == 1.0
    np.testing.assert_allclose(traj.x_final, [T_END, 2 * w], rtol=1e-9)


def test_a_return_is_a_sample_below_the_surface_before_one_across():
    tol = np.array([1e-9, 1e-9])
    h = np.array([[1e-17, -1.0], [-1e-3, -0.5], [-2e-3, -0.2], [5e-3, -0.1]])
    assert excursions._return(h, tol) == 2  # the lowest sample before the return
    assert excursions._return(h[:, ::-1], tol[::-1]) == 2
    assert excursions._return(h[[0, 3]], tol) is None  # across at once: no sample below
    assert excursions._return(h[:3], tol) is None  # never back across
    assert excursions._return(h - 1e-2, tol) is None
    # across by less than tol (a rounding): no return
    assert excursions._return(np.array([[0.0], [-1e-3], [1e-10]]), tol[:1]) is None


class _UnknownRates(excursions._EndRates):
    """The rates at a stretch's ends unknown (NaN): every bracket is searched, as the
    screen did before it read them."""

    def _rate(self, model, x):
        return np.full(self.sign.size, np.nan)


def test_an_event_rising_into_a_stop_is_not_searched(monkeypatch):
    # the feet of a tilted pronking body land and lift off one by one: at each stop the
    # other foot's event rises into it (or leaves the previous stop), its samples' maximum
    # at the end. The search found those ends and left them to the switching rule; the
    # rates there say so at once: the same run, without a search and its evaluations.
    ex = pronking(legs=2)
    x0 = ex.x0 + np.array([0.0, 1e-5, 0.0, 0.0])  # the feet 3.5-4.5 us apart
    searches, evaluations = [], []
    real_peak_of, real_events = excursions.peak_of, ex.system.calls.eval_events
    monkeypatch.setattr(excursions, "peak_of",
                        lambda *args: searches.append(args[1:]) or real_peak_of(*args))
    monkeypatch.setattr(ex.system.calls, "eval_events",
                        lambda x: evaluations.append(1) or real_events(x))

    def run():
        searches.clear(), evaluations.clear()
        traj = ex.system.simulate(x0, 0.5, simultaneity_tol=1e-12)
        return traj, len(searches), len(evaluations)

    traj, n_searches, n_evaluations = run()
    assert n_searches == 0
    monkeypatch.setattr(excursions, "_EndRates", _UnknownRates)
    before, n_before, n_evaluations_before = run()
    assert [len(g.events) for g in traj.groups] == [1, 1, 1, 1]
    assert n_before >= 2  # 4: one at each stop, for the other foot
    assert n_evaluations_before - n_evaluations >= 20 * n_before  # a search: ~25 calls
    assert [(r.time, r.event) for r in before.events] == \
        [(r.time, r.event) for r in traj.events]
    np.testing.assert_array_equal(before.x_final, traj.x_final)
