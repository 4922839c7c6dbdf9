"""Impacts: a body on two massive feet that land together (resets at simultaneous events).

State ``(Y, vY, s0, p0, u0, w0, s1, p1, u1, w1)`` (d = 10): the body's height and vertical
velocity, and for foot i its horizontal offset s_i and height p_i with their velocities
u_i and w_i. The feet (mass ``foot_mass``, a sizeable share of the body's unit mass) hang
from the body on leg springs of rest length 1; a hip spring swings them horizontally.
Event i is foot i going through the ground: ``h_i = -p_i``.

At touchdown friction stops the foot's sliding at once: a plastic tangential impact, the
reset ``u_i -> 0`` (rank one, so the B-derivative has no inverse). The ground is compliant
in the normal direction (spring and damper on the foot), so the foot keeps sinking
(``w_i < 0``) and both surfaces are crossed transversally. While both feet are down the
legs push (``thrust``): the stance force depends on the mode, so the touchdown order
matters (the two pieces differ). The feet's horizontal motions are independent, so the
two resets commute and the flow has a B-derivative at the double touchdown (mathematics.md
section 9). With ``coupling != 0`` the horizontal impulses are shared through an inverse
mass matrix ``[[1, c], [c, 1]] / foot_mass`` (contacts not orthogonal in the inverse-mass
metric): stopping one foot moves the other, the resets do not commute, and the library
refuses the model at the double touchdown with that explanation.

The event point ``rho`` has both feet on the ground, falling, with opposite horizontal
velocities; ``x0`` is the state ``t_event`` earlier (both feet in the air), and
``t_final`` lies in the stance that follows (the feet settle; no further event).
"""

from __future__ import annotations

import numpy as np
from numba.extending import register_jitable

from .._limits import FD_EPS
from .._support._format import format_steps
from .._support._validate import check_numbers
from ._common import Example, check_start, finite_ratios, flow_back

__all__ = ["landing", "landing_summary", "summary_text"]

_G = 9.81
#: indices of (s, p, u, w) of each foot in the state
_FOOT = ((2, 3, 4, 5), (6, 7, 8, 9))


def _tables(foot_mass, leg_stiffness, leg_damping, ground_stiffness, ground_damping,
            hip_stiffness, friction, thrust):
    """The affine fields ``A[mask] x + b[mask]`` of the four regions: A (4, 10, 10), b
    (4, 10)."""
    m = foot_mass
    A = np.zeros((4, 10, 10))
    b = np.zeros((4, 10))
    for mask in range(4):
        Am, bm = A[mask], b[mask]
        Am[0, 1] = 1.0
        bm[1] = -_G
        push = thrust if mask == 3 else 0.0
        for i, (s, p, u, w) in enumerate(_FOOT):
            # leg force f_i = k (1 - (Y - p_i)) - c (vY - w_i) + push, up on the body
            f = np.zeros(10)
            f[0], f[p], f[1], f[w] = -leg_stiffness, leg_stiffness, -leg_damping, leg_damping
            f0 = leg_stiffness + push
            Am[1] += f
            bm[1] += f0
            Am[s, u] = Am[p, w] = 1.0
            Am[u, s] = -hip_stiffness / m
            Am[w] = -f / m
            bm[w] = -_G - f0 / m
            if mask >> i & 1:  # stance: ground spring and damper, sliding damped
                Am[w, p] -= ground_stiffness / m
                Am[w, w] -= ground_damping / m
                Am[u, u] -= friction / m
    return A, b


@register_jitable
def _stop(mask, k, coupling):
    """The reset Jacobian of crossing event k from ``mask``: at touchdown (bit k clear) the
    plastic stop of u_k, the other foot's u moved by ``-coupling u_k``; at lift-off no
    jump."""
    J = np.eye(10)
    if not mask >> k & 1:
        uk, uo = _FOOT[k][2], _FOOT[1 - k][2]
        J[uk, uk] = 0.0
        J[uo, uk] = -coupling
    return J


def _functions(A, b, coupling) -> dict:
    """The landing's fields, events, resets and their Jacobians: plain functions over the
    tables, for Python as they are and for numba compiled."""
    Dh = np.zeros((2, 10))
    Dh[0, 3] = Dh[1, 7] = -1.0  # h_i = -p_i

    def field(x, mask):
        return A[mask] @ x + b[mask]

    def field_jacobian(x, mask):
        return A[mask].copy()

    def events(x):
        return Dh @ x

    def event_jacobian(x):
        return Dh.copy()

    def reset(x, mask, k):
        return _stop(mask, k, coupling) @ x

    def reset_jacobian(x, mask, k):
        return _stop(mask, k, coupling)

    return {"field": field, "events": events, "event_jacobian": event_jacobian,
            "field_jacobian": field_jacobian, "reset": reset, "reset_jacobian": reset_jacobian}


def landing(*, foot_mass=0.4, leg_stiffness=200.0, leg_damping=4.0, ground_stiffness=2000.0,
            ground_damping=20.0, hip_stiffness=30.0, friction=40.0, thrust=6.0,
            coupling=0.0, t_event=0.1, t_after=0.1, compiled=False) -> Example:
    """The two-foot landing (module docstring); ``coupling != 0``: the refused variant;
    ``compiled``: the model's functions compiled with numba (the same equations)."""
    # checked by name: a negative mass built a model, a mass of 0 divided by zero
    foot_mass, leg_stiffness, ground_stiffness = check_numbers(
        foot_mass=foot_mass, leg_stiffness=leg_stiffness, ground_stiffness=ground_stiffness)
    leg_damping, ground_damping, hip_stiffness, friction = check_numbers(
        strict=False, leg_damping=leg_damping, ground_damping=ground_damping,
        hip_stiffness=hip_stiffness, friction=friction)
    thrust, coupling = check_numbers(low=-np.inf, strict=False, thrust=thrust,
                                     coupling=coupling)
    A, b = _tables(foot_mass, leg_stiffness, leg_damping, ground_stiffness, ground_damping,
                   hip_stiffness, friction, thrust)
    functions = _functions(A, b, coupling)
    rho = np.array([1.0, -1.0, 0.05, 0.0, 0.6, -1.2, -0.05, 0.0, -0.6, -1.2])
    field = functions["field"]
    x0 = flow_back(lambda x: field(x, 0), rho, t_event)
    name = "landing" if coupling == 0 else "landing-coupled"
    description = (f"body on two massive feet (mass {foot_mass:g}) landing together: plastic "
                   f"stop of the sliding at touchdown (reset), compliant ground, legs push "
                   f"in double support (d = 10, n = 2"
                   + (f", horizontal impulses coupled by {coupling:g})" if coupling else ")"))
    ex = Example.from_functions(functions, compiled=compiled, n_events=2, dim=10, rho=rho,
                                x0=x0, t_event=t_event, t_after=t_after, name=name,
                                description=description)
    return check_start(ex, {"t_event": float(t_event), "t_after": float(t_after)})


def landing_summary(*, n_check=8, eps=FD_EPS, seed=0, compiled=False):
    """The landing from model to checked B-derivative, and the refused variant.

    Simulates the landing (the event group and the resets it applied), builds the
    B-derivative M at the double touchdown and the flow map's D over ``[0, t_final]``,
    checks D against finite differences of the simulation on ``n_check`` random unit
    directions (both touchdown orders), and builds the coupled variant to show why it is
    refused. ``compiled``: the compiled model (:func:`landing` with ``compiled=True``).

    Returns
    -------
    dict
        JSON-friendly: ``groups`` (time, events, state before and after), ``pieces``
        (orders, share of a batch, rank and the norm of their difference), ``fd`` (eps,
        max errors, ratios: None where a step's error is exactly 0), ``refused`` (the
        library's message for the coupled feet).
    """
    from ..analysis.checks import fd_check  # simulates: only here

    ex = landing(compiled=compiled)
    system = ex.system
    traj = system.simulate(ex.x0, ex.t_final, simultaneity_tol=1e-7)
    M = system.bderivative(ex.rho)
    D = system.flow_bderivative(ex.x0, ex.t_final)
    rng = np.random.default_rng(seed)
    W = rng.standard_normal((100_000, 10))
    shares = {tuple(o): float(np.mean((M.orders(W) == o).all(axis=1))) for o in ((0, 1), (1, 0))}
    V = rng.standard_normal((n_check, 10))
    V /= np.linalg.norm(V, axis=1)[:, None]
    fd = fd_check(system, ex.x0, ex.t_final, V, D(V), eps=eps)
    try:
        landing(coupling=0.5).system.bderivative(ex.rho)
        refused = None
    except ValueError as exc:
        refused = str(exc)
    return {
        "name": ex.name, "description": ex.description, "t_final": ex.t_final,
        "groups": [{"time": g.time, "events": list(g.events), "state": g.state.tolist(),
                    "state_after": g.state_after.tolist()} for g in traj.groups],
        "pieces": {"shares": {str(k): v for k, v in shares.items()},
                   "ranks": [int(np.linalg.matrix_rank(M.piece(o))) for o in ((0, 1), (1, 0))],
                   "difference": float(np.abs(M.piece([0, 1]) - M.piece([1, 0])).max())},
        "fd": {"eps": list(fd.eps), "max_errors": list(fd.max_errors),
               "ratios": finite_ratios(fd), "vectors": n_check,
               "orders": sorted({tuple(int(k) for k in o) for o in D.orders(V)[0]})},
        "refused": refused,
    }


def summary_text(res):
    """The lines of :func:`landing_summary` for a terminal."""
    names = ("Y", "vY", "s0", "p0", "u0", "w0", "s1", "p1", "u1", "w1")
    lines = [f"bderiv demo: {res['name']}", f"  {res['description']}"]
    for g in res["groups"]:
        jumps = ", ".join(f"{names[i]} {a:.4g} -> {b:.4g}" for i, (a, b) in
                          enumerate(zip(g["state"], g["state_after"], strict=True)) if a != b)
        lines.append(f"  event group at t = {g['time']:.6f}: events {tuple(g['events'])} "
                     f"together; resets: {jumps}")
    p = res["pieces"]
    shares = ", ".join(f"{k} {100 * v:.1f} %" for k, v in p["shares"].items())
    lines += [f"M at the double touchdown: 2 pieces ({shares} of 100,000 directions), rank "
              f"{p['ranks'][0]} of 10 each (the stopped sliding is forgotten: no inverse); "
              f"max |M_(0,1) - M_(1,0)| = {p['difference']:.3g} (the thrust in double "
              f"support makes the order matter)"]
    fd = res["fd"]
    lines.append(f"check of D (flow over [0, {res['t_final']:g}]) against finite differences "
                 f"of the simulation ({fd['vectors']} unit vectors, touchdown orders "
                 f"{', '.join(map(str, fd['orders']))}), max |FD - D V| / max |D V|:")
    lines += format_steps(fd["eps"], fd["max_errors"])
    if fd["ratios"]:  # one step: no ratio
        lines.append("  error shrinks with eps by "
                     + ", ".join(f"{1 / r:.1f}x" if r else "- (to 0)" if r == 0 else "-"
                                 for r in fd["ratios"]) + " per step (O(eps) expected)")
    lines.append("variant with coupled feet (horizontal impulses shared through the "
                 "inverse mass, coupling 0.5: contacts not orthogonal in its metric): refused:")
    lines.append(f"  {res['refused']}")
    return "\n".join(lines)
