"""Cyclic coordinates (issue 20 item 2): a gait that advances.

Oracles: the running gait's closed forms (on the orbit the stance controller holds the
speed at its target, so the advance per stride is ``v_target * period`` and the apex and
period are those of the pronking gait; the speed mode decays by ``exp(-2 traction
T_stance)`` per stride), a stride simulated by another integrator, and perturbations
followed in long simulations.
"""

from __future__ import annotations

import re

import numpy as np
import pytest

from bderiv.analysis.checks import decay_check
from bderiv.examples import gaits, runner


@pytest.fixture(scope="module")
def gait():
    ex = runner.running(v_target=1.0, traction=8.0)
    return ex, runner.running_orbit(ex)


def test_running_orbit_advances_at_the_target_speed(gait):
    ex, orb = gait
    assert orb.cyclic == (0,) and orb.residual < 1e-9
    assert orb.x0[3] == pytest.approx(1.0, abs=1e-9)       # vx at its target
    assert orb.advance[0] == pytest.approx(1.0 * orb.period, abs=1e-8)
    # the body's motion is the pronking gait's (the forward force vanishes on the orbit)
    pronk = gaits.pronking_orbit()
    assert orb.period == pytest.approx(pronk.period, rel=1e-9)
    np.testing.assert_allclose(orb.x0[[1, 2, 4, 5]], pronk.x0, atol=1e-8)
    # one stride by another integrator: everything returns but x, which advances
    radau = ex.system.simulate(orb.x0, 3.0, section=runner.apex_section, method="Radau",
                               rtol=1e-11, atol=1e-13)
    expected = orb.x0 + np.eye(6)[0] * orb.advance[0]
    np.testing.assert_allclose(radau.x_final, expected, atol=1e-7)


def test_stability_leaves_the_advance_out(gait):
    ex, orb = gait
    st = orb.stability(n_directions=100, iterations=300)
    # the body's modes (the pronking gait's rate) and the speed mode, which decays by
    # exp(-2 traction T_stance) per stride: the double stance lasts from touchdown to
    # lift-off, and both feet push with traction (v_target - vx) each
    touchdown, liftoff = (g.time for g in orb.trajectory.groups)
    speed_mode = np.exp(-2 * 8.0 * (liftoff - touchdown))
    moduli = np.sort(np.abs(next(iter(st.multipliers.values()))))
    assert moduli.size == 4  # d - 1 - len(cyclic): no neutral multiplier 1 for x
    assert np.min(np.abs(moduli - speed_mode)) < 1e-6
    assert st.stable and st.growth_rate == pytest.approx(0.7785, abs=2e-3)
    V = np.zeros((1, 6))
    V[0, 3] = 1.0  # a speed error
    decay = decay_check(ex.system, orb.x0, runner.apex_section, V, eps=1e-3, strides=12,
                        cyclic=[0])
    assert decay.rate < 0.8


@pytest.mark.parametrize("which", ["running, x cyclic", "pronking, none cyclic"])
def test_a_converged_guess_builds_the_orbits_map_once(gait, monkeypatch, which):
    """From the orbit itself (a stored orbit), the return map is built once, with the
    caller's settings, and it is the orbit's (the same period and state, one iterate):
    with a cyclic coordinate and without."""
    from bderiv.analysis import orbit as orbit_module

    if which.startswith("running"):
        ex, orb = gait
        section, kwargs = runner.apex_section, {
            "cyclic": [0], "section_gradient": runner.apex_section_gradient}
    else:
        ex = gaits.pronking()
        orb = gaits.pronking_orbit(ex)
        section, kwargs = gaits.apex_section, {}
    assert bool(orb.cyclic) == which.startswith("running")
    built = []

    def counted(*args, **kw):
        built.append(kw["options"])
        return return_map(*args, **kw)

    return_map = orbit_module.return_map
    monkeypatch.setattr(orbit_module, "return_map", counted)
    again = ex.system.periodic_orbit(orb.x0, section, period_guess=0.5, **kwargs)
    assert built == [orbit_module.ORBIT_OPTIONS] and len(again.history) == 1
    assert again.period == pytest.approx(orb.period, rel=1e-12)
    np.testing.assert_allclose(again.x0, orb.x0, rtol=0, atol=1e-12)
    assert again.residual <= orb.residual + 1e-12


def test_coordinates_that_are_not_cyclic_are_refused(gait):
    ex, _ = gait
    guess = ex.x0 + [0.0, 0.02, 0.0, 0.0, 0.0, 0.0]

    def orbit(cyclic):
        return ex.system.periodic_orbit(guess, runner.apex_section, period_guess=0.5,
                                        cyclic=cyclic)

    with pytest.raises(ValueError, match=r"coordinate 1 is not cyclic: shifting it by 1.41421 .* "
                       r"the field, events, resets or section depend on it"):
        orbit([1])
    with pytest.raises(ValueError, match="coordinate 4 cannot be cyclic: the section depends"):
        orbit([4])
    with pytest.raises(ValueError, match=r"distinct coordinate indices in \[0, 6\), got \[0, 0\]"):
        orbit([0, 0])
    with pytest.raises(TypeError, match=r"cyclic must be a sequence of coordinate indices "
                       r"\(integers\), got 0 \(int, not a sequence\)"):
        orbit(0)
    # a review: int(0.5) made 0.5 coordinate 0, and the orbit was found with it cyclic
    for bad, what in (([0.5], "0.5 is float"), ([np.float64(0.0)], "is float64"),
                      ([False], "False is bool"), (["0"], "'0' is str")):
        with pytest.raises(TypeError, match=r"cyclic must be a sequence of coordinate indices "
                           r"\(integers\), got .* \(.*" + re.escape(what) + r"\)$"):
            orbit(bad)


def test_a_forward_position_left_out_of_cyclic_is_named_when_the_search_fails(gait):
    """Without cyclic=[0] the runner's search failed at its second iterate with "the flow
    must cross the section upward ...": Newton's method, unable to undo the advance (the
    return map's column of x is the shift itself), walked to the bottom of stance (a
    review). The failure now names the coordinate, its advance, and cyclic=[0]."""
    ex, orb = gait
    with pytest.raises((ValueError, RuntimeError)) as info:
        runner.running_orbit(ex, cyclic=[])
    message = str(info.value)
    found = re.search(r"coordinates \[0\] advanced by \[([-0-9.e]+)\] at the guess and the "
                      r"return map's derivative along them is the shift itself: pass "
                      r"cyclic=\[0\]", message)
    assert found, message
    # the advance at the guess: about the orbit's (v_target times the period)
    assert float(found.group(1)) == pytest.approx(orb.advance[0], rel=0.5)
