"""bderiv.robots: Solo12's touchdowns from its URDF against an independent simulation.

The oracle is tests/robot_sim.py: Pinocchio called directly on its own state (q with
the base's quaternion), its own kinematics and contact forces, scipy's DOP853 with its own
event logic. The flow's B-derivative is piecewise linear, so each direction is checked
inside its own foot order's cone by one-sided differences, whose error must fall as
O(eps). The agreement per order is printed (``pytest -s``).
"""

from __future__ import annotations

import json

import numpy as np
import pytest

pin = pytest.importorskip("pinocchio")

from bderiv.robots import _files  # noqa: E402

try:
    _files.example_robot_data()
except ImportError:  # pragma: no cover - the extra installs both
    pytest.skip("example-robot-data is not installed", allow_module_level=True)

from robot_sim import GroundSim  # noqa: E402

from bderiv.robots import drop_state, legged_robot, quadruped  # noqa: E402
from bderiv.robots._lie import (  # noqa: E402
    base_configuration,
    rate_inverse,
    se3_rate_jacobians,
    se3_rate_matrix,
)  # noqa: E402

STANCE = 0.05  # seconds of stance after the touchdown
EPS = (1e-5, 1e-6)
TOUCHDOWN = 0.017123551038388  # a drop from 1 cm at 0.5 m/s: (sqrt(v^2 + 2 g h) - v) / g


def _independent(robot, sim, x, T):
    """The flow map in the robot's coordinates by the independent simulation, and the
    order of the touchdowns it met."""
    q, v = robot.configuration(x)
    qT, vT, log = sim.run(q, v.copy(), T)
    return np.concatenate((pin.difference(robot.model, robot.q_ref, qT), vT)), log


def _agreement(robot, x0, T, n_orders, seed):
    """Directions in ``n_orders`` distinct foot orders (of the flow map's first group):
    for each, the relative error of one-sided differences of the independent simulation
    against ``D(u)`` at each eps, and the order the simulation met."""
    D = robot.system.flow_bderivative(x0, T)
    sim = GroundSim(robot.model, robot.feet, robot.q_ref, robot.law)
    base, log = _independent(robot, sim, x0, T)
    U = np.random.default_rng(seed).standard_normal((400, 2 * robot.nv))
    picked = {}
    for u, order in zip(U, D.orders(U)[0], strict=True):
        # orders are local to the group: its events by position
        picked.setdefault(tuple(D.group_events[0][k] for k in order), u)
    rows = []
    for order, u in list(picked.items())[:n_orders]:
        Du = D(u)
        errs, met = [], None
        for eps in EPS:
            xe, met = _independent(robot, sim, x0 + eps * u, T)
            errs.append(np.linalg.norm((xe - base) / eps - Du) / np.linalg.norm(Du))
        rows.append((order, tuple(k for _, k in met), errs))
        print(f"order {order}: relative error {errs[0]:.2e} at eps {EPS[0]:g}, "
              f"{errs[1]:.2e} at eps {EPS[1]:g}")
    return D, base, log, rows


@pytest.fixture(scope="module")
def solo():
    return quadruped("solo12")


def test_the_base_rate_is_pinocchios_and_its_derivative_exact():
    rng = np.random.default_rng(0)
    model = pin.buildModelFromUrdf(str(_files.robot_file(
        "solo_description/robots/solo12.urdf")), pin.JointModelFreeFlyer())
    q_ref = pin.neutral(model)
    for scale in (0.0, 1e-4, 0.09, 0.11, 0.7):  # both sides of the series' switch
        xi, nu = scale * rng.standard_normal(6), rng.standard_normal(6)
        q_base = pin.randomConfiguration(model, -np.ones(model.nq), np.ones(model.nq))[:7]
        assert np.abs(base_configuration(q_base, xi) - pin.integrate(
            model, np.concatenate((q_base, q_ref[7:])), np.concatenate(
                (xi, np.zeros(model.nv - 6))))[:7]).max() < 1e-14
        assert np.abs(se3_rate_matrix(xi) - pin.Jlog6(pin.exp6(xi))).max() < 1e-13
        assert np.abs(rate_inverse(xi) - pin.Jexp6(xi)).max() < 1e-13  # its inverse
        e = np.concatenate((xi, np.zeros(model.nv - 6)))
        Jq = pin.dIntegrate(model, q_ref, e, pin.ARG1)[:6, :6]
        assert np.abs(se3_rate_matrix(xi) @ Jq - np.eye(6)).max() < 1e-9  # Pinocchio's
        # dIntegrate is off by 3e-10 at angles near 1e-4 (bderiv.robots._lie)
        _, _, d_xi = se3_rate_jacobians(xi, nu)
        h = 1e-6
        central = np.array([(se3_rate_matrix(xi + h * s) - se3_rate_matrix(xi - h * s)) @ nu
                            / (2 * h) for s in np.eye(6)]).T
        assert np.abs(d_xi - central).max() < 1e-8


def test_the_jacobians_are_the_fields(solo):
    """The analytical Jacobians against central differences, in flight and in stance
    (a state with the feet deep in the ground, spinning and sliding)."""
    x = 0.1 * np.random.default_rng(1).standard_normal(2 * solo.nv)
    x[2] = -0.075  # every foot below the ground
    h = 1e-6
    for mask in (0b0000, 0b0101, 0b1111):
        J = solo.field_jacobian(x, mask)
        central = np.array([(solo.field(x + h * s, mask) - solo.field(x - h * s, mask))
                            / (2 * h) for s in np.eye(2 * solo.nv)]).T
        assert np.abs(J - central).max() < 1e-8 * np.abs(central).max(), mask
    central = np.array([(solo.events(x + h * s) - solo.events(x - h * s)) / (2 * h)
                        for s in np.eye(2 * solo.nv)]).T
    assert np.abs(solo.event_jacobian(x) - central).max() < 1e-8


def test_the_field_is_the_independent_simulations(solo):
    """The accelerations of the field (the contact forces as ``J^T f`` from the joints'
    world Jacobian, compiled) against the independent simulation's right-hand side
    (Pinocchio's frame Jacobians, written in the test's simulation), in every region at a
    state deep in the ground, spinning and sliding."""
    x = 0.1 * np.random.default_rng(2).standard_normal(2 * solo.nv)
    x[2] = -0.075  # every foot below the ground
    sim = GroundSim(solo.model, solo.feet, solo.q_ref, solo.law)
    q, v = solo.configuration(x)
    for mask in range(16):
        a = sim.rhs(0.0, np.concatenate((q, v)), [k for k in range(4) if mask >> k & 1])
        f = solo.field(x, mask)
        assert np.abs(f[solo.nv:] - a[solo.model.nq:]).max() < 1e-12 * np.abs(a).max(), mask
        # after a Jacobian the field at its state reuses its numbers: the same to the bit,
        # and nothing of it elsewhere
        solo.field_jacobian(x, mask)
        assert np.array_equal(solo.field(x, mask), f), mask
        solo.field_jacobian(x + 1e-3, mask)
        assert np.array_equal(solo.field(x, mask), f), mask


def test_four_feet_touch_down_at_once_and_the_flow_map_is_the_simulations(solo):
    x0 = drop_state(solo, 0.01, -0.5)
    T = TOUCHDOWN + STANCE
    D, base, log, rows = _agreement(solo, x0, T, n_orders=4, seed=1)
    assert D.group_events == ((0, 1, 2, 3),)
    assert abs(D.group_times[0] - TOUCHDOWN) < 1e-12
    assert sorted(k for _, k in log) == [0, 1, 2, 3] and len({t for t, _ in log}) == 1
    assert np.abs(solo.system.simulate(x0, T).x_final - base).max() < 1e-9
    assert len({order for order, _, _ in rows}) >= 3
    for order, met, (coarse, fine) in rows:
        assert met == order  # the simulation's own touchdown order
        assert fine < 1e-4 and fine < 0.2 * coarse, (order, coarse, fine)


def test_a_trot_two_diagonal_feet_at_once():
    """FR and HL tucked up: FL and HR touch together, the others stay in the air."""
    trot = quadruped("solo12", joints=(0.0, 0.8, -1.6, 0.0, 1.1, -2.2,
                                       0.0, -1.1, 2.2, 0.0, -0.8, 1.6))
    x0 = drop_state(trot, 0.01, -0.5)
    D, _, log, rows = _agreement(trot, x0, TOUCHDOWN + STANCE, n_orders=2, seed=2)
    assert D.group_events == ((0, 3),) and sorted(k for _, k in log) == [0, 3]
    assert {order for order, _, _ in rows} == {(0, 3), (3, 0)}
    for order, met, (coarse, fine) in rows:
        assert met == order
        assert fine < 1e-4 and fine < 0.2 * coarse, (order, coarse, fine)


def test_a_second_robot_by_its_file_name():
    """Go1: another file, its feet and posture (and its mass's contact law); its four-foot
    touchdown and 50 ms of stance against the independent simulation as Solo12's (about
    4 s of CPU)."""
    model = pin.buildModelFromUrdf(str(_files.robot_file("go1_description/urdf/go1.urdf")),
                                   pin.JointModelFreeFlyer())
    q_ref = pin.neutral(model)
    q_ref[7:] = (0.0, 0.9, -1.8) * 4
    go1 = legged_robot("go1_description/urdf/go1.urdf",
                       ["FL_foot", "FR_foot", "RL_foot", "RR_foot"], q_ref,
                       stiffness=2.5e4, damping=250.0, friction=250.0, kp=25.0, kd=0.5)
    x0 = drop_state(go1, 0.01, -0.5)
    T = TOUCHDOWN + STANCE
    D, base, log, rows = _agreement(go1, x0, T, n_orders=4, seed=1)
    assert D.group_events == ((0, 1, 2, 3),)
    assert sorted(k for _, k in log) == [0, 1, 2, 3] and len({t for t, _ in log}) == 1
    assert np.abs(go1.system.simulate(x0, T).x_final - base).max() < 1e-9
    assert len({order for order, _, _ in rows}) >= 3
    for order, met, (coarse, fine) in rows:
        assert met == order
        assert fine < 1e-4 and fine < 0.2 * coarse, (order, coarse, fine)


def test_bad_input_is_refused_by_name(solo):
    with pytest.raises(ValueError, match="feet must name frames.*FL_TOE"):
        legged_robot(solo.model, ["FL_TOE"], solo.q_ref)
    with pytest.raises(FileNotFoundError, match="solo13.urdf.*solo12.urdf"):
        _files.robot_file("solo_description/robots/solo13.urdf")
    with pytest.raises(ValueError, match="stiffnes"):
        legged_robot(solo.model, solo.feet, solo.q_ref, stiffnes=1.0)
    with pytest.raises(ValueError, match="damping must be a finite number >= 0"):
        legged_robot(solo.model, solo.feet, solo.q_ref, damping=-1.0)
    with pytest.raises(ValueError, match="q_ref must have shape"):
        legged_robot(solo.model, solo.feet, solo.q_ref[:7])
    fixed = pin.buildModelFromUrdf(str(_files.robot_file(
        "solo_description/robots/solo12.urdf")))
    with pytest.raises(ValueError, match="free-flying base"):
        legged_robot(fixed, ["FL_FOOT"])
    with pytest.raises(ValueError, match="name must be one of"):
        quadruped("solo13")


def test_a_missing_file_of_ones_own_a_world_frame_and_a_non_path_are_refused(solo, tmp_path):
    """An absolute path that does not exist searched the whole filesystem (root / path
    is path: rglob from "/") and then failed naming a file the user never gave; the
    world's frame was taken as a foot; a number reached pathlib's TypeError (a review)."""
    missing = tmp_path / "my_robot.urdf"
    with pytest.raises(FileNotFoundError, match=f"{missing}': no such file"):
        legged_robot(missing, ["foot"])
    with pytest.raises(FileNotFoundError, match="a folder"):
        legged_robot(str(tmp_path), ["foot"])
    with pytest.raises(TypeError, match="source, the robot's description file, must be a "
                                        "path.*got int 123"):
        legged_robot(123, ["foot"])
    with pytest.raises(ValueError, match=r"frames of the robot, got \['universe'\], fixed "
                                         "to the world"):
        legged_robot(solo.model, ["universe"], solo.q_ref)


def test_the_law_and_reference_are_read_only(solo):
    """The compiled field holds the law's numbers, the events and the Jacobian read the
    mapping: an edit of ``robot.law`` made a model whose parts disagreed (a stiffness x10
    left the field as it was; a new ``kp`` put the Jacobian 1e5 off the field's
    differences), silently (a review). Both are read-only now."""
    with pytest.raises(TypeError):
        solo.law["stiffness"] = 1.0
    with pytest.raises(ValueError, match="read-only"):
        solo.q_ref[7] = 0.3
    stiffer = legged_robot(solo.model, solo.feet, solo.q_ref,
                           **{**solo.law, "stiffness": 10 * solo.law["stiffness"]})
    x = drop_state(solo, -0.002)  # every foot 2 mm in the ground
    grow = stiffer.field(x, 0b1111) - solo.field(x, 0b1111)
    assert np.abs(grow).max() > 1.0


@pytest.mark.parametrize("contact", ["compliant", "rigid"])
def test_a_robot_and_its_system_pickle(contact):
    """They did not (the Pinocchio module a robot holds): a stability map or a Monte
    Carlo on Dask workers or processes could not take a robot. Rebuilt from what built
    them, their functions give the same numbers."""
    import pickle

    robot = quadruped("solo12", contact=contact, sticking=False)
    again = pickle.loads(pickle.dumps(robot))
    assert type(again) is type(robot) and dict(again.law) == dict(robot.law)
    assert again.feet == robot.feet and np.array_equal(again.q_ref, robot.q_ref)
    assert getattr(again, "sticking", None) == getattr(robot, "sticking", None)
    system = pickle.loads(pickle.dumps(robot.system))
    x = drop_state(robot, -0.001, -0.3)
    mask = 0b1111 if contact == "compliant" else 0
    assert np.array_equal(system.field(x, mask), robot.system.field(x, mask))
    assert np.array_equal(system.events(x), robot.system.events(x))


def test_a_pitched_reference_drops_its_lowest_foot_to_the_height_asked():
    """drop_state wrote the height and the fall into the base's own frame: with the
    reference base pitched by 0.5 rad two feet started 2.7 cm inside the ground and the
    base fell at (-0.24, 0, -0.44) m/s instead of (0, 0, -0.5) (a review). Oracle:
    Pinocchio's own kinematics of the state's configuration and velocity."""
    robot = quadruped("solo12")
    q_ref = robot.q_ref.copy()
    q_ref[3:7] = pin.Quaternion(pin.utils.rpyToMatrix(0.2, 0.5, 0.1)).coeffs()
    pitched = legged_robot(robot.model, robot.feet, q_ref, **robot.law)
    x = drop_state(pitched, 0.01, -0.5)
    q, v = pitched.configuration(x)
    data = robot.model.createData()
    pin.forwardKinematics(robot.model, data, q, v)
    pin.updateFramePlacements(robot.model, data)
    feet = [data.oMf[robot.model.getFrameId(f)].translation[2] for f in robot.feet]
    assert min(feet) == pytest.approx(pitched.law["ground"] + 0.01, abs=1e-12)
    np.testing.assert_allclose(q[3:7], q_ref[3:7], atol=1e-15)  # the posture kept
    base = pin.getVelocity(robot.model, data, 1, pin.LOCAL_WORLD_ALIGNED).linear
    np.testing.assert_allclose(base, [0.0, 0.0, -0.5], atol=1e-12)


@pytest.mark.slow
def test_the_demo_from_the_command_line(capsys):
    """``bderiv demo --example solo12`` (a minute on a loaded machine: its check runs
    seven simulations)."""
    from bderiv.cli import main

    assert main(["demo", "--example", "solo12", "--eps", "1e-4", "1e-5", "--json"]) == 0
    out = capsys.readouterr().out
    assert '"orders_met": 24' in out and '"FL_FOOT"' in out
    assert json.loads(out)["check"]["eps"] == [1e-4, 1e-5]


def test_nan_starts_and_a_foot_named_twice_are_refused_by_name():
    """drop_state(robot, nan) gave a NaN state, a NaN joint reference a NaN posture, and
    a foot named twice doubled its contact force, silently (a review)."""
    robot = quadruped()
    with pytest.raises(ValueError, match="height must be a finite number, got nan"):
        drop_state(robot, np.nan)
    with pytest.raises(ValueError, match="vz must be a finite number, got nan"):
        drop_state(robot, 0.01, vz=np.nan)
    with pytest.raises(ValueError, match=r"joints must be finite, but joints\[0\] = nan"):
        quadruped(joints=(np.nan,) * 12)
    with pytest.raises(ValueError, match=r"q_ref must be finite, but q_ref\[7\] = nan"):
        legged_robot(robot.model, robot.feet, np.r_[robot.q_ref[:7], [np.nan] * 12])
    with pytest.raises(ValueError, match=r"feet must name each foot once, got \['FL_foot'\]"):
        legged_robot("go1_description/urdf/go1.urdf",
                     ["FL_foot", "FL_foot", "RL_foot", "RR_foot"])


def test_a_state_of_another_size_is_refused_by_name(solo):
    """A short state was read past its end by the compiled configuration (garbage, run to
    run), a long one cut silently, a short q or v reached Pinocchio's C++ errors or gave
    a state of another size (a review). The system's own functions are not checked
    again (the integration's hot path: HybridSystem checks its states)."""
    x = drop_state(solo, 0.01)
    shape = r"x must have shape \(36,\) \(a state \(e, v\) of this robot, 2 nv = 36\)"
    for bad in (x[:5], np.r_[x, 0.0], x[None]):
        for method in (solo.configuration, solo.foot_positions, solo.events,
                       solo.event_jacobian):
            with pytest.raises(ValueError, match=shape + ", got shape"):
                method(bad)
        for method in (solo.field, solo.field_jacobian):
            with pytest.raises(ValueError, match=shape):
                method(bad, 0)
    with pytest.raises(ValueError, match=r"x must be finite, but x\[3\] = nan"):
        solo.events(np.where(np.arange(36) == 3, np.nan, x))
    with pytest.raises(ValueError, match=r"mask must be in \[0, 2\*\*4\), got 16"):
        solo.field(x, 16)
    with pytest.raises(TypeError, match="x must hold real numbers"):
        solo.events(x.astype(complex))
    q, v = solo.configuration(x)
    assert np.array_equal(solo.state(q, v), x)
    with pytest.raises(ValueError, match=r"v must have shape \(18,\) \(a velocity"):
        solo.state(q, v[:5])
    with pytest.raises(ValueError, match=r"q must have shape \(19,\) \(a configuration"):
        solo.state(q[:5], v)
    with pytest.raises(ValueError, match=r"v must be finite, but v\[0\] = nan"):
        solo.state(q, np.full(18, np.nan))
    with pytest.raises(ValueError, match=r"q\[3:7\], the base's quaternion .* unit norm"):
        solo.state(np.r_[q[:3], 2 * q[3:7], q[7:]], v)  # Pinocchio took it as another
    assert solo.system.events.__func__ is type(solo)._events  # not the checked events


def test_one_foot_named_alone():
    """``legged_robot(source, "FL_FOOT")`` was refused as the feet 'F', 'L', '_', ...: one
    name is one foot (a review)."""
    solo = quadruped()
    one = legged_robot(solo.model, "FL_FOOT", solo.q_ref, **solo.law)
    assert one.feet == ("FL_FOOT",) and one.system.n_events == 1
    groups = one.system.simulate(drop_state(one, 0.01, -0.5), TOUCHDOWN + 0.005).groups
    assert [g.events for g in groups] == [(0,)]
    assert abs(groups[0].time - TOUCHDOWN) < 1e-12


def test_bad_parameters_are_refused_by_name_before_any_work(solo):
    """Raw NumPy, Pinocchio and Boost errors, and a NaN state or a zero base quaternion
    taken silently (the quaternion failed much later, inside simulate), before (a
    review)."""
    with pytest.raises(ValueError, match=r"joints must have shape \(12,\) \(a standing "
                       r"posture of solo12: one angle per joint, 12\), got shape \(5,\)"):
        quadruped("solo12", joints=(0.0,) * 5)
    with pytest.raises(ValueError, match=r"velocity must have shape \(18,\)"):
        drop_state(solo, 0.01, velocity=np.zeros(5))
    with pytest.raises(ValueError, match=r"velocity must be finite, but velocity\[0\]"):
        drop_state(solo, 0.01, velocity=np.full(18, np.nan))
    with pytest.raises(TypeError, match="robot must be a LeggedRobot"):
        drop_state(solo.model, 0.01)
    with pytest.raises(TypeError, match="stiffness must be a real number, got str '1'"):
        quadruped("solo12", stiffness="1")
    with pytest.raises(TypeError, match=r"feet must be names of frames \(str\), got int 1 "
                       r"at feet\[0\]"):
        legged_robot(solo.model, [1, 2])
    with pytest.raises(TypeError, match="feet must be a foot frame's name or a sequence"):
        legged_robot(solo.model, 3)
    with pytest.raises(TypeError, match="sticking must be True or False, got str 'no'"):
        quadruped("solo12", contact="rigid", sticking="no")
    with pytest.raises(ValueError, match=r"q_ref\[3:7\], the base's quaternion \(x, y, z, "
                       r"w\), must have unit norm \(to 1e-09; it is used as given\), got "
                       r"\[0.0, 0.0, 0.0, 0.0\] of norm 0"):
        legged_robot(solo.model, solo.feet, q_ref=np.zeros(19))
    q_ref = solo.q_ref.copy()
    q_ref[6] = 1 + 1e-6
    with pytest.raises(ValueError, match="unit norm.*pinocchio.normalize"):
        legged_robot(solo.model, solo.feet, q_ref)
    q_ref[6] = 1 + 1e-12  # within the tolerance: taken as given
    assert legged_robot(solo.model, solo.feet, q_ref).q_ref[6] == 1 + 1e-12
