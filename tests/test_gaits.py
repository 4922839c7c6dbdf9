"""Gaits (issue 12): return maps, periodic orbits, stability of a piecewise-linear map.

Oracles: closed forms (the square spiral's return map, a rotating PL map's growth rate),
finite differences of the Poincare map computed by event-detecting simulation, and
independent long simulations of the nonlinear system.
"""

from __future__ import annotations

import ctypes
import gc
import itertools
import pickle
import tracemalloc

import numpy as np
import pytest
from reference import ref_apply
from scipy.integrate import solve_ivp
from test_recurring import square_spiral

from bderiv.analysis.checks import decay_check, fd_check
from bderiv.analysis.flowmap import FlowBDerivative
from bderiv.analysis.newton import MAX_PIECE_SWITCHES, newton_step
from bderiv.analysis.orbit import PeriodicOrbit
from bderiv.analysis.returnmap import ReturnMap
from bderiv.analysis.stability import Stability, growth_rate, piece_multipliers
from bderiv.analysis.system import HybridSystem
from bderiv.engine.bderivative import BDerivative
from bderiv.examples import gaits


def diagonal(x):
    """The section x_1 - x_0 = 0, crossed upward in the quadrant x > 0 of the spiral."""
    return x[1] - x[0]


def spiral_period(a, c):
    """Return time of the square spiral from (c, c) back to the diagonal (closed form)."""
    y = c * (1 + a)  # where it crosses x_0 = 0 downward, after time c
    return c + y * (1 + a + a**2) + a**3 * y / (1 + a)


# ------------------------------------------------------------------------------------------
# return maps
# ------------------------------------------------------------------------------------------
@pytest.mark.parametrize("a", [1.0, 0.9, 1.2])
def test_spiral_return_map_closed_form(a):
    # constant fields and surfaces through the origin: P(x) = a^4 x on the diagonal, and a
    # shift along the flow F = (-1, a) does not move P: DP = a^4 (I - F n^T / (n . F))
    s, c = square_spiral(a), 0.7
    x0 = np.array([c, c])
    traj = s.simulate(x0, 50.0, section=diagonal)
    np.testing.assert_allclose(traj.x_final, a**4 * x0, rtol=1e-9)
    assert traj.t[-1] == pytest.approx(spiral_period(a, c), rel=1e-9)
    assert [g.directions for g in traj.groups] == [(-1,), (-1,), (1,), (1,)]
    R = s.return_map(x0, diagonal)
    assert isinstance(R, ReturnMap) and isinstance(R, FlowBDerivative)
    assert R.period == pytest.approx(spiral_period(a, c), rel=1e-9) and R.n_groups == 4
    F, n = np.array([-1.0, a]), np.array([-1.0, 1.0])
    expected = a**4 * (np.eye(2) - np.outer(F, n) / (n @ F))
    V = np.random.default_rng(0).standard_normal((5, 2))
    np.testing.assert_allclose(R(V), V @ expected.T, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(R.piece(), expected, rtol=1e-9, atol=1e-9)
    # the inverse on the section: tangent vectors (1, 1) t come back
    T = np.outer(np.linspace(-1, 1, 5), [1.0, 1.0])
    np.testing.assert_allclose(R.inverse(R(T)), T, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(R.tangent_basis[:, 0] ** 2, [0.5, 0.5])


def test_spiral_return_map_matches_finite_differences_of_the_poincare_map():
    s, x0 = square_spiral(1.1), np.array([0.7, 0.7])
    R = s.return_map(x0, diagonal)
    V = np.array([[1.0, 1.0], [-1.0, -1.0], [1.0, 0.0], [0.3, -0.5]])
    check = fd_check(s, x0, 50.0, V, R(V), eps=(1e-4, 1e-5), section=diagonal)
    assert max(check.max_errors) < 1e-6  # exactly piecewise linear: no O(eps) term


def test_return_map_refuses_bad_sections():
    s = square_spiral(1.0)
    with pytest.raises(ValueError, match=r"x0 is not on the section: section\(x0\) = 0.1"):
        s.return_map(np.array([0.6, 0.7]), diagonal)
    with pytest.raises(ValueError, match=r"cross the section upward and transversally, but "
                       r"at x0 \(t=0\) the rate of section\(x\) is -2"):
        s.return_map(np.array([0.7, 0.7]), lambda x: x[0] - x[1])
    with pytest.raises(ValueError, match=r"did not return to the section \(upward\) before "
                       r"t=1"):
        s.return_map(np.array([0.7, 0.7]), diagonal, t_max=1.0)
    with pytest.raises(ValueError, match=r"section\(x\) must return one real number, got "
                       r"shape \(2,\)"):
        s.return_map(np.array([0.7, 0.7]), lambda x: x)
    with pytest.raises(TypeError, match="section must be callable"):
        s.return_map(np.array([0.7, 0.7]), "x0")
    with pytest.raises(ValueError, match="t_max must be a finite number > 0"):
        s.return_map(np.array([0.7, 0.7]), diagonal, t_max=-1.0)
    with pytest.raises(ValueError, match=r"section_gradient\(x\) must return an array of "
                       r"shape \(2,\)"):
        s.return_map(np.array([0.7, 0.7]), diagonal, section_gradient=lambda x: np.ones(3))


def test_event_group_at_the_section_is_refused():
    # start on the section x_1 = 2 just 1e-8 (in time) before crossing x_0 = 0 downward
    s = square_spiral(1.0)
    with pytest.raises(ValueError, match=r"event group \(0,\) at t=1e-08 is within "
                       r"simultaneity_tol=1e-07 of the section"):
        s.return_map(np.array([1e-8, 2.0]), lambda x: x[1] - 2.0)


# ------------------------------------------------------------------------------------------
# the growth rate of a piecewise-linear map
# ------------------------------------------------------------------------------------------
def rotating_pl_map(a, b, c, d):
    """The PL map sending e_x -> a e_y -> -ab e_x ... quadrant to quadrant (linear on each).

    Its fourth power is ``abcd * I`` (worked by hand), so its growth rate is
    ``(abcd)^(1/4)``; the piece on the first quadrant, ``[[0, -b], [a, 0]]``, has
    spectral radius ``sqrt(ab)``.
    """
    pieces = {  # (x >= 0, y >= 0) -> matrix
        (True, True): np.array([[0.0, -b], [a, 0.0]]),
        (False, True): np.array([[0.0, -b], [c, 0.0]]),
        (False, False): np.array([[0.0, -d], [c, 0.0]]),
        (True, False): np.array([[0.0, -d], [a, 0.0]]),
    }

    def fmap(V):
        out = np.empty_like(V)
        for i, v in enumerate(V):
            out[i] = pieces[(bool(v[0] >= 0), bool(v[1] >= 0))] @ v
        return out

    return fmap, pieces


def test_growth_rate_closed_form_and_pieces_do_not_decide():
    fmap, pieces = rotating_pl_map(2.0, 2.0, 0.25, 0.25)
    V0 = np.random.default_rng(0).standard_normal((50, 2))
    rates, spread, visits = growth_rate(fmap, V0, iterations=802, burn_in=2)
    # the log-growth oscillates with period 4 about the slope: the fit's error is
    # O(1 / window) = O(1e-3 / 800) here
    np.testing.assert_allclose(rates, 0.25**0.25, rtol=1e-4)
    assert visits == {}
    # one piece has spectral radius 2, yet the map is stable
    radii = [np.abs(piece_multipliers(M, np.eye(2))).max() for M in pieces.values()]
    assert max(radii) == pytest.approx(2.0) and rates.max() < 1
    # an unstable one: abcd = 4
    rates, _, _ = growth_rate(rotating_pl_map(2.0, 2.0, 1.0, 1.0)[0], V0, 802, 2)
    np.testing.assert_allclose(rates, 2.0**0.5, rtol=1e-4)


@pytest.mark.parametrize("sizes", [(2, 3), (8, 8), (9, 9, 9)])  # the last: rows sorted
def test_visits_count_every_piece_of_the_batch(sizes):
    """The pieces visited are counted as a tally of the rows' tuples does it, whether
    they are coded as one int64 a row or sorted as rows (beyond 2**62 codes)."""
    from collections import Counter

    from bderiv.analysis.stability import _Visits

    rng = np.random.default_rng(sum(sizes))
    orders = [np.argsort(rng.integers(0, 2, (500, n)), axis=1, kind="stable")
              for n in sizes]
    tally = _Visits()
    tally.add(orders)
    tally.add([o[:7] for o in orders])  # a second batch adds to the counts
    visits = tally.result()
    want = Counter(tuple(tuple(int(k) for k in o[i]) for o in orders) for i in range(500))
    want.update(tuple(tuple(int(k) for k in o[i]) for o in orders) for i in range(7))
    assert visits == dict(want) and len(visits) > 2


def test_growth_rate_validation():
    fmap = rotating_pl_map(1.0, 1.0, 1.0, 1.0)[0]
    V0 = np.ones((3, 2))
    # one message for every count below 2 (0 said ">= 1", 1 said ">= 2"; a review)
    for bad in (1, 0, -3):
        with pytest.raises(ValueError, match=rf"iterations must be an integer >= 2, got {bad}$"):
            growth_rate(fmap, V0, iterations=bad)
    with pytest.raises(TypeError, match=r"iterations must be an integer >= 2, got float 2.0"):
        growth_rate(fmap, V0, iterations=2.0)
    # a burn-in of 1.5 was silently 1
    with pytest.raises(TypeError, match=r"burn_in must be an integer in \[0, iterations - 2 = "
                       r"8\] \(or None: iterations // 4\), got float 1.5"):
        growth_rate(fmap, V0, iterations=10, burn_in=1.5)
    with pytest.raises(ValueError, match=r"burn_in must be an integer in \[0, iterations - 2 = "
                       r"8\] \(or None: iterations // 4\), got 9"):
        growth_rate(fmap, V0, iterations=10, burn_in=9)
    with pytest.raises(ValueError, match="V0 must have no zero row, but row 1 is zero"):
        growth_rate(fmap, np.array([[1.0, 0.0], [0.0, 0.0]]))
    with pytest.raises(ValueError, match=r"V0 must have 2 dimensions|V0 must be"):
        growth_rate(fmap, np.ones(2))
    # a direction mapped to 0 has rate 0, the others go on
    rates, spread, _ = growth_rate(lambda V: V * [0.5, 0.0], np.array([[1.0, 0.0], [0.0, 1.0]]),
                                   iterations=8)
    np.testing.assert_allclose(rates, [0.5, 0.0])
    assert np.isfinite(spread).all()


# ------------------------------------------------------------------------------------------
# the pronking gait: orbit, return map, stability, against simulation
# ------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def gait(pronking_gait):
    return pronking_gait  # tests/conftest.py: found once per process


def vertical_hop_apex(ex_params, z_apex):
    """The next apex height of the symmetric hop, computed apart from the package: free
    fall to touchdown and rise from lift-off in closed form, the stance (both legs,
    theta = 0) by scipy's solve_ivp of the 1-D equation. Also returns the period."""
    K, C, gain, v_ref, kappa, leg = ex_params
    g = 9.81
    t_fall = np.sqrt(2 * (z_apex - leg) / g)

    def stance(t, y):
        z, v = y
        f = -K * (z - leg) - C * v + gain * (1 + kappa) * (1 - v**2 / v_ref**2) * v
        return [v, -g + 2 * f]

    def lift_off(t, y):
        return y[0] - leg

    lift_off.terminal, lift_off.direction = True, 1
    sol = solve_ivp(stance, (0, 5), [leg - 1e-14, -g * t_fall], events=lift_off,
                    rtol=1e-12, atol=1e-14, method="DOP853")
    v_up = sol.y_events[0][0][1]
    return leg + v_up**2 / (2 * g), t_fall + sol.t_events[0][0] + v_up / g


def test_orbit_converges_and_is_confirmed_by_an_independent_simulation(gait):
    ex, orb = gait
    assert isinstance(orb, PeriodicOrbit)
    res = [h.residual for h in orb.history]
    assert res[-1] < 1e-10 and orb.residual < 1e-10
    assert all(b < 10 * a**2 for a, b in zip(res, res[1:], strict=False))  # quadratic
    # the symmetric pronking orbit: level, not pitching, at the apex
    np.testing.assert_allclose(orb.x0[1:], 0.0, atol=1e-10)
    z_next, period = vertical_hop_apex((400.0, 2.0, 4.0, 2.0, 0.5, 0.5), orb.x0[0])
    assert z_next == pytest.approx(orb.x0[0], abs=1e-9)
    assert orb.period == pytest.approx(period, rel=1e-9)
    # both legs touch down together, then lift off together
    groups = orb.trajectory.groups
    assert [(g.events, g.directions) for g in groups] == [((0, 1), (1, 1)),
                                                          ((0, 1), (-1, -1))]
    assert [bd.n_events for bd in orb.return_map.jumps] == [2, 2]
    # a different integrator agrees on P(x0) = x0
    radau = ex.system.simulate(orb.x0, 3.0, section=gaits.apex_section, method="Radau",
                               rtol=1e-11, atol=1e-13)
    np.testing.assert_allclose(radau.x_final, orb.x0, atol=1e-8)


def _random_event_map(rng, n, d):
    """A BDerivative with random transversal tables (positive rates, mask-dependent)."""
    Dh = np.linalg.qr(rng.standard_normal((d, n)))[0].T  # orthonormal rows
    F0 = Dh.T @ np.ones(n)  # every rate 1 in region 0
    F = F0 + 0.3 * rng.uniform(-1, 1, (1 << n, d)) / np.sqrt(d)  # rates in [0.7, 1.3]
    return BDerivative(Dh, F), Dh, F


@pytest.mark.parametrize("n, groups", [(3, 1), (8, 2)])
def test_pl_newton_step_solves_the_equation_without_listing_pieces(n, groups):
    # two groups of 8 events: (8!)^2 = 1.6e9 pieces, which the old solver listed; the step
    # must land on the exact solution delta* of r + A(delta) - delta = 0, n . delta = -s
    # (A evaluated by the plain reference, tests/reference.py, not by the kernels)
    rng = np.random.default_rng(n)
    d = n + 2
    maps = [_random_event_map(rng, n, d) for _ in range(groups)]
    Ls = [np.eye(d) + 0.2 * rng.standard_normal((d, d)) / np.sqrt(d)
          for _ in range(groups + 1)]
    # a contraction, as the return map of a stable gait: every I - A_piece then has a
    # positive determinant, so the PL equation has exactly one solution
    V = rng.standard_normal((4000, d))
    lipschitz = (np.linalg.norm(FlowBDerivative(Ls, [m[0] for m in maps])(V), axis=1)
                 / np.linalg.norm(V, axis=1)).max()
    Ls[-1] *= 0.5 / lipschitz
    R = FlowBDerivative(Ls, [m[0] for m in maps])

    def A(v):
        v = Ls[0] @ v
        for (_, Dh, F), L in zip(maps, Ls[1:], strict=True):
            v = L @ ref_apply(Dh, F, v)
        return v

    moved = 0
    for _ in range(5):
        delta_star = rng.standard_normal(d)
        normal = rng.standard_normal(d)
        r = delta_star - A(delta_star)
        delta, piece, switches = newton_step(R, r, normal, -normal @ delta_star)
        assert np.abs(r + A(delta) - delta).max() < 1e-12
        np.testing.assert_allclose(delta, delta_star, rtol=1e-9, atol=1e-9)
        assert [sorted(o) for o in piece] == [list(range(n))] * groups
        assert switches < MAX_PIECE_SWITCHES
        moved += switches
    assert moved > 0  # the start piece (that of -r) was not always the solution's


def test_newton_solves_the_piecewise_linear_equation_on_the_symmetric_subspace():
    # an exactly symmetric guess: the events of every iterate are simultaneous, and the
    # Newton steps come from the PL equation of groups of two events
    orb = gaits.pronking_orbit(perturbation=(0.05, 0.0, 0.0, 0.0))
    assert any(len(h.piece) == 2 and len(h.piece[0]) == 2 for h in orb.history)
    assert orb.residual < 1e-10


def test_return_map_matches_finite_differences_through_every_piece(gait):
    ex, orb = gait
    R = orb.return_map
    W = np.random.default_rng(1).standard_normal((20000, 4)) @ R.tangent_basis @ \
        R.tangent_basis.T
    td, lo = R.orders(W)
    V = [W[np.flatnonzero((td[:, 0] == i) & (lo[:, 0] == j))[0]] for i in (0, 1)
         for j in (0, 1)]  # one direction in each of the four pieces
    V = np.array(V) / np.linalg.norm(V, axis=1)[:, None]
    check = fd_check(ex.system, orb.x0, 3.0, V, R(V), eps=(1e-4, 1e-5, 1e-6),
                     section=gaits.apex_section)
    assert check.max_errors[-1] < 1e-4
    assert check.first_order(), check.ratios


def test_too_few_iterations_give_no_verdict(gait):
    """Two iterations of the stable pronk's return map (its rate 0.7785) estimate 3.7 from
    a transient, its halves 3.1 apart in log-rate: no verdict (it said "unstable")."""
    ex, orb = gait
    st = orb.stability(n_directions=200, iterations=2)
    assert st.growth_rate > 1 and st.spread > abs(np.log(st.growth_rate))
    assert st.stable is None and st.verdict_word == "undecided"
    assert st.summary().startswith(f"growth rate {st.growth_rate:.6g} (undecided: the "
                                   f"estimate has not settled in 2 iterations, pass more")


def test_no_short_window_calls_the_stable_pronk_unstable(gait):
    """Five iterations put the stable pronk's rate (0.7785: 1000 iterations below, and the
    simulations) at 1.107 with halves of two iterations agreeing by chance (spread 0.09
    against |log 1.107| = 0.10: "unstable"); the wobble of the log-norms about their line
    over so short a window says undecided. At no count from 2 to 40 is it "unstable"."""
    ex, orb = gait
    words = {k: orb.stability(n_directions=200, iterations=k).verdict_word
             for k in range(2, 41)}
    assert "unstable" not in words.values(), words
    assert words[5] == "undecided" and words[40] == "stable"


def test_predicted_growth_rate_matches_long_simulations(gait):
    ex, orb = gait
    st = orb.stability(n_directions=500, iterations=1000)
    assert isinstance(st, Stability) and st.stable and st.spread < 5e-3  # 2.3e-3: wobble
    # two groups of two events: at most 2! * 2! pieces
    every_piece = set(itertools.product(itertools.permutations(range(2)), repeat=2))
    assert set(st.visits) <= every_piece and len(st.visits) >= 2
    assert all(m.shape == (3,) for m in st.multipliers.values())
    V = np.random.default_rng(0).standard_normal((2, 3)) @ orb.return_map.tangent_basis.T
    decay = decay_check(ex.system, orb.x0, gaits.apex_section,
                        V / np.linalg.norm(V, axis=1)[:, None], eps=1e-2, strides=60)
    assert decay.rate == pytest.approx(st.growth_rate, abs=0.03)
    assert "stable" in st.summary() and "piece ((0, 1), (0, 1))" in st.summary()


# ------------------------------------------------------------------------------------------
# figures
# ------------------------------------------------------------------------------------------
def test_gait_figures(gait, tmp_path):
    pytest.importorskip("matplotlib")
    from bderiv.plot._gait import gait_growth, gait_orbit

    ex, orb = gait
    fig = gait_orbit(orb, labels=["z", "theta", "vz", "omega"])
    *ax_t, ax_p = fig.axes
    legend = [t.get_text() for t in ax_p.get_legend().get_texts()]
    assert legend == ["events (0, 1) up at t = 0.1823", "events (0, 1) down at t = 0.3075",
                      "fixed point on the section"]
    assert ax_p.get_xlabel() == "z" and ax_p.get_ylabel() == "vz"
    fig.savefig(tmp_path / "orbit.png")
    with pytest.raises(ValueError, match=r"phase must be two state indices in \[0, 4\)"):
        gait_orbit(orb, phase=(0, 4))
    with pytest.raises(ValueError, match="labels must name the 4 state components, got 2"):
        gait_orbit(orb, labels=["z", "vz"])
    st = orb.stability(n_directions=50, iterations=100)
    fig = gait_growth(orb, n_directions=30, iterations=25, stability=st)
    (ax,) = fig.axes
    lines = ax.get_lines()
    growth = [ln for ln in lines if len(ln.get_xdata()) == 26]
    assert len(growth) >= 31  # 30 directions and the predicted rate
    dashed = [ln for ln in lines if ln.get_linestyle() == "--"][0]
    np.testing.assert_allclose(dashed.get_ydata(), st.growth_rate ** np.arange(26.0))
    fig.savefig(tmp_path / "growth.png")


# ------------------------------------------------------------------------------------------
# bad input and failures, named
# ------------------------------------------------------------------------------------------
def test_periodic_orbit_validation_and_failure(gait):
    ex, orb = gait
    s, guess = ex.system, ex.x0
    with pytest.raises(ValueError, match="tol must be a finite number > 0, got 0.0"):
        s.periodic_orbit(guess, gaits.apex_section, tol=0.0)
    with pytest.raises(ValueError, match="max_iter must be an integer >= 1"):
        s.periodic_orbit(guess, gaits.apex_section, max_iter=0)
    with pytest.raises(ValueError, match="period_guess must be a finite number > 0"):
        s.periodic_orbit(guess, gaits.apex_section, period_guess=-1.0)
    with pytest.raises(ValueError, match=r"x_guess must have shape \(4,\)"):
        s.periodic_orbit(np.ones(3), gaits.apex_section)
    with pytest.raises(RuntimeError, match=r"did not converge in max_iter=1 iterations: max "
                       r"\|P\(x\) - x\| = "):
        gaits.pronking_orbit(ex, max_iter=1)
    with pytest.raises(ValueError, match="n_directions must be an integer >= 1"):
        orb.stability(n_directions=0)
    # a review: iterations 0 and 1 gave two different bounds, burn_in=1.5 became 1 silently,
    # a negative seed got NumPy's "expected non-negative integer", naming nothing
    for bad in (0, 1):
        with pytest.raises(ValueError, match=rf"iterations must be an integer >= 2, got {bad}$"):
            orb.stability(n_directions=5, iterations=bad)
    for burn_in in (1.5, True, "3"):
        with pytest.raises(TypeError, match=r"burn_in must be an integer in \[0, iterations "
                           r"- 2 = 18\]"):
            orb.stability(n_directions=5, iterations=20, burn_in=burn_in)
    with pytest.raises(ValueError, match=r"burn_in must be an integer in \[0, iterations - 2 = "
                       r"18\] \(or None: iterations // 4\), got 19"):
        orb.stability(n_directions=5, iterations=20, burn_in=19)
    with pytest.raises(ValueError, match=r"seed must be an integer >= 0, got -1$"):
        orb.stability(n_directions=5, iterations=20, seed=-1)
    with pytest.raises(TypeError, match=r"seed must be an integer >= 0, got float 1.5"):
        orb.stability(n_directions=5, iterations=20, seed=1.5)
    assert orb.stability(n_directions=5, iterations=20, burn_in=np.int64(3)).burn_in == 3
    # a periodic_orbit coordinate 1.5 was coordinate 1
    for cyclic in ([1.5], [True], [np.float64(1.0)]):
        with pytest.raises(TypeError, match=r"cyclic must be a sequence of coordinate "
                           r"indices \(integers\), got .* is (float|bool|float64)\)"):
            s.periodic_orbit(orb.x0, gaits.apex_section, period_guess=0.5, cyclic=cyclic)
    # the perturbation of the guess is a state, not broadcast (its docstring: shape (4,))
    for bad, got in (((0.1,), r"shape \(1,\)"), (np.zeros((2, 4)), r"shape \(2, 4\)"),
                     ([0.1, [0.0, 1.0]], r"a ragged nest \[0.1, \[0.0, 1.0\]\]")):
        with pytest.raises(ValueError, match=r"perturbation must have shape \(4,\) \(added to "
                           r"the example's start x0, a state of pronking\), got " + got):
            gaits.pronking_orbit(ex, perturbation=bad)
    with pytest.raises(ValueError, match=r"perturbation must be finite, but perturbation\[3\] = "
                       r"nan; got \[0.1, 0.0, 0.0, nan\]"):
        gaits.pronking_orbit(ex, perturbation=[0.1, 0.0, 0.0, np.nan])
    with pytest.raises(TypeError, match=r"perturbation must hold real numbers"):
        gaits.pronking_orbit(ex, perturbation="abcd")
    assert "PeriodicOrbit(period=0.48976329" in repr(orb)
    assert "ReturnMap(dim=4, groups=[2, 2], period=0.48976329" in repr(orb.return_map)


def test_decay_check_validation(gait):
    ex, orb = gait
    V = np.array([[1.0, 0.0, 0.0, 0.0]])
    for bad in (3, 0):  # one message for both (0 said ">= 1")
        with pytest.raises(ValueError, match=rf"strides must be an integer >= 4, got {bad}$"):
            decay_check(ex.system, orb.x0, gaits.apex_section, V, strides=bad)
    with pytest.raises(ValueError, match=r"deviation of vector 0 falls below floor=1 before "
                       r"stride 4"):
        decay_check(ex.system, orb.x0, gaits.apex_section, V, strides=4, floor=1.0)


def _simulations_counted(monkeypatch):
    """A list that grows by one at every simulation of a HybridSystem (none must run
    before the arguments are checked)."""
    runs = []
    for name in ("simulate", "simulate_many"):
        real = getattr(HybridSystem, name)

        def counted(*args, _real=real, **kwargs):
            runs.append(1)
            return _real(*args, **kwargs)

        monkeypatch.setattr(HybridSystem, name, counted)
    return runs


@pytest.mark.parametrize(("change", "error", "message"), [
    # a review: numpy's "zero-size array to reduction operation maximum", an IndexError, a
    # broadcast error and "X0 must be finite" (an internal name) before these
    ({"V": np.zeros((0, 4))}, ValueError,
     r"V must hold at least one direction of perturbation \(shape \(m, 4\) with m >= 1\), "
     r"got shape \(0, 4\)"),
    ({"x0": "short"}, ValueError, r"x0 must have shape \(4,\) \(a state of this system\), "
                                  r"got shape \(3,\)"),
    ({"x0": "long"}, ValueError, r"x0 must have shape \(4,\) .*got shape \(5,\)"),
    ({"x0": "nan"}, ValueError, r"x0 must be finite, but x0\[3\] = nan; got \[.* nan\]"),
    ({"V": np.zeros((2, 4))}, ValueError,
     r"V must have no zero row \(each row is a direction of perturbation\), but row 0 is "
     r"zero"),
    ({"V": np.ones((2, 3))}, ValueError, r"V must have shape \(any, 4\), got \(2, 3\)"),
    ({"floor": np.nan}, ValueError, r"floor must be a finite number >= 0, got nan"),
    ({"floor": -1.0}, ValueError, r"floor must be a finite number >= 0, got -1.0"),
    ({"section": 3}, TypeError, r"section must be callable, got int"),
    ({"system": 3}, TypeError, r"system must be a HybridSystem, got int"),
    ({"cyclic": [1.5]}, TypeError, r"cyclic must be a sequence of coordinate indices "
                                   r"\(integers\), got \[1.5\] \(1.5 is float\)"),
    ({"rtoll": 1e-9}, TypeError, r"decay_check got unknown settings \['rtoll'\]; it takes "
                                 r"rtol, atol"),
    ({"strides": 4.0}, TypeError, r"strides must be an integer >= 4, got float 4.0"),
])
def test_decay_check_refuses_bad_arguments_by_name_before_simulating(gait, monkeypatch,
                                                                      change, error, message):
    ex, orb = gait
    args = {"system": ex.system, "x0": orb.x0, "section": gaits.apex_section,
            "V": np.eye(4)[:2], "strides": 4}
    states = {"short": orb.x0[:3], "long": np.r_[orb.x0, 0.0],
              "nan": np.r_[orb.x0[:3], np.nan]}
    change = {k: states.get(v, v) if isinstance(v, str) else v for k, v in change.items()}
    runs = _simulations_counted(monkeypatch)
    kwargs = {**args, **change}
    with pytest.raises(error, match=message):
        decay_check(kwargs.pop("system"), kwargs.pop("x0"), kwargs.pop("section"),
                    kwargs.pop("V"), **kwargs)
    assert runs == []


@pytest.mark.parametrize(("change", "error", "message"), [
    ({"V": np.zeros((0, 4)), "D_V": np.zeros((0, 4))}, ValueError,
     r"V must hold at least one vector \(shape \(m, 4\) with m >= 1\), got shape \(0, 4\)"),
    ({"x0": "short"}, ValueError, r"x0 must have shape \(4,\) \(a state of this system\), "
                                  r"got shape \(3,\)"),
    ({"x0": "nan"}, ValueError, r"x0 must be finite, but x0\[3\] = nan; got"),
    ({"eps": ()}, ValueError, r"eps must be a step or a non-empty 1-d sequence of steps, got "
                              r"shape \(0,\)"),
    ({"eps": [[1e-4]]}, ValueError, r"eps must be a step or a non-empty 1-d sequence of "
                                    r"steps, got shape \(1, 1\)"),
    ({"eps": "a"}, TypeError, r"eps\[0\] must be a real number, got str 'a'"),
    ({"eps": (1e-4, -1e-5)}, ValueError, r"eps\[1\] must be a finite number > 0, got -1e-05"),
    ({"system": 3}, TypeError, r"system must be a HybridSystem, got int"),
])
def test_fd_check_refuses_bad_arguments_by_name_before_simulating(gait, monkeypatch, change,
                                                                   error, message):
    ex, orb = gait
    V = np.eye(4)[:2]
    states = {"short": orb.x0[:3], "nan": np.r_[orb.x0[:3], np.nan]}
    kwargs = {"system": ex.system, "x0": orb.x0, "t_final": 1.0, "V": V, "D_V": V,
              "eps": (1e-4, 1e-5)}
    kwargs.update({k: states.get(v, v) if isinstance(v, str) else v
                   for k, v in change.items()})
    runs = _simulations_counted(monkeypatch)
    with pytest.raises(error, match=message):
        fd_check(**kwargs)
    assert runs == []


def test_return_map_pickles_and_is_read_only(gait):
    _, orb = gait
    R = orb.return_map
    R2 = pickle.loads(pickle.dumps(R))
    V = np.random.default_rng(4).standard_normal((7, 4))
    np.testing.assert_array_equal(R2(V), R(V))
    np.testing.assert_array_equal(R2.inverse(R(V)), R.inverse(R(V)))
    for arr in (R2.projection, R2.start_projection, R2.tangent_basis, R.projection):
        assert not arr.flags.writeable
    # the inverse on the section: tangent vectors at x0 come back
    T = V @ R.tangent_basis @ R.tangent_basis.T
    np.testing.assert_allclose(R.inverse(R(T)), T, atol=1e-10)
    out = np.empty_like(T)
    assert R.inverse(R(T), out=out) is out


def radial_cycle(multiplier):
    """A planar limit cycle r = 1 turning once per unit time, with the closed-form
    multiplier of its return map to the half-line y = 0, x > 0: r' = mu (r - 1) (1 -
    4 (r - 1)^2) gives delta r' = mu delta r near r = 1, so P'(1) = exp(mu) per turn; an
    unstable cycle's perturbations saturate at the cycles r = 0.5 and 1.5."""
    mu, omega = np.log(multiplier), 2 * np.pi

    def field(x, mask):
        r = np.hypot(x[0], x[1])
        g = mu * (r - 1) * (1 - 4 * (r - 1) ** 2) / r
        return np.array([-omega * x[1] + g * x[0], omega * x[0] + g * x[1]])

    # one event that never happens (r stays below 1.5)
    return HybridSystem(field, lambda x: np.array([x[0] - 10.0]), n_events=1, dim=2)


def test_decay_check_fits_only_the_linear_regime():
    V = np.array([[1.0, 0.0]])  # radial, on the section y = 0
    x0 = np.array([1.0, 0.0])

    def section(x):
        return x[1]

    stable = decay_check(radial_cycle(0.5), x0, section, V, eps=1e-2, strides=16)
    assert stable.rate == pytest.approx(0.5, rel=0.01)
    # growth 2.35 from eps = 1e-2 leaves the linear regime (5 % of |x0|) at stride 2: it
    # must not report a rate (the old fit over the saturated strides gave about 1)
    with pytest.warns(RuntimeWarning, match=r"vector 0 left the linear regime at stride 2 "
                      r"\(deviation 0.05\d* > ceiling 0.05\).*smaller eps"):
        grown = decay_check(radial_cycle(2.35), x0, section, V, eps=1e-2, strides=16)
    assert np.isnan(grown.rate) and not grown.fitted[0, 3:].any()
    # from eps = 1e-7 the growth is measured before the saturation: within 20 %
    measured = decay_check(radial_cycle(2.35), x0, section, V, eps=1e-7, strides=12)
    assert measured.rate == pytest.approx(2.35, rel=0.2)
    assert measured.fitted[0].sum() >= 3 and measured.deviations[0, -1] > 1e-3


def _status_bytes(field: str) -> int:
    with open("/proc/self/status") as f:
        line = next(line for line in f if line.startswith(field + ":"))
    return int(line.split()[1]) * 1024


def _reset_peak() -> bool:
    """Reset the peak resident set to the current one (Linux); whether that worked."""
    gc.collect()
    try:
        ctypes.CDLL(None).malloc_trim(0)  # glibc: give freed heap back, so reuse counts
    except (AttributeError, OSError):
        pass
    try:
        with open("/proc/self/clear_refs", "w") as f:
            f.write("5")
        return _status_bytes("VmHWM") - _status_bytes("VmRSS") < 8 << 20
    except (OSError, StopIteration, ValueError):
        return False


def peak_growth(fn):
    """``fn()`` and the most memory it held beyond what the process held before: on Linux
    the growth of the peak resident set (``/proc/self/clear_refs`` resets the peak: a
    measure of the whole process that does not slow ``fn``), else tracemalloc's peak
    (Python and NumPy allocations: it made the eight legs' orbit 9 times slower). With
    the resident set ``fn`` runs twice, the first run unmeasured, so that numba's
    compiling (hundreds of MiB on an empty cache) is not counted."""
    if _reset_peak():
        fn()
        if _reset_peak():
            base = _status_bytes("VmRSS")
            return fn(), _status_bytes("VmHWM") - base
    tracemalloc.start()
    try:
        return fn(), tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


def test_eight_legs_orbit_and_its_growth_confirmed_by_simulation():
    # eight feet land and lift off together: (8!)^2 = 1.6e9 pieces per stride, which the
    # old Newton step listed (MemoryError after 34-53 s)
    ex = gaits.pronking(legs=8)
    orb, peak = peak_growth(lambda: gaits.pronking_orbit(ex, perturbation=(0.05, 0.0, 0.0,
                                                                            0.0)))
    assert peak < 100 * 2**20 and orb.residual < 1e-10
    assert [bd.n_events for bd in orb.return_map.jumps] == [8, 8]
    assert all(len(h.piece) == 2 and len(h.piece[0]) == 8 for h in orb.history[:-1])
    # the legs share the two-legged totals, so the vertical motion of the symmetric gait,
    # and the period, are those of two legs
    assert orb.period == pytest.approx(0.48976329184, rel=1e-9)
    # the pitch is unstable with eight legs: perturbations measured in simulation, fitted
    # in the linear regime, grow at the rate the PL return map predicts
    st = orb.stability(n_directions=200, iterations=300)
    V = np.random.default_rng(0).standard_normal((2, 3)) @ orb.return_map.tangent_basis.T
    decay = decay_check(ex.system, orb.x0, gaits.apex_section,
                        V / np.linalg.norm(V, axis=1)[:, None], eps=1e-9, floor=1e-12,
                        strides=10)
    assert not st.stable and st.growth_rate > 4
    assert decay.rate == pytest.approx(st.growth_rate, rel=0.01)


def test_a_guess_near_the_orbit_converges_as_from_the_iterates_maps():
    """1e-8 from the pronking orbit the feet land apart, closer than the caller's
    simultaneity_tol: the guess's map merges them, and a step from it would be a chord
    (Newton's method then converges linearly: three iterates, the orbit found to 1e-10
    only). It is built again with the iterates' tolerance: two iterates, the orbit to
    rounding."""
    ex = gaits.pronking()
    orb = gaits.pronking_orbit(ex)
    d = np.random.default_rng(5).standard_normal(orb.x0.size)
    d[2] = 0.0  # along the section
    for scale in (1e-8, 1e-7):
        again = ex.system.periodic_orbit(orb.x0 + scale * d, gaits.apex_section,
                                         period_guess=0.5)
        assert len(again.history) == 2
        np.testing.assert_allclose(again.x0, orb.x0, rtol=0, atol=1e-12)


@pytest.mark.parametrize("name", ["pronking", "running"])
def test_the_orbit_map_is_built_once_at_the_orbit(monkeypatch, name):
    # the last iterate's map is built with the caller's simultaneity_tol and returned, not
    # built again; it is the map a fresh build at the orbit gives, bit for bit (on the
    # running gait the iterates' tolerance 0 splits the feet's touchdown in two groups
    # 1e-12 apart: the orbit's map must group them, as 1e-7 does)
    import bderiv.analysis.orbit as orbit_module
    from bderiv.examples import runner

    real, built = orbit_module.return_map, []

    def counted(system, x, section, **kw):
        built.append((x.copy(), kw["options"].simultaneity_tol))
        return real(system, x, section, **kw)

    monkeypatch.setattr(orbit_module, "return_map", counted)
    if name == "pronking":
        ex = gaits.pronking(compiled=True)
        orb = gaits.pronking_orbit(ex)
    else:
        ex = runner.running(compiled=True)
        orb = runner.running_orbit(ex)
    assert len(built) == len(orb.history) >= 3  # one map per iterate, none again
    assert np.array_equal(built[-1][0], orb.x0) and built[-1][1] == 1e-7
    assert [g.events for g in orb.trajectory.groups] == [(0, 1), (0, 1)]
    R, traj = real(ex.system, orb.x0, orb.section, t_max=1.5, tol=1e-9,
                   options=orbit_module.ORBIT_OPTIONS)  # simultaneity_tol 1e-7
    V = np.random.default_rng(0).standard_normal((100, ex.system.dim))
    for a, b in ((R.x_final, orb.return_map.x_final), (R.period, orb.period),
                 (R(V), orb.return_map(V)), (traj.t, orb.trajectory.t)):
        np.testing.assert_array_equal(a, b)


def test_a_neutral_orbit_is_undecided_whatever_the_rounding():
    """An elastic ball's apex map is the identity (closed form: every apex height is a
    periodic orbit, multiplier exactly 1). The rate came out 1 + 4e-16 from apex 1 and 2
    ("unstable", spread 4e-32) and exactly 1 from apex 0.5 ("undecided"): a verdict from
    rounding (a review). The spread's floor is RATE_ROUNDING."""
    from bderiv._limits import RATE_ROUNDING
    from bderiv.examples import bouncing_ball

    ex = bouncing_ball(e=1.0)
    for h in (0.5, 1.0, 2.0):
        orbit = ex.system.periodic_orbit(np.array([h, 0.0]), lambda x: -x[1],
                                         period_guess=1.0)
        st = orbit.stability(n_directions=10, iterations=100)
        assert abs(np.log(st.growth_rate)) < RATE_ROUNDING <= st.spread
        assert st.verdict_word == "undecided" and "neutral" in st.summary()


def test_a_neutral_orbit_is_undecided_whatever_the_integration_error():
    """An oscillator x'' = -x bouncing elastically off a wall at x = -0.5 keeps its energy:
    every amplitude is a periodic orbit, multiplier exactly 1 (closed form). Its map is
    integrated, not exact (a ball's flight is): the rate came out 1 +- 1e-12 at the
    default rtol, "stable", "unstable" or "undecided" by the amplitude, and 1 - 1.1e-10,
    "stable", at rtol 1e-9: a verdict from the integration's error (a review). The
    spread's floor is the map's accuracy, 10 rtol."""
    from bderiv.models.integrate.options import SolverOptions

    system = HybridSystem(lambda x, m: np.array([x[1], -x[0]]),
                          lambda x: np.array([-0.5 - x[0]]), n_events=1, dim=2,
                          reset=lambda x, m, k: np.array([x[0], -x[1]]),
                          event_jacobian=lambda x: np.array([[-1.0, 0.0]]),
                          field_jacobian=lambda x, m: np.array([[0.0, 1.0], [-1.0, 0.0]]))
    for rtol, amplitudes in ((None, (1.0, 1.3, 0.8)), (1e-9, (1.0, 1.3))):
        options = None if rtol is None else SolverOptions(rtol=rtol, atol=rtol / 10)
        for a in amplitudes:
            orbit = system.periodic_orbit(np.array([a, 0.0]), lambda x: -x[1], 4.0,
                                          options=options)
            st = orbit.stability(n_directions=10, iterations=200)
            assert orbit.accuracy == 10 * (rtol or 1e-12)
            assert abs(np.log(st.growth_rate)) < orbit.accuracy <= st.spread
            assert st.verdict_word == "undecided" and "accuracy" in st.summary()
    # at rtol 1e-7 Newton's method stalls on the family (a multiplier 1), and its return's
    # integration error, 3e-7 in the position, was taken for a cyclic coordinate's
    # advance: "pass cyclic=[0]" (a review)
    with pytest.raises(RuntimeError, match="degenerate") as info:
        system.periodic_orbit(np.array([1.0, 0.0]), lambda x: -x[1], 4.0,
                              options=SolverOptions(rtol=1e-7, atol=1e-8))
    assert "cyclic" not in str(info.value)


def test_a_section_flat_at_the_guess_is_named(gait):
    """A section whose gradient is 0 where the guess is moved onto it divided by 0: a
    RuntimeWarning, then "section(x) returned a non-finite value" about a NaN state, or a
    numerical Jacobian's failure at x = [nan ...] (a review)."""
    ex, _ = gait
    with pytest.raises(ValueError, match=r"section's gradient is \[0.0, 0.0, 0.0, 0.0\] "
                                         r"at x = .*x_guess cannot be moved onto section"):
        ex.system.periodic_orbit(ex.x0, lambda x: 1.0 + 0.0 * x[0], period_guess=0.5)


def test_a_guess_that_never_returns_is_named_by_periodic_orbits_arguments():
    """With a large period_guess a run that never crossed the section again ended at
    run's max_groups, whose advice ("pass a larger max_groups") names no argument of
    periodic_orbit, without saying where Newton was (a review): it now says what to
    change. (The run's own error: tests/test_recurring.py.)"""
    from bderiv.analysis.orbit import _at_iterate
    from bderiv.models.integrate.trajectory import TooManyGroups

    def never():
        raise TooManyGroups(10_000, 2449.18)

    with pytest.raises(RuntimeError, match=r"periodic_orbit at the guess, x = \[0.7 0. \]: "
                                           r"the run did not return to the section in 10000 "
                                           r"event groups \(t = 2449.18 of the 3e\+07 it "
                                           r"waits.*a guess nearer the orbit") as info:
        _at_iterate(0, np.array([0.7, 0.0]), 3e7, never)
    assert "max_groups" not in str(info.value)
