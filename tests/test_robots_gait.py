"""bderiv.robots.gaits: Solo12 pronking, its orbit and its stability, against an
independent simulation.

The oracle is tests/robot_sim.py's ``PronkSim``: Pinocchio called directly on its own
state (q with the base's quaternion), its own contact forces and the PD reference
switched on its own contact set, scipy's DOP853 with its own event logic, a stride from
one apex to the next. The numbers are printed (``pytest -s``).
"""

from __future__ import annotations

import itertools

import numpy as np
import pytest

pin = pytest.importorskip("pinocchio")

from bderiv.robots import _files  # noqa: E402

try:
    _files.example_robot_data()
except ImportError:  # pragma: no cover - the extra installs both
    pytest.skip("example-robot-data is not installed", allow_module_level=True)

from robot_sim import PronkSim  # noqa: E402

from bderiv.analysis._cyclic import reduced_basis  # noqa: E402
from bderiv.robots import quadruped  # noqa: E402
from bderiv.robots.gaits import (  # noqa: E402
    APEX,
    CYCLIC,
    PERIOD,
    mirrors,
    pronking,
    pronking_orbit,
)

NV = 18


@pytest.fixture(scope="module")
def gait():
    return pronking()


def _independent_return(gait, x):
    """The independent simulation's return map in the robot's coordinates (its own chart:
    ``pinocchio.integrate`` and ``difference``), the return time and the switches."""
    robot = gait.robot
    sim = PronkSim(robot.model, robot.feet, robot.q_ref, gait.stance.q_ref, robot.law)
    q = pin.integrate(robot.model, robot.q_ref, x[:NV])
    qT, vT, T, log = sim.stride(q, x[NV:].copy())
    return np.concatenate((pin.difference(robot.model, robot.q_ref, qT), vT)), T, log


def _mirror_masks(feet, mask):
    return sum(1 << feet[k] for k in range(4) if mask >> k & 1)


def test_the_symmetrised_robot_is_mirror_symmetric_and_the_urdf_is_not(gait):
    """``field(G x, mask') = G field(x, mask)`` for both mirrors (the permuted feet), and
    the events permute: the orbit's four feet are at one height by symmetry. The URDF's
    own Solo12 breaks it (the asymmetries ``symmetric_solo12`` removes)."""
    x = 0.1 * np.random.default_rng(3).standard_normal(2 * NV)
    x[2] = -0.1  # every foot in the ground
    urdf = quadruped("solo12", damping=gait.law["damping"])
    for G, feet in mirrors(NV):
        assert np.allclose(G @ G, np.eye(2 * NV))
        assert np.abs(gait.robot.events(G @ x) - gait.robot.events(x)[np.argsort(feet)]
                      ).max() < 1e-14
        for mask in (0b0000, 0b0011, 0b1111):
            f, fG = gait.field(x, mask), gait.field(G @ x, _mirror_masks(feet, mask))
            assert np.abs(fG - G @ f).max() < 1e-11 * np.abs(f).max(), mask
        broken = urdf.field(G @ x, 0b1111) - G @ urdf.field(x, 0b1111)
        assert np.abs(broken).max() > 1e-6


def test_the_stored_apex_returns_to_itself_in_both_simulations(gait):
    """One stride from the orbit's apex: bderiv's simulation and the independent one both
    return to it (the residual of the fixed point, 6e-12 when found), through one group of
    four touchdowns and one of four lift-offs, in the same time."""
    x0 = gait.apex_state()
    traj = gait.system.simulate(x0, 1.0, section=gait.section, rtol=1e-12, atol=1e-13)
    assert [(g.events, g.directions) for g in traj.groups] == [
        ((0, 1, 2, 3), (1, 1, 1, 1)), ((0, 1, 2, 3), (-1, -1, -1, -1))]
    assert abs(traj.t[-1] - PERIOD) < 1e-10
    assert np.abs(traj.x_final - x0).max() < 1e-10
    xT, T, log = _independent_return(gait, x0)
    print(f"residual: bderiv {np.abs(traj.x_final - x0).max():.2e}, independent "
          f"{np.abs(xT - x0).max():.2e}; the two {np.abs(traj.x_final - xT).max():.2e}; "
          f"period {T:.12f} s")
    assert abs(T - PERIOD) < 1e-10 and np.abs(xT - x0).max() < 1e-10
    assert np.abs(traj.x_final - xT).max() < 1e-10
    times = [t for t, _, _ in log]
    assert [(k, s) for _, k, s in log] == [(k, 1) for k in range(4)] + [(k, -1) for k in range(4)]
    assert times[:4] == [times[0]] * 4 and times[4:] == [times[4]] * 4  # at once


def _symmetry_types():
    """The projectors on the mirrors' four symmetry types (characters ``(cx, cy)``; (1, 1):
    symmetric), (2 nv, 2 nv) each."""
    (Gx, _), (Gy, _) = mirrors(NV)
    return {(cx, cy): (np.eye(2 * NV) + cx * Gx + cy * Gy + cx * cy * Gx @ Gy) / 4
            for cx, cy in itertools.product((1, -1), repeat=2)}


def test_the_return_map_pieces_share_their_multipliers(gait):
    """The return map at the orbit: its 24 x 24 pieces differ (the first foot down switches
    the PD reference), but only by maps from the antisymmetric perturbations into the
    symmetric ones (the switch is symmetric, the difference of two feet's times is not),
    so every piece has the same multipliers. The dominant one against one-sided
    differences of the independent simulation's return map along its eigenvector u: on
    u's symmetry type every piece is ``lambda``, whichever piece the difference meets."""
    x0 = gait.apex_state()
    R = gait.system.return_map(x0, gait.section, section_gradient=gait.section_gradient,
                               t_max=1.0, rtol=1e-12, atol=1e-13)
    B = reduced_basis(gait.section_gradient(x0), CYCLIC, 2 * NV)
    perms = list(itertools.permutations(range(4)))
    P0 = R.piece([perms[0], perms[0]])
    w, V = np.linalg.eig(B.T @ P0 @ B)
    types = _symmetry_types()
    for a, b in [(perms[5], perms[17]), (perms[23], perms[9])]:
        P = R.piece([a, b])
        assert np.abs(P - P0).max() > 0.01 * np.abs(P0).max()
        wp = np.linalg.eigvals(B.T @ P @ B)
        assert np.abs(np.sort_complex(wp) - np.sort_complex(w)).max() < 1e-9
        for t, Pc in types.items():  # the difference: into the symmetric type only
            bound = 1e-9 * np.abs(P0).max()
            if t != (1, 1):
                assert np.abs(Pc @ (P - P0)).max() < bound
            else:  # ... from the others: none from the symmetric
                assert np.abs((P - P0) @ Pc).max() < bound
    top = np.argmax(np.abs(w))
    lam, u = w[top].real, (B @ V[:, top]).real
    assert abs(lam + 0.711513) < 1e-5 and w[top].imag == 0.0
    share = {t: np.linalg.norm(Pc @ u) for t, Pc in types.items() if t != (1, 1)}
    kind = max(share, key=share.get)
    assert kind == (1, -1)  # odd in y: a roll and sideways mode
    Pc = types[kind]
    base, _, _ = _independent_return(gait, x0)
    errs = []
    for eps in (1e-5, 1e-6):
        xe, _, _ = _independent_return(gait, x0 + eps * u)
        fd = (xe - base) / eps
        fd[list(CYCLIC)] = 0.0  # the drift along the cyclic coordinates: left out
        errs.append(np.linalg.norm(Pc @ (fd - lam * u)) / np.linalg.norm(lam * Pc @ u))
    print(f"dominant multiplier {lam:.6f} (odd in y): relative error of the independent "
          f"return map's differences {errs[0]:.2e} (eps 1e-5), {errs[1]:.2e} (eps 1e-6)")
    assert errs[1] < 1e-4 and errs[1] < 0.2 * errs[0]


@pytest.mark.slow
def test_newton_finds_the_orbit_and_its_verdict_holds_in_simulation(gait):
    """From a guess 1 cm higher with the legs' offsets halved: Newton's method with the
    B-derivative (about 35 s of CPU); the verdict (stable, growth rate 0.7115) and the
    whole return map against one-sided differences of the independent simulation, in a
    basis of the mirrors' symmetry types (each FD column meets its own piece; the
    multipliers of the differences' matrix are the pieces')."""
    apex = np.array(APEX)
    apex[0] += 0.01
    apex[1:] *= 0.5
    orbit = pronking_orbit(gait, gait.apex_state(apex))
    assert orbit.residual < 1e-11 and len(orbit.history) <= 6
    assert np.abs(orbit.x0 - gait.apex_state()).max() < 1e-10
    assert abs(orbit.period - PERIOD) < 1e-10 and np.abs(orbit.advance).max() < 1e-12
    st = orbit.stability()
    assert st.stable and abs(st.growth_rate - 0.711513) < 1e-5
    for mult in st.multipliers.values():
        assert abs(np.abs(mult).max() - st.growth_rate) < 1e-9
    # a basis of the section's tangent space by symmetry type (characters of the mirrors)
    B = reduced_basis(gait.section_gradient(orbit.x0), CYCLIC, 2 * NV)
    columns = []
    for Pc in _symmetry_types().values():
        U, s, _ = np.linalg.svd(Pc @ B)
        columns.append(U[:, :s.size][:, s > 1e-9])
    Biso = np.hstack(columns)
    assert Biso.shape == (2 * NV, 2 * NV - 1 - len(CYCLIC))
    base, _, _ = _independent_return(gait, orbit.x0)
    fd = []
    for u in Biso.T:
        xe, _, _ = _independent_return(gait, orbit.x0 + 1e-6 * u)
        d, Ru = (xe - base) / 1e-6, orbit.return_map(u)
        d[list(CYCLIC)] = Ru[list(CYCLIC)] = 0.0
        assert np.linalg.norm(d - Ru) < 1e-4 * max(np.linalg.norm(Ru), 1e-2)
        fd.append(d)
    mult = np.linalg.eigvals(Biso.T @ np.array(fd).T)
    ref = next(iter(st.multipliers.values()))
    top = np.sort(np.abs(mult))[::-1][:8]
    print("multipliers of the differences:", np.round(top, 6))
    assert np.abs(top - np.abs(ref[:8])).max() < 1e-4
