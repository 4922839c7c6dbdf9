"""The free-flying base's tangent coordinates: ``d e / dt`` from the body velocity, exactly.

A robot's configuration is ``q = integrate(q_ref, e)`` (``pinocchio.integrate``): for the
free-flyer ``M = M_ref exp6(e_base)`` on SE(3), the joints ``q_j = q_ref_j + e_j``. The
state of bderiv holds ``e`` (nv numbers, no quaternion, no constraint), so ``de/dt`` is
the body velocity ``nu`` (Pinocchio's free-flyer velocity, in the base frame) through
the inverse right Jacobian of SE(3): ``de/dt = Jr(e)^-1 nu`` (Pinocchio's
``Jlog6(exp6(e))``, or the inverse of ``dIntegrate(q_ref, e, ARG1)``'s base block).

Why our own formula: the field's Jacobian needs ``d/de (Jr(e)^-1 nu)``, a second
derivative of the exponential that Pinocchio does not give on SE(3). The closed form of
Barfoot's ``J_l^-1`` (State Estimation for Robotics, 2017, eqs. 7.86, 7.87, with
``J_r(xi) = J_l(-xi)``), written here in cross products for any dtype, is evaluated at
``e + i h u`` (complex step: exact to rounding, not a finite difference) for its
derivative, and at small angles by its Taylor series (where the closed form cancels).
The matrix and its complex steps are compiled (numba, cached on disk: about 20 us a
Jacobian against 300 us in NumPy's small-array calls, which were the model's largest
cost in ``benchmarks/robots.py``).
``tests/test_robots.py`` holds it to Pinocchio's ``Jlog6`` and to ``dIntegrate``.

Why our own exponential too (:func:`base_configuration`, equal to ``pinocchio.integrate``
to rounding): Pinocchio's ``integrate`` and ``dIntegrate`` of the free-flyer are rough at
small angles (measured on Go1 in stance, |e_base| angle 1.2e-4: ``dIntegrate`` moved by
4.6e-6 and jumped by 2.7e-5 between states 5e-12 s apart on the trajectory), which is
harmless to a simulation but stalls the variational equation's step control (steps of
1e-12 s). The series below keep every coefficient smooth to rounding.
"""

from __future__ import annotations

import numpy as np

from .._kernels._cache import checked_njit

#: below this squared angle the coefficients come from their Taylor series (the closed
#: forms lose up to 1e-16 / theta^4 relative there: 1e-12 at theta = 0.1)
SERIES_THETA2 = 1e-2
#: the complex step's size (any tiny number: no subtraction, exact to rounding)
STEP = 1e-30


def base_configuration(q_ref, xi) -> np.ndarray:
    """The free-flyer's configuration ``(p, quaternion x y z w)`` (7,) of
    ``M_ref exp6(xi)``, ``M_ref`` given as such a 7-vector ``q_ref``: Pinocchio's
    ``integrate`` of the base (module docstring; compiled)."""
    out = np.empty(7)
    _base_into(np.ascontiguousarray(q_ref, dtype=np.float64),
               np.ascontiguousarray(xi, dtype=np.float64), out)
    return out


@checked_njit()
def configuration(q_ref, x, nv):
    """``q = integrate(q_ref, x[:nv])`` (nq,) of a free-flyer then one-coordinate joints
    (compiled)."""
    q = np.empty(q_ref.size)
    _base_into(q_ref, x[:6], q)
    for i in range(7, q.size):
        q[i] = q_ref[i] + x[i - 1]
    return q


@checked_njit()
def _base_into(q_ref, xi, out):
    """:func:`base_configuration` into ``out[:7]``."""
    t2 = xi[3] * xi[3] + xi[4] * xi[4] + xi[5] * xi[5]
    if t2 < SERIES_THETA2:
        a = 1 / 6 - t2 / 120 + t2**2 / 5040 - t2**3 / 362880  # (t - sin t) / t^3
        half = 0.5 - t2 / 48 + t2**2 / 3840 - t2**3 / 645120  # sin(t/2) / t
        cos_half = 1 - t2 / 8 + t2**2 / 384 - t2**3 / 46080
        v1 = 0.5 - t2 / 24 + t2**2 / 720 - t2**3 / 40320  # (1 - cos t) / t^2
    else:
        t = np.sqrt(t2)
        a = (t - np.sin(t)) / t**3
        half, cos_half, v1 = np.sin(t / 2) / t, np.cos(t / 2), (1 - np.cos(t)) / t2
    rho, phi = xi[:3], xi[3:6]
    P = _skew_one(phi)
    Pr = P @ rho
    step = rho + v1 * Pr + a * (P @ Pr)  # J_l3(phi) rho
    x0, y0, z0, w0 = q_ref[3], q_ref[4], q_ref[5], q_ref[6]
    x1, y1, z1 = half * phi[0], half * phi[1], half * phi[2]
    w1 = cos_half
    R0 = np.array([[1 - 2 * (y0 * y0 + z0 * z0), 2 * (x0 * y0 - z0 * w0),
                    2 * (x0 * z0 + y0 * w0)],
                   [2 * (x0 * y0 + z0 * w0), 1 - 2 * (x0 * x0 + z0 * z0),
                    2 * (y0 * z0 - x0 * w0)],
                   [2 * (x0 * z0 - y0 * w0), 2 * (y0 * z0 + x0 * w0),
                    1 - 2 * (x0 * x0 + y0 * y0)]])
    put1(out, 0, q_ref[:3] + R0 @ step)
    out[3] = w0 * x1 + x0 * w1 + y0 * z1 - z0 * y1
    out[4] = w0 * y1 - x0 * z1 + y0 * w1 + z0 * x1
    out[5] = w0 * z1 + x0 * y1 - y0 * x1 + z0 * w1
    out[6] = w0 * w1 - x0 * x1 - y0 * y1 - z0 * z1


@checked_njit()
def _coefficients_one(t2):
    """``a, b, c`` of Q and ``g`` of ``J_l3^-1`` (module docstring) of one real or
    complex theta^2: a = (t - sin t)/t^3, b = (t^2 + 2 cos t - 2)/(2 t^4),
    c = (2t - 3 sin t + t cos t)/(2 t^5), g = 1/t^2 - (1 + cos t)/(2 t sin t)."""
    if t2.real < SERIES_THETA2:
        return (1 / 6 - t2 / 120 + t2**2 / 5040 - t2**3 / 362880,
                1 / 24 - t2 / 720 + t2**2 / 40320 - t2**3 / 3628800,
                1 / 120 - t2 / 2520 + t2**2 / 120960 - t2**3 / 6652800,
                1 / 12 + t2 / 720 + t2**2 / 30240 + t2**3 / 1209600)
    t = np.sqrt(t2)
    s, co = np.sin(t), np.cos(t)
    return ((t - s) / t**3, (t2 + 2 * co - 2) / (2 * t2**2),
            (2 * t - 3 * s + t * co) / (2 * t2**2 * t), 1 / t2 - (1 + co) / (2 * t * s))


@checked_njit(inline="always")
def put(out, r0, c0, M):
    """``out[r0:r0 + M.shape[0], c0:c0 + M.shape[1]] = M`` by loops (an array assigned
    into a slice compiles numba's shape-mismatch error and its string formatting, seconds
    in every process that compiles these kernels). Inlined: called with constant offsets,
    a function of its own would compile once per literal."""
    for i in range(M.shape[0]):
        for j in range(M.shape[1]):
            out[r0 + i, c0 + j] = M[i, j]


@checked_njit(inline="always")
def put1(out, i0, v):
    """``out[i0:i0 + v.size] = v`` by a loop (see :func:`put`)."""
    for i in range(v.shape[0]):
        out[i0 + i] = v[i]


@checked_njit()
def _skew_one(w):
    out = np.zeros((3, 3), dtype=w.dtype)
    out[0, 1], out[0, 2], out[1, 2] = -w[2], w[1], -w[0]
    out[1, 0], out[2, 0], out[2, 1] = w[2], -w[1], w[0]
    return out


@checked_njit()
def _mm(A, B):
    """A 3 x 3 product by loops (numba's ``@`` of complex matrices goes to BLAS)."""
    out = np.zeros((3, 3), dtype=A.dtype)
    for i in range(3):
        for j in range(3):
            acc = A[i, 0] * B[0, j]
            for k in range(1, 3):
                acc += A[i, k] * B[k, j]
            out[i, j] = acc
    return out


@checked_njit()
def _rate_matrix(xi):
    """:func:`se3_rate_matrix`, compiled for float64 and complex128 ``xi`` (6,)."""
    rho, phi = -xi[:3], -xi[3:]  # J_r(xi) = J_l(-xi)
    a, b, c, g = _coefficients_one(phi[0] * phi[0] + phi[1] * phi[1] + phi[2] * phi[2])
    P, R = _skew_one(phi), _skew_one(rho)
    PP = _mm(P, P)
    PR, RP = _mm(P, R), _mm(R, P)
    PRP = _mm(PR, P)
    Q = (R / 2 + a * (PR + RP + PRP) + b * (_mm(P, PR) + _mm(RP, P) - 3 * PRP)
         + c * (_mm(PRP, P) + _mm(P, PRP)))  # Barfoot's eq. 7.86
    inv3 = -P / 2 + g * PP  # J_l3(phi)^-1 - I
    for i in range(3):
        inv3[i, i] += 1
    out = np.zeros((6, 6), dtype=xi.dtype)
    put(out, 0, 0, inv3)
    put(out, 3, 3, inv3)
    put(out, 0, 3, -_mm(_mm(inv3, Q), inv3))
    return out


@checked_njit()
def _cr(a0, a1, a2, b0, b1, b2):
    """``a x b`` of scalars (real or complex) as a tuple."""
    return a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0


@checked_njit()
def _rate_times(x0, x1, x2, x3, x4, x5, nu):
    """``Jr(xi)^-1 nu`` (a 6-tuple) of ``xi = (x0 .. x5)``, real or complex scalars, by
    cross products (:func:`_rate_matrix` applied to ``nu`` without its matrices: no
    small arrays, for the complex steps)."""
    r0, r1, r2, p0, p1, p2 = -x0, -x1, -x2, -x3, -x4, -x5  # J_r(xi) = J_l(-xi)
    a, b, c, g = _coefficients_one(p0 * p0 + p1 * p1 + p2 * p2)
    # w = J_l3^-1 nu_ang, J_l3^-1 y = y - (phi x y) / 2 + g phi x (phi x y)
    y0, y1, y2 = nu[3], nu[4], nu[5]
    s0, s1, s2 = _cr(p0, p1, p2, y0, y1, y2)
    t0, t1, t2 = _cr(p0, p1, p2, s0, s1, s2)
    w0, w1, w2 = y0 - s0 / 2 + g * t0, y1 - s1 / 2 + g * t1, y2 - s2 / 2 + g * t2
    # Q w (Barfoot's eq. 7.86), P y = phi x y, R y = rho x y
    Rw = _cr(r0, r1, r2, w0, w1, w2)
    Pw = _cr(p0, p1, p2, w0, w1, w2)
    PRw = _cr(p0, p1, p2, Rw[0], Rw[1], Rw[2])
    RPw = _cr(r0, r1, r2, Pw[0], Pw[1], Pw[2])
    PRPw = _cr(p0, p1, p2, RPw[0], RPw[1], RPw[2])
    PPRw = _cr(p0, p1, p2, PRw[0], PRw[1], PRw[2])
    PPw = _cr(p0, p1, p2, Pw[0], Pw[1], Pw[2])
    RPPw = _cr(r0, r1, r2, PPw[0], PPw[1], PPw[2])
    PRPPw = _cr(p0, p1, p2, RPPw[0], RPPw[1], RPPw[2])
    PPRPw = _cr(p0, p1, p2, PRPw[0], PRPw[1], PRPw[2])

    def q(i):
        return (Rw[i] / 2 + a * (PRw[i] + RPw[i] + PRPw[i])
                + b * (PPRw[i] + RPPw[i] - 3 * PRPw[i]) + c * (PRPPw[i] + PPRPw[i]))

    # the linear rows: J_l3^-1 (nu_lin - Q w)
    y0, y1, y2 = nu[0] - q(0), nu[1] - q(1), nu[2] - q(2)
    s0, s1, s2 = _cr(p0, p1, p2, y0, y1, y2)
    t0, t1, t2 = _cr(p0, p1, p2, s0, s1, s2)
    return (y0 - s0 / 2 + g * t0, y1 - s1 / 2 + g * t1, y2 - s2 / 2 + g * t2, w0, w1, w2)


@checked_njit()
def _rate_jacobian_xi(xi, nu):
    """d(Jr(xi)^-1 nu)/dxi (6, 6) by six complex steps."""
    out = np.empty((6, 6))
    z = np.empty(6, dtype=np.complex128)
    for j in range(6):
        for i in range(6):
            z[i] = xi[i]
        z[j] += 1j * STEP
        r = _rate_times(z[0], z[1], z[2], z[3], z[4], z[5], nu)
        for i in range(6):
            out[i, j] = r[i].imag / STEP
    return out


@checked_njit()
def rate_inverse(xi):
    """``Jr(xi)`` (6, 6), the inverse of :func:`se3_rate_matrix` of real ``xi`` in closed
    form: ``J_l(-xi) = [[J_l3, Q], [0, J_l3]]`` at ``(-rho, -phi)`` (Barfoot's eqs.
    7.85, 7.86), ``J_l3(phi) = I + (1 - cos t)/t^2 [phi]x + (t - sin t)/t^3 [phi]x^2``."""
    rho, phi = -xi[:3], -xi[3:]
    t2 = phi[0] * phi[0] + phi[1] * phi[1] + phi[2] * phi[2]
    a, b, c, _ = _coefficients_one(t2)
    if t2 < SERIES_THETA2:
        v1 = 0.5 - t2 / 24 + t2**2 / 720 - t2**3 / 40320
    else:
        v1 = (1 - np.cos(np.sqrt(t2))) / t2
    P, R = _skew_one(phi), _skew_one(rho)
    PP = _mm(P, P)
    PR, RP = _mm(P, R), _mm(R, P)
    PRP = _mm(PR, P)
    out = np.zeros((6, 6))
    put(out, 0, 3, R / 2 + a * (PR + RP + PRP) + b * (_mm(P, PR) + _mm(RP, P) - 3 * PRP)
        + c * (_mm(PRP, P) + _mm(P, PRP)))
    J3 = v1 * P + a * PP
    for i in range(3):
        J3[i, i] += 1
    put(out, 0, 0, J3)
    put(out, 3, 3, J3)
    return out


@checked_njit()
def rate(xi, nu):
    """``Jr(xi)^-1 nu`` (6,) of real ``xi``, ``nu`` (6,) (compiled)."""
    r = _rate_times(xi[0], xi[1], xi[2], xi[3], xi[4], xi[5], nu)
    out = np.empty(6)
    for i in range(6):
        out[i] = r[i]
    return out


def se3_rate_matrix(xi) -> np.ndarray:
    """``Jr(xi)^-1`` (6, 6): the rate of the SE(3) tangent coordinates ``xi`` (6,), linear
    then angular as Pinocchio orders them, is ``Jr(xi)^-1 nu`` under the body velocity
    ``nu``. Real or complex ``xi`` (compiled, numba).
    """
    xi = np.asarray(xi)
    return _rate_matrix(np.ascontiguousarray(
        xi, dtype=np.complex128 if np.iscomplexobj(xi) else np.float64))


def se3_rate_jacobians(xi, nu):
    """The rate ``Jr(xi)^-1 nu`` (6,), its Jacobian in ``nu`` (6, 6) (the matrix
    ``Jr(xi)^-1``) and in ``xi`` (6, 6), the latter by the complex step.

    Parameters
    ----------
    xi, nu : ndarray, (6,), float

    Returns
    -------
    rate : ndarray, (6,)
    d_nu : ndarray, (6, 6)
    d_xi : ndarray, (6, 6)
    """
    xi = np.ascontiguousarray(xi, dtype=np.float64)
    nu = np.ascontiguousarray(nu, dtype=np.float64)
    d_nu = _rate_matrix(xi)
    return d_nu @ nu, d_nu, _rate_jacobian_xi(xi, nu)
