"""The examples start where they say: a start they build outside the region they promise
(beyond a surface, no event where they say there is one) is a ValueError naming the
parameters, never an example whose trajectory misses its event point.

Oracles: the geometry of each case written out here (the ball flown back in closed form,
a fall from below the legs, a negative flight time), and for the valid defaults a
simulation that meets every event at ``t_event``.
"""

from __future__ import annotations

import numpy as np
import pytest

from bderiv import examples
from bderiv.examples import bounces, walkers

G = 9.81


def test_a_slow_ball_flown_back_far_is_refused_below_the_floor():
    """speed 0.5 at the corner, 0.3 s of flight back: y0 = -v_y t - g t^2 / 2 with
    v_y = -0.5 / sqrt(2) (closed form), below the floor."""
    speed, t = 0.5, 0.3
    vy = -speed / np.sqrt(2) + G * t  # at x0, flown back
    y0 = -vy * t - 0.5 * -G * t * t
    assert y0 == pytest.approx(-0.335384, abs=1e-6)
    with pytest.raises(ValueError, match=r"ball-in-corner with angle=1.5708, speed=0.5, "
                                         r"g=9.81, t_event=0.3: the start it builds, x0 = "
                                         r"\[.*-0.335384.*\], is not in region 0b00 .* event "
                                         r"0 has h_0\(x0\) = 0.335384"):
        bounces.ball_in_corner(speed=speed, t_event=t)
    # a faster ball from the same time starts inside and meets both walls at t_event
    ex = bounces.ball_in_corner(speed=3.0, t_event=t)
    first = ex.system.simulate(ex.x0, ex.t_final, simultaneity_tol=1e-7).groups[0]
    assert first.events == (0, 1) and first.time == pytest.approx(t, abs=1e-9)


@pytest.mark.parametrize(("make", "kwargs", "named"), [
    (examples.chair, {"t_event": -0.1}, r"chair with t_event=-0.1, t_after=0.05: the event "
                                        r"time must be > 0"),
    (examples.chair, {"t_after": -0.01}, r"chair with t_event=0.1, t_after=-0.01: .* before "
                                         r"the final time"),
    (examples.table, {"t_event": 0.0}, r"table with t_event=0, t_after=0.05: the event time"),
    (examples.network, {"t_event": -1.0}, r"network\(n=3\) with n=3, seed=0, coupling=1, "
                                          r"t_event=-1"),
    (examples.landing, {"t_event": -0.05}, r"landing with t_event=-0.05"),
    (examples.pronking, {"apex": 0.4}, r"pronking with apex=0.4, leg=0.5: the start it "
                                       r"builds, x0 = \(apex, 0, 0, 0\), must be above"),
    (examples.running, {"apex": 0.5}, r"pronking with apex=0.5, leg=0.5"),
    # the short-period gait's start: its swing leg passes the stance leg after mid-stance,
    # where the heel-strike event jumped (t_event was quoted at the legs' passing, 0.25)
    (walkers.compass_gait, {"start": (0.193937, -0.203867)},
     r"compass-gait with slope=0.009, theta=0.193937, theta'=-0.203867: the start it "
     r"builds, .* is not in region 0b0.* at t_event=1.4864"),
    (walkers.compass_gait, {"start": (0.25, -0.3)},
     r"the compass gait with these parameters does not complete a step from \(theta, "
     r"theta'\) = \[0.25, -0.3\]"),
    (bounces.bouncing_ball, {"t_after": 1.0}, r"within the first flight after the bounce "
                                              r"\(before the second impact, 0.722438 s"),
    (bounces.ball_in_corner, {"t_after": 0.0}, r"t_after must be > 0"),
])
def test_a_start_not_where_the_example_says_is_refused_naming_the_parameters(make, kwargs,
                                                                             named):
    with pytest.raises(ValueError, match=named):
        make(**kwargs)


@pytest.mark.parametrize("make", [examples.chair, examples.table, examples.network,
                                  examples.landing, examples.pronking, examples.running,
                                  bounces.bouncing_ball, bounces.ball_in_corner,
                                  walkers.rimless_wheel, walkers.compass_gait])
def test_every_default_example_meets_all_its_events_at_t_event(make):
    ex = make()
    traj = ex.system.simulate(ex.x0, ex.t_final, simultaneity_tol=1e-7)
    first = traj.groups[0]
    assert first.events == tuple(range(ex.system.n_events)) and first.mask_before == 0
    assert first.time == pytest.approx(ex.t_event, abs=1e-7)
