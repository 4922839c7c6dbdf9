"""A prototype, not part of the library: Solo12's forward dynamics (Featherstone's ABA)
in numba, generated from the tree of its ``pinocchio.Model``, timed against
``pinocchio.aba`` to measure what a compiled route of ``bderiv.robots`` would cost
per field and per Jacobian (docs/robots.md, "Time, and where it goes").

``python benchmarks/robots_compiled_prototype.py`` reads the tree (parents, joint
placements, joint axes, spatial inertias; a free-flyer then revolute joints about x, y
or z), checks the numba ABA against ``pinocchio.aba`` on random states (to 1e-9
relative), then times, per call (CPU, minimum of 5 rounds):

- ``pinocchio.aba`` from Python (Boost.Python's call included), and
  ``computeABADerivatives``;
- the numba ABA from Python (numba's dispatch included) and inside a compiled loop
  (what a compiled integrator calling it pays);
- a Jacobian of the compiled ABA by 2 nv = 36 complex steps (exact to rounding, each an
  ABA in complex arithmetic) inside a compiled loop: an upper bound for a compiled
  Jacobian (an analytical one, as Pinocchio's derivatives, costs about
  ``computeABADerivatives / aba`` times an ABA).

The ABA is the plain textbook one on 6 x 6 matrices (no exploitation of the joints'
sparsity as Pinocchio's templates do): a first estimate, not an optimized kernel.
"""

from __future__ import annotations

import time

import numba
import numpy as np

from bderiv.robots._contact import field_jacobian_matrix, torque, torque_derivatives
from bderiv.robots._lie import configuration


def tree(model):
    """The arrays of the numba ABA: parents (nj,), joint kind (nj,: 0 free-flyer, 1-3
    revolute about x, y, z), first velocity index (nj,), placements' R (nj, 3, 3) and p
    (nj, 3), spatial inertias (nj, 6, 6); joint 0 is the universe."""
    kinds = {"JointModelFreeFlyer": 0, "JointModelRX": 1, "JointModelRY": 2,
             "JointModelRZ": 3}
    nj = model.njoints
    kind = np.array([-1] + [kinds[model.joints[j].shortname()] for j in range(1, nj)])
    R = np.array([model.jointPlacements[j].rotation for j in range(nj)])
    p = np.array([model.jointPlacements[j].translation for j in range(nj)])
    inertia = np.array([model.inertias[j].matrix() for j in range(nj)])
    idx_v = np.array([model.joints[j].idx_v for j in range(nj)])
    return (np.array(model.parents), kind, idx_v, np.ascontiguousarray(R),
            np.ascontiguousarray(p), np.ascontiguousarray(inertia))


@numba.njit(cache=True)
def workspace(nj, dtype):
    """The ABA's arrays, allocated once (a compiled integrator would hold them)."""
    return (np.zeros((nj, 3, 3), dtype), np.zeros((nj, 3), dtype), np.zeros((nj, 6), dtype),
            np.zeros((nj, 6), dtype), np.zeros((nj, 6, 6), dtype), np.zeros((nj, 6), dtype),
            np.zeros((nj, 6), dtype), np.zeros((nj, 6), dtype), np.zeros((6, 6), dtype),
            np.zeros((6, 6), dtype), np.zeros((6, 6), dtype))


@numba.njit(cache=True)
def _motion_to_child(R, p, m, out):
    """``X m``: the motion ``m`` of the parent's frame in the child's, the child placed
    at (R, p) in the parent: ``(R^T (m_l - p x m_w), R^T m_w)``."""
    l0 = m[0] - (p[1] * m[5] - p[2] * m[4])
    l1 = m[1] - (p[2] * m[3] - p[0] * m[5])
    l2 = m[2] - (p[0] * m[4] - p[1] * m[3])
    for r in range(3):
        out[r] = R[0, r] * l0 + R[1, r] * l1 + R[2, r] * l2
        out[3 + r] = R[0, r] * m[3] + R[1, r] * m[4] + R[2, r] * m[5]


@numba.njit(cache=True)
def _force_to_parent(R, p, f, out):
    """``out += X^T f``: ``(R f_l, p x (R f_l) + R f_a)``."""
    a0 = R[0, 0] * f[0] + R[0, 1] * f[1] + R[0, 2] * f[2]
    a1 = R[1, 0] * f[0] + R[1, 1] * f[1] + R[1, 2] * f[2]
    a2 = R[2, 0] * f[0] + R[2, 1] * f[1] + R[2, 2] * f[2]
    out[0] += a0
    out[1] += a1
    out[2] += a2
    out[3] += p[1] * a2 - p[2] * a1 + R[0, 0] * f[3] + R[0, 1] * f[4] + R[0, 2] * f[5]
    out[4] += p[2] * a0 - p[0] * a2 + R[1, 0] * f[3] + R[1, 1] * f[4] + R[1, 2] * f[5]
    out[5] += p[0] * a1 - p[1] * a0 + R[2, 0] * f[3] + R[2, 1] * f[4] + R[2, 2] * f[5]


@numba.njit(cache=True)
def _matvec(A, x, out):
    for r in range(6):
        acc = A[r, 0] * x[0]
        for k in range(1, 6):
            acc += A[r, k] * x[k]
        out[r] = acc


@numba.njit(cache=True)
def _inertia_to_parent(R, p, Ia, X, B, out):
    """``out += X^T Ia X`` (6 x 6), X the motion transform of (R, p); X, B scratch."""
    # X = [[R^T, -R^T [p]x], [0, R^T]]
    for r in range(3):
        for s in range(3):
            X[r, s] = X[3 + r, 3 + s] = R[s, r]
            X[3 + r, s] = 0.0
        X[r, 3] = -(R[1, r] * p[2] - R[2, r] * p[1])
        X[r, 4] = -(R[2, r] * p[0] - R[0, r] * p[2])
        X[r, 5] = -(R[0, r] * p[1] - R[1, r] * p[0])
    for i in range(6):
        for j in range(6):
            acc = Ia[i, 0] * X[0, j]
            for k in range(1, 6):
                acc += Ia[i, k] * X[k, j]
            B[i, j] = acc
    for i in range(6):
        for j in range(i, 6):
            acc = X[0, i] * B[0, j]
            for k in range(1, 6):
                acc += X[k, i] * B[k, j]
            out[i, j] += acc
            if j != i:
                out[j, i] += acc


@numba.njit(cache=True)
def _cross_motion(m, a, out):
    """``out = m x (0, e_a)`` for the unit angular axis a (a revolute joint's S)."""
    for r in range(6):
        out[r] = 0.0
    b, c = (a + 1) % 3, (a + 2) % 3
    # (v, w) x (0, e_a) = (v x e_a, w x e_a); (u x e_a)_b = u_c, (u x e_a)_c = -u_b
    out[b], out[c] = m[c], -m[b]
    out[3 + b], out[3 + c] = m[3 + c], -m[3 + b]


@numba.njit(cache=True)
def aba(q, v, tau, parents, kind, idx_v, R0, p0, inertia, g, ws):
    """Featherstone's ABA in the joints' local frames (real or complex ``q``, ``v``,
    ``tau``; ``g`` the gravity (3,); ``ws`` from :func:`workspace`): the acceleration
    (nv,). Joint 1 a free-flyer (its placement the identity), the others revolute."""
    R, P, vel, c, IA, pA, U, a, X, B, L = ws
    nj = parents.size
    out = np.empty(v.size, dtype=q.dtype)
    h, pa = np.empty(6, dtype=q.dtype), np.empty(6, dtype=q.dtype)
    qi = 7
    for i in range(1, nj):
        par = parents[i]
        if kind[i] == 0:
            x, y, z, w = q[3], q[4], q[5], q[6]
            R[i, 0, 0], R[i, 0, 1], R[i, 0, 2] = (1 - 2 * (y * y + z * z), 2 * (x * y - z * w),
                                                  2 * (x * z + y * w))
            R[i, 1, 0], R[i, 1, 1], R[i, 1, 2] = (2 * (x * y + z * w), 1 - 2 * (x * x + z * z),
                                                  2 * (y * z - x * w))
            R[i, 2, 0], R[i, 2, 1], R[i, 2, 2] = (2 * (x * z - y * w), 2 * (y * z + x * w),
                                                  1 - 2 * (x * x + y * y))
            P[i] = q[:3]
            vel[i] = v[:6]
            c[i] = 0.0
        else:
            ax = kind[i] - 1
            b, d = (ax + 1) % 3, (ax + 2) % 3
            co, si = np.cos(q[qi]), np.sin(q[qi])
            qi += 1
            for r in range(3):  # R0 @ rot(axis, q): columns b, d turn
                R[i, r, ax] = R0[i, r, ax]
                R[i, r, b] = co * R0[i, r, b] + si * R0[i, r, d]
                R[i, r, d] = -si * R0[i, r, b] + co * R0[i, r, d]
            P[i] = p0[i]
            _motion_to_child(R[i], P[i], vel[par], vel[i])
            _cross_motion(vel[i], ax, c[i])
            qd = v[idx_v[i]]
            for r in range(6):
                c[i, r] *= qd
            vel[i, 3 + ax] += qd
        IA[i] = inertia[i]
        _matvec(inertia[i], vel[i], h)  # pA = v x* (I v)
        vv = vel[i]
        pA[i, 0] = vv[4] * h[2] - vv[5] * h[1]
        pA[i, 1] = vv[5] * h[0] - vv[3] * h[2]
        pA[i, 2] = vv[3] * h[1] - vv[4] * h[0]
        pA[i, 3] = vv[4] * h[5] - vv[5] * h[4] + vv[1] * h[2] - vv[2] * h[1]
        pA[i, 4] = vv[5] * h[3] - vv[3] * h[5] + vv[2] * h[0] - vv[0] * h[2]
        pA[i, 5] = vv[3] * h[4] - vv[4] * h[3] + vv[0] * h[1] - vv[1] * h[0]
    for i in range(nj - 1, 1, -1):  # the revolute joints, leaves first
        k = 3 + kind[i] - 1
        U[i] = IA[i, :, k]
        D = U[i, k]
        u = tau[idx_v[i]] - pA[i, k]
        out[idx_v[i]] = u  # held until the third pass
        for r in range(6):
            for s in range(6):
                L[r, s] = IA[i, r, s] - U[i, r] * U[i, s] / D
        _matvec(L, c[i], pa)
        for r in range(6):
            pa[r] += pA[i, r] + U[i, r] * (u / D)
        _inertia_to_parent(R[i], P[i], L, X, B, IA[parents[i]])
        _force_to_parent(R[i], P[i], pa, pA[parents[i]])
    # the free-flyer: its 6 x 6 articulated inertia solved (Cholesky)
    a0 = np.zeros(6, dtype=q.dtype)
    a0[:3] = -g
    _motion_to_child(R[1], P[1], a0, a[1])
    rhs = np.empty(6, dtype=q.dtype)
    _matvec(IA[1], a[1], rhs)
    for r in range(6):
        rhs[r] = tau[r] - pA[1, r] - rhs[r]
    for r in range(6):
        for s in range(r + 1):
            acc = IA[1, r, s]
            for k in range(s):
                acc -= L[r, k] * L[s, k]
            L[r, s] = np.sqrt(acc) if r == s else acc / L[s, s]
    for r in range(6):
        acc = rhs[r]
        for k in range(r):
            acc -= L[r, k] * rhs[k]
        rhs[r] = acc / L[r, r]
    for r in range(5, -1, -1):
        acc = rhs[r]
        for k in range(r + 1, 6):
            acc -= L[k, r] * rhs[k]
        rhs[r] = acc / L[r, r]
    for r in range(6):
        out[r] = rhs[r]
        a[1, r] += rhs[r]
    for i in range(2, nj):
        k = 3 + kind[i] - 1
        _motion_to_child(R[i], P[i], a[parents[i]], a[i])
        acc = out[idx_v[i]]
        for r in range(6):
            a[i, r] += c[i, r]
            acc -= U[i, r] * a[i, r]
        qdd = acc / U[i, k]
        out[idx_v[i]] = qdd
        a[i, k] += qdd
    return out


@numba.njit(cache=True)
def _loop(n, q, v, tau, parents, kind, idx_v, R0, p0, inertia, g):
    ws = workspace(parents.size, q.dtype)
    acc = 0.0
    for _ in range(n):
        acc += aba(q, v, tau, parents, kind, idx_v, R0, p0, inertia, g, ws)[0].real
    return acc


@numba.njit(cache=True)
def _complex_jacobian_loop(n, q, v, tau, parents, kind, idx_v, R0, p0, inertia, g):
    """n Jacobians of the ABA by 2 nv complex steps (v and the joints' coordinates and,
    for the timing, the base's position coordinates as a stand-in for its six)."""
    nv = v.size
    acc = 0.0
    z = np.complex128
    qc, vc, tc = q.astype(z), v.astype(z), tau.astype(z)
    R0, p0, inertia, g = R0.astype(z), p0.astype(z), inertia.astype(z), g.astype(z)
    ws = workspace(parents.size, z)
    for _ in range(n):
        for j in range(2 * nv):
            k = j if j < 3 else (j + 1 if j >= 6 else j % 3)
            if j < nv:
                qc[k] += 1e-30j
            else:
                vc[j - nv] += 1e-30j
            acc += aba(qc, vc, tc, parents, kind, idx_v, R0, p0, inertia, g, ws)[0].imag
            if j < nv:
                qc[k] -= 1e-30j
            else:
                vc[j - nv] -= 1e-30j
    return acc


@numba.njit(cache=True)
def _kernels_loop(n, jacobian, x, Jw, P, support, ancestor, law, da_dq, da_dv, minv, q_ref,
                  Phi):
    """n rounds of bderiv.robots' compiled pieces (no Python between them) of a field
    (the configuration, the contact torque) or, with ``jacobian``, of a Jacobian (the
    configuration, the contact torque's derivatives, the assembly) and the variational
    equation's product ``J Phi``."""
    nv = Jw.shape[1]
    acc = 0.0
    for _ in range(n):
        acc += configuration(q_ref, x, nv)[0]
        if jacobian:
            tau, dq, dv = torque_derivatives(x, Jw, P, support, ancestor, 15, law)
            J = field_jacobian_matrix(x, da_dq, da_dv, minv, dq, dv, law[4], law[5])
            acc += (J @ Phi)[0, 0] + tau[0]
        else:
            acc += torque(x, Jw, P, support, 15, law)[0]
    return acc


def _cpu(fn, n, rounds=5):
    best = np.inf
    for _ in range(rounds):
        t = time.process_time()
        fn()
        best = min(best, (time.process_time() - t) / n)
    return best


def _drop(robot):
    from bderiv.robots import drop_state

    return drop_state(robot, 0.01, -0.5), 0.017123551038388 + 0.05


def _counts(robot):
    """The model's calls in a simulate and a flow_bderivative of the benchmark's run."""
    from bderiv import HybridSystem

    counts = {}
    for run in ("simulate", "flow_bderivative"):
        n = {"field": 0, "field_jacobian": 0}

        def counted(name, n=n):
            fn = getattr(robot, name)

            def call(*args):
                n[name] += 1
                return fn(*args)
            return call
        system = HybridSystem(counted("field"), robot.events, n_events=4,
                              dim=robot.system.dim, field_jacobian=counted("field_jacobian"),
                              event_jacobian=robot.event_jacobian)
        getattr(system, run)(*_drop(robot))
        n["field"] = n["field_jacobian"] = 0
        getattr(system, run)(*_drop(robot))
        counts[run] = dict(n)
    return counts


def main():
    import os

    import pinocchio as pin

    from bderiv.robots import quadruped

    robot = quadruped("solo12")
    model, data = robot.model, robot.data
    arrays = tree(model)
    g = np.ascontiguousarray(model.gravity.linear)
    rng = np.random.default_rng(0)
    ws = workspace(model.njoints, np.float64)
    worst = 0.0
    for _ in range(20):
        q = pin.randomConfiguration(model, -np.ones(model.nq), np.ones(model.nq))
        v, tau = rng.standard_normal(model.nv), rng.standard_normal(model.nv)
        ref = pin.aba(model, data, q, v, tau)
        got = aba(q, v, tau, *arrays, g, ws)
        worst = max(worst, np.abs(got - ref).max() / np.abs(ref).max())
    print(f"{time.strftime('%Y-%m-%d %H:%M', time.gmtime())} UTC, load "
          f"{os.getloadavg()[0]:.1f}; numba ABA against pinocchio.aba on 20 random states: "
          f"largest relative difference {worst:.1e}")
    assert worst < 1e-9
    n = 2000
    ours = _cpu(lambda: [aba(q, v, tau, *arrays, g, ws) for _ in range(n)], n)
    inner = _cpu(lambda: _loop(n, q, v, tau, *arrays, g), n)
    theirs = _cpu(lambda: [pin.aba(model, data, q, v, tau) for _ in range(n)], n)
    dtheirs = _cpu(lambda: [pin.computeABADerivatives(model, data, q, v, tau)
                            for _ in range(n)], n)
    m = 100
    cjac = _cpu(lambda: _complex_jacobian_loop(m, q, v, tau, *arrays, g), m)
    print(f"  pinocchio.aba from Python               {theirs * 1e6:7.2f} us")
    print(f"  pinocchio.computeABADerivatives          {dtheirs * 1e6:7.2f} us "
          f"({dtheirs / theirs:.1f}x aba)")
    print(f"  numba ABA from Python                    {ours * 1e6:7.2f} us")
    print(f"  numba ABA inside a compiled loop         {inner * 1e6:7.2f} us")
    print(f"  its Jacobian by 36 complex steps         {cjac * 1e6:7.1f} us (compiled loop)")
    # the compiled pieces bderiv.robots already has, timed without Python between them
    x = robot.system.simulate(*_drop(robot)).x_final
    nv = robot.nv
    qx, vx = robot.configuration(x)
    robot.field_jacobian(x, 15)
    Jw, P = np.array(data.J), robot._positions()  # noqa: SLF001 - a prototype's probe
    tau = torque(x, Jw, P, robot._support, 15, robot._law)
    da_dq, da_dv, minv = (np.array(m) for m in pin.computeABADerivatives(model, data, qx, vx,
                                                                         tau))
    Phi = rng.standard_normal((2 * nv, 2 * nv))
    args = (x, Jw, P, robot._support, robot._ancestor, robot._law, da_dq, da_dv, minv,
            robot.q_ref, Phi)
    k_field = _cpu(lambda: _kernels_loop(n, False, *args), n)
    k_jac = _cpu(lambda: _kernels_loop(n, True, *args), n)
    pin_kin = _cpu(lambda: [(pin.computeJointJacobians(model, data, qx),
                             pin.updateFramePlacements(model, data)) for _ in range(n)], n)
    print(f"  bderiv.robots' compiled pieces (compiled loop): of a field {k_field * 1e6:.2f}"
          f" us, of a Jacobian with J Phi {k_jac * 1e6:.2f} us")
    print(f"  the joints' Jacobian and placements (Pinocchio, from Python, a stand-in for "
          f"generated kinematics) {pin_kin * 1e6:.2f} us")
    counts = _counts(robot)
    field = inner + pin_kin + k_field
    jacobian = dtheirs / theirs * inner + pin_kin + k_jac
    sim = counts["simulate"]["field"] * field
    flow = counts["flow_bderivative"]["field"] * field + \
        counts["flow_bderivative"]["field_jacobian"] * jacobian
    print(f"  estimate of a compiled route: a field {field * 1e6:.1f} us, a Jacobian "
          f"{jacobian * 1e6:.1f} us (an analytical ABA derivative at Pinocchio's "
          f"{dtheirs / theirs:.1f} ABAs); simulate {counts['simulate']['field']} fields "
          f"{sim * 1e3:.1f} ms, flow_bderivative {counts['flow_bderivative']['field']} "
          f"fields and {counts['flow_bderivative']['field_jacobian']} Jacobians "
          f"{flow * 1e3:.1f} ms, against central differences 72 x simulate: "
          f"{72 * sim / flow:.1f}x (the integrator's own steps not counted)")
    return {"pin_aba": theirs, "pin_abad": dtheirs, "numba_aba_py": ours,
            "numba_aba": inner, "numba_complex_jacobian": cjac}


if __name__ == "__main__":
    main()
