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
own leg (``J_i M^-1 J_j^T = 0``, :func:`~bderiv.symbolic.coupling`); a
pitched body couples the feet (the variant refused in the tests). ``x`` is a cyclic
coordinate (``periodic_orbit(..., cyclic=[0])``).

:func:`quadruped` builds the model (the user code: under 60 lines), :func:`quadruped_orbit`
finds the gait, :func:`quadruped_summary` goes from the equations to the stability verdict
(``summary_text`` prints it; ``bderiv demo --example quadruped``).
"""

from __future__ import annotations

import time

import numpy as np

from .._kernels._cache import checked_njit
from ..analysis.stability import verdict_word

__all__ = ["APEX", "LABELS", "apex_section", "quadruped", "quadruped_figure",
           "quadruped_orbit", "quadruped_summary", "summary_text"]

#: the body's apex state on the gait with the default parameters (a guess for Newton)
APEX = np.array([0.0, 0.56, 0.0, 0.49, 0.49, 0.49, 0.49, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0])
#: index of the body's vertical velocity in the state
VZ = 8


def quadruped(**values):
    """The pronking quadruped from :func:`~bderiv.symbolic.contact_system` (d = 14, n = 4).

    Parameters
    ----------
    **values
        Parameter values by name (module docstring; the defaults below), e.g.
        ``gain=3.0``.

    Returns
    -------
    HybridSystem
        State ``(x, z, theta, l_0..l_3, vx, vz, omega, l_0'..l_3')``; event k is foot
        k's penetration of the ground (0, 1 hind, 2, 3 front). The first build derives
        and compiles (timed by ``benchmarks/quadruped.py``: docs/benchmarks.md, "Kernel
        design choices, measured"); later ones load the cached kernels.
    """
    import sympy as sp

    from ..symbolic import contact_system

    x, z, th = sp.symbols("x z theta")
    legs = sp.symbols("l0:4")
    q = [x, z, th, *legs]
    v = sp.symbols("vx vz omega dl0:4")
    flags = sp.symbols("s0:4")
    P = dict(m_body=1.0, I_body=0.16, m_foot=0.05, half_base=0.4, rest=0.5, k_leg=100.0,
             c_leg=1.0, gain=2.0, v_ref=2.0, mu=2.0, g=9.81, contact_stiffness=1e4,
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


@checked_njit()
def apex_section(x):
    """The apex section ``-vz``: crossed upward when the body starts to fall (compiled:
    the compiled integrator watches it at every step)."""
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


#: names of the state components, with their units (figures)
LABELS = ("$x$ (m)", "height $z$ (m)", "pitch $\\theta$ (rad)",
          *(f"leg $l_{k}$ (m)" for k in range(4)), "$v_x$ (m/s)", "$v_z$ (m/s)",
          "$\\omega$ (rad/s)", *(f"$l_{k}'$ (m/s)" for k in range(4)))


def quadruped_figure(orbit):
    """The gait over one period: height, pitch, a leg, the vertical velocity, stance
    shaded, the event groups marked (:func:`bderiv.plot.gait_orbit`)."""
    from ..plot import gait_orbit

    return gait_orbit(orbit, components=[1, 2, 3, VZ], phase=(1, VZ), labels=LABELS,
                      time_label="time (s)", phases={15: "stance: all four feet down"})


def _max_coupling(system, x) -> float:
    """The largest relative inverse-mass coupling of two contacts at ``x``."""
    from ..symbolic import coupling

    C = coupling(system, x)
    rel = np.abs(C) / np.sqrt(np.outer(np.diag(C), np.diag(C)))
    return float((rel - np.eye(len(C))).max())


def quadruped_summary(*, seed=0, n_directions=200, iterations=200, figure=None):
    """From the equations to the stability verdict, with the times and the
    mass-orthogonality check of the touchdowns.

    Parameters
    ----------
    seed, n_directions, iterations
        Of :meth:`~bderiv.analysis.orbit.PeriodicOrbit.stability`.
    figure : str or os.PathLike, optional
        Where to save :func:`quadruped_figure` (needs matplotlib).

    Returns
    -------
    dict
        JSON-friendly: ``build`` (derivation and compilation seconds, cache hit),
        ``orbit`` (x0, period, Newton residuals, seconds), ``groups`` (time, events,
        directions, the largest relative coupling of the contacts there), ``coupling``
        (the same at a pitched touchdown, for contrast), ``stability`` (growth rate,
        stable, pieces met, ``|multipliers|`` of the most visited, seconds).
    """
    start = time.perf_counter()
    system = quadruped()
    built = time.perf_counter()
    build = system.source.build
    orb = quadruped_orbit(system)
    found = time.perf_counter()
    st = orb.stability(n_directions=n_directions, iterations=iterations, seed=seed)
    judged = time.perf_counter()
    pitched = orb.trajectory.groups[0].state.copy()
    pitched[2] = 0.2
    top = max(st.visits, key=st.visits.get)
    res = {
        "name": "quadruped",
        "description": "planar quadruped pronking: body x, z, pitch and four telescopic "
                       "legs with massive feet (d = 14, n = 4), plastic foot impacts, "
                       "compliant ground, from bderiv.symbolic.contact_system",
        "build": {"cached": build.cached, "derive_seconds": build.derive_seconds,
                  "load_seconds": build.load_seconds, "seconds": built - start},
        "orbit": {"x0": orb.x0.tolist(), "period": orb.period, "residual": orb.residual,
                  "newton_residuals": [h.residual for h in orb.history],
                  "seconds": found - built},
        "groups": [{"time": g.time, "events": list(g.events), "directions": list(g.directions),
                    "coupling": _max_coupling(system, g.state)}
                   for g in orb.trajectory.groups],
        "coupling": {"pitch": 0.2, "max_relative": _max_coupling(system, pitched)},
        "stability": {"growth_rate": st.growth_rate, "stable": st.stable,
                      "pieces": len(st.visits), "top_piece": [list(o) for o in top],
                      "abs_multipliers": np.abs(st.multipliers[top]).tolist(),
                      "seconds": judged - found},
    }
    if figure is not None:
        quadruped_figure(orb).savefig(figure)
        res["figure"] = str(figure)
    return res


def summary_text(res) -> str:
    """The lines of :func:`quadruped_summary` for a terminal."""
    b, o, st = res["build"], res["orbit"], res["stability"]
    lines = [f"bderiv demo: {res['name']}", f"  {res['description']}",
             f"model: derivation {b['derive_seconds']:.2f} s, compilation or cache load "
             f"{b['load_seconds']:.2f} s ({'cache hit' if b['cached'] else 'generated'})",
             f"periodic orbit (apex section -vz = 0, x cyclic) in {o['seconds']:.2f} s: "
             f"period {o['period']:.10g}, apex height {o['x0'][1]:.6f}; Newton residuals "
             + ", ".join(f"{r:.2e}" for r in o["newton_residuals"])]
    for g in res["groups"]:
        kind = "touchdown" if g["directions"][0] == 1 else "lift-off"
        lines.append(f"  {kind} of feet {tuple(g['events'])} at t = {g['time']:.6f}: largest "
                     f"inverse-mass coupling of two feet {g['coupling']:.1e}")
    lines.append(f"  at a touchdown pitched by {res['coupling']['pitch']} rad the feet would "
                 f"be coupled ({res['coupling']['max_relative']:.3f}): refused if simultaneous")
    verdict = verdict_word(st["stable"])
    mult = ", ".join(f"{m:.4f}" for m in st["abs_multipliers"] if m > 1e-9)
    lines.append(f"return map: growth rate {st['growth_rate']:.6f} -> {verdict} in "
                 f"{st['seconds']:.2f} s ({st['pieces']} pieces met; the most visited has "
                 f"|multipliers| {mult}, the others below 1e-9)")
    if "figure" in res:
        lines.append(f"figure: {res['figure']}")
    return "\n".join(lines)
