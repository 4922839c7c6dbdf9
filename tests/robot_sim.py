"""An independent simulation of a legged robot on a flat ground, with Pinocchio directly.

The oracle of tests/test_robots.py: its own state (the configuration q with the base's
quaternion, and v), its own kinematics (the quaternion's rate written out), its own
contact forces (``J^T f`` added to the torques, not external forces in the joints'
frames), scipy's DOP853 with scipy's event location (one terminal event per foot, the
contact set switched at each one; feet within ``touch_tol`` of the ground switch
together). Nothing of bderiv.robots is used; the law is written out from its docstring.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin
from scipy.integrate import solve_ivp


class GroundSim:
    def __init__(self, model, feet, q_ref, law):
        self.model, self.data = model, model.createData()
        self.fids = [model.getFrameId(f) for f in feet]
        self.q_ref, self.law = np.asarray(q_ref, dtype=float), law
        self.nq, self.nv = model.nq, model.nv

    def _q(self, y):
        q = y[:self.nq].copy()
        q[3:7] /= np.linalg.norm(q[3:7])
        return q

    def heights(self, y):
        pin.framesForwardKinematics(self.model, self.data, self._q(y))
        return np.array([self.data.oMf[f].translation[2] for f in self.fids]) - self.law["ground"]

    def reference(self, contact):
        """The PD law's reference configuration with the feet ``contact`` down."""
        return self.q_ref

    def rhs(self, t, y, contact):
        m, d, law = self.model, self.data, self.law
        q, v = self._q(y), y[self.nq:]
        tau = np.zeros(self.nv)
        tau[6:] = -law["kp"] * (q[7:] - self.reference(contact)[7:]) - law["kd"] * v[6:]
        pin.computeJointJacobians(m, d, q)
        pin.framesForwardKinematics(m, d, q)
        for k in contact:
            J = pin.getFrameJacobian(m, d, self.fids[k], pin.LOCAL_WORLD_ALIGNED)[:3]
            vel = J @ v
            z = d.oMf[self.fids[k]].translation[2] - law["ground"]
            f = np.array([-law["friction"] * vel[0], -law["friction"] * vel[1],
                          -law["stiffness"] * z - law["damping"] * vel[2]])
            tau += J.T @ f
        a = pin.aba(m, d, q, v, tau)
        R = pin.Quaternion(q[6], q[3], q[4], q[5]).toRotationMatrix()
        w = v[3:6]
        qv, qw = y[3:6], y[6]
        dq = np.empty(self.nq)
        dq[:3] = R @ v[:3]
        dq[3:6] = 0.5 * (qw * w + np.cross(qv, w))
        dq[6] = -0.5 * qv @ w
        dq[7:] = v[6:]
        return np.concatenate((dq, a))

    def run(self, q0, v0, T, rtol=1e-12, atol=1e-13, touch_tol=1e-9):
        """The state (q, v) at T and the touchdowns [(time, foot)] in order."""
        y = np.concatenate((q0, v0))
        t, contact, log = 0.0, set(np.flatnonzero(self.heights(y) < 0)), []
        while t < T:
            evs = []
            for k in range(len(self.fids)):
                def ev(t, y, _contact, k=k):
                    return self.heights(y)[k]
                ev.terminal, ev.direction = True, (1.0 if k in contact else -1.0)
                evs.append(ev)
            sol = solve_ivp(self.rhs, (t, T), y, method="DOP853", rtol=rtol, atol=atol,
                            events=evs, args=(frozenset(contact),))
            y, t = sol.y[:, -1], sol.t[-1]
            if sol.status != 1:
                break
            h = self.heights(y)
            for k in range(len(self.fids)):
                if k not in contact and h[k] <= touch_tol:
                    contact.add(k)
                    log.append((t, k))
                elif k in contact and h[k] >= -touch_tol and sol.t_events[k].size:
                    contact.discard(k)
        q = self._q(y)
        return q, y[self.nq:], log


class PronkSim(GroundSim):
    """The pronking robot, independently (the oracle of tests/test_robots_gait.py): the
    PD reference ``q_stance`` while any foot is down, ``q_ref`` in flight; a stride from
    an apex to the next (the base's vertical velocity, in its frame, crossing zero
    downward after a touchdown). A foot lifts off when it is back at the ground moving
    up; feet within ``touch_tol`` of the ground switch together (rounding: a perturbed
    stride's feet a few nanometres apart are not simultaneous, and switching them
    together would move the state by O(eps))."""

    def __init__(self, model, feet, q_ref, q_stance, law):
        super().__init__(model, feet, q_ref, law)
        self.q_stance = np.asarray(q_stance, dtype=float)

    def reference(self, contact):
        return self.q_stance if contact else self.q_ref

    def _foot_vz(self, y):
        m, d = self.model, self.data
        q, v = self._q(y), y[self.nq:]
        pin.computeJointJacobians(m, d, q)
        pin.framesForwardKinematics(m, d, q)
        return np.array([pin.getFrameJacobian(m, d, f, pin.LOCAL_WORLD_ALIGNED)[2] @ v
                         for f in self.fids])

    def stride(self, q0, v0, t_max=1.0, rtol=1e-12, atol=1e-13, touch_tol=1e-13):
        """From an apex (q0, v0) in the air to the next apex: (q, v) there, the return
        time and the switches [(time, foot, +1 down / -1 up)] in order."""
        y = np.concatenate((q0, v0))
        t, contact, log = 0.0, set(), []
        while True:
            evs = []
            for k in range(len(self.fids)):
                def ev(t, y, _contact, k=k):
                    return self.heights(y)[k]
                ev.terminal, ev.direction = True, (1.0 if k in contact else -1.0)
                evs.append(ev)
            if log:  # the apex once the stride has landed
                def apex(t, y, _contact):
                    return y[self.nq + 2]
                apex.terminal, apex.direction = True, -1.0
                evs.append(apex)
            sol = solve_ivp(self.rhs, (t, t_max), y, method="DOP853", rtol=rtol, atol=atol,
                            events=evs, args=(frozenset(contact),))
            y, t = sol.y[:, -1], sol.t[-1]
            if sol.status != 1:
                raise RuntimeError(f"no apex before t_max={t_max}")
            if log and sol.t_events[-1].size:
                return self._q(y), y[self.nq:], t, log
            h, vz = self.heights(y), self._foot_vz(y)
            for k in range(len(self.fids)):
                if k not in contact and h[k] <= touch_tol:
                    contact.add(k)
                    log.append((t, k, 1))
                elif k in contact and h[k] >= -touch_tol and vz[k] > 0:
                    contact.discard(k)
                    log.append((t, k, -1))

class RigidSim(GroundSim):
    """Rigid feet, independently (the oracle of tests/test_robots_rigid.py): at a
    touchdown the feet landing (within ``touch_tol``) and those down take one plastic
    impulse, ``v+ = v - M^-1 J^T (J M^-1 J^T)^-1 J v`` (M from ``crba``, J the feet's
    world rows from their LOCAL Jacobians rotated); in stance the KKT system written out
    (the drift from the LOCAL spatial velocity and acceleration); the feet stay down.
    ``rows``: (0, 1, 2) sticking feet, (2,) the normal alone."""

    def __init__(self, model, feet, q_ref, law, rows=(0, 1, 2)):
        super().__init__(model, feet, q_ref, law)
        self.rows = list(rows)

    def _world(self, q, v, contact):
        """J (r, nv) and the drift (r,) of the feet ``contact`` (world rows)."""
        m, d = self.model, self.data
        pin.forwardKinematics(m, d, q, v, np.zeros(self.nv))
        pin.computeJointJacobians(m, d, q)
        pin.updateFramePlacements(m, d)
        Js, drift = [np.zeros((0, self.nv))], [np.zeros(0)]
        for k in sorted(contact):
            fid = self.fids[k]
            R = d.oMf[fid].rotation
            Js.append((R @ pin.getFrameJacobian(m, d, fid, pin.LOCAL)[:3])[self.rows])
            vel = pin.getFrameVelocity(m, d, fid, pin.LOCAL)
            acc = pin.getFrameAcceleration(m, d, fid, pin.LOCAL)
            drift.append((R @ (acc.linear + np.cross(vel.angular, vel.linear)))[self.rows])
        return np.vstack(Js), np.concatenate(drift)

    def impact(self, q, v, contact):
        J, _ = self._world(q, v, contact)
        M = pin.crba(self.model, self.data, q)
        M = np.triu(M) + np.triu(M, 1).T
        MJ = np.linalg.solve(M, J.T)
        return v - MJ @ np.linalg.solve(J @ MJ, J @ v)

    def rhs(self, t, y, contact):
        m, d, law = self.model, self.data, self.law
        q, v = self._q(y), y[self.nq:]
        tau = np.zeros(self.nv)
        tau[6:] = -law["kp"] * (q[7:] - self.q_ref[7:]) - law["kd"] * v[6:]
        J, drift = self._world(q, v, contact)
        M = pin.crba(m, d, q)
        M = np.triu(M) + np.triu(M, 1).T
        b = pin.rnea(m, d, q, v, np.zeros(self.nv))
        r = J.shape[0]
        a = np.linalg.solve(np.block([[M, J.T], [J, np.zeros((r, r))]]),
                            np.concatenate((tau - b, -drift)))[:self.nv]
        R = pin.Quaternion(q[6], q[3], q[4], q[5]).toRotationMatrix()
        w, qv, qw = v[3:6], y[3:6], y[6]
        dq = np.concatenate((R @ v[:3], 0.5 * (qw * w + np.cross(qv, w)), [-0.5 * qv @ w],
                             v[6:]))
        return np.concatenate((dq, a))

    def run(self, q0, v0, T, rtol=1e-12, atol=1e-13, touch_tol=1e-9):
        """The state (q, v) at T, the touchdowns [(time, foot)] in order and the feet
        down at T."""
        y = np.concatenate((q0, v0))
        t, contact, log = 0.0, set(), []
        while t < T:
            flying = [k for k in range(len(self.fids)) if k not in contact]
            evs = []
            for k in flying:
                def ev(t, y, _contact, k=k):
                    return self.heights(y)[k]
                ev.terminal, ev.direction = True, -1.0
                evs.append(ev)
            sol = solve_ivp(self.rhs, (t, T), y, method="DOP853", rtol=rtol, atol=atol,
                            events=evs or None, args=(frozenset(contact),))
            y, t = sol.y[:, -1], sol.t[-1]
            if sol.status != 1:
                break
            h = self.heights(y)
            for k in flying:
                if h[k] <= touch_tol:
                    contact.add(k)
                    log.append((t, k))
            y[self.nq:] = self.impact(self._q(y), y[self.nq:], contact)
        return self._q(y), y[self.nq:], log, contact
