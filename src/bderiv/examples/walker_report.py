"""The walkers' demo report: a gait from the model to its stability verdict, beside its
reference numbers (the rimless wheel's closed forms, Garcia et al.'s compass gait), for
``bderiv demo --example rimless-wheel`` / ``compass-gait``. Models in
:mod:`bderiv.examples.walkers`.
"""

from __future__ import annotations

import numpy as np

from ..analysis.stability import verdict_word
from .walkers import (
    GARCIA_EIGENVALUES,
    GARCIA_FIXED_POINT,
    compass_gait,
    compass_gait_orbit,
    rimless_wheel,
    rimless_wheel_orbit,
)

__all__ = ["summary_text", "walker_summary"]


def walker_summary(name="rimless-wheel", *, seed=0):
    """A walker's gait from the model to its stability, beside its reference numbers.

    Parameters
    ----------
    name : str
        ``"rimless-wheel"`` (compared with the closed forms of the module docstring) or
        ``"compass-gait"`` (compared with Garcia et al.'s published fixed point and
        eigenvalues).
    seed : int
        Seed of the stability estimate's directions.

    Returns
    -------
    dict
        JSON-friendly: ``orbit`` (x0, period, residual, Newton residuals), ``groups``
        (time, events, directions, states before and after, whether the event's bit was
        flipped), ``stability`` (growth rate, verdict, multipliers of the piece as
        ``[re, im]``), ``reference`` (name, the values and the library's).
    """
    if name == "rimless-wheel":
        ex = rimless_wheel()
        orb = rimless_wheel_orbit(ex)
    elif name == "compass-gait":
        ex = compass_gait()
        orb = compass_gait_orbit(ex)
    else:
        raise ValueError(f"name must be 'rimless-wheel' or 'compass-gait', got {name!r}")
    st = orb.stability(n_directions=100, iterations=200, seed=seed)
    (piece, mult), = st.multipliers.items()  # one event per group: a single piece
    groups = orb.trajectory.groups
    res = {
        "name": ex.name, "description": ex.description,
        "orbit": {"x0": orb.x0.tolist(), "period": orb.period, "residual": orb.residual,
                  "newton_residuals": [h.residual for h in orb.history]},
        "groups": [{"time": g.time, "events": list(g.events), "directions": list(g.directions),
                    "state": g.state.tolist(), "state_after": g.state_after.tolist(),
                    "flipped": bool((g.mask_before ^ g.mask_after) & 1)} for g in groups],
        "stability": {"growth_rate": st.growth_rate, "stable": st.stable,
                      "multipliers": [[float(z.real), float(z.imag)] for z in mult]},
    }
    strike = next(g for g in groups if g.directions[0] > 0)  # the impact of the step
    if name == "rimless-wheel":
        alpha, slope = np.pi / 8, 0.08  # the closed forms of the default wheel
        c2 = np.cos(2 * alpha) ** 2
        u = c2 * 4 * np.sin(alpha) * np.sin(slope) / (1 - c2)
        res["reference"] = {
            "source": "energy balance (closed form)",
            "omega_after_impact": [float(np.sqrt(u)), float(strike.state_after[1])],
            "multiplier": [float(c2), float(abs(mult[0]))],
        }
    else:
        res["reference"] = {
            "source": "Garcia, Chatterjee, Ruina & Coleman 1998, slope 0.009",
            "theta_after_strike": [GARCIA_FIXED_POINT[0], float(strike.state_after[0])],
            "theta_rate_after_strike": [GARCIA_FIXED_POINT[1], float(strike.state_after[2])],
            "eigenvalues": [[[z.real, z.imag] for z in GARCIA_EIGENVALUES],
                            [[float(z.real), float(z.imag)] for z in mult[:2]]],
            "note": "the eigenvalues differ from the published ones by 1.7e-3 and agree to "
                    "1e-8 with central differences of the stride map of the same equations "
                    "integrated at rtol 1e-13 (tests/test_bounces.py); the published digits "
                    "come from code whose integration and differencing steps are not given",
        }
    return res


def summary_text(res):
    """The lines of :func:`walker_summary` for a terminal."""
    o, st = res["orbit"], res["stability"]
    lines = [f"bderiv demo: {res['name']}", f"  {res['description']}",
             f"periodic orbit (mid-stance section): x0 = "
             f"{(np.round(o['x0'], 10) + 0.0).tolist()}",
             f"  period {o['period']:.10g}; Newton residuals "
             + ", ".join(f"{r:.2e}" for r in o["newton_residuals"])
             + f"; fixed-point residual |P(x0) - x0| = {o['residual']:.2e}"]
    for g in res["groups"]:
        kind = ("the bit flipped" if g["flipped"] else "back on the side it came from, "
                "the bit kept")
        jump = ("" if g["state"] == g["state_after"] else
                f"; reset {np.round(g['state'], 6).tolist()} -> "
                f"{np.round(g['state_after'], 6).tolist()}")
        way = "up" if g["directions"][0] > 0 else "down"
        lines.append(f"  t = {g['time']:.6f}: event {g['events'][0]} crossed {way}{jump} "
                     f"({kind})")
    mult = ", ".join(f"{complex(*z):.6f}" for z in st["multipliers"])
    verdict = verdict_word(st["stable"])
    lines.append(f"return map: growth rate {st['growth_rate']:.6f} -> {verdict}; multipliers "
                 f"on the section {mult}")
    ref = res["reference"]
    lines.append(f"reference ({ref['source']}), published or closed form / bderiv:")
    for key, pair in ref.items():
        if key == "note":
            lines.append(f"  note: {pair}")
            continue
        if key == "source":
            continue
        want, got = pair
        if key == "eigenvalues":
            want = ", ".join(f"{complex(*z):.8f}" for z in want)
            got = ", ".join(f"{complex(*z):.8f}" for z in got)
            lines.append(f"  {key}: {want} / {got}")
        else:
            lines.append(f"  {key}: {want:.10f} / {got:.10f}")
    return "\n".join(lines)
