"""Where a reset lands (mathematics.md section 9): the rule of ``crossings.landing`` and
the reset engine's pieces and inverse when a reset sends the state back.

Oracles: the saltation matrix with reset written out here, and the cases' geometry (which
side each state is on, which way its flow goes) chosen by hand.
"""

import numpy as np
import pytest

from bderiv import BDerivative, HybridSystem


def _line(reset, field_after=None):
    """A point moving right at speed 1 in region 0 towards the surface x = 0 (h = x);
    ``field_after`` the field of region 1 (default: the same)."""
    def field(x, mask):
        if mask & 1 and field_after is not None:
            return np.array([field_after, 0.0])
        return np.array([1.0, 0.0])

    return HybridSystem(field, lambda x: x[:1], n_events=1, dim=2,
                        field_jacobian=lambda x, m: np.zeros((2, 2)),
                        event_jacobian=lambda x: np.array([[1.0, 0.0]]),
                        reset=reset, reset_jacobian=lambda x, m, k: np.eye(2))


def test_landing_on_the_far_side_flips_the_bit():
    traj = _line(lambda x, m, k: x + np.array([0.5, 0.0])).simulate(np.array([-1.0, 0.0]), 2.0)
    (group,) = traj.groups
    assert group.mask_after == 1 and group.bounced == ()
    assert traj.x_final[0] == pytest.approx(1.5, abs=1e-9)


def test_a_leg_swap_lands_back_and_the_surface_is_crossed_again():
    """Put back at x = -0.5 each time: crossings at t = 1, 1.5, 2.0, 2.5 ..."""
    traj = _line(lambda x, m, k: np.array([-0.5, x[1] + 1.0])).simulate(
        np.array([-1.0, 0.0]), 2.25)
    assert [round(g.time, 9) for g in traj.groups] == [1.0, 1.5, 2.0]
    assert all(g.bounced == (0,) and g.mask_after == 0 for g in traj.groups)
    assert [r.direction for r in traj.events] == [1, 1, 1]
    assert traj.x_final == pytest.approx([-0.25, 3.0])


def test_a_bounce_on_the_surface_keeps_the_bit():
    """The velocity is the second coordinate: x' = v; the reset reverses it."""
    def field(x, mask):
        return np.array([x[1], 0.0])

    system = HybridSystem(field, lambda x: x[:1], n_events=1, dim=2,
                          field_jacobian=lambda x, m: np.array([[0.0, 1.0], [0.0, 0.0]]),
                          event_jacobian=lambda x: np.array([[1.0, 0.0]]),
                          reset=lambda x, m, k: np.array([x[0], -0.5 * x[1]]),
                          reset_jacobian=lambda x, m, k: np.diag([1.0, -0.5]))
    traj = system.simulate(np.array([-1.0, 1.0]), 3.0)
    (group,) = traj.groups
    assert group.bounced == (0,) and group.mask_after == 0
    assert traj.x_final == pytest.approx([-1.0, -0.5])  # back 2 s at speed 0.5
    flow = system.flow_bderivative(np.array([-1.0, 1.0]), 3.0)
    assert flow.group_masks == ((0, 0),)  # what the demo reports: the bit kept


def test_a_plastic_impact_on_compliant_ground_stays_in_contact():
    """A mass falling on a spring-damper ground (h = -height) whose impact stops it: the
    rate after the reset is zero, the bit flips (contact), and the ground's force takes
    over; the flow map agrees with forward differences of the simulation."""
    g, k, c = 9.81, 400.0, 2.0

    def field(x, mask):
        if mask & 1:
            return np.array([x[1], -g - k * x[0] - c * x[1]])
        return np.array([x[1], -g])

    def reset(x, mask, _k):
        return np.array([x[0], 0.0]) if not mask & 1 else x.copy()

    system = HybridSystem(field, lambda x: -x[:1], n_events=1, dim=2, reset=reset)
    x0 = np.array([0.5, 0.0])
    traj = system.simulate(x0, 1.0)
    (group,) = traj.groups
    assert group.time == pytest.approx(np.sqrt(2 * 0.5 / g), rel=1e-9)
    assert group.bounced == () and group.mask_after == 1 and traj.mask_final == 1
    D = system.flow_bderivative(x0, 1.0)(np.eye(2))
    fd = system.flow_fd(x0, 1.0, np.eye(2), 1e-6)
    np.testing.assert_allclose(D, fd, atol=2e-5)


def test_a_landing_that_would_slide_along_the_surface_is_refused():
    """Sent back by the contact region's field, pushed on by the free region's field."""
    sliding = _line(lambda x, m, k: np.array([0.0, x[1]]), field_after=-1.0)
    with pytest.raises(ValueError, match=r"rate of h_0 .* is -1 in region 0b1 .* and 1 in "
                                         r"region 0b0 \(sent back\), so the state would slide"):
        sliding.simulate(np.array([-1.0, 0.0]), 2.0)
    # the same landing with a field after that pushes on: an ordinary crossing
    system = _line(lambda x, m, k: np.array([0.0, x[1]]))
    assert system.simulate(np.array([-1.0, 0.0]), 2.0).groups[0].bounced == ()


def _saltation(R, f_minus, f_plus, dh):
    return R + np.outer(f_plus - R @ f_minus, dh) / (dh @ f_minus)


def test_a_single_bounce_is_the_saltation_matrix_with_reset():
    rng = np.random.default_rng(5)
    for _ in range(20):
        d = int(rng.integers(2, 6))
        dh = rng.standard_normal(d)
        f_minus = rng.standard_normal(d)
        f_minus += (1.0 - dh @ f_minus) * dh / (dh @ dh)  # rate 1 before
        f_plus = rng.standard_normal(d)
        f_plus -= (2.0 + dh @ f_plus) * dh / (dh @ dh)  # rate -2 after: sent back
        R = np.eye(d) + 0.3 * rng.standard_normal((d, d))
        bd = BDerivative(dh[None], np.array([f_minus, f_plus]), resets=np.array([[R], [R]]))
        U = rng.standard_normal((7, d))
        assert np.allclose(bd(U), U @ _saltation(R, f_minus, f_plus, dh).T, atol=1e-12)


def _corner(e0=0.7, e1=0.5, v=(-1.0, -2.0), flip=False):
    """A ball at the corner of two walls x = 0 and y = 0 (h = -x, -y) at velocity v, state
    (x, y, vx, vy), no gravity; restitution e0, e1 (``flip``: the second wall's reset
    does not reverse the velocity, so its event lands on the far side)."""
    Dh = np.array([[-1.0, 0, 0, 0], [0, -1.0, 0, 0]])
    F, R = np.zeros((4, 4)), np.zeros((4, 2, 4, 4))
    for B in range(4):
        vel = np.array(v)
        vel[0] *= -e0 if B & 1 else 1.0
        vel[1] *= (e1 if flip else -e1) if B & 2 else 1.0
        F[B] = [vel[0], vel[1], 0.0, 0.0]
        R[B, 0] = np.diag([1.0, 1.0, -e0, 1.0])
        R[B, 1] = np.diag([1.0, 1.0, 1.0, e1 if flip else -e1])
    return Dh, F, R


def test_two_bounces_in_a_corner_have_an_exact_inverse():
    bd = BDerivative(*_corner()[:2], resets=_corner()[2])
    V = np.random.default_rng(0).standard_normal((50, 4))
    assert np.allclose(bd.inverse(bd(V)), V, atol=1e-13)
    times, orders = bd.event_times(V)
    assert set(map(tuple, orders)) == {(0, 1), (1, 0)}


def test_the_inverse_is_refused_where_time_cannot_be_read_back():
    """Mixed signs of an event's rate after it happened: the order is not recoverable."""
    Dh, F, R = _corner()
    F[3, 0] = -F[3, 0]  # event 0's rate after it: negative in region 01, positive in 11
    bd = BDerivative(Dh, F, resets=R)
    with pytest.raises(ValueError, match="rate of event 0 after it happened changes sign"):
        bd.inverse(np.zeros(4))
    # a reset that tilts the wall it was crossed on
    Dh, F, R = _corner()
    R[:, 0] = np.eye(4)
    R[:, 0, 0, 1] = 0.5  # x after depends on y: Dh_0 R not parallel to Dh_0
    bd = BDerivative(Dh, F, resets=R)
    with pytest.raises(ValueError, match="does not map the surface of event 0 to itself"):
        bd.inverse(np.zeros(4))
    assert np.isfinite(bd(np.ones(4))).all()  # the map itself is defined


def test_walls_at_sixty_degrees_are_refused_naming_the_walls():
    th = np.pi / 3
    normals = (np.array([0.0, 1.0]), np.array([np.sin(th), -np.cos(th)]))
    vel0 = -np.array([np.cos(th / 2), np.sin(th / 2)])  # into the corner

    def reflect(nrm, e):
        return np.eye(2) - (1 + e) * np.outer(nrm, nrm)

    Dh = np.zeros((2, 4))
    Dh[0, :2], Dh[1, :2] = -normals[0], -normals[1]
    F, R = np.zeros((4, 4)), np.zeros((4, 2, 4, 4))
    for B in range(4):
        M = np.eye(2)
        for k in range(2):
            if B >> k & 1:
                M = reflect(normals[k], 0.8) @ M
            R[B, k] = np.eye(4)
            R[B, k][2:, 2:] = reflect(normals[k], 0.8)
        F[B, :2] = M @ vel0
    with pytest.raises(ValueError, match="resets of events 0 and 1 .* do not commute"):
        BDerivative(Dh, F, resets=R)


def test_a_corner_bounce_has_corner_points_and_a_triangulation():
    bd = BDerivative(*_corner()[:2], resets=_corner()[2])
    tri = bd.triangulation()
    V = np.random.default_rng(4).standard_normal((200, 4))
    np.testing.assert_allclose(tri(V), bd(V), atol=1e-12)
    U, W = bd.corner_points()
    np.testing.assert_allclose(bd(U), W, atol=1e-12)


def test_jvp_and_vjp_of_a_corner_bounce_are_the_selected_piece():
    bd = BDerivative(*_corner()[:2], resets=_corner()[2])
    rng = np.random.default_rng(6)
    V, T, W = (rng.standard_normal((30, 4)) for _ in range(3))
    _, orders = bd.event_times(V)
    pieces = np.array([bd.piece(o) for o in orders])
    np.testing.assert_allclose(bd.jvp(V, T), np.einsum("mij,mj->mi", pieces, T), atol=1e-12)
    np.testing.assert_allclose(bd.vjp(V, W), np.einsum("mji,mj->mi", pieces, W), atol=1e-12)


@pytest.mark.parametrize("lift", [0.0, 0.3], ids=["on the diagonal", "off it"])
def test_a_reset_that_puts_the_state_on_another_surface_is_crossed_after_it(lift):
    """A point moving at (1, 1); event 0 (x_0 = 0) resets x_1 to 0, onto the surface of
    event 1 (x_1 = 0), which it then crosses at once, from every nearby start: the flow
    from x0 over [0, 2] is x -> (1 + v_0, 1 + v_0) for x0 + v, smooth, its derivative
    [[1, 0], [1, 0]] (closed form). The two groups share their time, and had been merged
    as simultaneous: refused, the flow said to have no B-derivative there. Event 1's
    surface was moved by event 0's reset (from -2 to 0): its group stays apart."""

    def reset(x, mask, k):
        y = x.copy()
        if k == 0:
            y[1] = 0.0
        return y

    def reset_jacobian(x, mask, k):
        return np.diag([1.0, 0.0]) if k == 0 else np.eye(2)

    model = HybridSystem(lambda x, m: np.array([1.0, 1.0]), lambda x: x.copy(), n_events=2,
                         dim=2, reset=reset, reset_jacobian=reset_jacobian)
    x0 = np.array([-1.0, -3.0 + lift])
    D = model.flow_bderivative(x0, 2.0)
    assert D.group_events == ((0,), (1,)) and D.group_times[0] == D.group_times[1]
    V = np.vstack([np.eye(2), -np.eye(2), [[1.0, 1.0], [-1.0, 2.0]]])
    np.testing.assert_allclose(D(V), V[:, :1] * [1.0, 1.0], rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(model.simulate(x0, 2.0).x_final, [1.0, 1.0], atol=1e-12)
