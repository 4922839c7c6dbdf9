"""The compliant feet's generalized forces and their derivatives, compiled (numba), from
Pinocchio's world Jacobian of the joints.

Why: the model's field and Jacobian call Pinocchio once per foot for frame Jacobians,
velocities and their derivatives, and glue their small arrays in NumPy; that Python was
nine tenths of a Jacobian's time (``benchmarks/robots.py``). Here one call of
``computeJointJacobians`` gives ``data.J`` (6, nv): column j is joint coordinate j's
motion ``S_j = (v_j, w_j)`` in the world frame at the world's origin (Pinocchio's order,
linear then angular), and the rest is a few loops over its columns.

**The force.** Foot k at the world point ``p`` (on its parent joint's body) has the
linear Jacobian ``J_k[:, j] = v_j + w_j x p`` over the columns j of its support (zero
elsewhere), the velocity ``u = J_k v`` and the ground's force ``f`` (the compliant law of
:mod:`bderiv.robots.legged`); the generalized force is ``J_k^T f``, its column j
``S_j . F`` with the wrench ``F = (f, p x f)`` at the origin. The dynamics are then
``a = ABA(q, v, tau + sum_k J_k^T f_k)`` (Pinocchio's ``aba`` without external forces).

**Its derivatives** in Pinocchio's tangent coordinates of q (``integrate(q, dq)``, right
perturbations): a column moves with the coordinates of its joint's ancestors and of its
own joint, ``dS_j/dq_i = S_i x S_j`` (the motion cross product; zero for i = j), and the
foot's point with those of its support, ``dp/dq_i = J_k[:, i]``. So, with ``f`` held,
``d(J_k^T f)_j/dq_i = (S_i x S_j) . F + w_j . (dp/dq_i x f)``, and
``du/dq_i = sum_j (c_j + c'_j x p) v_j + W x dp/dq_i`` (``(c, c') = S_i x S_j``,
``W = sum_j w_j v_j`` the body's angular velocity); ``f``'s own derivative follows from
``du`` and ``dp``. ``tests/test_robots.py`` holds the result to central differences of
the field.
"""

from __future__ import annotations

import sys

import numba
import numpy as np

from .._kernels._cache import rekey_modules, sources_digest
from . import _lie
from ._lie import _cr, _rate_jacobian_xi, _rate_matrix, put, put1, rate, rate_inverse


@numba.njit(cache=True)
def _point_jacobian(Jw, support, p, out):
    """``out`` (3, nv) = the point ``p``'s linear Jacobian over the ``support`` columns."""
    for j in range(Jw.shape[1]):
        if support[j]:
            out[0, j] = Jw[0, j] + Jw[4, j] * p[2] - Jw[5, j] * p[1]
            out[1, j] = Jw[1, j] + Jw[5, j] * p[0] - Jw[3, j] * p[2]
            out[2, j] = Jw[2, j] + Jw[3, j] * p[1] - Jw[4, j] * p[0]
        else:
            out[0, j] = out[1, j] = out[2, j] = 0.0


@numba.njit(cache=True)
def _force(Jk, p, v, law):
    """The ground's world force (3,) on a foot at ``p`` with linear Jacobian ``Jk``;
    ``law`` = (friction, stiffness, damping, ground)."""
    u = Jk @ v
    out = np.empty(3)
    out[0] = -law[0] * u[0]
    out[1] = -law[0] * u[1]
    out[2] = law[1] * (law[3] - p[2]) - law[2] * u[2]
    return out


@numba.njit(cache=True)
def _posture(x, nv, law):
    """The PD posture torques ``-kp e_j - kd v_j`` (nv,), none on the base."""
    tau = np.zeros(nv)
    for j in range(6, nv):
        tau[j] = -law[4] * x[j] - law[5] * x[nv + j]
    return tau


@numba.njit(cache=True)
def torque(x, Jw, P, support, mask, law):
    """The PD posture torques plus ``sum_k J_k^T f_k`` over the feet k in stance (bit k
    of ``mask``), (nv,).

    Parameters
    ----------
    x : ndarray, (>= 2 nv,)
        The state ``(e, v, ...)``.
    Jw : ndarray, (6, nv)
        ``data.J`` after ``computeJointJacobians`` (unused if ``mask`` is 0).
    P : ndarray, (n, 3)
        The feet's world positions (rows of feet not in ``mask`` unused).
    support : ndarray of bool, (n, nv)
        The columns of each foot's support.
    mask : int
    law : ndarray, (6,)
        friction, stiffness, damping, ground, kp, kd.
    """
    nv = Jw.shape[1]
    v = np.ascontiguousarray(x[nv:2 * nv])
    tau = _posture(x, nv, law)
    Jk = np.empty((3, nv))
    for k in range(P.shape[0]):
        if (mask >> k) & 1:
            _point_jacobian(Jw, support[k], P[k], Jk)
            tau += Jk.T @ _force(Jk, P[k], v, law)
    return tau


@numba.njit(cache=True)
def torque_derivatives(x, Jw, P, support, ancestor, mask, law):
    """:func:`torque` and the derivatives of its contact part in q (tangent,
    Pinocchio's) and v (module docstring).

    Parameters
    ----------
    ancestor : ndarray of bool, (nv, nv)
        ``ancestor[i, j]``: coordinate i's joint is coordinate j's or one of its ancestors.
    (the rest as :func:`torque`'s)

    Returns
    -------
    tau : ndarray, (nv,)
    dtau_dq, dtau_dv : ndarray, (nv, nv)
    """
    nv = Jw.shape[1]
    v = np.ascontiguousarray(x[nv:2 * nv])
    tau = _posture(x, nv, law)
    dq = np.zeros((nv, nv))
    dv = np.zeros((nv, nv))
    Jk = np.empty((3, nv))
    gain = np.array([law[0], law[0], law[2]])  # -df/du, diagonal
    for k in range(P.shape[0]):
        if not (mask >> k) & 1:
            continue
        p = P[k]
        cols = np.nonzero(support[k])[0]
        _point_jacobian(Jw, support[k], p, Jk)
        f = _force(Jk, p, v, law)
        tau += Jk.T @ f
        pf0, pf1, pf2 = _cr(p[0], p[1], p[2], f[0], f[1], f[2])
        W0 = W1 = W2 = 0.0  # the body's angular velocity
        for j in cols:
            W0 += Jw[3, j] * v[j]
            W1 += Jw[4, j] * v[j]
            W2 += Jw[5, j] * v[j]
        for i in cols:
            vi0, vi1, vi2, wi0, wi1, wi2 = (Jw[0, i], Jw[1, i], Jw[2, i], Jw[3, i],
                                            Jw[4, i], Jw[5, i])
            d0, d1, d2 = Jk[0, i], Jk[1, i], Jk[2, i]  # dp/dq_i
            u0, u1, u2 = _cr(W0, W1, W2, d0, d1, d2)  # du/dq_i
            e0, e1, e2 = _cr(d0, d1, d2, f[0], f[1], f[2])
            for j in cols:
                vj0, vj1, vj2, wj0, wj1, wj2 = (Jw[0, j], Jw[1, j], Jw[2, j], Jw[3, j],
                                                Jw[4, j], Jw[5, j])
                acc = wj0 * e0 + wj1 * e1 + wj2 * e2
                if ancestor[i, j] and i != j:  # (c, a) = S_i x S_j
                    c0, c1, c2 = _cr(wi0, wi1, wi2, vj0, vj1, vj2)
                    b0, b1, b2 = _cr(vi0, vi1, vi2, wj0, wj1, wj2)
                    c0, c1, c2 = c0 + b0, c1 + b1, c2 + b2
                    a0, a1, a2 = _cr(wi0, wi1, wi2, wj0, wj1, wj2)
                    b0, b1, b2 = _cr(a0, a1, a2, p[0], p[1], p[2])
                    u0 += (c0 + b0) * v[j]
                    u1 += (c1 + b1) * v[j]
                    u2 += (c2 + b2) * v[j]
                    acc += c0 * f[0] + c1 * f[1] + c2 * f[2] + a0 * pf0 + a1 * pf1 + a2 * pf2
                dq[j, i] += acc
            # f's own derivative: -gain du, and the spring's -stiffness dp_z
            g0, g1, g2 = -gain[0] * u0, -gain[1] * u1, -gain[2] * u2 - law[1] * d2
            for j in cols:
                dq[j, i] += Jk[0, j] * g0 + Jk[1, j] * g1 + Jk[2, j] * g2
                dv[j, i] -= (Jk[0, j] * gain[0] * Jk[0, i] + Jk[1, j] * gain[1] * Jk[1, i]
                             + Jk[2, j] * gain[2] * Jk[2, i])
    return tau, dq, dv


@numba.njit(cache=True)
def field_vector(x, a, nv):
    """The field ``(de/dt, dv/dt)`` (2 nv,) from the state and the acceleration ``a``."""
    out = np.empty(2 * nv)
    put1(out, 0, rate(x[:6], x[nv:nv + 6]))
    for i in range(6, nv):
        out[i] = x[nv + i]
    put1(out, nv, a)
    return out


@numba.njit(cache=True)
def field_jacobian_matrix(x, da_dq, da_dv, minv_upper, dtau_dq, dtau_dv, kp, kd):
    """The field's Jacobian (2 nv, 2 nv) in the state ``x = (e, v)``, from Pinocchio's
    ``computeABADerivatives`` at the total torque (its ``Minv`` filled in the upper
    triangle only) and the derivatives of the contact torque; the PD torques
    ``-kp e_j - kd v_j`` in e directly, the chain rule through ``dIntegrate(q_ref, e)``
    (the base's ``Jr(e_base)``, the inverse of its coordinate rate)."""
    nv = da_dq.shape[0]
    Minv = np.empty((nv, nv))
    for i in range(nv):
        for j in range(i, nv):
            Minv[i, j] = Minv[j, i] = minv_upper[i, j]
    xi = np.ascontiguousarray(x[:6])
    d_nu = _rate_matrix(xi)
    d_xi = _rate_jacobian_xi(xi, np.ascontiguousarray(x[nv:nv + 6]))
    Aq = da_dq + Minv @ dtau_dq
    out = np.zeros((2 * nv, 2 * nv))
    put(out, 0, 0, d_xi)
    put(out, 0, nv, d_nu)
    for i in range(6, nv):
        out[i, nv + i] = 1.0
    put(out, nv, 0, np.ascontiguousarray(Aq[:, :6]) @ rate_inverse(xi))
    put(out, nv, nv, da_dv + Minv @ dtau_dv)
    for i in range(nv):
        for j in range(6, nv):
            out[nv + i, j] = Aq[i, j] - kp * Minv[i, j]
            out[nv + i, nv + j] -= kd * Minv[i, j]
    return out


# numba watches a cached kernel's own file only, and these compile _lie's kernels into
# theirs: cached under a digest of both files, an edit of either names new entries
rekey_modules([sys.modules[__name__]], sources_digest(None, _lie.__file__, __file__))
