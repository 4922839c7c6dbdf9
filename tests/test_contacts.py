"""bderiv.symbolic.contact_system against independent oracles.

Oracles: a two-link pendulum whose tip strikes the ground, written out by hand in numpy
(its mass matrix, Coriolis and gravity terms, tip gap and gradient, the plastic impact
``v - M^-1 J^T (J M^-1 J^T)^-1 J v``) and simulated with scipy's solve_ivp with event
detection written here; a ball's bounces in closed form; the inverse-mass coupling of two
walls at angle beta, ``sin(beta)``; a fresh build with other parameter values.
"""

from __future__ import annotations

import numpy as np
import pytest
from numpy.testing import assert_allclose
from scipy.integrate import solve_ivp

sp = pytest.importorskip("sympy")

from bderiv.analysis.system import HybridSystem  # noqa: E402
from bderiv.symbolic import ModelFunctions, contact_system, coupling  # noqa: E402

G = 9.81
LINK = dict(m1=1.0, m2=0.7, l1=1.0, l2=0.8, I1=0.1, I2=0.05, H=0.5, k=3000.0, c=30.0)


@pytest.fixture(scope="module")
def cache(tmp_path_factory):
    return tmp_path_factory.mktemp("contacts-cache")


# --- the two-link pendulum ------------------------------------------------------------
def two_link_equations():
    """The user's side: q = (q1, q2) (absolute angle of link 1 from the downward
    vertical, angle of link 2 relative to it), pivot at height H, tip gap to the floor."""
    q1, q2 = q = sp.symbols("q1 q2")
    P = {n: sp.Symbol(n) for n in LINK}
    m1, m2, l1, l2, I1, I2, H = (P[n] for n in ("m1", "m2", "l1", "l2", "I1", "I2", "H"))
    lc1, lc2 = l1 / 2, l2 / 2
    M = [[I1 + I2 + m1 * lc1**2 + m2 * (l1**2 + lc2**2 + 2 * l1 * lc2 * sp.cos(q2)),
          I2 + m2 * (lc2**2 + l1 * lc2 * sp.cos(q2))],
         [I2 + m2 * (lc2**2 + l1 * lc2 * sp.cos(q2)), I2 + m2 * lc2**2]]
    V = -G * (m1 * lc1 * sp.cos(q1) + m2 * (l1 * sp.cos(q1) + lc2 * sp.cos(q1 + q2)))
    forces = [-sp.diff(V, s) for s in q]
    tip = H - l1 * sp.cos(q1) - l2 * sp.cos(q1 + q2)
    law = lambda pen, rate: P["k"] * pen + P["c"] * rate  # noqa: E731
    return dict(q=q, mass_matrix=M, forces=forces, contacts=[tip], stance=law,
                params={P[n]: v for n, v in LINK.items()})


def link_oracle(x, p=LINK):
    """Hand-written M, Coriolis + gravity vector, tip gap and its gradient."""
    q1, q2, w1, w2 = x
    m1, m2, l1, l2, I1, I2 = (p[n] for n in ("m1", "m2", "l1", "l2", "I1", "I2"))
    lc1, lc2 = l1 / 2, l2 / 2
    c2 = np.cos(q2)
    M = np.array([[I1 + I2 + m1 * lc1**2 + m2 * (l1**2 + lc2**2 + 2 * l1 * lc2 * c2),
                   I2 + m2 * (lc2**2 + l1 * lc2 * c2)],
                  [I2 + m2 * (lc2**2 + l1 * lc2 * c2), I2 + m2 * lc2**2]])
    h = m2 * l1 * lc2 * np.sin(q2)
    coriolis = np.array([-h * (2 * w1 * w2 + w2**2), h * w1**2])
    gravity = np.array([G * (m1 * lc1 * np.sin(q1) + m2 * (l1 * np.sin(q1)
                                                           + lc2 * np.sin(q1 + q2))),
                        G * m2 * lc2 * np.sin(q1 + q2)])
    phi = p["H"] - l1 * np.cos(q1) - l2 * np.cos(q1 + q2)
    J = np.array([l1 * np.sin(q1) + l2 * np.sin(q1 + q2), l2 * np.sin(q1 + q2)])
    return M, coriolis + gravity, phi, J


def link_field(x, stance, p=LINK):
    M, cg, phi, J = link_oracle(x, p)
    force = -cg
    if stance:
        force = force + J * (p["k"] * -phi + p["c"] * -(J @ x[2:]))
    return np.concatenate((x[2:], np.linalg.solve(M, force)))


def link_impact(x):
    M, _, _, J = link_oracle(x)
    v = x[2:]
    w = np.linalg.solve(M, J)
    return np.concatenate((x[:2], v - w * (J @ v) / (J @ w)))


def central(f, x, h=1e-6):
    return np.array([(f(x + h * e) - f(x - h * e)) / (2 * h) for e in np.eye(x.size)]).T


@pytest.fixture(scope="module")
def link(cache):
    return contact_system(**two_link_equations(), cache_dir=cache)


STATES = [np.array([0.9, 0.7, -1.2, 2.0]), np.array([-0.4, 1.9, 0.8, -0.3]),
          np.array([2.5, -1.1, 0.3, 1.7])]


@pytest.mark.parametrize("x", STATES)
def test_two_link_field_and_jacobian_against_the_hand_written_equations(link, x):
    for mask in (0, 1):
        assert_allclose(ModelFunctions(link).field(x, mask), link_field(x, mask), rtol=1e-12,
                        atol=1e-11)
        assert_allclose(ModelFunctions(link).field_jacobian(x, mask),
                        central(lambda y, m=mask: link_field(y, m), x), rtol=1e-6, atol=1e-5)
    _, _, phi, J = link_oracle(x)
    assert_allclose(ModelFunctions(link).events(x), [-phi], rtol=1e-14)
    assert_allclose(ModelFunctions(link).event_jacobian(x), [[-J[0], -J[1], 0.0, 0.0]], atol=1e-15)


@pytest.mark.parametrize("x", STATES)
def test_two_link_plastic_impact_against_the_hand_derived_reset(link, x):
    after = ModelFunctions(link).reset(x, 0, 0)
    assert_allclose(after, link_impact(x), rtol=1e-12, atol=1e-13)
    J = link_oracle(x)[3]
    assert abs(J @ after[2:]) <= 1e-12 * np.abs(J).max() * np.abs(x[2:]).max()
    assert_allclose(ModelFunctions(link).reset_jacobian(x, 0, 0), central(link_impact, x),
                    rtol=1e-6, atol=1e-6)
    # a lift-off (bit set) does not move the state
    assert_allclose(ModelFunctions(link).reset(x, 1, 0), x)
    assert_allclose(ModelFunctions(link).reset_jacobian(x, 1, 0), np.eye(4))


def simulate_link(x0, T):
    """Flight until the tip touches, the hand-derived impact, stance until T (solve_ivp,
    events written here); the state at T."""
    tip = lambda t, y: link_oracle(y)[2]  # noqa: E731
    tip.terminal, tip.direction = True, -1.0
    opts = dict(rtol=1e-12, atol=1e-12, method="DOP853")
    a = solve_ivp(lambda t, y: link_field(y, False), (0.0, T), x0, events=tip, **opts)
    assert a.status == 1, "the tip must touch the ground before T"
    y = link_impact(a.y_events[0][0])
    b = solve_ivp(lambda t, y: link_field(y, True), (a.t_events[0][0], T), y, **opts)
    assert link_oracle(b.y[:, -1])[2] < 0.0  # still in stance
    return b.y[:, -1]


def test_plastic_flow_map_against_forward_differences_of_an_independent_simulation(link):
    x0 = np.array([1.3, 0.4, -1.0, -1.0])  # the tip strikes at t = 0.107 and stays down
    assert link_oracle(x0)[2] > 0.0
    T = 0.3
    assert [g.events for g in link.simulate(x0, T).groups] == [(0,)]
    D = link.flow_bderivative(x0, T)
    rng = np.random.default_rng(1)
    V = rng.standard_normal((4, 4))
    base = simulate_link(x0, T)
    for v in V:
        fd = [(simulate_link(x0 + eps * v, T) - base) / eps for eps in (1e-5, 1e-6)]
        err = [np.abs(f - D(v)).max() / np.abs(D(v)).max() for f in fd]
        assert min(err) < 2e-4, err


# --- a point mass, a floor and a wall at angle beta -----------------------------------
def corner(beta=0.0, e=0.0):
    x, y, b = sp.symbols("x y beta")
    return dict(q=[x, y], mass_matrix=sp.eye(2), forces=[0, -G],
                contacts=[y, sp.cos(b) * x + sp.sin(b) * y], impact=("restitution", e),
                params={b: beta})


@pytest.fixture(scope="module")
def walls(cache):
    return contact_system(**corner(), cache_dir=cache)


def test_ball_bounces_as_the_closed_form(walls):
    ball = walls.with_params(restitution=0.8)
    h0, T = 1.0, 2.0
    x0 = np.array([5.0, h0, 0.0, 0.0])  # far from the wall, no horizontal motion
    traj = ball.simulate(x0, T)
    # closed form: impacts at t1 = sqrt(2 h0 / g), then every 2 e^j g t1 / g
    t, u, times = np.sqrt(2 * h0 / G), G * np.sqrt(2 * h0 / G), []
    while t < T:
        times.append(t)
        u *= 0.8
        t += 2 * u / G
    got = [g.time for g in traj.groups]
    assert_allclose(got, times, rtol=1e-9)
    assert all(g.events == (0,) and g.bounced == (0,) for g in traj.groups)
    t_last = times[-1]
    u_last = G * np.sqrt(2 * h0 / G) * 0.8 ** len(times)
    s = T - t_last
    assert_allclose(traj.x_final[[1, 3]], [u_last * s - G * s**2 / 2, u_last - G * s],
                    rtol=1e-8, atol=1e-9)


def test_mass_orthogonal_contacts_accepted_and_coupled_ones_refused(walls):
    rho = np.array([0.0, 0.0, -1.0, -2.0])  # in the corner, moving into both walls
    assert_allclose(coupling(walls, rho), np.eye(2), atol=1e-15)
    bd = walls.bderivative(rho)  # plastic: both velocities stopped, the orders agree
    assert bd.n_events == 2
    beta = np.pi / 6
    tilted = walls.with_params(beta=beta)
    rho = np.array([0.0, 0.0, -1.0, -2.0])
    # closed form: J_0 = (0, 1), J_1 = (cos b, sin b), M = I: the coupling is sin(b)
    assert_allclose(coupling(tilted, rho), [[1.0, np.sin(beta)], [np.sin(beta), 1.0]],
                    rtol=1e-14)
    message = (r"contacts 0 \(phi = y\) and 1 \(phi = x\*cos\(beta\) \+ y\*sin\(beta\)\) "
               r"are hit at the same instant and are coupled through the inverse mass "
               r"matrix: J_0 M\^-1 J_1\^T = 0.5 .*impact=None.*one after the other")
    with pytest.raises(ValueError, match=message):
        tilted.bderivative(rho)
    x0 = np.array([0.1, 0.2 - 0.005 * G, -1.0, -2.0 + 0.1 * G])  # reaches rho at t = 0.1
    with pytest.raises(ValueError, match=message):
        tilted.simulate(x0, 0.2, simultaneity_tol=1e-9)
    # one at a time (not simultaneous) the tilted walls are fine
    tilted.simulate(x0 + np.array([0.05, 0.0, 0.0, 0.0]), 0.2)


def test_parameters_changed_without_rederiving_equal_a_fresh_build(walls, cache):
    changed = walls.with_params(beta=0.3, restitution=0.5, contact_stiffness=2e3)
    equations = corner(beta=0.3, e=0.5)
    equations["params"][sp.Symbol("contact_stiffness")] = 2e3
    fresh = contact_system(**equations, cache_dir=cache)
    # the same expressions: one cache entry
    assert fresh.source.build.key == changed.source.build.key
    assert type(changed) is HybridSystem and changed.param_values == fresh.param_values
    rng = np.random.default_rng(3)
    f_changed, f_fresh = ModelFunctions(changed), ModelFunctions(fresh)
    for x in rng.standard_normal((5, 4)):
        for mask in range(4):
            assert_allclose(f_changed.field(x, mask), f_fresh.field(x, mask), rtol=0, atol=0)
        assert_allclose(f_changed.reset(x, 0, 1), f_fresh.reset(x, 0, 1), rtol=0, atol=0)
    # on the compiled integrator: the parameters reach the kernels through its model
    assert changed.compiled is not None and changed.compiled is not walls.compiled
    x0 = np.array([0.3, 0.5, -1.0, 0.0])  # bounces between the floor and the leaning wall
    # its floor impacts (e = 0.5) accumulate at t = 0.80086: the runs end before
    a, b = changed.simulate(x0, 0.79), fresh.simulate(x0, 0.79)
    assert [g.events for g in a.groups] == [g.events for g in b.groups]
    assert {k for g in a.groups for k in g.events} == {0, 1}
    assert_allclose([g.time for g in a.groups], [g.time for g in b.groups], rtol=0, atol=0)
    assert_allclose(a.x_final, b.x_final, rtol=0, atol=0)


def test_a_rebound_too_small_to_follow_is_refused_not_run_through_the_floor(walls):
    """Past the accumulation of the floor impacts (t = 0.80086) the last rebound rises
    1.5e-17 (post-impact rate 1.7e-8, just above the grazing threshold) and falls back
    within a rounding of the floor: the ball fell through it, out of contact, to y = -0.19
    at t = 1 (mask 0b00) on 9ccdcc3. Oracle: the floor (y >= 0 out of contact)."""
    changed = walls.with_params(beta=0.3, restitution=0.5, contact_stiffness=2e3)
    try:
        traj = changed.simulate(np.array([0.3, 0.5, -1.0, 0.0]), 1.0)
    except ValueError as err:
        assert "event 0" in str(err) and "too small to follow" in str(err), str(err)
        return
    for x, mask in zip(traj.x, traj.masks, strict=True):
        assert mask & 1 or x[1] >= -1e-9, (x, bin(mask))


# --- refusals (before any derivation or compilation) ----------------------------------
def test_bad_input_is_refused_with_the_argument_named(tmp_path):
    x, y, vx, k = sp.symbols("x y x_dot k")
    ok = dict(q=[x, y], mass_matrix=sp.eye(2), forces=[0, -G], contacts=[y],
              cache_dir=tmp_path)
    cases = [
        (dict(q=[x, 2]), TypeError, r"q\[1\] must be a sympy Symbol"),
        (dict(mass_matrix=sp.eye(3)), ValueError, r"mass_matrix must be 2 x 2 .* \(3, 3\)"),
        (dict(mass_matrix=[[1, x], [0, 1]]), ValueError, "mass_matrix must be symmetric"),
        (dict(forces=[0]), ValueError, r"forces must have 2 expressions"),
        (dict(contacts=[y + vx]), ValueError, r"contacts\[0\] = .* contains x_dot, which "
                                              r"are not coordinates or parameters"),
        (dict(forces=[k, 0]), ValueError, r"forces\[0\] = k contains k, which are neither"),
        (dict(impact=1.5), ValueError, r"restitution e must be in \[0, 1\], got 1.5"),
        (dict(impact="elastic"), ValueError, "impact must be 'plastic'"),
        (dict(impact=[0.5]), TypeError, "impact must be 'plastic'"),
        (dict(stance=[None]), TypeError, "stance must be None, a callable"),
        (dict(params=[1.0]), TypeError, "params must be a mapping"),
    ]
    for change, error, message in cases:
        with pytest.raises(error, match=message):
            contact_system(**{**ok, **change})
    assert not any(tmp_path.rglob("*.py"))  # nothing was generated


# --- the quadruped (slow: its first build compiles for about 30 s of CPU) -------------
@pytest.fixture(scope="module")
def quadruped_system():
    from bderiv.examples.quadruped import quadruped

    return quadruped()


@pytest.mark.slow
def test_quadruped_feet_are_orthogonal_with_vertical_legs_and_refused_pitched(
        quadruped_system):
    system = quadruped_system
    x = np.zeros(14)
    x[1], x[3:7] = 0.5, 0.5  # theta = 0: every foot on the ground
    C = coupling(system, x)
    # an impulse at a foot shortens its own leg only: M^-1 J_k^T = -e_{l_k} / m_foot
    assert_allclose(C, np.eye(4) / 0.05, atol=1e-12)
    # nose down by 0.2, the front feet (2, 3) land together, the hind ones are still up
    th, b = -0.2, 0.4
    x = np.zeros(14)
    x[2], x[3:7] = th, 0.5
    x[1] = 0.5 * np.cos(th) - b * np.sin(th) + 0.01  # front feet 0.01 above the ground
    x[8] = -1.0
    assert coupling(system, x)[2, 3] != 0.0
    with pytest.raises(ValueError, match=r"contacts 2 \(phi = .*\) and 3 .* are hit at the "
                                         r"same instant and are coupled"):
        system.simulate(x, 0.05, simultaneity_tol=1e-9)


@pytest.mark.slow
def test_quadruped_pronking_orbit_is_found_and_stable(quadruped_system):
    from bderiv.examples.quadruped import quadruped_orbit

    orb = quadruped_orbit(quadruped_system)
    assert orb.residual < 1e-10
    assert [(g.events, g.directions) for g in orb.trajectory.groups] == [
        ((0, 1, 2, 3), (1, 1, 1, 1)), ((0, 1, 2, 3), (-1, -1, -1, -1))]
    assert abs(orb.x0[2]) < 1e-12 and abs(orb.advance[0]) < 1e-9  # pronking in place
    # the return map against the simulation: one stride's differences
    V = np.zeros((2, 14))
    V[0, 1], V[1, 3:7] = 1.0, 1.0
    from bderiv.analysis.checks import fd_check
    from bderiv.examples.quadruped import apex_section

    fd = fd_check(quadruped_system, orb.x0, 2.0, V, orb.return_map(V), eps=(1e-5, 1e-6),
                  section=apex_section)
    assert min(fd.max_errors) < 1e-4, fd.max_errors
    assert orb.stability(n_directions=50, iterations=60).stable


@pytest.mark.slow
def test_demo_quadruped(capsys, quadruped_system):
    """``bderiv demo --example quadruped``: orbit, groups, couplings, verdict."""
    import json

    from bderiv.cli.parser import main

    assert main(["demo", "--example", "quadruped", "--json"]) == 0
    res = json.loads(capsys.readouterr().out)
    assert res["orbit"]["residual"] < 1e-10 and res["stability"]["stable"] is True
    assert [g["directions"] for g in res["groups"]] == [[1] * 4, [-1] * 4]
    assert max(g["coupling"] for g in res["groups"]) < 1e-12
    assert res["coupling"]["max_relative"] > 1e-3
