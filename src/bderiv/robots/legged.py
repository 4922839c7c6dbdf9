"""A legged robot from its Pinocchio model: feet touching a flat ground as events.

:func:`legged_robot` takes a Pinocchio model with a free-flying base (or a URDF file, one of
example-robot-data's or your own) and the names of its foot frames, and builds the
:class:`~bderiv.analysis.system.HybridSystem` whose event k is foot k's penetration of the
ground ``z = ground``, ``h_k = ground - z_k(q)`` (touchdown: an upward crossing, bit k
set in stance; lift-off: downward). It is a Python model: each call goes into Pinocchio
(``aba``, ``computeABADerivatives``, frame Jacobians), integrated by scipy's
``solve_ivp``. ``contact="rigid"`` gives rigid feet instead (a plastic impact, the feet
then held: :mod:`bderiv.robots.rigid`); the rest of this docstring is the compliant law.

**Coordinates.** The state is ``x = (e, v)``, d = 2 nv: ``q = pinocchio.integrate(q_ref,
e)`` (the base ``M_ref exp6(e_base)`` on SE(3), the joints ``q_ref_j + e_j``) and
Pinocchio's velocity ``v`` (the base's in its own frame, then the joint rates); so
``de/dt = (Jr(e_base)^-1 v_base, v_joints)`` (:mod:`bderiv.robots._lie`). A flow map, its
B-derivative and a finite difference are all in these coordinates; ``state(q, v)`` and
``configuration(x)`` convert (``pinocchio.difference``, ``pinocchio.integrate``). Keep
``|e_base|`` angles below pi (the logarithm's domain); choose ``q_ref`` near the motion.

**The contact law** (compliant: no impulse, the state is continuous, the field jumps at
touchdown). Foot k in stance receives the world-frame force
``f_k = (-friction * vx_k, -friction * vy_k, stiffness * pen_k + damping * rate_k)``
at the foot frame's origin, ``pen_k = ground - z_k`` and ``rate_k = -vz_k`` (the foot's
velocity in the world), added to the dynamics as ``J_k^T f_k`` (``J_k`` the foot's
LOCAL_WORLD_ALIGNED linear Jacobian). The joints are held by a PD law around ``q_ref``:
``tau = -kp e_j - kd v_j`` (the robot's posture controller; a free-falling robot keeps its
posture, since gravity alone moves no joint). The feet are points (a foot's radius: lower
``ground`` by it).

**Derivatives.** Analytical: ``computeABADerivatives`` with the contact forces as
external forces in the joints' frames (whose derivative holds them fixed in those frames),
the missing rotation of a world-fixed force written out (``J_i^T [[g]x; [r]x [g]x]
J_i,ang`` for the force ``g`` in joint i's frame at ``r``), the force's own dependence
on the state from ``getFrameVelocityDerivatives``, and the chain rule through
``dIntegrate``; the events' Jacobian from the feet's frame Jacobians. No finite
differences (``check_jacobians`` compares them with differences once per region).
"""

from __future__ import annotations

import numpy as np

from ..analysis.system import HybridSystem
from ._files import require_pinocchio
from ._lie import base_configuration, se3_rate_jacobians, se3_rate_matrix

__all__ = ["CONTACT", "LeggedRobot"]

#: the contact and posture law's defaults (module docstring): N/m, N s/m, N s/m, N m/rad,
#: N m s/rad; Solo12 (2.5 kg) sinks about 1.2 mm per foot standing on four feet
CONTACT = {"stiffness": 5.0e3, "damping": 50.0, "friction": 50.0, "kp": 5.0, "kd": 0.1,
           "ground": 0.0}


def _skew(w):
    return np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])


class LeggedRobot:
    """A legged robot as a hybrid system (module docstring).

    Attributes
    ----------
    model : pinocchio.Model
    feet : tuple of str
        The foot frames, event k is foot k's touchdown.
    q_ref : ndarray, (nq,)
        The reference configuration of the tangent coordinates and the PD posture.
    law : dict
        The contact and posture parameters (:data:`CONTACT`).
    system : HybridSystem
        n = len(feet) events, d = 2 nv.
    """

    def __init__(self, model, feet, q_ref, law):
        pin = require_pinocchio()
        self.pin, self.model, self.law = pin, model, dict(law)
        self.data = model.createData()
        self.nv = model.nv
        names = [f.name for f in model.frames]
        self.feet = tuple(feet)
        missing = [f for f in self.feet if not model.existFrame(f)]
        if missing or not self.feet:
            raise ValueError(f"feet must name frames of the model, got {missing or 'none'}; "
                             f"the model's frames with 'foot' in their name: "
                             f"{[n for n in names if 'foot' in n.lower()]}")
        self.frame_ids = [model.getFrameId(f) for f in self.feet]
        self.joint_ids = [model.frames[i].parentJoint for i in self.frame_ids]
        self.q_ref = np.array(q_ref, dtype=np.float64)
        if self.q_ref.shape != (model.nq,):
            raise ValueError(f"q_ref must have shape ({model.nq},), got {self.q_ref.shape}")
        self.system = self._build_system()

    def _build_system(self) -> HybridSystem:
        return HybridSystem(self.field, self.events, n_events=len(self.feet),
                            dim=2 * self.nv, field_jacobian=self.field_jacobian,
                            event_jacobian=self.event_jacobian)

    # ------------------------------------------------------------------ coordinates
    def state(self, q, v) -> np.ndarray:
        """``x = (difference(q_ref, q), v)`` (2 nv,)."""
        q, v = np.asarray(q, dtype=np.float64), np.asarray(v, dtype=np.float64)
        return np.concatenate((self.pin.difference(self.model, self.q_ref, q), v))

    def configuration(self, x):
        """``(q, v)`` of the state ``x``: ``q = integrate(q_ref, e)``."""
        x = np.asarray(x, dtype=np.float64)
        q = np.empty(self.model.nq)
        q[:7] = base_configuration(self.q_ref[:7], x[:6])  # pinocchio.integrate's, smooth
        q[7:] = self.q_ref[7:] + x[6:self.nv]
        return q, x[self.nv:2 * self.nv]

    def _dintegrate(self, x, rate=None):
        """``dIntegrate(q_ref, e, ARG1)`` (nv, nv): ``Jr(e_base)`` (the inverse of
        ``rate``, the base's ``Jr^-1``, if given), then the identity."""
        out = np.eye(self.nv)
        out[:6, :6] = np.linalg.inv(se3_rate_matrix(x[:6]) if rate is None else rate)
        return out

    def foot_positions(self, x) -> np.ndarray:
        """(n, 3): the feet's positions in the world."""
        q, _ = self.configuration(x)
        self.pin.framesForwardKinematics(self.model, self.data, q)
        return np.array([self.data.oMf[i].translation for i in self.frame_ids])

    # ------------------------------------------------------------------ the model
    def events(self, x) -> np.ndarray:
        """(n,): ``ground - z_k``, positive in penetration."""
        return self.law["ground"] - self.foot_positions(x)[:, 2]

    def event_jacobian(self, x) -> np.ndarray:
        """(n, d): ``-dz_k/de`` (the velocities do not enter)."""
        pin, model, data = self.pin, self.model, self.data
        q, _ = self.configuration(x)
        pin.computeJointJacobians(model, data, q)
        pin.updateFramePlacements(model, data)
        Jq = self._dintegrate(x)
        out = np.zeros((len(self.feet), 2 * self.nv))
        for k, fid in enumerate(self.frame_ids):
            J = pin.getFrameJacobian(model, data, fid, pin.LOCAL_WORLD_ALIGNED)
            out[k, :self.nv] = -J[2] @ Jq
        return out

    def _forces(self, q, v, mask):
        """The stance feet's world forces and the external forces in the joints' frames
        (after ``forwardKinematics(q, v)``)."""
        pin, model, data, law = self.pin, self.model, self.data, self.law
        fext = pin.StdVec_Force()
        for _ in range(model.njoints):
            fext.append(pin.Force.Zero())
        forces = {}
        for k, (fid, jid) in enumerate(zip(self.frame_ids, self.joint_ids, strict=True)):
            if not mask >> k & 1:
                continue
            p = data.oMf[fid].translation
            vel = pin.getFrameVelocity(model, data, fid, pin.LOCAL_WORLD_ALIGNED).linear
            f = np.array([-law["friction"] * vel[0], -law["friction"] * vel[1],
                          law["stiffness"] * (law["ground"] - p[2]) - law["damping"] * vel[2]])
            oMi = data.oMi[jid]
            g = oMi.rotation.T @ f
            r = oMi.rotation.T @ (p - oMi.translation)
            fext[jid] = fext[jid] + pin.Force(g, _skew(r) @ g)
            forces[k] = (f, g, r)
        return fext, forces

    def _torque(self, x):
        tau = np.zeros(self.nv)
        tau[6:] = -self.law["kp"] * x[6:self.nv] - self.law["kd"] * x[self.nv + 6:2 * self.nv]
        return tau

    def field(self, x, mask) -> np.ndarray:
        """(d,): ``(de/dt, dv/dt)`` in region ``mask`` (bit k: foot k in stance)."""
        pin, model, data = self.pin, self.model, self.data
        q, v = self.configuration(x)
        pin.forwardKinematics(model, data, q, v)
        pin.updateFramePlacements(model, data)
        fext, _ = self._forces(q, v, int(mask))
        a = pin.aba(model, data, q, v, self._torque(x), fext)
        de = v.copy()
        de[:6] = se3_rate_matrix(x[:6]) @ v[:6]
        return np.concatenate((de, a))

    def field_jacobian(self, x, mask) -> np.ndarray:
        """(d, d): the field's Jacobian, analytical (module docstring)."""
        pin, model, data, law, nv = self.pin, self.model, self.data, self.law, self.nv
        q, v = self.configuration(x)
        mask = int(mask)
        pin.computeForwardKinematicsDerivatives(model, data, q, v, np.zeros(nv))
        pin.computeJointJacobians(model, data, q)
        pin.updateFramePlacements(model, data)
        fext, forces = self._forces(q, v, mask)
        tau = self._torque(x)
        da_dq, da_dv, Minv = pin.computeABADerivatives(model, data, q, v, tau, fext)
        da_dq, da_dv, Minv = np.array(da_dq), np.array(da_dv), np.array(Minv)
        Minv = np.triu(Minv) + np.triu(Minv, 1).T  # Pinocchio fills the upper triangle
        dtau_dq, dtau_dv = np.zeros((nv, nv)), np.zeros((nv, nv))
        for k, (_, g, r) in forces.items():
            fid, jid = self.frame_ids[k], self.joint_ids[k]
            J = pin.getFrameJacobian(model, data, fid, pin.LOCAL_WORLD_ALIGNED)[:3]
            # the foot's world velocity R_f w (w: LOCAL): d(R_f w) = R_f (dw - [w]x dtheta_f)
            # (Pinocchio's LOCAL_WORLD_ALIGNED derivatives are of the spatial velocity)
            dw_dq, dw_dv = pin.getFrameVelocityDerivatives(model, data, fid, pin.LOCAL)
            Rf = data.oMf[fid].rotation
            w = pin.getFrameVelocity(model, data, fid, pin.LOCAL).linear
            JfL = pin.getFrameJacobian(model, data, fid, pin.LOCAL)
            dvel_dq = Rf @ (dw_dq[:3] - _skew(w) @ JfL[3:])
            dvel_dv = Rf @ dw_dv[:3]
            c = np.array([law["friction"], law["friction"], law["damping"]])
            df_dq = -c[:, None] * dvel_dq
            df_dq[2] -= law["stiffness"] * J[2]
            dtau_dq += J.T @ df_dq
            dtau_dv += J.T @ (-c[:, None] * dvel_dv)
            # the world-fixed force turns in joint i's frame: d(R_i^T f) = [g]x dtheta_i
            Ji = pin.getJointJacobian(model, data, jid, pin.LOCAL)
            G = _skew(g)
            dtau_dq += Ji.T @ np.vstack((G, _skew(r) @ G)) @ Ji[3:]
        _, d_nu, d_xi = se3_rate_jacobians(x[:6], v[:6])
        Jq = self._dintegrate(x, d_nu)
        out = np.zeros((2 * nv, 2 * nv))
        out[:6, :6] = d_xi
        out[:6, nv:nv + 6] = d_nu
        out[6:nv, nv + 6:] = np.eye(nv - 6)
        out[nv:, :nv] = (da_dq + Minv @ dtau_dq) @ Jq
        out[nv:, nv:] = da_dv + Minv @ dtau_dv
        # the PD torques, in e directly
        out[nv:, 6:nv] -= law["kp"] * Minv[:, 6:]
        out[nv:, nv + 6:] -= law["kd"] * Minv[:, 6:]
        return out
