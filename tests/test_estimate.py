"""The hybrid Kalman filter (bderiv.estimate, issue 40).

- Side by side with hybrid-tools' salted Kalman filter (``SKF``) on its own bouncing balls
  (1-D and 2-D, one guard), the same model written in bderiv and the same measurements.
  Its ``predict`` integrates a step ``dt`` with ``solve_ivp`` and guards that are not
  terminal, so at a step with a guard it propagates the prior covariance over the whole
  step before the saltation matrix (``sol.t[-1] - sol.t[0]`` is ``dt``, not the time to
  the guard) and adds the process noise of the whole step and again of the rest; it also
  switches mode at every apex (a guard ``qdot = 0`` with the identity saltation). So:
  (a) as shipped, step by step from the same prior: equal to rounding on the steps
  without a guard; on a guard step hybrid-tools' covariance is that convention written
  out and ours the salted covariance written out (saltation formula, fundamental
  matrices of the free flight); (b) with its guards terminal and no process noise (its
  predict is then the salted filter), whole runs over several bounces are equal to
  rounding. Both integrators are exact for the ball's quadratic motion, so rounding is
  what is left.
- Where it cannot: the chair's two-foot landing. Monte Carlo with a prior wide enough that
  both feet land first; our filter's NEES is within the chi-square band where a salted
  filter that assumes either order is overconfident.
- Refusals of bad input.
"""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest
from hybrid_tools_balls import ball_2d
from scipy.stats import chi2

from bderiv import examples
from bderiv.estimate import HybridKalmanFilter, SplitPriorWarning

G = 9.81


def _ht():
    return pytest.importorskip("hybrid_tools")


def _case(dim):
    """(bderiv model, hybrid-tools system, its parameters, start, height coordinate)."""
    ht = _ht()
    from hybrid_tools.basic_hybrid_systems import bouncing_ball, bouncing_ball_2d

    e = 0.7
    if dim == 2:
        return (examples.bouncing_ball(e=e, g=G).system, bouncing_ball(),
                np.array([e, G]), np.array([1.0, 0.0]), 0, ht)
    floor = 0.25
    return (ball_2d(e, G, floor), bouncing_ball_2d(), np.array([e, G, floor]),
            np.array([0.0, 1.2, 0.4, 0.0]), 1, ht)


def _noises(system, W, V):
    from hybrid_tools import ModeNoise

    system.noises = {m: ModeNoise(W=W * np.eye(n.W.shape[0]), V=V * np.eye(n.V.shape[0]))
                     for m, n in system.noises.items()}


def _flight(d, s):
    """Fundamental matrix of the free flight over s: positions += s velocities."""
    A = np.eye(d)
    A[: d // 2, d // 2:] = s * np.eye(d // 2)
    return A


def _noise(d, s, W):
    """hybrid-tools' process noise over s: B W B^T, B = d(x + f dt)/du = s on the
    velocities (Euler)."""
    Q = np.zeros((d, d))
    Q[d // 2:, d // 2:] = W * s * s * np.eye(d // 2)
    return Q


def _measurements(model, x0, dt, steps, r, seed):
    """The true states at the step ends (bderiv's simulation) and noisy measurements of
    the whole state."""
    rng = np.random.default_rng(seed)
    xs, x = [], x0
    for _ in range(steps):
        x = model.simulate(x, dt, t_eval=()).x_final
        xs.append(x)
    X = np.array(xs)
    return X, X + np.sqrt(r) * rng.standard_normal(X.shape)


def _mode(v):
    return "I" if v <= 0 else "J"  # hybrid-tools: I falling (guard q), J rising (guard v)


#: hybrid-tools' fixed steps end near bounces: both filters take the bounce on the mean's
#: side there (this filter warns of it, SplitPriorWarning), so they agree step for step
SPLIT_STEPS = pytest.mark.filterwarnings("ignore::bderiv.estimate.SplitPriorWarning")


@SPLIT_STEPS
@pytest.mark.parametrize("dim", [2, 4], ids=["1-D ball", "2-D ball"])
def test_side_by_side_with_hybrid_tools_skf_as_shipped(dim):
    """Step by step from the same prior: equal to rounding without a guard; at a guard,
    each equals its own covariance formula written out here."""
    model, system, params, x0, iq, ht = _case(dim)
    W, r, dt = 0.01, 1e-4, 0.05
    _noises(system, W, r)
    d = dim
    R = r * np.eye(d)
    _, Z = _measurements(model, x0, dt, 24, r, seed=3)
    m, P = x0.copy(), 1e-4 * np.eye(d)
    e, iv = params[0], iq + d // 2
    guards = plain = 0
    for k, z in enumerate(Z):
        ours = HybridKalmanFilter(model, m, P)
        skf = ht.SKF(m.copy(), _mode(m[iv]), P.copy(), dt, params, system)
        t = k * dt
        mp, Pp = ours.predict(dt, Q=_noise(d, dt, W))
        mode_before = skf.current_mode
        hm, hP = skf.predict(t, np.zeros(d // 2))
        assert np.allclose(mp, hm, rtol=0, atol=1e-12), (k, mp, hm)
        q, v = m[iq] - params[2] if d == 4 else m[iq], m[iv]
        hit = (v + np.sqrt(v * v + 2 * G * q)) / G  # time to the floor
        apex = v / G if v > 0 else np.inf
        if skf.current_mode == mode_before and min(hit, apex) > dt:
            plain += 1
            assert np.allclose(Pp, hP, rtol=1e-12, atol=1e-15), (k, Pp, hP)
        else:
            guards += 1
            tau = min(hit, apex)
            S = np.eye(d)
            if hit < apex:  # the saltation matrix written out: R + (f+ - R f-) G^T / (G f-)
                Rj = np.eye(d)
                Rj[iv, iv] = -e
                vel = m[d // 2:].copy()
                vel[iv - d // 2] = v - G * tau  # velocities at the impact
                acc = np.zeros(d // 2)
                acc[iv - d // 2] = -G
                f_pre = np.concatenate([vel, acc])  # the field before and after the reset
                f_post = np.concatenate([Rj[d // 2:, d // 2:] @ vel, acc])
                Gr = np.zeros(d)
                Gr[iq] = 1.0
                S = Rj + np.outer(f_post - Rj @ f_pre, Gr) / (Gr @ f_pre)
            A1, A2 = _flight(d, tau), _flight(d, dt - tau)
            salted = A2 @ S @ A1 @ P @ A1.T @ S.T @ A2.T + _noise(d, dt, W)
            Ad = _flight(d, dt)
            convention = (A2 @ S @ (Ad @ P @ Ad.T + _noise(d, dt, W)) @ S.T @ A2.T
                          + _noise(d, dt - tau, W))
            assert np.allclose(Pp, salted, rtol=1e-12, atol=1e-15), k
            assert np.allclose(hP, convention, rtol=1e-12, atol=1e-15), k
        m_u, P_u = ours.update(z, R, H=np.eye(d))
        same_prior = HybridKalmanFilter(model, hm, hP)  # its prior (differs at a guard)
        mine = same_prior.update(z, R, H=np.eye(d))
        hm_u, hP_u = skf.update(t + dt, np.zeros(d // 2), z)
        assert np.allclose(mine[0], hm_u, rtol=0, atol=1e-12), k
        assert np.allclose(mine[1], hP_u, rtol=1e-10, atol=1e-16), k
        m, P = m_u, P_u
    assert guards >= 2 and plain >= 10  # bounces and apexes both met


@SPLIT_STEPS
@pytest.mark.parametrize("dim", [2, 4], ids=["1-D ball", "2-D ball"])
def test_whole_runs_equal_hybrid_tools_skf_with_terminal_guards(dim, monkeypatch):
    """With its guards terminal and no process noise, hybrid-tools' SKF is the salted
    filter: ours equals it over whole runs (several bounces), means and covariances."""
    model, system, params, x0, iq, ht = _case(dim)
    import hybrid_tools.skf as skf_module

    original = skf_module.solve_ivp_guard_funcs

    def terminal(*args, **kwargs):
        guards, modes = original(*args, **kwargs)
        for g in guards:
            g.terminal = True
        return guards, modes

    monkeypatch.setattr(skf_module, "solve_ivp_guard_funcs", terminal)
    r, dt = 1e-4, 0.05
    _noises(system, 0.0, r)
    d = dim
    X, Z = _measurements(model, x0, dt, 40, r, seed=5)
    ours = HybridKalmanFilter(model, x0, 1e-4 * np.eye(d))
    skf = ht.SKF(x0.copy(), "I", 1e-4 * np.eye(d), dt, params, system)
    bounces = 0
    for k, z in enumerate(Z):
        mp, Pp = ours.predict(dt)
        hm, hP = skf.predict(k * dt, np.zeros(d // 2))
        bounces += len(ours.mode.groups)
        assert np.allclose(mp, hm, rtol=0, atol=1e-11), k
        assert np.allclose(Pp, hP, rtol=1e-10, atol=1e-15), k
        mode = skf.current_mode
        m_u, P_u = ours.update(z, r * np.eye(d), H=np.eye(d))
        hm_u, hP_u = skf.update((k + 1) * dt, np.zeros(d // 2), z)
        assert skf.current_mode == mode  # no posterior reset: the estimates stay comparable
        assert np.allclose(m_u, hm_u, rtol=0, atol=1e-11), k
        assert np.allclose(P_u, hP_u, rtol=1e-10, atol=1e-16), k
    assert bounces >= 3


# ----------------------------------------------------------------------------------
# where one guard at a time cannot: the chair's two-foot landing
# ----------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def chair():
    return examples.chair(compiled=True)


def test_chair_monte_carlo_nees_consistent_where_salted_filters_are_overconfident(chair):
    """200 runs with every filter's default window (benchmarks/kalman_consistency.py runs
    1,000): the truth is simulated from each sampled start, both feet land first in some
    runs. The mean NEES of the mixture and sigma filters is in the 99.9 % chi-square band
    (a seed-robust criterion: seeds 0 to 7 give 5.43 to 6.29 for the mixture); a salted
    filter is overconfident: by 1.24 to 1.60 times the mixture's NEES following the mean's
    own order, by 2.2 to 3.0 times assuming either order (seeds 0 to 7)."""
    from bderiv.estimate.consistency import consistency

    c = consistency(chair, 200, seed=0)
    first = np.mean(c.orders[:, 0] == 0)
    assert 0.3 < first < 0.7  # both orders happen
    assert np.allclose(c.band, chi2.ppf([0.025, 0.975], 1200) / 200)
    lo, hi = chi2.ppf([0.0005, 0.9995], 1200) / 200
    mean = {name: float(v.mean()) for name, v in c.nees.items()}
    for name in ("mixture", "sigma"):
        assert lo <= mean[name] <= hi, (name, c.table())
    assert mean["salted, mean's order"] > 1.15 * mean["mixture"], c.table()
    for name in ("salted, order (0, 1)", "salted, order (1, 0)"):
        assert mean[name] > 1.8 * mean["mixture"], (name, c.table())


@pytest.fixture(scope="module")
def offset_cloud(chair):
    """The chair from a start with the feet apart (the mean's touchdowns 2e-5 rad of
    pitch apart, within the prior's spread), P = (3e-5)^2 I, 2,000 sampled starts
    simulated to t_final: (start, P, V, final states, which foot landed first)."""
    start = chair.x0 + np.array([0.0, 0.0, 2e-5, 0.0, 0.0, 0.0])
    P = (3e-5) ** 2 * np.eye(6)
    V = np.random.default_rng(2).multivariate_normal(np.zeros(6), P, size=200_000)
    runs = chair.system.simulate_many(start + V[:2000], chair.t_final, progress=False)
    first = np.array([run.groups[0].events[0] for run in runs])
    return start, P, V, runs.x_final, first


def test_a_merged_groups_offsets_come_from_the_flow_maps_own_run(chair, monkeypatch):
    """The offsets of a merged group are measured at its first crossing in the run the
    flow map was built along (``D.group_states``): those of a separate simulation of the
    mean to integration accuracy, and the filter's step simulates nothing more than its
    flow maps' runs. A map that holds no states (built by hand) needs the trajectory."""
    from bderiv.analysis.flowmap import FlowBDerivative
    from bderiv.estimate import group_offsets

    model = chair.system
    start = chair.x0 + np.array([0.0, 0.0, 2e-5, 0.0, 0.0, 0.0])
    D = model.flow_bderivative(start, chair.t_final, simultaneity_tol=1e-3)
    assert D.group_spreads[0] > 1e-6 and len(D.group_states) == D.n_groups
    own, = group_offsets(model, D)
    separate, = group_offsets(model, D, model.simulate(start, chair.t_final))
    assert np.allclose(own, separate, rtol=1e-7, atol=1e-12) and np.abs(own).max() > 1e-6
    bare = FlowBDerivative(D.linear, D.jumps, group_spreads=D.group_spreads)
    with pytest.raises(ValueError, match="pass traj, the mean's trajectory"):
        group_offsets(model, bare)
    with pytest.raises(ValueError, match="group_states has 2 states but there are 1 jumps"):
        FlowBDerivative(D.linear, D.jumps, group_states=[start, start])
    with pytest.raises(ValueError, match=r"group_states must have shape \(1, 6\)"):
        FlowBDerivative(D.linear, D.jumps, group_states=np.zeros((1, 5)))
    runs = []
    for name in ("simulate", "flow_bderivative"):  # the model is frozen: its class's
        real = getattr(type(model), name)
        monkeypatch.setattr(type(model), name, lambda *args, _real=real, _name=name,
                            **kwargs: runs.append(_name) or _real(*args, **kwargs))
    kf = HybridKalmanFilter(model, start, (3e-5) ** 2 * np.eye(6), window=1e-3)
    kf.predict(chair.t_final)
    assert kf.mode.window == 1e-3 and kf.mode.groups  # the merged group, its spread > 0
    assert runs == ["flow_bderivative"]


def test_mixture_moments_equal_a_sample_of_the_local_map(chair, offset_cloud):
    """The mixture's closed-form moments (the prior cut by the orders' hyperplane) equal
    the moments of 200,000 samples pushed through the flow's B-derivative one by one,
    with the mean off the simultaneous trajectory (an offset group); and the order
    probabilities equal the samples' frequencies."""
    from bderiv.estimate import LocalMap, group_offsets, push_mixture

    model = chair.system
    start, P, V, _, first = offset_cloud
    T = chair.t_final
    D = model.flow_bderivative(start, T, simultaneity_tol=1e-3)
    assert D.group_spreads[0] > 1e-6
    local = LocalMap(D, group_offsets(model, D, model.simulate(start, T)))
    push = push_mixture(local, P)
    Y = local(V)
    sd = Y.std(axis=0)
    assert np.abs(push.mean - Y.mean(axis=0)).max() < 0.01 * sd.max()
    assert np.allclose(push.cov, np.cov(Y.T), rtol=0.02, atol=0.02 * sd.max() ** 2)
    freq = np.mean(local.orders(V)[0][:, 0] == 0)
    assert abs(push.order_probabilities[0][(0, 1)] - freq) < 0.005
    assert 0.05 < freq < 0.95 and abs(freq - 0.5) > 0.1  # the offset moves the odds
    # the odds of the simulated flow: which foot lands first from 2,000 sampled starts
    assert abs(np.mean(first == 0) - push.order_probabilities[0][(0, 1)]) < 0.035
    # and the local map is the flow: one-sided differences of the simulation
    eps = 1e-3
    W = V[:5] * eps / 3e-5
    fd = np.array([model.simulate(start + w, T).x_final for w in W]) - D.x_final
    assert np.allclose(local(W), fd, rtol=0, atol=0.05 * np.abs(fd).max())


def test_default_filter_follows_the_simulated_cloud_through_an_offset_touchdown(
        chair, offset_cloud):
    """With its default arguments the filter meets the two touchdowns as one group (the
    window derived from the prior holds their 2e-5 gap) and takes the mixture: its mean
    is the mean of 2,000 simulated runs (within 4 standard errors; the simulated mean
    ``Phi(T, m)`` alone is not: the mean correction), its covariance theirs (whitened
    eigenvalues within sampling error), its order probability their frequency."""
    start, P, _, X, first = offset_cloud
    f = HybridKalmanFilter(chair.system, start, P)
    mean, cov = f.predict(chair.t_final)
    (t, events, probs), = f.mode.groups
    assert events == (0, 1) and f.mode.method == "mixture"
    assert 1e-5 < f.mode.window < 1e-3
    assert abs(probs[(0, 1)] - np.mean(first == 0)) < 0.035
    se = X.std(axis=0) / np.sqrt(len(X))
    assert np.all(np.abs(mean - X.mean(axis=0)) < 4 * se)
    plain = chair.system.simulate(start, chair.t_final, t_eval=()).x_final
    assert np.any(np.abs(plain - X.mean(axis=0)) > 8 * se)  # the correction matters
    L = np.linalg.inv(np.linalg.cholesky(np.cov(X.T)))
    w = np.linalg.eigvalsh(L @ cov @ L.T)
    assert 0.8 < w.min() and w.max() < 1.25, w


@pytest.mark.parametrize("gap", [-3e-4, 3e-4], ids=["bounce before the end", "just after"])
@pytest.mark.parametrize("window", [1e-3, None], ids=["window 1e-3", "derived window"])
def test_a_step_ending_within_the_window_of_a_bounce(gap, window):
    """The 1-D ball bouncing 3e-4 s before (or after) the step's end, within a given
    window of 1e-3, far beyond the spread of the bounce's time (2e-6 s): no refusal; the
    bounce is taken on the mean's side (the window shrinks for the step), the mean and
    covariance those of the salted filter written out here (free flight, saltation matrix
    ``R + (f+ - R f-) G^T / (G f-)``)."""
    e, dt = 0.7, 0.05
    model = examples.bouncing_ball(e=e, g=G).system
    t_hit = dt + gap
    m0 = np.array([0.5 * G * t_hit**2, 0.0])  # from rest: at the floor at t_hit
    P = 1e-12 * np.array([[1.0, 0.2], [0.2, 2.0]])
    f = HybridKalmanFilter(model, m0, P, window=window)
    mean, cov = f.predict(dt)
    assert f.mode.window < abs(gap)
    v = -G * t_hit  # the impact velocity
    if gap < 0:
        s = dt - t_hit
        R = np.diag([1.0, -e])
        f_pre, f_post = np.array([v, -G]), np.array([-e * v, -G])
        Gr = np.array([1.0, 0.0])
        S = R + np.outer(f_post - R @ f_pre, Gr) / (Gr @ f_pre)
        M = _flight(2, s) @ S @ _flight(2, t_hit)
        expected = np.array([-e * v * s - 0.5 * G * s * s, -e * v - G * s])
        assert len(f.mode.groups) == 1
    else:
        M = _flight(2, dt)
        expected = np.array([m0[0] - 0.5 * G * dt * dt, -G * dt])
        assert not f.mode.groups
    assert np.allclose(mean, expected, rtol=0, atol=1e-9)
    assert np.allclose(cov, M @ P @ M.T, rtol=1e-7, atol=1e-15)


@pytest.mark.parametrize("gap", [-3e-4, 3e-4], ids=["after the bounce", "before it"])
@pytest.mark.parametrize("window", [1e-3, None], ids=["window 1e-3", "derived window"])
def test_a_step_ending_within_the_spread_of_a_bounce_warns_and_says_its_share(gap, window):
    """The same ball, its position's spread 1e-3 (the bounce's time about 2e-3 s): a step
    that ends 3e-4 s from the bounce splits the prior, part bounced and part not, which
    the step takes on the mean's side (the simulated cloud's velocity spread 1,000 times
    the filter's, 1e-5 s after the bounce); it was silent. It warns, naming dt, and
    ``mode.split`` is the share left out: Phi(-|gap| / sd), with the first-order spread of
    the bounce's time written out here, ``sd(x) / |v|``, v = -G t_hit. Four standard
    deviations away it is silent."""
    model = examples.bouncing_ball(e=0.7, g=G).system
    dt = 0.05
    t_hit = dt + gap
    m0 = np.array([0.5 * G * t_hit**2, 0.0])
    P = 1e-6 * np.array([[1.0, 0.2], [0.2, 2.0]])
    sd = 1e-3 / (G * t_hit)
    f = HybridKalmanFilter(model, m0, P, window=window)
    with pytest.warns(SplitPriorWarning, match=rf"dt={dt!r} ends the step 0.0003\d* s from "
                                               r"an event of the mean's trajectory"):
        f.predict(dt)
    share = 0.5 * math.erfc(abs(gap) / sd / math.sqrt(2.0))
    assert f.mode.split == pytest.approx(share, rel=0.05)
    with warnings.catch_warnings():
        warnings.simplefilter("error", SplitPriorWarning)
        away = HybridKalmanFilter(model, m0, P, window=window)
        away.predict(t_hit + 4 * sd)
    assert away.mode.split is None


def test_a_given_window_reaching_the_steps_end_shrinks_for_simultaneous_events(chair):
    """The chair's feet touch down together (spread 0) 0.05 s before the step's end. A
    given window of 0.06 reaches the end: it shrinks to half the distance, and the step is
    the one a window of 0.04 gives (two pieces, the mixture). It was kept whole for events
    exactly simultaneous: the final time joined their group as a third event, and sigma
    directions through that map gave a covariance off the simulated cloud's by 0.03 to 135
    times along its axes, the mean 2 standard deviations off."""
    P0 = 1e-4**2 * np.eye(6)
    steps = {}
    for window in (0.04, 0.06):
        f = HybridKalmanFilter(chair.system, chair.x0, P0, window=window)
        steps[window] = (*f.predict(chair.t_final), f.mode)
    gap = chair.t_final - chair.t_event
    mean, cov, mode = steps[0.06]
    assert mode.window == pytest.approx(gap / 2, rel=1e-9)
    assert mode.method == "mixture" and set(mode.groups[0][2]) == {(0, 1), (1, 0)}
    np.testing.assert_allclose(mean, steps[0.04][0], rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(cov, steps[0.04][1], rtol=1e-9, atol=1e-20)


def test_a_mean_moved_onto_a_surface_is_refused_and_leaves_the_filter_as_it_was():
    """An update whose mean lands exactly on an event's surface (its region undefined, and
    no step could start there: a measurement of x_0 = 1 with R = 2**-60 against a prior
    variance of 1 gives the gain 1.0 in float64) is refused by name, and the filter keeps
    its state. A predict step ending so is refused the same way (the same check, made
    before anything is assigned); it had moved the mean and the time, kept the old mode,
    and said "x0 lies on the surface" of an x0 the caller never passed."""
    from bderiv import HybridSystem

    def field(x, mask):
        return np.array([1.0, 0.0])

    def events(x):
        return np.array([x[0] - 1.0])

    model = HybridSystem(field, events, n_events=1, dim=2)
    f = HybridKalmanFilter(model, np.array([0.5, 0.0]), np.eye(2))
    before = (f.mean.copy(), f.cov.copy(), f.time, f.mode)
    with pytest.raises(ValueError, match=r"the update with the mean on the surface of "
                                         r"event\(s\) \[0\] .* \(the filter is left as it "
                                         r"was\)"):
        f.update([1.0], [[2.0**-60]], H=[[1.0, 0.0]])
    assert np.array_equal(f.mean, before[0]) and np.array_equal(f.cov, before[1])
    assert (f.time, f.mode) == before[2:]
    f.update([0.9], [[1e-2]], H=[[1.0, 0.0]])  # and it goes on from there
    assert f.mode.mask == 0 and f.mean[0] < 1.0


def test_sigma_directions_each_take_their_own_piece(chair):
    """The sigma method's mean and covariance are those of the 2 d directions pushed
    one by one through D (each by its own piece, D.jvp(v, v) = D(v))."""
    from bderiv.estimate import LocalMap, push_sigma
    from bderiv.estimate.pushforward import sqrt_psd

    D = chair.system.flow_bderivative(chair.x0, chair.t_final)
    P = np.diag([1.0, 2.0, 0.5, 1.0, 3.0, 1.0]) * 1e-8
    push = push_sigma(LocalMap(D, [None]), P)
    S = np.sqrt(6) * sqrt_psd(P)
    V = np.concatenate([S.T, -S.T])
    Y = D.jvp(V, V)
    assert len({tuple(o) for o in D.orders(V)[0]}) == 2
    assert np.allclose(push.mean, Y.mean(axis=0), atol=1e-15)
    assert np.allclose(push.cov, (Y - Y.mean(0)).T @ (Y - Y.mean(0)) / 12, atol=1e-18)


def test_auto_takes_sigma_directions_where_the_mixture_does_not_apply():
    """Three thresholds crossed at once (six pieces): the mixture is exact for two pieces
    only and refuses by name; the default ("auto") takes the sigma directions, the 2 d
    directions of the unscented transform each pushed through its own piece of D
    (D.jvp(v, v) = D(v)), written out here."""
    from bderiv.estimate.pushforward import sqrt_psd

    ex = examples.network(3)
    d = ex.system.dim
    P = np.eye(d) * 1e-10
    with pytest.raises(ValueError, match="method='sigma'"):
        HybridKalmanFilter(ex.system, ex.x0, P, method="mixture").predict(ex.t_final)
    kf = HybridKalmanFilter(ex.system, ex.x0, P)
    mean, cov = kf.predict(ex.t_final)
    assert kf.mode.method == "sigma"
    assert [len(events) for _, events, _ in kf.mode.groups] == [3]
    D = ex.system.flow_bderivative(ex.x0, ex.t_final)
    S = np.sqrt(d) * sqrt_psd(P)
    V = np.concatenate([S.T, -S.T])
    Y = D.jvp(V, V)
    assert len({tuple(o) for o in D.orders(V)[0]}) > 2  # more than two pieces met
    R = Y - Y.mean(axis=0)
    scale = np.abs(R.T @ R).max() / len(V)
    assert np.allclose(cov, R.T @ R / len(V), rtol=0, atol=1e-9 * scale)
    assert np.allclose(mean, D.x_final + Y.mean(axis=0), rtol=0, atol=1e-12)


# ----------------------------------------------------------------------------------
# refusals
# ----------------------------------------------------------------------------------
def test_bad_inputs_are_refused_by_name():
    model = examples.bouncing_ball().system
    x, P = np.array([1.0, 0.0]), 1e-4 * np.eye(2)
    cases = [
        (lambda: HybridKalmanFilter(model, [1.0, 0.0, 0.0], P), ValueError, "mean must"),
        (lambda: HybridKalmanFilter(model, x, np.eye(3)), ValueError, "cov must have shape"),
        (lambda: HybridKalmanFilter(model, x, [[1.0, 0.5], [0.0, 1.0]]), ValueError,
         "symmetric"),
        (lambda: HybridKalmanFilter(model, x, [[1.0, 0.0], [0.0, -1.0]]), ValueError,
         "positive semi-definite"),
        (lambda: HybridKalmanFilter(model, x, [[np.nan, 0], [0, 1]]), ValueError, "finite"),
        (lambda: HybridKalmanFilter(model, x, P, method="ukf"), ValueError, "method must"),
        (lambda: HybridKalmanFilter(model, x, P, priority=(0,)), ValueError, "priority"),
        (lambda: HybridKalmanFilter(model, x, P, window=0.0), ValueError, "window"),
        (lambda: HybridKalmanFilter("ball", x, P), TypeError, "model must"),
        (lambda: HybridKalmanFilter(model, x, P, rtoll=1e-9), TypeError, "rtoll"),
        (lambda: HybridKalmanFilter(model, "x", P), TypeError, "mean must"),
    ]
    f = HybridKalmanFilter(model, x, P)
    cases += [
        (lambda: f.predict(-0.1), ValueError, "dt must"),
        (lambda: f.predict(0.1, Q=np.ones((2, 2)) * [[1, 2], [2, 1]]), ValueError,
         "Q must be positive semi-definite"),
        (lambda: f.update([1.0], np.eye(2), H=np.eye(2)), ValueError, "z must have shape"),
        (lambda: f.update([1.0, 0.0], np.zeros((2, 2)), H=np.eye(2)), ValueError,
         "R must be positive definite"),
        (lambda: f.update([1.0, 0.0], [[1.0]], H=np.eye(2)), ValueError, "R must have shape"),
        (lambda: f.update([1.0], [[1.0]], H=[[1.0, 0.0, 0.0]]), ValueError,
         "H must have shape"),
        (lambda: f.update([1.0], [[1.0]], H=[[1.0, 0.0]], h=lambda x: x), ValueError,
         "h(x) has 2 entries"),
        (lambda: f.update([1.0], [[1.0]], H=None), TypeError, "H must be given"),
        (lambda: f.nees([1.0]), ValueError, "x_true must have shape"),
        (lambda: HybridKalmanFilter(model, x, np.diag([1.0, 0.0])).nees(x), ValueError,
         "covariance is singular"),
    ]
    for call, kind, words in cases:
        with pytest.raises(kind, match=words.replace("(", r"\(").replace(")", r"\)")):
            call()
    assert np.array_equal(f.mean, x) and np.array_equal(f.cov, P)  # nothing half done


def test_nonlinear_measurement_update_is_the_extended_kalman_update():
    """A range measurement h(x) = sqrt(q^2 + 1) with its Jacobian: the update written out."""
    model = examples.bouncing_ball().system
    m, P = np.array([1.0, -0.5]), np.array([[0.04, 0.01], [0.01, 0.09]])
    f = HybridKalmanFilter(model, m, P)
    h = lambda x: np.array([np.hypot(x[0], 1.0)])  # noqa: E731
    H = lambda x: np.array([[x[0] / np.hypot(x[0], 1.0), 0.0]])  # noqa: E731
    mu, Pu = f.update([1.5], [[0.01]], H=H, h=h)
    Hm = H(m)
    K = P @ Hm.T / (Hm @ P @ Hm.T + 0.01)
    assert np.allclose(mu, m + (K * (1.5 - h(m))).ravel(), atol=1e-15)
    assert np.allclose(Pu, P - K @ Hm @ P, atol=1e-15)
    assert f.mode.mask == 0


def test_measurements_and_priorities_are_refused_by_name_with_what_came():
    """An empty H (no measured quantity), a complex H (numpy would drop its imaginary
    part with a warning; a complex z is refused the same way) and priorities that are
    not events of the model each once: a ValueError/TypeError naming the parameter, what
    was expected and what came; the filter left as it was."""
    model = examples.bouncing_ball().system  # one event: 0
    x, P = np.array([1.0, 0.0]), 1e-4 * np.eye(2)
    f = HybridKalmanFilter(model, x, P)
    cases = [
        (lambda: f.update(np.zeros(0), np.zeros((0, 0)), H=np.zeros((0, 2))), ValueError,
         r"H must have at least one row .*p >= 1\), got shape \(0, 2\)"),
        (lambda: f.update(np.zeros(0), np.zeros((0, 0)), H=lambda v: np.zeros((0, 2))),
         ValueError, r"H\(x\) must have at least one row"),
        (lambda: f.update([1.0, 0.0], np.eye(2), H=1j * np.eye(2)), TypeError,
         r"H must be an array of real numbers, got array\(\[\[0\.\+1\.j"),
        (lambda: f.update(np.array([1.0 + 0j, 0.0]), np.eye(2), H=np.eye(2)), TypeError,
         "z must be an array of real numbers"),
    ]
    for priority, kind, words in [
        ("ab", TypeError, "priority .* must be a 1-D sequence of integers, got str 'ab'"),
        ((0, 0), ValueError, r"priority must name each event once, got \[0\] more than once "
                             r"in \[0, 0\]"),
        ((0, 5), ValueError, r"priority must hold event indices in \[0, 1\), got \[5\] in "
                             r"\[0, 5\]"),
        ((0.5,), TypeError, "priority .* must hold integers, got 0.5"),
    ]:
        cases.append((lambda p=priority: HybridKalmanFilter(model, x, P, method="piece",
                                                            priority=p), kind, words))
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no ComplexWarning on the way
        for call, kind, words in cases:
            with pytest.raises(kind, match=words):
                call()
    assert np.array_equal(f.mean, x) and np.array_equal(f.cov, P)
    assert HybridKalmanFilter(model, x, P, method="piece", priority=[np.int64(0)]).priority \
        == (0,)


def test_a_prior_with_no_spread_across_the_orders_boundary_keeps_its_covariance():
    """Two thresholds crossed at once, fields constant by region: a perturbation a (1, 1)
    moves both crossings together (x(T) = x(T) + 2 a (1, 1), closed form), so the
    covariance of P = 1e-4 [[1, 1], [1, 1]] is 4e-4 [[1, 1], [1, 1]]. The prior has no
    spread across the boundary of the two orders: the mixture gave neither order any
    probability, and the covariance 0, silently (a review). Every method agrees now."""
    from bderiv import HybridSystem

    F = {0: [1.0, 1.0], 1: [2.0, 1.0], 2: [1.0, 3.0], 3: [2.0, 2.0]}
    model = HybridSystem(lambda x, m: np.array(F[int(m)]), lambda x: np.array([x[0], x[1]]),
                         n_events=2, dim=2, field_jacobian=lambda x, m: np.zeros((2, 2)),
                         event_jacobian=lambda x: np.eye(2))
    P = 1e-4 * np.ones((2, 2))
    for method in ("auto", "mixture", "sigma", "piece"):
        f = HybridKalmanFilter(model, np.array([-1.0, -1.0]), P, method=method)
        _, cov = f.predict(2.0)
        np.testing.assert_allclose(cov, 4e-4 * np.ones((2, 2)), rtol=1e-9)
        assert sum(f.mode.groups[0][2].values()) == pytest.approx(1.0)


def test_a_prior_straddling_a_surface_at_the_steps_start_warns_and_the_mean_is_named():
    """A ball 1e-6 above the floor with a position sd of 1e-3: half of the prior is below
    it, in the region beyond, which the step does not hold; its covariance came out 50
    times too small in velocity, without a word (a review). It warns, with the share; a
    prior well clear of the floor is silent. A mean exactly on the floor names ``mean``
    (the words were "x0 lies on the surface")."""
    model = examples.bouncing_ball(e=0.7, g=G).system
    P = np.diag([1e-6, 1e-6])
    f = HybridKalmanFilter(model, np.array([1e-6, -1.0]), P)
    with pytest.warns(SplitPriorWarning, match=r"the step starts with the mean 0.001 "
                                               r"standard deviations of event 0's value .* "
                                               r"0.5 of the prior lies on the other side"):
        f.predict(0.1)
    with warnings.catch_warnings():
        warnings.simplefilter("error", SplitPriorWarning)
        HybridKalmanFilter(model, np.array([0.5, 0.0]), P).predict(0.1)
    with pytest.raises(ValueError, match=r"mean lies on the surface of event\(s\) \[0\]"):
        HybridKalmanFilter(model, np.array([0.0, -1.0]), P)
    # 1e-9 s before the impact: refused, in the filter's terms (it advised a
    # simultaneity_tol, which the filter does not take)
    near = HybridKalmanFilter(model, np.array([1e-9, -1.0]), P)
    with pytest.warns(SplitPriorWarning), pytest.raises(
            ValueError, match=r"the step of dt=0.1 starts 1e-09 s before an impact of event\(s\) "
                              r"\[0\], .* pass window= below 1e-09 \(the filter is left"):
        near.predict(0.1)
