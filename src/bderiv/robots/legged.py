"""A legged robot from its Pinocchio model: feet touching a flat ground as events.

:func:`legged_robot` takes a Pinocchio model with a free-flying base (or a URDF file, one of
example-robot-data's or your own) and the names of its foot frames, and builds the
:class:`~bderiv.analysis.system.HybridSystem` whose event k is foot k's penetration of the
ground ``z = ground``, ``h_k = ground - z_k(q)`` (touchdown: an upward crossing, bit k
set in stance; lift-off: downward). It is a Python model: each call goes into Pinocchio
(``aba``, ``computeABADerivatives``, the joints' Jacobians), integrated by scipy's
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

**Derivatives.** Analytical: the contact forces enter as the generalized force
``sum_k J_k^T f_k`` in ``aba``'s torque, so ``computeABADerivatives`` at that torque gives
the rest, and the force's derivatives (its Jacobian's turn, the foot's motion, the law)
come from the joints' world Jacobian ``data.J`` alone (:mod:`bderiv.robots._contact`,
compiled), with the chain rule through ``dIntegrate``; the events' Jacobian from the
feet's frame Jacobians. No finite differences (``check_jacobians`` compares them with
differences once per region). Per call: one ``computeJointJacobians``, the feet's
positions, and ``aba`` (the field) or ``computeABADerivatives`` (its Jacobian), the rest
in compiled code (``benchmarks/robots.py --profile`` says where the time goes). The
variational equation asks for the field at the state of the Jacobian it just took: the
field then reuses that call's configuration and torque (the same numbers) and only
calls ``aba``.
"""

from __future__ import annotations

import types

import numpy as np

from .._support._validate import check_state
from .._support._validate_ints import check_mask
from ..analysis.system import HybridSystem
from ._checks import check_configuration, check_feet
from ._contact import field_jacobian_matrix, field_vector, torque, torque_derivatives
from ._files import require_pinocchio
from ._lie import configuration, se3_rate_matrix

__all__ = ["CONTACT", "LeggedRobot"]

#: the contact and posture law's defaults (module docstring): N/m, N s/m, N s/m, N m/rad,
#: N m s/rad; Solo12 (2.5 kg) sinks about 1.2 mm per foot standing on four feet
CONTACT = {"stiffness": 5.0e3, "damping": 50.0, "friction": 50.0, "kp": 5.0, "kd": 0.1,
           "ground": 0.0}


class LeggedRobot:
    """A legged robot as a hybrid system (module docstring).

    Attributes
    ----------
    model : pinocchio.Model
    feet : tuple of str
        The foot frames, event k is foot k's touchdown.
    q_ref : ndarray, (nq,), read-only
        The reference configuration of the tangent coordinates and the PD posture.
    law : mapping, read-only
        The contact and posture parameters (:data:`CONTACT`), as built: the compiled
        field holds them, so a robot with other values is built anew
        (``legged_robot(model, feet, q_ref, **{**robot.law, "stiffness": k})``).
    system : HybridSystem
        n = len(feet) events, d = 2 nv. The methods below check their arguments (a
        state of another size, a mask beyond the feet: a ValueError naming them); the
        system's functions are their unchecked versions (it checks its states itself).
    """

    def __init__(self, model, feet, q_ref, law):
        pin = require_pinocchio()
        self.pin, self.model, self.law = pin, model, types.MappingProxyType(dict(law))
        self.nv = model.nv
        self.feet = check_feet(feet, model)
        self.q_ref = check_configuration(q_ref, model, "q_ref")
        self.q_ref.flags.writeable = False
        self.data = model.createData()
        self.frame_ids = [model.getFrameId(f) for f in self.feet]
        self.joint_ids = [model.frames[i].parentJoint for i in self.frame_ids]
        # the joint of each velocity coordinate; the coordinates of each foot's support;
        # ancestor[i, j]: coordinate i's joint is coordinate j's or one of its ancestors
        joint = np.array([j for j in range(1, model.njoints) for _ in range(model.joints[j].nv)])
        supports = [set(model.supports[j]) for j in range(model.njoints)]
        self._support = np.array([[joint[c] in supports[j] for c in range(self.nv)]
                                  for j in self.joint_ids])
        self._ancestor = np.array([[joint[i] in supports[joint[j]] for j in range(self.nv)]
                                   for i in range(self.nv)])
        self._flight = np.zeros((6, self.nv), order="F"), np.zeros((len(self.feet), 3))
        # (mask, x's bytes, q, torque) of the last Jacobian: the variational equation asks
        # for the field at the same state next, whose q and torque are those numbers
        self._last = None
        self._law = np.array([self.law[k] for k in ("friction", "stiffness", "damping",
                                                     "ground", "kp", "kd")], dtype=np.float64)
        self.system = self._build_system()
        self._state = self._STATE.format(d=self.system.dim)

    def __reduce__(self):
        """Pickled as what builds it (its Pinocchio model pickles; the module and the
        data it holds do not), so a robot and its system go to Dask workers and
        processes."""
        return type(self), (self.model, self.feet, np.array(self.q_ref), dict(self.law))

    def _build_system(self) -> HybridSystem:
        # the unchecked functions: the system checks the states it passes them itself
        return HybridSystem(self._field, self._events, n_events=len(self.feet),
                            dim=2 * self.nv, field_jacobian=self._field_jacobian,
                            event_jacobian=self._event_jacobian)

    # ------------------------------------------------------------------ checks
    #: what a state is, in the message refusing its shape ({d}: its size)
    _STATE = "a state (e, v) of this robot, 2 nv = {d}"

    def _x(self, x) -> np.ndarray:
        """The state ``x`` of a public method: a finite float64 copy, (system.dim,)."""
        return check_state(x, self.system.dim, "x", meaning=self._state)

    def _mask(self, mask) -> int:
        """A region ``mask`` of a public method: bit k foot k, none beyond the feet."""
        return check_mask(mask, len(self.feet), "mask")

    # ------------------------------------------------------------------ coordinates
    def state(self, q, v) -> np.ndarray:
        """``x = (difference(q_ref, q), v)`` (2 nv,) of a configuration ``q`` (nq,), its
        base quaternion of unit norm, and a velocity ``v`` (nv,)."""
        q = check_configuration(q, self.model, "q")
        v = check_state(v, self.nv, "v", meaning=f"a velocity of the model, nv = {self.nv}")
        return np.concatenate((self.pin.difference(self.model, self.q_ref, q), v))

    def configuration(self, x):
        """``(q, v)`` of the state ``x``: ``q = integrate(q_ref, e)``."""
        return self._configuration(self._x(x))

    def _configuration(self, x):
        """:meth:`configuration` of a state of the right size (unchecked)."""
        x = np.ascontiguousarray(x, dtype=np.float64)
        return configuration(self.q_ref, x, self.nv), x[self.nv:2 * self.nv]

    def _dintegrate(self, x, rate=None):
        """``dIntegrate(q_ref, e, ARG1)`` (nv, nv): ``Jr(e_base)`` (the inverse of
        ``rate``, the base's ``Jr^-1``, if given), then the identity."""
        out = np.eye(self.nv)
        out[:6, :6] = np.linalg.inv(se3_rate_matrix(x[:6]) if rate is None else rate)
        return out

    def foot_positions(self, x) -> np.ndarray:
        """(n, 3): the feet's positions in the world."""
        return self._foot_positions(self._x(x))

    def _foot_positions(self, x) -> np.ndarray:
        q, _ = self._configuration(x)
        self.pin.framesForwardKinematics(self.model, self.data, q)
        return self._positions()

    def _positions(self):
        """(n, 3): the feet's positions of the frame placements computed last."""
        oMf = self.data.oMf
        return np.array([oMf[i].translation for i in self.frame_ids])

    # ------------------------------------------------------------------ the model
    # The public methods check their arguments and call the unchecked ones that the
    # system calls (its integration's hot path).
    def events(self, x) -> np.ndarray:
        """(n,): ``ground - z_k`` (``+ c_k`` with rigid feet), positive in penetration."""
        return self._events(self._x(x))

    def event_jacobian(self, x) -> np.ndarray:
        """(n, d): ``-dz_k/de`` (the velocities do not enter; rigid feet: and the
        latches')."""
        return self._event_jacobian(self._x(x))

    def field(self, x, mask) -> np.ndarray:
        """(d,): ``(de/dt, dv/dt)`` in region ``mask`` (bit k: foot k in stance; rigid
        feet: held, and the latches' rate 0)."""
        return self._field(self._x(x), self._mask(mask))

    def field_jacobian(self, x, mask) -> np.ndarray:
        """(d, d): the field's Jacobian, analytical (module docstring; rigid feet:
        :mod:`bderiv.robots.rigid`'s)."""
        return self._field_jacobian(self._x(x), self._mask(mask))

    def _events(self, x) -> np.ndarray:
        return self.law["ground"] - self._foot_positions(x)[:, 2]

    def _event_jacobian(self, x) -> np.ndarray:
        pin, model, data = self.pin, self.model, self.data
        q, _ = self._configuration(x)
        pin.computeJointJacobians(model, data, q)
        pin.updateFramePlacements(model, data)
        Jq = self._dintegrate(x)
        out = np.zeros((len(self.feet), 2 * self.nv))
        for k, fid in enumerate(self.frame_ids):
            J = pin.getFrameJacobian(model, data, fid, pin.LOCAL_WORLD_ALIGNED)
            out[k, :self.nv] = -J[2] @ Jq
        return out

    def _torque(self, x):
        """The PD posture torques (nv,), none on the base."""
        tau = np.zeros(self.nv)
        tau[6:] = -self.law["kp"] * x[6:self.nv] - self.law["kd"] * x[self.nv + 6:2 * self.nv]
        return tau

    def _stance_kinematics(self, q, mask):
        """``data.J`` and the feet's positions at ``q`` (placeholders in flight)."""
        if not mask:
            return self._flight
        pin, model, data = self.pin, self.model, self.data
        pin.computeJointJacobians(model, data, q)
        pin.updateFramePlacements(model, data)
        return data.J, self._positions()

    def _field(self, x, mask) -> np.ndarray:
        x = np.ascontiguousarray(x, dtype=np.float64)
        nv, mask = self.nv, int(mask)
        last = self._last
        if last is not None and last[0] == mask and last[1] == x.tobytes():
            q, tau = last[2], last[3]  # the variational equation's: the same numbers
        else:
            q = configuration(self.q_ref, x, nv)
            tau = torque(x, *self._stance_kinematics(q, mask), self._support, mask,
                         self._law)
        a = self.pin.aba(self.model, self.data, q, x[nv:2 * nv], tau)
        return field_vector(x, a, nv)

    def _field_jacobian(self, x, mask) -> np.ndarray:
        x = np.ascontiguousarray(x, dtype=np.float64)
        nv, law, mask = self.nv, self.law, int(mask)
        q = configuration(self.q_ref, x, nv)
        Jw, P = self._stance_kinematics(q, mask)
        tau, dtau_dq, dtau_dv = torque_derivatives(x, Jw, P, self._support, self._ancestor,
                                                   mask, self._law)
        self._last = (mask, x.tobytes(), q, tau)
        da_dq, da_dv, minv = self.pin.computeABADerivatives(self.model, self.data, q,
                                                            x[nv:2 * nv], tau)
        return field_jacobian_matrix(x, da_dq, da_dv, minv, dtau_dq, dtau_dv,
                                     law["kp"], law["kd"])
