"""Bounces and leg swaps (issue 24): resets that send the state back to the side it came
from. The examples (bouncing ball, ball in a corner, rimless wheel, compass gait) against
closed forms, the saltation formula written out here, finite differences of closed-form
flows, a scipy simulation of Garcia et al.'s walker, and their published numbers."""

from __future__ import annotations

import numpy as np
import pytest
from garcia_walker import garcia_stride
from scipy.integrate import quad

from bderiv import HybridSystem
from bderiv.examples import bounces, walkers
from bderiv.examples.walkers._compass import _Compass

G = 9.81


# ----------------------------------------------------------------------------------
# the bouncing ball
# ----------------------------------------------------------------------------------
def _ball_flow(x, T, e, g=G):
    """The ball's state at T from x = (q, v), q > 0, in closed form (impacts by the
    quadratic formula, the rebound velocity -e v)."""
    q, v, t = float(x[0]), float(x[1]), 0.0
    while True:
        hit = (v + np.sqrt(v * v + 2 * g * q)) / g  # q + v s - g s^2 / 2 = 0, s > 0
        if t + hit > T:
            s = T - t
            return np.array([q + v * s - 0.5 * g * s * s, v - g * s])
        t, q, v = t + hit, 0.0, -e * (v - g * hit)


def test_ball_bounces_at_the_closed_form_times_with_velocities_e_to_the_k():
    e, height = 0.8, 1.0
    ex = bounces.bouncing_ball(e=e, height=height)
    traj = ex.system.simulate(ex.x0, 3.0)
    v1 = np.sqrt(2 * G * height)
    k = np.arange(1, len(traj.groups) + 1)
    # t_k = t_1 + 2 (e + ... + e^(k-1)) v_1 / g
    times = np.sqrt(2 * height / G) + 2 * v1 / G * (e - e**k) / (1 - e)
    assert len(traj.groups) == 6  # the 7th impact is at 3.12 s
    np.testing.assert_allclose([g.time for g in traj.groups], times, rtol=1e-10)
    np.testing.assert_allclose([g.state_after[1] for g in traj.groups], e**k * v1, rtol=1e-9)
    for g in traj.groups:  # every impact an upward crossing of h = -q, its bit kept
        assert g.events == (0,) and g.directions == (1,)
        assert g.mask_before == g.mask_after == 0 and g.bounced == (0,)
    np.testing.assert_allclose(traj.x_final, _ball_flow(ex.x0, 3.0, e), rtol=1e-9, atol=1e-10)


def test_ball_flow_bderivative_across_bounces_matches_the_closed_form_flow():
    """Four bounces; central differences of the closed-form flow (each impact is one
    event, so the flow is smooth at x0 and its B-derivative linear)."""
    e, T = 0.7, 2.0
    ex = bounces.bouncing_ball(e=e)
    x0 = np.array([0.8, 1.3])
    D = ex.system.flow_bderivative(x0, T)
    assert len(D.group_times) == 4
    h = 1e-6
    J = np.column_stack([(_ball_flow(x0 + h * d, T, e) - _ball_flow(x0 - h * d, T, e)) / (2 * h)
                         for d in np.eye(2)])
    np.testing.assert_allclose(D(np.eye(2)).T, J, rtol=1e-7, atol=1e-7)


def test_bouncing_ball_refuses_bad_parameters():
    with pytest.raises(ValueError, match="restitution e must be between 0 and 1, got 1.5"):
        bounces.bouncing_ball(e=1.5)
    with pytest.raises(ValueError, match="height and g must be > 0"):
        bounces.bouncing_ball(height=-1.0)


# ----------------------------------------------------------------------------------
# one impact on random systems: the saltation formula with reset
# ----------------------------------------------------------------------------------
def _random_system(rng, landing):
    """A random smooth system in R^3 with one event at rho and a reset that lands
    ``"back"`` (off the surface, where it came from: a leg swap), on the surface with
    the flow leaving it (``"bounce"``) or on the far side (``"far"``: bit flipped).

    Fields ``A_m (x - rho) + b_m + (x - rho).(x - rho) q_m``; event ``c.(x - rho) +
    (x - rho)^T H (x - rho) / 2`` (linear for the bounce: the reset keeps it on it);
    reset ``rho + s + L (x - rho) + ((x - rho).(x - rho)) p``."""
    d = 3
    rho = rng.standard_normal(d)
    A, b = rng.standard_normal((2, d, d)), rng.standard_normal((2, d))
    q = rng.standard_normal((2, d))
    c = rng.standard_normal(d)
    H = np.zeros((d, d)) if landing == "bounce" else 0.2 * rng.standard_normal((d, d))
    H = 0.5 * (H + np.transpose(H))
    if c @ b[0] < 0:  # crossing upward from region 0
        b[0] = -b[0]
    L, p = rng.standard_normal((d, d)), 0.3 * rng.standard_normal(d)
    tangent = np.linalg.svd(c[None])[2][1:]  # rows: a basis of c's orthogonal complement
    if landing == "bounce":  # on the surface, the flow of both regions leaving it
        s = rng.standard_normal(2) @ tangent
        for m in (0, 1):  # the rate -1 at rho + s, by the quadratic term (0 at rho)
            rate = c @ (A[m] @ s + b[m] + (s @ s) * q[m])
            q[m] -= (rate + 1.0) / (s @ s) * c / (c @ c)
    else:  # off the surface by one unit of c, back or across
        s = ((-1.0 if landing == "back" else 1.0) * c / (c @ c)
             + 0.3 * rng.standard_normal(2) @ tangent)
        if landing == "far" and c @ (A[1] @ s + b[1]) < 0:
            b[1] -= 2 * (c @ (A[1] @ s + b[1])) * c / (c @ c)  # crossing still, after

    def field(x, mask):
        y = x - rho
        return A[mask] @ y + b[mask] + (y @ y) * q[mask]

    def field_jacobian(x, mask):
        return A[mask] + 2.0 * np.outer(q[mask], x - rho)

    def events(x):
        y = x - rho
        return np.array([c @ y + 0.5 * y @ H @ y])

    def event_jacobian(x):
        return (c + H @ (x - rho))[None]

    def reset(x, mask, k):
        y = x - rho
        return rho + s + L @ y + (y @ y) * p

    def reset_jacobian(x, mask, k):
        return L + 2.0 * np.outer(p, x - rho)

    system = HybridSystem(field, events, n_events=1, dim=d, event_jacobian=event_jacobian,
                          field_jacobian=field_jacobian, reset=reset,
                          reset_jacobian=reset_jacobian)
    return system, rho, field, reset, reset_jacobian, c


@pytest.mark.parametrize("seed", range(6))
@pytest.mark.parametrize("landing", ["back", "bounce", "far"])
def test_single_impact_bderivative_is_the_saltation_matrix_with_reset(seed, landing):
    """Xi = R + (f+ - R f-) Dh / (Dh f-), f+ the field at the reset state of the region
    it lands in: region 0 (bit kept) after a leg swap or a bounce, region 1 after."""
    rng = np.random.default_rng(100 * seed + len(landing))
    system, rho, field, reset, reset_jacobian, c = _random_system(rng, landing)
    R = reset_jacobian(rho, 0, 0)
    f_minus = field(rho, 0)
    f_plus = field(reset(rho, 0, 0), 1 if landing == "far" else 0)
    Xi = R + np.outer(f_plus - R @ f_minus, c) / (c @ f_minus)
    M = system.bderivative(rho)
    np.testing.assert_allclose(M.piece([0]), Xi, rtol=1e-12, atol=1e-12)
    V = rng.standard_normal((5, 3))
    np.testing.assert_allclose(M(V), V @ Xi.T, rtol=1e-12, atol=1e-12)


# ----------------------------------------------------------------------------------
# the ball in a corner: two bounces at once
# ----------------------------------------------------------------------------------
def _corner_flow(x, T, e, g=G):
    """The ball in the right-angled corner x, y >= 0 in closed form: the walls act on
    orthogonal components, so x and y bounce independently (x: at most one impact, the
    ball then moves away; y: under gravity, impacts by the quadratic formula)."""
    px, py, vx, vy = (float(v) for v in x)
    hit = -px / vx if vx < 0 else np.inf
    px, vx = (px + vx * T, vx) if T < hit else (-e * vx * (T - hit), -e * vx)
    y = _ball_flow(np.array([py, vy]), T, e, g)
    return np.array([px, y[0], vx, y[1]])


def test_right_corner_double_bounce_flow_matches_closed_form_differences():
    """Directions on both sides of the simultaneous impact (floor first, wall first);
    one-sided differences of the closed-form flow agree to O(eps). Both pieces are the
    same map: the walls act on orthogonal components (the B-derivative is linear)."""
    e = 0.8
    ex = bounces.ball_in_corner(e=e)
    traj = ex.system.simulate(ex.x0, ex.t_final, simultaneity_tol=1e-7)
    np.testing.assert_allclose(traj.x_final, _corner_flow(ex.x0, ex.t_final, e), rtol=1e-9,
                               atol=1e-10)
    D = ex.system.flow_bderivative(ex.x0, ex.t_final)
    assert list(D.group_events) == [(0, 1)]
    V = np.random.default_rng(3).standard_normal((12, 4))
    V /= np.linalg.norm(V, axis=1)[:, None]
    orders = {tuple(int(k) for k in o) for o in D.orders(V)[0]}
    assert orders == {(0, 1), (1, 0)}
    base = _corner_flow(ex.x0, ex.t_final, e)
    DV = D(V)
    errors = []
    for eps in (1e-5, 1e-6):
        fd = np.array([(_corner_flow(ex.x0 + eps * v, ex.t_final, e) - base) / eps for v in V])
        errors.append(np.abs(fd - DV).max() / np.abs(DV).max())
    assert errors[1] < 1e-5 and errors[1] < errors[0] / 5  # O(eps)
    M = ex.system.bderivative(ex.rho)
    np.testing.assert_allclose(M.piece([0, 1]), M.piece([1, 0]), atol=1e-13)


def test_sixty_degree_corner_is_refused_naming_the_two_walls():
    ex = bounces.ball_in_corner(angle=np.pi / 3)
    with pytest.raises(ValueError, match=r"resets of events 0 and 1 .* do not commute"):
        ex.system.bderivative(ex.rho)
    with pytest.raises(ValueError, match=r"resets of events \[0, 1\].* do not commute"):
        ex.system.simulate(ex.x0, ex.t_final, simultaneity_tol=1e-7)


def test_ball_in_corner_refuses_bad_angles():
    with pytest.raises(ValueError, match="angle must be in"):
        bounces.ball_in_corner(angle=np.pi)


# ----------------------------------------------------------------------------------
# the rimless wheel
# ----------------------------------------------------------------------------------
@pytest.mark.parametrize(("alpha", "slope"), [(np.pi / 8, 0.08), (np.pi / 6, 0.2)])
def test_rimless_wheel_orbit_and_multiplier_match_the_energy_balance(alpha, slope):
    """omega^2 after an impact maps as u -> c^2 (u + 4 sin(alpha) sin(slope)), c =
    cos(2 alpha) (g = leg = 1): fixed point u* = c^2 K / (1 - c^2), multiplier c^2; the
    period is the integral of dtheta / omega over a step."""
    ex = walkers.rimless_wheel(alpha=alpha, slope=slope)
    orbit = walkers.rimless_wheel_orbit(ex, perturbation=(0.0, 0.1))
    c2, K = np.cos(2 * alpha) ** 2, 4 * np.sin(alpha) * np.sin(slope)
    u = c2 * K / (1 - c2)

    def omega(theta):  # energy from theta = -alpha
        return np.sqrt(u + 2 * (np.cos(slope - alpha) - np.cos(theta + slope)))

    np.testing.assert_allclose(orbit.x0, [0.0, omega(0.0)], atol=1e-10)
    period = quad(lambda th: 1 / omega(th), -alpha, alpha, epsabs=1e-13, epsrel=1e-13)[0]
    assert abs(orbit.period - period) < 1e-9
    (group,) = orbit.trajectory.groups
    assert group.mask_before == group.mask_after == 0 and group.bounced == (0,)
    np.testing.assert_allclose(group.state_after, [-alpha, np.sqrt(u)], atol=1e-10)
    (mult,) = orbit.stability(n_directions=10, iterations=50).multipliers.values()
    assert abs(mult[0] - c2) < 1e-9


def test_rimless_wheel_refuses_a_wheel_that_cannot_roll_over():
    with pytest.raises(ValueError, match="stops before rolling over its spoke"):
        walkers.rimless_wheel(alpha=np.pi / 5, slope=0.01)


# ----------------------------------------------------------------------------------
# the compass gait: Garcia et al.'s simplest walker
# ----------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def compass_orbit():
    return walkers.compass_gait_orbit()


def test_compass_gait_matches_garcia_fixed_point(compass_orbit):
    groups = compass_orbit.trajectory.groups
    # a scuff (downward, no jump) and a heel strike (upward, the legs swapped)
    assert [g.directions for g in groups] == [(1,), (-1,)]
    strike, scuff = groups
    assert np.array_equal(scuff.state, scuff.state_after)
    th, ph, thd, phd = strike.state_after
    assert abs(th - walkers.GARCIA_FIXED_POINT[0]) < 1e-9
    assert abs(thd - walkers.GARCIA_FIXED_POINT[1]) < 1e-9
    np.testing.assert_allclose([ph, phd], [2 * th, thd * (1 - np.cos(2 * th))], atol=1e-12)


def test_compass_gait_eigenvalues_match_garcia_and_finite_differences(compass_orbit):
    R = compass_orbit.return_map
    from bderiv.analysis.stability import piece_multipliers

    mult = piece_multipliers(R.piece([[0], [0]]), R.tangent_basis)
    assert abs(mult[2]) < 1e-9  # the leg swap forgets a direction: rank 2 on the section
    pair = sorted(mult[:2], key=lambda z: z.imag)
    published = sorted(walkers.GARCIA_EIGENVALUES, key=lambda z: z.imag)
    assert np.abs(np.subtract(pair, published)).max() < 2e-3  # their digits: to 1.7e-3
    z, h = np.array(walkers.GARCIA_FIXED_POINT), 1e-6
    J = np.column_stack([(garcia_stride(z + h * d) - garcia_stride(z - h * d)) / (2 * h)
                         for d in np.eye(2)])
    fd = sorted(np.linalg.eigvals(J), key=lambda z: z.imag)
    assert np.abs(np.subtract(pair, fd)).max() < 1e-7


def test_compass_gait_refuses_a_heel_strike_behind_the_stance_leg():
    ex = walkers.compass_gait()
    x = np.array([0.1, 0.2, -0.3, 0.1])  # h = 0 with phi > 0: the scuff, crossed upward
    with pytest.raises(ValueError, match="swing leg behind the stance leg"):
        ex.system.bderivative(x)


# ----------------------------------------------------------------------------------
# the command line and the figure
# ----------------------------------------------------------------------------------
def test_demo_rimless_wheel_prints_the_gait_beside_its_closed_forms(capsys):
    from bderiv.cli import main

    assert main(["demo", "--example", "rimless-wheel"]) == 0
    out = capsys.readouterr().out
    assert "event 0 crossed up" in out and "the bit kept" in out
    c2 = np.cos(np.pi / 4) ** 2
    assert f"multiplier: {c2:.10f} / {c2:.10f}" in out
    assert main(["demo", "--example", "compass-gait", "--n", "3"]) == 2  # a network option
    assert "--n and --extended are options of --example network" in capsys.readouterr().err


def test_the_impacts_figure_script_draws_the_three_cases(tmp_path):
    pytest.importorskip("matplotlib")
    import importlib.util
    import pathlib

    tool = pathlib.Path(__file__).resolve().parents[1] / "tools" / "impacts_figure.py"
    spec = importlib.util.spec_from_file_location("bderiv_impacts_figure", tool)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    # the third case: the bit set at the landing, cleared at the lift-off, no other event
    system, x0, t_final = module.compliant_landing()
    traj = system.simulate(x0, t_final)
    assert [(g.directions, g.mask_after) for g in traj.groups] == [((1,), 1), ((-1,), 0)]
    module.main([str(tmp_path / "impacts.png")])
    assert (tmp_path / "impacts.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_compass_gait_refuses_bad_parameters_and_a_start_that_does_not_step():
    with pytest.raises(ValueError, match="leg_com must be in"):
        walkers.compass_gait(leg_com=0.0)
    with pytest.raises(ValueError, match="start must be two finite numbers"):
        walkers.compass_gait(start=(0.2,))
    with pytest.raises(ValueError, match="does not complete a step"):
        walkers.compass_gait(start=(0.2, 0.5))  # rolling backward


@pytest.mark.parametrize(("leg_mass", "leg_com"), [(5.0, 0.5), (0.3, 1.0), (1e-3, 0.8)])
def test_compass_heel_strike_is_the_rigid_impact_of_the_floating_walker(leg_mass, leg_com):
    """The leg swap's velocities against the impulsive dynamics of the free walker,
    written out here: coordinates (hip x, hip y, theta, psi) (psi = theta - phi, the swing
    leg's absolute angle), M (q'+ - q'-) = J^T lambda with the new stance foot stopped,
    J q'+ = 0 (no impulse on the old stance foot, which lifts off). Legs with mass (the
    massless limit is checked against Garcia et al.'s gait above)."""
    hip_mass, leg = 10.0, 1.2
    model = _Compass(hip_mass, leg_mass, leg, leg_com, 0.05, 9.81)
    b = leg_com * leg  # the leg mass from the hip

    def u(a):
        return np.array([-np.sin(a), np.cos(a)]), np.array([-np.cos(a), -np.sin(a)])

    theta, psi, thd, psd = -0.21, 0.23, -0.9, 0.4  # psi = theta - phi; phi < 0: ahead
    x = np.array([theta, theta - psi, thd, thd - psd])
    (_, du_t), (_, du_p) = u(theta), u(psi)
    # Jacobians of the point masses in (xh, yh, theta, psi): hip, stance mass, swing mass
    I2 = np.eye(2)
    J = [np.column_stack([I2, np.zeros((2, 2))]),
         np.column_stack([I2, -b * du_t, np.zeros(2)]),
         np.column_stack([I2, np.zeros(2), -b * du_p])]
    masses = [hip_mass, leg_mass, leg_mass]
    M = sum(m * Ji.T @ Ji for m, Ji in zip(masses, J, strict=True))
    J_foot = np.column_stack([I2, np.zeros(2), -leg * du_p])  # the new stance foot
    qd_minus = np.array([*(leg * thd * du_t), thd, psd])  # the old stance foot at rest
    K = np.block([[M, -J_foot.T], [J_foot, np.zeros((2, 2))]])
    qd_plus = np.linalg.solve(K, np.concatenate([M @ qd_minus, np.zeros(2)]))[:4]
    new_theta_rate, new_psi_rate = qd_plus[3], qd_plus[2]  # the legs' roles swapped
    after = model.reset(x, 0, 0)
    np.testing.assert_allclose(after[:2], [psi, psi - theta], atol=1e-15)
    np.testing.assert_allclose(after[2:], [new_theta_rate, new_theta_rate - new_psi_rate],
                               rtol=1e-9, atol=1e-12)


def test_export_of_the_corner_double_bounce_round_trips(tmp_path, capsys):
    from bderiv.cli import main

    assert main(["export", "--example", "ball-in-corner", "--out", str(tmp_path / "tri"),
                 "--format", "npz"]) == 0
    out = capsys.readouterr().out
    assert "triangulation of 2 events in R^4" in out
    error = float(out.split("max |tri(V) - M(V)| = ")[1].split()[0])
    assert error < 1e-12


def test_an_impact_within_the_tolerance_of_the_start_is_refused():
    """The ball 1e-10 above the floor, falling at 1: its bounce at t = 1e-10 was taken as a
    saltation for every direction, but a start lowered by more than 1e-10 is below the
    floor, never bounces, and ends a whole bounce away (a review): refused, as a group with
    resets at the final time is. From 1e-3 above, or with a simultaneity_tol below the
    gap, the map is the closed form's: the flights before and after the bounce and its
    saltation ``[[-e, 0], [-(1 + e) g / v, -e]]`` (v the impact's velocity)."""
    e, g = 0.8, 9.81
    system = bounces.bouncing_ball(e=e).system
    with pytest.raises(ValueError, match=r"an event group with resets at the start: event\(s\) "
                                         r"\[0\] cross at t = 1e-10, within "
                                         r"simultaneity_tol=1e-07"):
        system.flow_bderivative(np.array([1e-10, -1.0]), 0.1)
    for gap, tol in ((1e-3, None), (1e-10, 1e-11)):
        t_hit = (np.sqrt(1.0 + 2.0 * g * gap) - 1.0) / g  # gap - t - g t^2 / 2 = 0
        v = -1.0 - g * t_hit
        S = np.array([[-e, 0.0], [-(1 + e) * g / v, -e]])
        def flight(t):
            return np.array([[1.0, t], [0.0, 1.0]])

        D = system.flow_bderivative(np.array([gap, -1.0]), 0.1, simultaneity_tol=tol)
        np.testing.assert_allclose(D(np.eye(2)), (flight(0.1 - t_hit) @ S @ flight(t_hit)).T,
                                   rtol=1e-4, atol=1e-9)


@pytest.mark.parametrize("compiled", [False, True])
def test_a_reset_that_edits_its_argument_is_given_a_copy(compiled):
    """``x[3] = -e x[3]; return x``, the natural idiom, edited the state the library held:
    at a ball's two simultaneous impacts each velocity was reset twice (simulate ended at
    [-0.05, -0.392, -0.25, -2.94]), and a single bounce's flow B-derivative was wrong,
    silently, Python and numba alike (a review). Closed forms: the flight after the
    corner, and the copying reset's map (itself checked against closed forms above)."""
    import numba

    g = 9.81

    def field(x, mask):
        return np.array([x[2], x[3], 0.0, -g])

    def events(x):
        return np.array([-x[1], -x[0]])

    def in_place(x, mask, k):
        if k == 0:
            x[3] = -0.7 * x[3]
        else:
            x[2] = -0.5 * x[2]
        return x

    def copying(x, mask, k):
        return in_place(x.copy(), mask, k)

    if compiled:
        field, events, in_place = numba.njit(field), numba.njit(events), numba.njit(in_place)
    t0, T = 0.3, 0.5  # both walls reached at t0 with velocity (-1, -2)
    x0 = np.array([t0, 2 * t0 - 0.5 * g * t0**2, -1.0, -2.0 + g * t0])
    edits = HybridSystem(field, events, n_events=2, dim=4, reset=in_place)
    copies = HybridSystem(field, events, n_events=2, dim=4, reset=copying)
    s = T - t0  # after: (0.5, 1.4) for s
    np.testing.assert_allclose(edits.simulate(x0, T).x_final,
                               [0.5 * s, 1.4 * s - 0.5 * g * s**2, 0.5, 1.4 - g * s],
                               rtol=1e-9, atol=1e-12)
    V = np.random.default_rng(2).standard_normal((6, 4))
    np.testing.assert_allclose(edits.flow_bderivative(x0, T)(V),
                               copies.flow_bderivative(x0, T)(V), rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("compiled", [False, True])
def test_functions_that_write_into_their_argument_are_given_copies(compiled):
    """A field that writes its derivative into ``x`` and returns it, events and a section
    that round ``x`` in place: the Python path handed them the integrator's own state, so
    a fall under gravity through a floor at 0.5 ended at [-1.0, -1.0] with no event (a
    review); the compiled integrator copied already. Closed form: x = 2 t - t**2 / 2 to
    the floor at t1 = 2 - sqrt(3), then the rate -1.5 (mask 1)."""
    import numba

    def field(x, mask):
        v = x[1]
        x[1] = -1.0 - 0.5 * (mask & 1)
        x[0] = v
        return x

    def events(x):
        x[0] = x[0] + 0.0 * x[1]  # a write of the same value: harmless, but a write
        return np.array([x[0] - 0.5])

    def section(x):
        x[1] = 0.0
        return -x[0] - 0.2

    if compiled:
        field, events, section = numba.njit(field), numba.njit(events), numba.njit(section)
    s = HybridSystem(field, events, n_events=1, dim=2)
    t1 = 2.0 - np.sqrt(3.0)
    traj = s.simulate([0.0, 2.0], 1.0)
    assert len(traj.groups) == 1 and traj.groups[0].time == pytest.approx(t1, abs=1e-9)
    v1 = 2.0 - t1
    np.testing.assert_allclose(traj.x_final, [0.5 + v1 * (1 - t1) - 0.75 * (1 - t1) ** 2,
                                              v1 - 1.5 * (1 - t1)], rtol=1e-9)
    # a section's function that writes: reached from -0.1 at rest at x0 = -0.2
    back = s.simulate([-0.1, 0.0], 5.0, section=section)
    assert back.x_final[1] == pytest.approx(-np.sqrt(0.2), rel=1e-9)


def test_a_guard_and_jacobians_that_write_into_their_argument_change_nothing():
    """A review: a reset_guard that wrote into its x moved the run (a ball's group state
    0.5 above the floor, and its x_final with it); an event_jacobian that wrote into x was
    checked at the moved point and a correct one refused; bderiv.check_jacobians handed
    the given Jacobians its own x and reported correct ones FAILED. Each now gets a copy:
    the same answers as the clean twins."""
    from bderiv import check_jacobians

    g = 9.81

    def field(x, mask):
        return np.array([x[1], -g])

    def events(x):
        return np.array([-x[0]])

    def reset(x, mask, k):
        return np.array([x[0], -0.8 * x[1]])

    def guard(x, mask, k):
        x[0] = 0.5

    plain = HybridSystem(field, events, n_events=1, dim=2, reset=reset)
    guarded = HybridSystem(field, events, n_events=1, dim=2, reset=reset, reset_guard=guard)
    a, b = (s.simulate(np.array([1.0, 0.0]), 1.0) for s in (plain, guarded))
    np.testing.assert_array_equal(a.x_final, b.x_final)
    assert a.groups[0].state[0] == b.groups[0].state[0] == 0.0  # on the floor

    def tilted(x):
        return np.array([x[0] + 0.1 * x[1] ** 2 - 1.0])

    def event_jacobian(x):
        J = np.array([[1.0, 0.2 * x[1]]])
        x[1] += 1.0
        return J

    def slowed(x, mask):
        return np.array([1.0, 0.5 if mask else 1.0])

    clean = HybridSystem(slowed, tilted, n_events=1, dim=2,
                         event_jacobian=lambda x: np.array([[1.0, 0.2 * x[1]]]))
    writes = HybridSystem(slowed, tilted, n_events=1, dim=2, event_jacobian=event_jacobian)
    V = np.array([[1.0, 0.0], [0.3, -0.7]])
    x0 = np.array([0.0, 0.3])
    np.testing.assert_array_equal(writes.flow_bderivative(x0, 2.0)(V),
                                  clean.flow_bderivative(x0, 2.0)(V))

    def field_jacobian(x, mask):
        J = np.array([[0.0, 1.0], [0.0, 0.0]])
        x[0] += 1.0
        return J

    x = np.array([0.5, 1.0])
    report = check_jacobians(HybridSystem(field, events, n_events=1, dim=2,
                                          field_jacobian=field_jacobian), x)
    assert not report.failures and x.tolist() == [0.5, 1.0]
