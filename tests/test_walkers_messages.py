"""The passive walkers' refusals say what to do (a review): a slope whose gait the default
start does not reach names ``start=``, a one-event model is not said to "meet the events
together", a perturbation of the wrong size is refused, and the rimless-wheel block of
docs/gaits.md runs on its own.

Oracles: the compass gait's fixed point at slope 0.015 from the start the docstring gives
(the return map's residual), and the wheel's closed-form multiplier ``cos(2 alpha)^2``.
"""

from __future__ import annotations

import pathlib
import re

import numpy as np
import pytest

from bderiv.examples import bounces, walkers

DOCS = pathlib.Path(__file__).resolve().parents[1] / "docs"


@pytest.mark.parametrize("slope", [0.015, 0.02])
def test_a_slope_the_default_start_does_not_suit_names_start(slope):
    # it said "...does not meet the events together ...; choose other parameters": the
    # model has one event, and the slope is not the parameter to change
    with pytest.raises(ValueError) as info:
        walkers.compass_gait(slope=slope)
    message = str(info.value)
    assert message.startswith(f"compass-gait with slope={slope:g}, theta=0.200311, "
                              f"theta'=-0.199832: the start it builds")
    assert "does not meet its event at t_event=" in message
    assert "events together" not in message and "choose other parameters" not in message
    assert message.endswith(
        "the default start, (theta, theta') = (0.200311, -0.199832), is Garcia et al.'s "
        "fixed point for slope 0.009 and suits slopes near it only: pass start=(theta, "
        f"theta'), a state just after a heel strike of the gait at slope {slope:g} (steeper "
        "slopes take longer steps: a larger theta)")


def test_the_start_the_docstring_gives_for_steeper_slopes_finds_the_gait():
    ex = walkers.compass_gait(slope=0.015, start=(0.24, -0.228))
    orbit = walkers.compass_gait_orbit(ex)
    assert orbit.residual < 1e-10 and [g.events for g in orbit.trajectory.groups] == [(0,)] * 2
    assert orbit.x0[0] == pytest.approx(0.0, abs=1e-12) and orbit.x0[1] < 0


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
