"""bderiv.robots with rigid feet: the plastic impact, the stance, the refusal of
simultaneous impacts that do not commute, and a mass-orthogonal pair against an
independent simulation.

Oracles: the impact's projection and the constrained dynamics written here with Pinocchio
directly (``crba``, frame Jacobians, ``constraintDynamics``); tests/robot_sim.py's
``RigidSim`` (its own state with the quaternion, its own KKT system and impulse, scipy's
DOP853 with its own event logic) for the flow map. The agreement per foot order is
printed (``pytest -s``).
"""

from __future__ import annotations

import numpy as np
import pytest

pin = pytest.importorskip("pinocchio")

from bderiv.robots import _files  # noqa: E402

try:
    _files.example_robot_data()
except ImportError:  # pragma: no cover - the extra installs both
    pytest.skip("example-robot-data is not installed", allow_module_level=True)

from robot_sim import RigidSim  # noqa: E402

from bderiv.robots import SOLO12_PACE, drop_state, quadruped  # noqa: E402

TOUCHDOWN = 0.017123551038388  # a drop from 1 cm at 0.5 m/s: (sqrt(v^2 + 2 g h) - v) / g
STANCE = 0.05
EPS = (1e-5, 1e-6)


def _pace():
    """Solo12 pacing: FL and HL land together, their normal rows mass-orthogonal."""
    return quadruped("solo12", joints=SOLO12_PACE, contact="rigid", sticking=False)


@pytest.fixture(scope="module")
def solo():
    return quadruped("solo12", contact="rigid")


def _mass_and_jacobian(robot, q, feet, rows):
    model, data = robot.model, robot.model.createData()
    M = pin.crba(model, data, q)
    M = np.triu(M) + np.triu(M, 1).T
    pin.computeJointJacobians(model, data, q)
    pin.updateFramePlacements(model, data)
    J = np.vstack([pin.getFrameJacobian(model, data, model.getFrameId(robot.feet[k]),
                                        pin.LOCAL_WORLD_ALIGNED)[rows] for k in feet])
    return M, J


@pytest.mark.parametrize("sticking", [True, False])
def test_the_plastic_impact_is_the_projection_written_out(sticking):
    robot = quadruped("solo12", contact="rigid", sticking=sticking)
    rows = [0, 1, 2] if sticking else [2]
    x = 0.1 * np.random.default_rng(4).standard_normal(robot.system.dim)
    x[2 * robot.nv:] = (0.0, 0.0, 1.0, 0.0)  # HL down, FL lands
    q, v = robot.configuration(x)
    M, J = _mass_and_jacobian(robot, q, (0, 2), rows)
    Minv = np.linalg.inv(M)
    expected = v - Minv @ J.T @ np.linalg.solve(J @ Minv @ J.T, J @ v)
    after = robot.reset(x, 0b0100, 0)
    err = np.abs(after[robot.nv:2 * robot.nv] - expected).max()
    print(f"sticking={sticking}: impact against the projection {err:.2e}")
    assert err < 1e-12 * np.abs(v).max()
    assert np.abs(J @ after[robot.nv:2 * robot.nv]).max() < 1e-12
    assert np.array_equal(after[:robot.nv], x[:robot.nv])
    assert tuple(after[2 * robot.nv:]) == (1.0, 0.0, 1.0, 0.0)
    h = 1e-6
    central = np.array([(robot.reset(x + h * s, 0b0100, 0) - robot.reset(x - h * s, 0b0100, 0))
                        / (2 * h) for s in np.eye(robot.system.dim)]).T
    assert np.abs(robot.reset_jacobian(x, 0b0100, 0) - central).max() < 1e-8


def test_the_stance_is_pinocchios_constrained_dynamics(solo):
    x = 0.1 * np.random.default_rng(3).standard_normal(solo.system.dim)
    x[2 * solo.nv:] = (1.0, 0.0, 0.0, 1.0)  # feet 0 and 3 down: region 0b1001
    q, v = solo.configuration(x)
    model = solo.model
    data = model.createData()
    models, datas = pin.StdVec_RigidConstraintModel(), pin.StdVec_RigidConstraintData()
    for foot in (solo.feet[0], solo.feet[3]):
        frame = model.frames[model.getFrameId(foot)]
        c = pin.RigidConstraintModel(pin.ContactType.CONTACT_3D, model, frame.parentJoint,
                                     frame.placement, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)
        models.append(c)
        datas.append(c.createData())
    pin.initConstraintDynamics(model, data, models, datas)
    tau = np.zeros(solo.nv)
    tau[6:] = -solo.law["kp"] * x[6:solo.nv] - solo.law["kd"] * v[6:]
    a = pin.constraintDynamics(model, data, q, v, tau, models, datas)
    assert np.abs(solo.field(x, 0b1001)[solo.nv:2 * solo.nv] - a).max() < 1e-10
    assert np.abs(solo.contact_forces(x, 0b1001).ravel() - data.lambda_c).max() < 1e-10


@pytest.mark.parametrize("sticking", [True, False])
def test_the_jacobians_are_the_fields(sticking):
    robot = quadruped("solo12", contact="rigid", sticking=sticking)
    x = 0.1 * np.random.default_rng(1).standard_normal(robot.system.dim)
    h = 1e-6
    for mask in (0b0000, 0b0110, 0b1111):
        J = robot.field_jacobian(x, mask)
        central = np.array([(robot.field(x + h * s, mask) - robot.field(x - h * s, mask))
                            / (2 * h) for s in np.eye(robot.system.dim)]).T
        assert np.abs(J - central).max() < 1e-8 * np.abs(central).max(), mask
    central = np.array([(robot.events(x + h * s) - robot.events(x - h * s)) / (2 * h)
                        for s in np.eye(robot.system.dim)]).T
    assert np.abs(robot.event_jacobian(x) - central).max() < 1e-8


@pytest.mark.parametrize("sticking", [True, False])
def test_solo12s_four_feet_landing_at_once_do_not_commute_and_are_refused(sticking):
    """The four-foot level drop of Solo12 has no B-derivative with rigid feet: its feet
    are coupled through the inverse mass matrix (the legs are light, the base is not)."""
    robot = quadruped("solo12", contact="rigid", sticking=sticking)
    x0 = drop_state(robot, 0.01, -0.5)
    w = 3 if sticking else 1
    C = robot.coupling(drop_state(robot, 0.0))
    for i in range(4):
        for j in range(i + 1, 4):
            block = C[w * i:w * (i + 1), w * j:w * (j + 1)]
            rel = np.linalg.norm(block, 2) / np.sqrt(
                np.linalg.norm(C[w * i:w * (i + 1), w * i:w * (i + 1)], 2)
                * np.linalg.norm(C[w * j:w * (j + 1), w * j:w * (j + 1)], 2))
            print(f"sticking={sticking} {robot.feet[i]}-{robot.feet[j]}: |J_i M^-1 J_j^T| "
                  f"= {np.linalg.norm(block, 2):.4g} ({rel:.3g} relative)")
            assert rel > 1e-5  # COUPLING_TOL is 1e-9
    with pytest.raises(ValueError, match=r"feet 0 \(FL_FOOT\) and 1 \(FR_FOOT\) touch down "
                       r"at the same instant.*do not commute.*no B-derivative") as err:
        robot.system.simulate(x0, TOUCHDOWN + STANCE)
    print(err.value)
    with pytest.raises(ValueError, match="do not commute"):
        robot.system.flow_bderivative(x0, TOUCHDOWN + STANCE)


def test_coupled_feet_reached_microseconds_apart_land_one_after_the_other():
    """Solo12's level drop with FR, HL and HR raised 5e-7, 1e-6 and 1.5e-6 m (by a knee
    each): they land 0.4 microseconds apart (each impact speeds the others' fall), each on
    its own, four times IMPACT_SIMULTANEITY_TOL apart. A foot within 1e-6 m of the ground
    counted as hit at the same instant whatever its speed, and the drop was refused as
    coupled simultaneous impacts. Oracle: the
    independent simulation, its impacts one at a time."""
    robot = quadruped("solo12", contact="rigid")
    x0 = drop_state(robot, 0.01, -0.5)
    for foot, raise_by in ((1, 5e-7), (2, 1e-6), (3, 1.5e-6)):
        knee = 6 + 3 * foot + 2  # x = (base 6, then the joints: HAA, HFE, KFE per leg)
        e = np.zeros(robot.system.dim)
        e[knee] = 1e-4
        rate = (robot.events(x0 + e)[foot] - robot.events(x0 - e)[foot]) / 2e-4
        x0[knee] -= raise_by / rate  # events are -height: lowered by raise_by
    h = robot.events(x0)
    np.testing.assert_allclose(h[1:] - h[0], [-5e-7, -1e-6, -1.5e-6], rtol=1e-3)
    T = TOUCHDOWN + 0.01
    sim = RigidSim(robot.model, robot.feet, robot.q_ref, robot.law)
    base, log = _independent(robot, sim, x0, T)
    assert [k for _, k in log] == [0, 1, 2, 3] and np.all(np.diff([t for t, _ in log]) > 3e-7)
    traj = robot.system.simulate(x0, T)
    assert [g.events for g in traj.groups] == [(0,), (1,), (2,), (3,)]
    assert np.abs(traj.x_final - base).max() < 1e-8


def _independent(robot, sim, x, T):
    q, v = robot.configuration(x)
    qT, vT, log, down = sim.run(q, v.copy(), T)
    return robot.state(qT, vT, sorted(down)), log


def test_a_mass_orthogonal_pair_lands_at_once_and_the_flow_map_is_the_simulations():
    """Solo12 pacing (FL and HL land together, FR and HR tucked up), frictionless feet at
    the posture where the two are mass-orthogonal: the impacts commute, the flow's
    B-derivative exists and is the independent simulation's in both foot orders."""
    robot = _pace()
    x0 = drop_state(robot, 0.01, -0.5)
    M, J = _mass_and_jacobian(robot, robot.configuration(x0)[0], (0, 2), [2])
    C = J @ np.linalg.solve(M, J.T)
    print(f"pace: J_FL M^-1 J_HL^T = {C[0, 1]:.3g} (J_FL M^-1 J_FL^T = {C[0, 0]:.4g})")
    assert abs(C[0, 1]) < 1e-14 * C[0, 0]
    T = TOUCHDOWN + STANCE
    D = robot.system.flow_bderivative(x0, T)
    assert D.group_events == ((0, 2),) and abs(D.group_times[0] - TOUCHDOWN) < 1e-12
    sim = RigidSim(robot.model, robot.feet, robot.q_ref, robot.law, rows=(2,))
    base, log = _independent(robot, sim, x0, T)
    assert sorted(k for _, k in log) == [0, 2] and len({t for t, _ in log}) == 1
    assert np.abs(robot.system.simulate(x0, T).x_final - base).max() < 1e-9
    U = np.random.default_rng(5).standard_normal((200, robot.system.dim))
    U[:, 2 * robot.nv:] = 0.0  # the latches are 0 in the air
    picked = {}
    for u, order in zip(U, D.orders(U)[0], strict=True):
        picked.setdefault(tuple(D.group_events[0][k] for k in order), u)
    assert set(picked) == {(0, 2), (2, 0)}
    for order, u in picked.items():
        Du = D(u)
        errs = []
        for eps in EPS:
            xe, met = _independent(robot, sim, x0 + eps * u, T)
            assert tuple(k for _, k in met) == order
            errs.append(np.linalg.norm((xe - base) / eps - Du) / np.linalg.norm(Du))
        print(f"order {order}: relative error {errs[0]:.2e} at eps {EPS[0]:g}, "
              f"{errs[1]:.2e} at eps {EPS[1]:g}")
        assert errs[1] < 1e-4 and errs[1] < 0.2 * errs[0], (order, errs)


def test_sticking_feet_landing_one_after_the_other_against_the_simulation():
    """Trot posture (FR and HL tucked up), sticking feet, a pitch rate so that FL lands
    before HR: two groups of one foot each (no commutation needed), the flow's derivative
    against the independent simulation's differences."""
    robot = quadruped("solo12", joints=(0.0, 0.8, -1.6, 0.0, 1.1, -2.2,
                                        0.0, -1.1, 2.2, 0.0, -0.8, 1.6), contact="rigid")
    velocity = np.zeros(robot.nv)
    velocity[4] = 0.5  # pitch, rad/s: the nose goes down
    x0 = drop_state(robot, 0.01, -0.5, velocity=velocity)
    T = TOUCHDOWN + STANCE
    D = robot.system.flow_bderivative(x0, T)
    assert D.group_events == ((0,), (3,))
    sim = RigidSim(robot.model, robot.feet, robot.q_ref, robot.law)
    base, log = _independent(robot, sim, x0, T)
    assert [k for _, k in log] == [0, 3]
    assert np.abs(np.array([t for t, _ in log]) - D.group_times).max() < 1e-9
    assert np.abs(robot.system.simulate(x0, T).x_final - base).max() < 1e-9
    u = np.random.default_rng(6).standard_normal(robot.system.dim)
    u[2 * robot.nv:] = 0.0
    Du = D(u)
    errs = [np.linalg.norm((_independent(robot, sim, x0 + eps * u, T)[0] - base) / eps - Du)
            / np.linalg.norm(Du) for eps in EPS]
    print(f"sticking, FL then HR: relative error {errs[0]:.2e} at eps {EPS[0]:g}, "
          f"{errs[1]:.2e} at eps {EPS[1]:g}")
    assert errs[1] < 1e-4 and errs[1] < 0.2 * errs[0], errs


def test_the_held_feet_push_and_bad_contact_is_refused():
    """Over the pace's stance the ground pushes the held feet (the model holds them
    without a lift-off: docs/robots.md), and a contact that is neither is refused."""
    robot = _pace()
    x0 = drop_state(robot, 0.01, -0.5)
    traj = robot.system.simulate(x0, TOUCHDOWN + STANCE,
                                 t_eval=np.linspace(TOUCHDOWN + 1e-4, TOUCHDOWN + STANCE, 6))
    normal = np.array([robot.contact_forces(x, 0b0101)[:, 2] for x in traj.x])
    assert normal.min() > 0.0, normal
    with pytest.raises(ValueError, match="contact must be 'compliant' or 'rigid', got 'hard'"):
        quadruped("solo12", contact="hard")


def test_down_holds_the_feet_indices_or_one_bool_per_foot(solo):
    """``down=[1, 1, 0, 0]`` (flags) was taken as the indices 1, 1, 0, 0 (feet 0 and 1),
    ``[0, 5, 0, 0]`` raised a raw IndexError (a review)."""
    q, v = solo.q_ref, np.zeros(solo.nv)
    for down in ((0, 3), [3, 0], np.array([0, 3]), [True, False, False, True]):
        assert tuple(solo.state(q, v, down)[2 * solo.nv:]) == (1.0, 0.0, 0.0, 1.0), down
    assert not solo.state(q, v).any()
    with pytest.raises(ValueError, match=r"down must name each foot once \(indices, not "
                       r"flags: pass booleans for flags\), got \[0, 1\] more than once"):
        solo.state(q, v, [1, 1, 0, 0])
    with pytest.raises(ValueError, match=r"down must hold foot indices in \[0, 4\), got "
                       r"\[5\] in \[0, 5, 0, 0\]"):
        solo.state(q, v, [0, 5, 0, 0])
    with pytest.raises(ValueError, match=r"got \[-1\]"):
        solo.state(q, v, [-1])
    with pytest.raises(TypeError, match=r"down must be a sequence of foot indices"):
        solo.state(q, v, [0.0, 3.0])
    with pytest.raises(ValueError, match="down as booleans must have one per foot, 4, got 2"):
        solo.state(q, v, [True, True])


def test_the_methods_refuse_a_state_mask_or_foot_of_another_size(solo):
    """A short state reached Pinocchio's C++ errors, a compliant robot's state (no
    latches) a broadcast error, and a mask's bits beyond the feet were ignored (99: feet
    0 and 1), silently (a review)."""
    x = drop_state(solo, 0.0)
    shape = r"x must have shape \(40,\) \(a state \(e, v, c\) of this robot, 2 nv \+ n = 40"
    for call in (lambda y: solo.contact_forces(y, 1), solo.coupling, solo.events,
                 solo.event_jacobian, solo.configuration, lambda y: solo.field(y, 1),
                 lambda y: solo.field_jacobian(y, 1), lambda y: solo.reset(y, 0, 1),
                 lambda y: solo.reset_jacobian(y, 0, 1)):
        for bad in (x[:5], x[:2 * solo.nv]):
            with pytest.raises(ValueError, match=shape):
                call(bad)
    for mask in (99, 16, -1):
        with pytest.raises(ValueError, match=rf"mask must be in \[0, 2\*\*4\), got {mask}"):
            solo.contact_forces(x, mask)
    with pytest.raises(TypeError, match="mask must be an integer, got float"):
        solo.contact_forces(x, 1.0)
    index = r"k must be an integer in \[0, 4\) \(a foot's index\), got "
    with pytest.raises(ValueError, match=index + "4"):
        solo.reset(x, 0, 4)
    with pytest.raises(TypeError, match=index + "float 1.0"):
        solo.reset_jacobian(x, 0, 1.0)
    x[2 * solo.nv:] = (1.0, 1.0, 0.0, 0.0)  # feet 0 and 1 down, as the mask says
    assert solo.contact_forces(x, 0b0011).shape == (2, 3)


def test_contact_forces_refuses_a_mask_the_latches_do_not_give(solo):
    """``contact_forces(x, mask)`` gave the forces of the mask's feet whatever the state's
    latches said (a foot in the air held, a foot down left out: a review). The mask the
    latches give is worked out here by hand: feet 0 and 3 down is 0b1001."""
    feet = solo.feet
    x = solo.state(solo.q_ref, np.zeros(solo.nv), down=(0, 3))
    with pytest.raises(ValueError) as info:
        solo.contact_forces(x, 0b0011)
    message = str(info.value)
    assert message.startswith("mask must hold the feet that the latches of x say are down")
    assert (f"x's latches [1.0, 0.0, 0.0, 1.0] give mask 0b1001 (feet down: 0 ({feet[0]}), "
            f"3 ({feet[3]})), got mask 0b0011 (feet held: 0 ({feet[0]}), 1 ({feet[1]})); "
            f"they disagree on feet 1, 3") in message, message
    with pytest.raises(ValueError, match=r"x's latches \[1.0, 0.0, 0.0, 1.0\] give mask "
                       r"0b1001 .*, got mask 0b0000 \(feet held: none\); they disagree on "
                       r"feet 0, 3"):
        solo.contact_forces(x, 0)
    flying = drop_state(solo, 0.0)  # every latch 0: in the air
    with pytest.raises(ValueError, match=r"give mask 0b0000 \(feet down: none\), got mask "
                       r"0b0100 .*disagree on foot 2\."):
        solo.contact_forces(flying, 0b0100)
    assert solo.contact_forces(flying, 0).shape == (0, 3)
    # a finite-difference step moves a latch, not the feet down; the forces do not
    # depend on the latches
    forces = solo.contact_forces(x, 0b1001)
    assert forces.shape == (2, 3)
    for step in (1e-6, -1e-6, 0.4):
        moved = x.copy()
        moved[2 * solo.nv:] += step
        assert np.array_equal(solo.contact_forces(moved, 0b1001), forces), step
    # the model's functions (the system's path) take the latches as coordinates, unchecked
    assert np.array_equal(solo.field(flying, 0b0100), solo.system.field(flying, 0b0100))
