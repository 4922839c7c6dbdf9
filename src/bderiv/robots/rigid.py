"""Rigid feet: a plastic impact at touchdown, the feet then held by the constraint.

``legged_robot(..., contact="rigid")`` builds a :class:`RigidLeggedRobot`. A foot that
touches the ground stops at once (an impulse), and stays where it landed: in region
``mask`` the feet with their bit set are held by the constraint, the rest fly.

**The state** is ``x = (e, v, c)``, d = 2 nv + n: the tangent coordinates and velocity of
:mod:`bderiv.robots.legged`, and one latch ``c_k`` per foot (0 in the air, 1 once down).
Event k is ``h_k = ground - z_k + c_k``: in the air the foot's penetration; the impact sets
``c_k = 1`` and the held foot stays at ``z_k = ground``, so the state lands on the far side
of surface k and stays there. A foot once down stays down: lift-off is not modelled (the
constraint is bilateral once made); :meth:`RigidLeggedRobot.contact_forces` gives the
ground's forces, whose normal component a user checks stays positive over the stance.
A robot's state has latches 0 or 1 (``state``, ``drop_state`` and the impact make no
other), but they are coordinates like ``e`` and ``v`` (the flow's B-derivative has their
columns, finite differences move them), so the methods take any finite value;
:meth:`RigidLeggedRobot.contact_forces` reads a latch above 1/2 as a foot down and refuses
a ``mask`` that holds other feet (their forces would be those of another region).

**Friction** (``sticking``): True (default) holds the foot's 3-D velocity at zero (a foot
that does not slip, as common for legged robots: three constraint rows per foot); False
holds the normal velocity only (a frictionless ground: one row per foot, the foot slides).
``J_k`` below is the foot's LOCAL_WORLD_ALIGNED linear Jacobian, those rows of it.

**The impact** of foot k from region ``mask`` holds the feet already down with it: with
``J`` the rows of the feet of ``mask`` and k, ``v+ = (I - M^-1 J^T (J M^-1 J^T)^-1 J) v-``
(the plastic impact: the velocity's M-orthogonal projection on ``J v = 0``); ``e`` is
continuous. **The stance** is the constrained forward dynamics (the KKT system)
``M a - J^T lambda = tau - b(q, v)``, ``J a + dJ/dt v = 0`` (the drift ``dJ/dt v``:
the feet's classical acceleration at ``a = 0``); the impact leaves ``J v = 0`` and the
dynamics keep it, so no Baumgarte term is needed (the feet drift by the integration's
error only).

**Simultaneous touchdowns** (the condition of :mod:`bderiv.symbolic.contacts`, Pace and
Burden): feet i and j landing at the same instant commute only when they are orthogonal
in the inverse-mass metric, ``J_i M^-1 J_j^T = 0``; otherwise the impulse at one changes
the other's velocity, on a ground that can only push the outcome depends on the order in
which they land, and the flow has no B-derivative there. The impact refuses such feet
with a ValueError naming them and the coupling (:meth:`RigidLeggedRobot.coupling` gives
the matrix at any state).

**Derivatives**, analytical (no finite differences): the stance field's by
differentiating the KKT system, ``[[M, -J^T], [J, 0]] [da; dlambda] = -[dr; dc]``, with
``dr`` the inverse dynamics' derivatives (``computeRNEADerivatives`` with the ground's
forces as external forces in the joints' frames, which Pinocchio's derivative holds fixed
there, plus the turn of a world-fixed force, ``J_i^T [[g]x; [r]x [g]x] J_i,ang`` for the
force ``g`` in joint i's frame at ``r``) and ``dc`` the feet's classical acceleration's
(``getFrameAccelerationDerivatives``, LOCAL, rotated to the world); the impact's by
differentiating ``M v+ + J^T Lambda = M v-``, ``J v+ = 0`` the same way (``d(M w)`` from
``computeRNEADerivatives`` at zero velocity less ``computeGeneralizedGravityDerivatives``).
"""

from __future__ import annotations

import numpy as np

from .._limits import COUPLING_TOL, IMPACT_SIMULTANEITY_TOL
from ..analysis.system import HybridSystem
from ._checks import check_down, check_index, check_latches
from ._contact import field_vector
from ._lie import se3_rate_jacobians
from .legged import LeggedRobot

__all__ = ["RigidLeggedRobot"]


def _skew(w):
    return np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])


def _kkt(M, J, sign):
    """``[[M, sign J^T], [J, 0]]`` (nv + r, nv + r); np.block's checks cost more."""
    nv, r = M.shape[0], J.shape[0]
    K = np.zeros((nv + r, nv + r))
    K[:nv, :nv] = M
    K[:nv, nv:] = sign * J.T
    K[nv:, :nv] = J
    return K


class RigidLeggedRobot(LeggedRobot):
    """A legged robot with rigid feet (module docstring); the stiffness, damping and
    friction of the law are unused, ``kp``, ``kd``, ``ground`` are.

    Attributes
    ----------
    sticking : bool
        True: a foot down has its 3-D velocity held at zero; False: its normal velocity.
    system : HybridSystem
        n = len(feet) events, d = 2 nv + n (the latches last).
    """

    def __reduce__(self):
        """As :meth:`LeggedRobot.__reduce__`, with ``sticking``."""
        return type(self), (self.model, self.feet, np.array(self.q_ref), dict(self.law),
                            self.sticking)

    def __init__(self, model, feet, q_ref, law, sticking=True):
        self.sticking = bool(sticking)
        self.rows = [0, 1, 2] if self.sticking else [2]
        self._lower = np.tril_indices(model.nv, -1)
        super().__init__(model, feet, q_ref, law)
        self._no_forces = self.pin.StdVec_Force()
        for _ in range(model.njoints):
            self._no_forces.append(self.pin.Force.Zero())

    def _build_system(self) -> HybridSystem:
        # the unchecked functions (the public ones check, then call them)
        return HybridSystem(self._field, self._events, n_events=len(self.feet),
                            dim=2 * self.nv + len(self.feet),
                            field_jacobian=self._field_jacobian,
                            event_jacobian=self._event_jacobian, reset=self._reset,
                            reset_jacobian=self._reset_jacobian)

    _STATE = "a state (e, v, c) of this robot, 2 nv + n = {d}: the feet's latches c last"

    def state(self, q, v, down=()) -> np.ndarray:
        """``(difference(q_ref, q), v, c)``: ``q`` (nq,) and ``v`` (nv,) as
        :meth:`LeggedRobot.state <bderiv.robots.legged.LeggedRobot.state>`'s, and the
        latches ``c_k = 1`` for the feet down, 0 for the others. ``down`` holds the
        indices of the feet down (positions in ``feet``, each in ``[0, n)`` and once:
        ``down=(0, 3)``, feet 0 and 3), or one bool per foot (``[True, False, False,
        True]``, the same); anything else is refused (flags as integers, ``[1, 1, 0,
        0]``, are refused as indices repeated)."""
        c = np.zeros(len(self.feet))
        c[check_down(down, len(self.feet))] = 1.0
        return np.concatenate((super().state(q, v), c))

    # ------------------------------------------------------------------ pieces
    def _kinematics(self, q, v):
        """Joint Jacobians, placements and velocities at (q, v) with zero acceleration."""
        pin, model, data = self.pin, self.model, self.data
        pin.computeJointJacobians(model, data, q)
        pin.forwardKinematics(model, data, q, v, np.zeros(self.nv))
        pin.updateFramePlacements(model, data)

    def _jacobian(self, feet):
        """(r, nv): the held rows of the feet's LOCAL_WORLD_ALIGNED linear Jacobians."""
        pin = self.pin
        if not feet:
            return np.zeros((0, self.nv))
        return np.vstack([pin.getFrameJacobian(self.model, self.data, self.frame_ids[k],
                                               pin.LOCAL_WORLD_ALIGNED)[self.rows]
                          for k in feet])

    def _mass(self, q):
        M = self.pin.crba(self.model, self.data, q)
        M = np.array(M)
        M[self._lower] = M.T[self._lower]  # Pinocchio fills the upper triangle
        return M

    def _feet(self, mask):
        return [k for k in range(len(self.feet)) if int(mask) >> k & 1]

    def _solve(self, x, mask):
        """The stance's acceleration (nv,), the ground's forces (r,), M, J, feet."""
        pin, model, data = self.pin, self.model, self.data
        q, v = self._configuration(x)
        self._kinematics(q, v)
        feet = self._feet(mask)
        M, J = self._mass(q), self._jacobian(feet)
        b = pin.nonLinearEffects(model, data, q, v)
        drift = np.concatenate([pin.getFrameClassicalAcceleration(
            model, data, self.frame_ids[k], pin.LOCAL_WORLD_ALIGNED).linear[self.rows]
            for k in feet]) if feet else np.zeros(0)
        sol = np.linalg.solve(_kkt(M, J, -1.0), np.concatenate((self._torque(x) - b, -drift)))
        return sol[:self.nv], sol[self.nv:], M, J, feet

    def _external(self, feet, lam):
        """World forces ``lam`` (r,) at the feet as Pinocchio's external forces in the
        joints' frames, and the term of their turn in those frames, ``d(J^T f)/dq``
        beyond Pinocchio's (module docstring), (nv, nv)."""
        pin, model, data = self.pin, self.model, self.data
        fext = pin.StdVec_Force(self._no_forces)  # a copy
        turn = np.zeros((self.nv, self.nv))
        w = len(self.rows)
        for i, k in enumerate(feet):
            f = np.zeros(3)
            f[self.rows] = lam[w * i:w * (i + 1)]
            jid, oMi = self.joint_ids[k], data.oMi[self.joint_ids[k]]
            g = oMi.rotation.T @ f
            r = oMi.rotation.T @ (data.oMf[self.frame_ids[k]].translation - oMi.translation)
            fext[jid] = fext[jid] + pin.Force(g, _skew(r) @ g)
            Ji = pin.getJointJacobian(model, data, jid, pin.LOCAL)
            G = _skew(g)
            turn += Ji.T @ np.vstack((G, _skew(r) @ G)) @ Ji[3:]
        return fext, turn

    def _world_rate(self, fid, d_local, u_local):
        """``d(R_f u)`` (3, nv) of a LOCAL vector ``u`` with derivative ``d_local``."""
        pin = self.pin
        JfL = pin.getFrameJacobian(self.model, self.data, fid, pin.LOCAL)
        return self.data.oMf[fid].rotation @ (d_local - _skew(u_local) @ JfL[3:])

    # ------------------------------------------------------------------ the model
    # The public events, event_jacobian, field, field_jacobian (LeggedRobot's), reset,
    # reset_jacobian, contact_forces and coupling check their arguments; the unchecked
    # functions below are the system's.
    def _events(self, x) -> np.ndarray:
        """(n,): ``ground - z_k + c_k``."""
        return super()._events(x) + x[2 * self.nv:]

    def _event_jacobian(self, x) -> np.ndarray:
        """(n, d): the feet's heights' and the latches'."""
        out = np.zeros((len(self.feet), 2 * self.nv + len(self.feet)))
        out[:, :2 * self.nv] = super()._event_jacobian(x)
        out[:, 2 * self.nv:] = np.eye(len(self.feet))
        return out

    def contact_forces(self, x, mask) -> np.ndarray:
        """(len(feet of mask), 3): the ground's world forces on the held feet (a foot's
        normal force is the last column; zeros in the friction columns without
        ``sticking``); ``mask``: bit k, foot k held, the feet whose latches in ``x`` say
        they are down (``c_k > 1/2``; another mask is refused, a ValueError)."""
        x, mask = self._x(x), self._mask(mask)
        check_latches(x[2 * self.nv:], mask, self.feet)
        _, lam, _, _, feet = self._solve(x, mask)
        out = np.zeros((len(feet), 3))
        out[:, self.rows] = lam.reshape(len(feet), len(self.rows))
        return out

    def _field(self, x, mask) -> np.ndarray:
        """(d,): ``(de/dt, dv/dt, 0)``, the stance's constrained dynamics (feet of mask
        held); in flight the compliant model's field without contacts (``aba``)."""
        x = np.ascontiguousarray(x, dtype=np.float64)
        if not int(mask):
            return np.concatenate((super()._field(x, 0), np.zeros(len(self.feet))))
        a = self._solve(x, mask)[0]
        return np.concatenate((field_vector(x, a, self.nv), np.zeros(len(self.feet))))

    def _field_jacobian(self, x, mask) -> np.ndarray:
        """(d, d): the field's Jacobian, by the KKT system's derivative (module
        docstring); in flight the compliant model's without contacts."""
        pin, model, data, law, nv = self.pin, self.model, self.data, self.law, self.nv
        if not int(mask):
            out = np.zeros((self.system.dim, self.system.dim))
            out[:2 * nv, :2 * nv] = super()._field_jacobian(x, 0)
            return out
        q, v = self._configuration(x)
        a, lam, M, J, feet = self._solve(x, mask)
        # the feet's classical acceleration J a + dJ/dt v, differentiated (a held fixed)
        pin.computeForwardKinematicsDerivatives(model, data, q, v, a)
        dc_dq, dc_dv = [], []
        for k in feet:
            fid = self.frame_ids[k]
            v_dq, a_dq, a_dv, a_da = pin.getFrameAccelerationDerivatives(model, data, fid,
                                                                        pin.LOCAL)
            vel = pin.getFrameVelocity(model, data, fid, pin.LOCAL)
            acc = pin.getFrameAcceleration(model, data, fid, pin.LOCAL)
            nu, om = vel.linear, vel.angular
            cl = acc.linear + _skew(om) @ nu
            lq = a_dq[:3] + _skew(om) @ v_dq[:3] - _skew(nu) @ v_dq[3:]
            lv = a_dv[:3] + _skew(om) @ a_da[:3] - _skew(nu) @ a_da[3:]
            dc_dq.append(self._world_rate(fid, lq, cl)[self.rows])
            dc_dv.append((data.oMf[fid].rotation @ lv)[self.rows])
        r = J.shape[0]
        dc_dq = np.vstack(dc_dq) if feet else np.zeros((0, nv))
        dc_dv = np.vstack(dc_dv) if feet else np.zeros((0, nv))
        # the inverse dynamics' residual rnea(q, v, a) - J^T lambda - tau, differentiated
        fext, turn = self._external(feet, lam)
        dr_dq, dr_dv, _ = pin.computeRNEADerivatives(model, data, q, v, a, fext)
        dr_dq, dr_dv = np.array(dr_dq) - turn, np.array(dr_dv)
        dr_dv[6:, 6:] += law["kd"] * np.eye(nv - 6)
        _, d_nu, d_xi = se3_rate_jacobians(x[:6], v[:6])
        Jq = self._dintegrate(x, d_nu)
        dr_de = dr_dq @ Jq
        dr_de[6:, 6:] += law["kp"] * np.eye(nv - 6)
        K = _kkt(M, J, -1.0)
        rhs = np.empty((nv + r, 2 * nv))
        rhs[:nv, :nv], rhs[:nv, nv:], rhs[nv:, :nv], rhs[nv:, nv:] = (-dr_de, -dr_dv,
                                                                       -dc_dq @ Jq, -dc_dv)
        da = np.linalg.solve(K, rhs)[:nv]
        out = np.zeros((self.system.dim, self.system.dim))
        out[:6, :6] = d_xi
        out[:6, nv:nv + 6] = d_nu
        out[6:nv, nv + 6:2 * nv] = np.eye(nv - 6)
        out[nv:2 * nv, :2 * nv] = da
        return out

    # ------------------------------------------------------------------ the impact
    def coupling(self, x) -> np.ndarray:
        """``J M^-1 J^T`` (r n, r n) of all the feet at the state ``x`` (r = 3 sticking,
        1 not): block (i, j) is the change of foot i's held velocity per unit impulse at
        foot j; zero off the diagonal where the feet are mass-orthogonal."""
        q, v = self._configuration(self._x(x))
        self._kinematics(q, v)
        J = self._jacobian(range(len(self.feet)))
        return J @ np.linalg.solve(self._mass(q), J.T)

    def _check_simultaneous(self, x, mask, k) -> None:
        pin, w = self.pin, len(self.rows)
        h = super()._events(x)
        vz = np.array([pin.getFrameVelocity(self.model, self.data, fid,
                                            pin.LOCAL_WORLD_ALIGNED).linear[2]
                       for fid in self.frame_ids])
        # another foot hit at the same instant: approaching, and on the ground within
        # IMPACT_SIMULTANEITY_TOL seconds at its speed (a distance alone counted a foot
        # reached measurably later, as symbolic.contacts' ImpactCheck did)
        hit = [j for j in range(len(self.feet)) if j != k and not mask >> j & 1
               and vz[j] < 0.0 and abs(h[j]) <= -vz[j] * IMPACT_SIMULTANEITY_TOL]
        if not hit:
            return
        C = self.coupling(x)

        def block(i, j):
            return C[w * i:w * (i + 1), w * j:w * (j + 1)]

        for j in hit:
            a, b = sorted((k, j))
            Cab = block(a, b)
            rel = np.linalg.norm(Cab, 2) / np.sqrt(np.linalg.norm(block(a, a), 2)
                                                   * np.linalg.norm(block(b, b), 2))
            if not rel <= COUPLING_TOL:
                what = "3 x 3 blocks (sticking feet)" if self.sticking else "normal rows"
                raise ValueError(
                    f"feet {a} ({self.feet[a]}) and {b} ({self.feet[b]}) touch down at the "
                    f"same instant and are coupled through the inverse mass matrix: "
                    f"J_{a} M^-1 J_{b}^T = {np.round(Cab, 6).tolist()} (their "
                    f"{what}; norm {rel:.3g} relative to J_{a} M^-1 J_{a}^T and J_{b} M^-1 "
                    f"J_{b}^T), so the impulse at one changes the other's velocity: the "
                    f"impacts do not commute, on a ground that can only push the state "
                    f"after them depends on the order in which the feet land, and the flow "
                    f"has no B-derivative there. Make the feet compliant "
                    f"(contact='compliant'), or land them one after the other (a state "
                    f"where they do not touch at once)")

    def _impact(self, x, mask, k):
        """v+, the impulses, M, J, the feet held, w = v- - v+ (after the kinematics)."""
        q, v = self._configuration(x)
        self._kinematics(q, v)
        feet = sorted(set(self._feet(mask)) | {k})
        M, J = self._mass(q), self._jacobian(feet)
        MJ = np.linalg.solve(M, J.T)
        impulse = np.linalg.solve(J @ MJ, J @ v)
        w = MJ @ impulse
        return v - w, impulse, M, J, feet, w

    def reset(self, x, mask, k) -> np.ndarray:
        """(d,): the plastic impact of foot k from region ``mask`` (module docstring);
        refused when another foot touches down at the same instant coupled to it
        (ValueError naming them)."""
        return self._reset(self._x(x), self._mask(mask), check_index(k, len(self.feet), "k"))

    def reset_jacobian(self, x, mask, k) -> np.ndarray:
        """(d, d): the impact's Jacobian, differentiating ``M v+ + J^T Lambda = M v-``,
        ``J v+ = 0`` (module docstring)."""
        return self._reset_jacobian(self._x(x), self._mask(mask),
                                    check_index(k, len(self.feet), "k"))

    def _reset(self, x, mask, k) -> np.ndarray:
        mask, k = int(mask), int(k)
        if mask >> k & 1:
            return np.array(x, dtype=np.float64)  # not met: the latch keeps h_k > 0
        x = np.asarray(x, dtype=np.float64)
        q, v = self._configuration(x)
        self._kinematics(q, v)
        self._check_simultaneous(x, mask, k)
        out = x.copy()
        out[self.nv:2 * self.nv] = self._impact(x, mask, k)[0]
        out[2 * self.nv + k] = 1.0
        return out

    def _reset_jacobian(self, x, mask, k) -> np.ndarray:
        pin, model, data, nv = self.pin, self.model, self.data, self.nv
        mask, k = int(mask), int(k)
        out = np.eye(self.system.dim)
        if mask >> k & 1:
            return out
        x = np.asarray(x, dtype=np.float64)
        q, _ = self._configuration(x)
        vp, impulse, M, J, feet, w = self._impact(x, mask, k)
        pin.computeForwardKinematicsDerivatives(model, data, q, vp, np.zeros(nv))
        dvel = []
        for j in feet:
            fid = self.frame_ids[j]
            dw_dq, _ = pin.getFrameVelocityDerivatives(model, data, fid, pin.LOCAL)
            u = pin.getFrameVelocity(model, data, fid, pin.LOCAL).linear
            dvel.append(self._world_rate(fid, dw_dq[:3], u)[self.rows])
        self._kinematics(q, np.zeros(nv))
        fext, turn = self._external(feet, impulse)
        dMw, _, _ = pin.computeRNEADerivatives(model, data, q, np.zeros(nv), w, fext)
        dg = pin.computeGeneralizedGravityDerivatives(model, data, q)
        r = J.shape[0]
        K = _kkt(M, J, 1.0)
        rhs_q = np.vstack((np.array(dMw) - dg - turn, -np.vstack(dvel)))
        rhs_v = np.vstack((M, np.zeros((r, nv))))
        Jq = self._dintegrate(x)
        sol = np.linalg.solve(K, np.hstack((rhs_q @ Jq, rhs_v)))[:nv]
        out[nv:2 * nv, :2 * nv] = sol
        out[2 * nv + k, 2 * nv + k] = 0.0
        return out
