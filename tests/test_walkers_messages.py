"""The passive walkers' refusals say what to do (a review): legs whose gait the default
start does not reach name ``start=``, a one-event model is not said to "meet the events
together", a perturbation of the wrong size is refused, and the rimless-wheel block of
docs/gaits.md runs on its own.

Oracles: the compass gait's fixed point at slope 0.015 from a start given (the return
map's residual; the default start finds the same), and the wheel's closed-form multiplier
``cos(2 alpha)^2``.
"""

from __future__ import annotations

import pathlib
import re

import numpy as np
import pytest

from bderiv.examples import bounces, walkers

DOCS = pathlib.Path(__file__).resolve().parents[1] / "docs"


@pytest.mark.parametrize("slope", [0.009, 0.015])
def test_legs_the_default_start_does_not_suit_name_start(slope):
    # it said "...does not meet the events together ...; choose other parameters": the
    # model has one event, and the parameters are not what to change. The default start
    # follows the slope (tests/test_compass_slopes.py); heavy legs walk another gait
    with pytest.raises(ValueError) as info:
        walkers.compass_gait(slope=slope, leg_mass=0.3)
    message = str(info.value)
    theta, rate = walkers.long_gait_start(slope)
    assert message.startswith(f"the compass gait with these parameters does not complete a "
                              f"step from (theta, theta') = {[theta, rate]}")
    assert "events together" not in message and "choose other parameters" not in message
    assert message.endswith(
        f"the default start, (theta, theta') = ({theta:.6g}, {rate:.6g}), is the long-period "
        f"gait of Garcia et al.'s walker (leg_mass 0) at slope {slope:g} (fitted for slopes "
        f"up to 0.04) and suits light legs only: pass start=(theta, theta'), a state just "
        f"after a heel strike of the gait with these parameters")


def test_a_start_given_for_a_steeper_slope_finds_the_gait_the_default_finds():
    ex = walkers.compass_gait(slope=0.015, start=(0.24, -0.228))
    orbit = walkers.compass_gait_orbit(ex)
    assert orbit.residual < 1e-10 and [g.events for g in orbit.trajectory.groups] == [(0,)] * 2
    assert orbit.x0[0] == pytest.approx(0.0, abs=1e-12) and orbit.x0[1] < 0
    default = walkers.compass_gait_orbit(walkers.compass_gait(slope=0.015))
    assert np.abs(default.x0 - orbit.x0).max() < 1e-9


def test_a_start_given_that_does_not_step_says_pass_another_start():
    with pytest.raises(ValueError, match=r"compass-gait with slope=0.015, theta=0.2, "
                       r"theta'=-0.2: .* does not meet its event at t_event=\S+; pass another "
                       r"start, or choose other parameters$"):
        walkers.compass_gait(slope=0.015, start=(0.2, -0.2))


def test_a_model_of_several_events_still_meets_them_together():
    with pytest.raises(ValueError, match=r"does not meet the events together at "
                       r"t_event=0.3; choose other parameters$"):
        bounces.ball_in_corner(speed=0.5, t_event=0.3)


@pytest.mark.parametrize(("make", "d", "name", "bad"), [
    (walkers.compass_gait_orbit, 4, "compass-gait", (0.1,)),
    (walkers.rimless_wheel_orbit, 2, "rimless-wheel", (0.0, 0.05, 0.0)),
])
def test_a_perturbation_of_the_wrong_shape_is_refused(make, d, name, bad):
    # (0.1,) was broadcast to every coordinate
    with pytest.raises(ValueError, match=rf"perturbation must have shape \({d},\) \(added to "
                       rf"the example's start x0, a state of {name}\), got shape "
                       rf"\({len(bad)},\)"):
        make(perturbation=bad)


def test_the_rimless_wheel_block_of_the_docs_runs_on_its_own():
    # it used np without importing it: a NameError unless an earlier block had imported it
    text = (DOCS / "gaits.md").read_text()
    (block,) = [b for b in re.findall(r"^```python\n(.*?)^```", text, re.S | re.M)
                if "rimless_wheel_orbit" in b]
    namespace = {}
    exec(compile(block, "docs/gaits.md", "exec"), namespace)  # noqa: S102
    assert abs(namespace["mult"][0]) == pytest.approx(np.cos(np.pi / 4) ** 2, abs=1e-9)


def test_a_wheel_at_its_stall_slope_names_period_guess():
    """At the slope below which the wheel stalls (0.0289219..., alpha 0.3: the closed
    form's spoke-crossing margin at 0), Newton's trial points stop returning, and the
    failure said "pass a longer time to wait", which names no argument of periodic_orbit
    (a review)."""
    with pytest.raises(RuntimeError, match=r"the last trial point did not return to the "
                                           r"section within .* pass a larger period_guess"):
        walkers.rimless_wheel_orbit(walkers.rimless_wheel(alpha=0.3,
                                                           slope=0.02892194287609923))
