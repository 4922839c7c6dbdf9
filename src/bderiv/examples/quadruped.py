"""A planar quadruped pronking, written as equations (:func:`bderiv.symbolic.contact_system`).

The body (mass ``m_body``, pitch inertia ``I_body``) has coordinates ``x, z, theta``; four
legs, two at each hip ``a = -half_base`` (hind) and ``a = +half_base`` (front), are
telescopic, at right angles to the body, each of length ``l_k`` ending in a foot of mass
``m_foot``: m = 7 coordinates, d = 14. A leg is a spring-damper (``k_leg``, ``c_leg``,
rest length ``rest``) whose actuator adds, in stance, a Van der Pol thrust ``gain (1 -
l_k'^2 / v_ref^2) l_k'`` (it feeds energy in slow stance and takes it out in fast stance,
so the hopping height settles); the ground is a spring-damper on each foot with viscous
friction ``mu`` along it. Touchdown is a plastic impact of the foot (its normal velocity
stopped through the inverse mass matrix), then stance on compliant ground.

On the pronking gait the body does not pitch and all four feet land and lift off
together: two simultaneous groups of four events per stride. The touchdowns pass the
mass-orthogonality check: with the legs vertical an impulse at a foot only shortens its
own leg (``J_i M^-1 J_j^T = 0``, :meth:`~bderiv.symbolic.ContactSystem.coupling`); a
pitched body couples the feet (the variant refused in the tests). ``x`` is a cyclic
coordinate (``periodic_orbit(..., cyclic=[0])``).

:func:`quadruped` builds the model (the user code: under 60 lines), :func:`quadruped_orbit`
finds the gait, :func:`quadruped_summary` goes from the equations to the stability verdict
(``summary_text`` prints it; ``bderiv demo --example quadruped``).
"""

from __future__ import annotations

import time

import numpy as np

__all__ = ["APEX", "apex_section", "quadruped", "quadruped_orbit", "quadruped_summary",
           "summary_text"]

#: the body's apex state on the gait with the default parameters (a guess for Newton)
APEX = np.array([0.0, 0.75, 0.0, 0.51, 0.51, 0.51, 0.51, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0])
#: index of the body's vertical velocity in the state
VZ = 8


def quadruped(**values):
    """The pronking quadruped as a :class:`~bderiv.symbolic.ContactSystem` (d = 14, n = 4).

    Parameters
    ----------
    **values
        Parameter values by name (module docstring; the defaults below), e.g.
        ``gain=3.0``.

    Examples
    --------
    >>> system = quadruped()
    >>> system.dim, system.n_events, system.param_values["m_foot"]
    (14, 4, 0.05)
    """
    import sympy as sp

    from ..symbolic import contact_system

    x, z, th = sp.symbols("x z theta")
    legs = sp.symbols("l0:4")
    q = [x, z, th, *legs]
    v = sp.symbols("vx vz omega dl0:4")
    flags = sp.symbols("s0:4")
    P = dict(m_body=1.0, I_body=0.16, m_foot=0.05, half_base=0.4, rest=0.5, k_leg=100.0,
             c_leg=1.0, gain=2.0, v_ref=1.0, mu=20.0, g=9.81, contact_stiffness=1e4,
             contact_damping=40.0)
    unknown = set(values) - set(P)
    if unknown:
        raise ValueError(f"{sorted(unknown)} are not parameters of the quadruped (its "
                         f"parameters: {', '.join(P)})")
    P.update(values)
    p = {name: sp.Symbol(name) for name in P}
    a = [-p["half_base"], -p["half_base"], p["half_base"], p["half_base"]]
    c, s = sp.cos(th), sp.sin(th)
    feet = [sp.Matrix([x + a[k] * c + legs[k] * s, z + a[k] * s - legs[k] * c])
            for k in range(4)]
    qv = sp.Matrix(q)
    Jf = [f.jacobian(qv) for f in feet]  # (2, 7) foot velocity per coordinate rate
    M = sp.diag(p["m_body"], p["m_body"], p["I_body"], 0, 0, 0, 0)
    M += sum((p["m_foot"] * J.T * J for J in Jf), sp.zeros(7, 7))
    V = p["g"] * (p["m_body"] * z + p["m_foot"] * sum(f[1] for f in feet))
    V += sum(p["k_leg"] * (lk - p["rest"]) ** 2 / 2 for lk in legs)
    forces = [-sp.diff(V, qi) for qi in q]
    vv = sp.Matrix(v)
    for k in range(4):
        dl = v[3 + k]
        forces[3 + k] += -p["c_leg"] * dl + flags[k] * p["gain"] * (1 - dl**2 / p["v_ref"]**2) * dl
        slide = (Jf[k] * vv)[0]  # the foot's horizontal velocity
        forces = [fi - flags[k] * p["mu"] * slide * Jf[k][0, i] for i, fi in enumerate(forces)]
    return contact_system(q, M, forces, [f[1] for f in feet], impact="plastic",
                          params={p[n]: P[n] for n in P}, velocities=v, flags=flags)


def apex_section(x):
    """The apex section ``-vz``: crossed upward when the body starts to fall."""
    return -x[VZ]


def _apex_gradient(x):
    g = np.zeros(14)
    g[VZ] = -1.0
    return g


def quadruped_orbit(system=None, guess=None, **kwargs):
    """The pronking orbit by Newton's method from ``guess`` (default :data:`APEX`).

    Returns
    -------
    PeriodicOrbit
    """
    system = quadruped() if system is None else system
    guess = APEX if guess is None else np.asarray(guess, dtype=np.float64)
    kwargs.setdefault("period_guess", 0.5)
    kwargs.setdefault("section_gradient", _apex_gradient)
    return system.periodic_orbit(guess, apex_section, cyclic=[0], **kwargs)
