"""Gaits: a planar body pronking on compliant legs that land and lift off together.

State ``(z, theta, vz, omega)`` (d = 4): height and pitch of the body and their rates;
unit mass, pitch inertia ``inertia``. Leg k ends at the body-frame point
``(a_k, -leg)``, the ``a_k`` evenly spaced from ``-half_base`` to ``+half_base`` (two legs
by default: ``a = (-half_base, +half_base)``): its foot height is
``z + a_k sin(theta) - leg cos(theta)``, and event k is ``h_k = -height_k`` (upward
crossing: touchdown; downward crossing: lift-off; both recur every stride).

In contact the ground pushes the foot up with ``f_k = -stiffness * height_k - damping *
v_k + thrust_k``, ``v_k`` the foot's vertical velocity, and an energy-regulating thrust
``thrust_k = gain(B) * (1 - vz^2 / v_ref^2) * vz`` (a Van der Pol term on the body's
vertical velocity: it pumps energy in slow stance and dissipates in fast stance, so the
hopping height settles); ``gain(B) = gain * (1 + coupling)`` while all legs touch, so
the corner table is not additive and the event orders give different pieces. Gravity
acts always; the forces are smooth in each region and jump at touchdown (damping and
thrust do not vanish there), so both touchdown and lift-off are event-selected.

The body is symmetric: on the pronking orbit (``theta = omega = 0``) both feet touch down
at the same instant and lift off at the same instant, so every stride crosses two
simultaneous groups, upward then downward. The Poincare section is the apex,
``section(x) = -vz = 0`` (crossed upward when the body starts falling). The stored apex
height ``APEX`` is only a start for Newton's method (:func:`pronking_orbit`); on the symmetric
subspace the events coincide for any height, so :func:`pronking`'s ``rho`` is an exact
simultaneous-event point.

:func:`pronking_orbit` finds the orbit, :func:`pronking_summary` goes from the model to the
stability verdict with its checks against simulation (``summary_text`` prints it).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba.extending import register_jitable

from .._limits import FD_EPS
from .._support._format import format_steps
from .._support._validate import check_number, check_numbers
from .._support._validate_ints import check_int
from ..analysis.stability import verdict_word
from ._common import Example, check_start, compile_function, finite_ratios, perturbed_start

__all__ = [
    "APEX",
    "apex_section",
    "apex_section_gradient",
    "body",
    "compiled_apex_section",
    "pronking",
    "pronking_orbit",
    "pronking_summary",
    "summary_text",
]

_G = 9.81
#: apex height of the pronking orbit with the default parameters (a guess for Newton).
APEX = 0.6629663141


#: where the body's constants sit in a pronking model's parameter vector (what its
#: functions read after the state): per-leg stiffness, damping and thrust gain, the
#: coupling, v_ref, the legs' length and the pitch inertia, then the feet's ``a_k`` (one
#: per leg, ``FEET`` onwards: the number of legs is the vector's length less ``FEET``)
STIFFNESS, DAMPING, GAIN, COUPLING, V_REF, LEG, INERTIA, FEET = range(8)


@register_jitable
def foot_offset(a_k, leg, theta):
    """Foot k's offset from the centre of mass in the world frame, ``(r_x, r_z)``, for the
    body pitched by ``theta`` (the foot at ``(a_k, -leg)`` in the body frame)."""
    c, s = np.cos(theta), np.sin(theta)
    return a_k * c + leg * s, a_k * s - leg * c


@register_jitable
def stance(z, theta, vz, omega, mask, q):
    """``(a_z, alpha)``: the body's vertical and pitch accelerations in region ``mask``:
    gravity, and each leg whose bit is set (spring, damper, thrust). ``q`` is the body's
    constants (:meth:`Body.values`, shape (FEET + legs,)). Plain code that numba compiles
    and Python runs alike (complex input passes through: the complex step)."""
    legs = q.size - FEET
    all_down = (1 << legs) - 1
    gain = q[GAIN] * (1.0 + q[COUPLING]) if mask == all_down else q[GAIN]
    thrust = gain * (1.0 - vz**2 / q[V_REF] ** 2) * vz
    az, alpha = -_G + 0.0 * vz, 0.0 * vz
    for k in range(legs):
        if mask >> k & 1:
            rx, rz = foot_offset(q[FEET + k], q[LEG], theta)
            f = -q[STIFFNESS] * (z + rz) - q[DAMPING] * (vz + omega * rx) + thrust
            az = az + f
            alpha = alpha + rx * f / q[INERTIA]
    return az, alpha


@register_jitable
def foot_heights(z, theta, q):
    """The event values ``-height_k`` of the feet, (legs,), ``q`` the body's constants."""
    legs = q.size - FEET
    out = np.empty(legs)
    for k in range(legs):
        out[k] = -(z + foot_offset(q[FEET + k], q[LEG], theta)[1])
    return out


@register_jitable
def foot_heights_jacobian(theta, q, dim, z_at, theta_at):
    """The Jacobian of :func:`foot_heights` in a state of size ``dim`` whose height and
    pitch are coordinates ``z_at`` and ``theta_at``: (legs, dim)."""
    legs = q.size - FEET
    D = np.zeros((legs, dim))
    for k in range(legs):
        D[k, z_at] = -1.0
        D[k, theta_at] = -foot_offset(q[FEET + k], q[LEG], theta)[0]
    return D


class Body(NamedTuple):
    """The pronking body's constants (per leg: the totals of two legs shared by all)."""

    a: np.ndarray  #: (legs,) body-frame horizontal positions of the feet
    K: float  #: ground stiffness per leg
    C: float  #: damping per leg
    gain: float  #: thrust gain per leg
    coupling: float  #: extra relative gain while all legs touch
    v_ref: float
    leg: float
    inertia: float

    def values(self) -> np.ndarray:
        """The constants as the model's functions read them: ``(K, C, gain, coupling,
        v_ref, leg, inertia, a_0, ..., a_{legs-1})``, shape (FEET + legs,)."""
        return np.concatenate(([self.K, self.C, self.gain, self.coupling, self.v_ref,
                                self.leg, self.inertia], self.a))


# The pronking model (d = 4): plain functions of ``x = (z, theta, vz, omega, *q)``, the
# state followed by the body's constants ``q`` (:meth:`Body.values`), for Python as they are
# and for numba compiled once (the constants come at run time: no compilation per body).

def field(x, mask):
    """The body's field in region ``mask``: (4,)."""
    out = np.empty_like(x[:4])  # complex for complex x: the complex step
    out[0], out[1] = x[2], x[3]
    out[2], out[3] = stance(x[0], x[1], x[2], x[3], mask, x[4:])
    return out


def events(x):
    """The feet's event values ``-height_k``: (legs,)."""
    return foot_heights(x[0], x[1], x[4:])


def event_jacobian(x):
    """The Jacobian of :func:`events` by the state: (legs, 4)."""
    return foot_heights_jacobian(x[1], x[4:], 4, 0, 1)


def apex_section(x):
    """The apex section ``-vz``: crossed upward when the body starts to fall."""
    return -x[2]


#: :func:`apex_section` compiled: the section of a compiled model (``pronking(...,
#: compiled=True)``)
compiled_apex_section = compile_function(apex_section)


def apex_section_gradient(x):
    """Gradient of :func:`apex_section`: ``(0, 0, -1, 0)``."""
    return np.array([0.0, 0.0, -1.0, 0.0])


def body(*, stiffness=400.0, damping=2.0, gain=4.0, v_ref=2.0, coupling=0.5, half_base=0.4,
         leg=0.5, inertia=0.16, legs=2) -> Body:
    """The pronking body's constants for :func:`pronking`'s parameters: the part other
    gaits build on (:mod:`bderiv.examples.runner`)."""
    legs = check_int(legs, "legs", low=2)
    # checked by name (a negative stiffness or a leg of 0 gave a model all the same)
    stiffness, leg, inertia, half_base = check_numbers(
        stiffness=stiffness, leg=leg, inertia=inertia, half_base=half_base)
    damping = check_number(damping, "damping", strict=False)
    gain, v_ref, coupling = check_numbers(low=-np.inf, strict=False, gain=gain, v_ref=v_ref,
                                          coupling=coupling)
    share = 2.0 / legs  # the totals of two legs, shared by all of them
    return Body(a=np.linspace(-half_base, half_base, legs), K=share * stiffness,
                C=share * damping, gain=share * gain, coupling=coupling, v_ref=v_ref,
                leg=leg, inertia=inertia)


def pronking(*, stiffness=400.0, damping=2.0, gain=4.0, v_ref=2.0, coupling=0.5,
             half_base=0.4, leg=0.5, inertia=0.16, apex=APEX, t_after=0.05, legs=2,
             compiled=False):
    """The pronking body at the apex of its gait, about to land on all legs at once.

    Parameters
    ----------
    stiffness, damping : float
        Ground spring and damper of each leg of a two-legged body (per unit mass); with
        other ``legs``, the same totals shared equally (``2 / legs`` of them per leg).
    gain, v_ref : float
        Thrust gain (shared the same way) and the vertical speed at which the thrust
        changes sign.
    coupling : float
        Extra relative thrust gain while all legs touch (0: additive contact forces).
    half_base, leg : float
        Half the distance between the outermost feet, and the legs' length.
    inertia : float
        Pitch inertia per unit mass (0.16 makes the pitch motion stable).
    apex : float
        Apex height of the start point ``x0 = (apex, 0, 0, 0)`` (> ``leg``).
    t_after : float
        ``t_final = t_event + t_after`` (the legs still touch then).
    legs : int
        Number of legs (>= 2), their feet evenly spaced along the body: all touch down and
        lift off together on the symmetric gait (n = legs simultaneous events; (legs!)^2
        pieces per stride). The vertical motion of the symmetric gait is the same for any
        number of legs.
    compiled : bool
        The model's functions compiled with numba (they run on the compiled integrator;
        the section is then :data:`compiled_apex_section`), else Python functions: the
        same equations either way. The constants are the system's parameters
        (:meth:`Body.values`), so the functions are compiled once per process for every
        body and number of legs (a stability map compiles nothing per point).

    Returns
    -------
    Example
        ``x0`` the apex state, ``rho`` the touchdown state (both feet on the ground, in
        closed form: free fall from the apex), ``t_event`` the fall time. Use
        :func:`apex_section` and :func:`pronking_orbit` for the gait.

    Examples
    --------
    >>> ex = pronking(legs=4, compiled=True)
    >>> ex.system.simulate(ex.x0, ex.t_final).groups[0].events
    (0, 1, 2, 3)
    """
    p = body(stiffness=stiffness, damping=damping, gain=gain, v_ref=v_ref,
             coupling=coupling, half_base=half_base, leg=leg, inertia=inertia, legs=legs)
    apex = float(apex)
    if not (np.isfinite(apex) and apex > p.leg):
        raise ValueError(f"pronking with apex={apex:g}, leg={p.leg:g}: the start it builds, "
                         f"x0 = (apex, 0, 0, 0), must be above the touchdown height (apex > "
                         f"leg), or the body never falls onto its legs; choose other "
                         f"parameters")
    fall = float(np.sqrt(2.0 * (apex - p.leg) / _G))
    rho = np.array([p.leg, 0.0, -_G * fall, 0.0])
    n = p.a.size
    ex = Example.from_functions(
        {"field": field, "events": events, "event_jacobian": event_jacobian},
        params=p.values(), compiled=compiled, n_events=n, dim=4, rho=rho,
        x0=np.array([apex, 0.0, 0.0, 0.0]), t_event=fall, t_after=t_after, name="pronking",
        description=(f"planar body pronking on {n} compliant legs: all land and lift "
                     f"off together every stride (d = 4, n = {n}, coupling = "
                     f"{coupling})"),
    )
    return check_start(ex, {"apex": apex, "leg": p.leg, "t_after": float(t_after)})


def pronking_orbit(example=None, *, perturbation=(0.02, 0.01, 0.0, -0.05), **kwargs):
    """The pronking orbit, found by Newton's method from a perturbed apex state.

    Parameters
    ----------
    example : Example, optional
        Default :func:`pronking`.
    perturbation : array_like, shape (4,)
        Added to ``example.x0`` for the guess (it breaks the symmetry on purpose).
    **kwargs
        Passed to :meth:`HybridSystem.periodic_orbit
        <bderiv.analysis.system.HybridSystem.periodic_orbit>`.

    Returns
    -------
    PeriodicOrbit
    """
    ex = pronking() if example is None else example
    guess = perturbed_start(ex, perturbation)
    kwargs.setdefault("section_gradient", apex_section_gradient)
    kwargs.setdefault("period_guess", 0.5)
    section = compiled_apex_section if ex.compiled else apex_section
    return ex.system.periodic_orbit(guess, section, **kwargs)


def pronking_summary(*, n_check=4, eps=FD_EPS, strides=60, seed=0,
                     compiled=False):
    """The gait from model to stability verdict, with its checks against simulation.

    Finds the orbit (:func:`pronking_orbit`), its event groups, the return map's pieces met
    by a batch with their Floquet multipliers, the growth rate, and two checks against
    simulation: finite differences of the simulated Poincare map against the return map
    (one direction in each piece, several steps), and the decay of perturbations over
    ``strides`` simulated strides against the predicted growth rate.

    Parameters
    ----------
    n_check : int
        Directions of the decay check.
    eps : sequence of float
        Steps of the finite differences.
    strides : int
        Strides of the decay check.
    seed : int
    compiled : bool
        The compiled model (:func:`pronking` with ``compiled=True``), else the Python one.

    Returns
    -------
    dict
        JSON-friendly: ``orbit`` (x0, period, residual, Newton residuals), ``groups``
        (time, events, directions), ``stability`` (growth rate, spread, stable, pieces
        with visits and ``|multipliers|``), ``fd`` (eps, max errors, ratios: None where a
        step's error is exactly 0), ``decay``
        (simulated rate per direction, the largest, the window).
    """
    from ..analysis.checks import decay_check, fd_check  # the checks simulate: only here

    ex = pronking(compiled=compiled)
    section = compiled_apex_section if compiled else apex_section
    orb = pronking_orbit(ex)
    st = orb.stability(seed=seed)
    R, rng = orb.return_map, np.random.default_rng(seed)
    W = rng.standard_normal((100_000, 4)) @ R.tangent_basis @ R.tangent_basis.T
    V = _one_per_piece(R, W)
    fd = fd_check(ex.system, orb.x0, 3.0, V, R(V), eps=eps, section=section)
    D = rng.standard_normal((n_check, 3)) @ R.tangent_basis.T
    decay = decay_check(ex.system, orb.x0, section,
                        D / np.linalg.norm(D, axis=1)[:, None], eps=1e-2, strides=strides)
    return {
        "name": ex.name, "description": ex.description,
        "orbit": {"x0": orb.x0.tolist(), "period": orb.period, "residual": orb.residual,
                  "newton_residuals": [h.residual for h in orb.history]},
        "groups": [{"time": g.time, "events": list(g.events), "directions": list(g.directions)}
                   for g in orb.trajectory.groups],
        "stability": {
            "growth_rate": st.growth_rate, "spread": st.spread, "stable": st.stable,
            "pieces": [{"orders": [list(o) for o in p], "visits": st.visits[p],
                        "abs_multipliers": np.abs(m).tolist()}
                       for p, m in st.multipliers.items()],
        },
        "fd": {"eps": list(fd.eps), "max_errors": list(fd.max_errors),
               "ratios": finite_ratios(fd), "vectors": len(V)},
        "decay": {"rates": decay.rates.tolist(), "rate": decay.rate,
                  "window": list(decay.window), "eps": 1e-2},
    }


def _one_per_piece(R, W):
    """One unit direction of W in each piece of R that W meets."""
    stacked = np.concatenate(R.orders(W), axis=1)
    _, first = np.unique(stacked, axis=0, return_index=True)
    V = W[np.sort(first)]
    return V / np.linalg.norm(V, axis=1)[:, None]


def summary_text(res):
    """The lines of :func:`pronking_summary` for a terminal."""
    o, st = res["orbit"], res["stability"]
    arrow = {1: "up", -1: "down"}
    lines = [f"bderiv demo: {res['name']}", f"  {res['description']}",
             "periodic orbit (apex section -vz = 0): x0 = "
             f"{(np.round(o['x0'], 10) + 0.0).tolist()}",  # + 0.0: no -0.0
             f"  period {o['period']:.10g}; Newton residuals "
             + ", ".join(f"{r:.2e}" for r in o["newton_residuals"])
             + f"; fixed-point residual |P(x0) - x0| = {o['residual']:.2e}"]
    for g in res["groups"]:
        dirs = ",".join(arrow[d] for d in g["directions"])
        lines.append(f"  event group at t = {g['time']:.6f}: events {tuple(g['events'])} "
                     f"crossed {dirs}")
    verdict = verdict_word(st["stable"])
    lines.append(f"return map: growth rate {st['growth_rate']:.6f} -> {verdict} (spread of "
                 f"the estimate {st['spread']:.1e})")
    for p in sorted(st["pieces"], key=lambda p: -p["visits"]):
        orders = " ".join("(" + ",".join(map(str, q)) + ")" for q in p["orders"])
        mult = ", ".join(f"{m:.6f}" for m in p["abs_multipliers"])
        lines.append(f"  piece {orders}: {p['visits']} visits, |multipliers| {mult}")
    fd = res["fd"]
    lines.append(f"check: finite differences of the simulated Poincare map ({fd['vectors']} "
                 f"directions, one per piece), max |FD - DP v| / max |DP v|:")
    lines += format_steps(fd["eps"], fd["max_errors"])
    dec = res["decay"]
    lines.append(f"check: decay of perturbations (eps = {dec['eps']:g}) in simulations, "
                 f"strides {dec['window'][0]}-{dec['window'][1]}: rate {dec['rate']:.4f} "
                 f"(per direction {', '.join(f'{r:.4f}' for r in dec['rates'])}); predicted "
                 f"{st['growth_rate']:.4f}")
    return "\n".join(lines)
