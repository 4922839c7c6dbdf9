"""Passive walkers down a slope: the rimless wheel and the compass gait (leg swaps as resets).

Both walk down a slope of angle ``slope`` under gravity alone; each step ends with an
impact at which the legs exchange their roles. The impact is a reset that relabels the
legs (and changes the velocities by the conservation of angular momentum), so the state
lands back on the side of the event surface it came from or on the surface with the flow
leaving it: a leg swap (mathematics.md section 9, "Where a reset lands"). Units are the
walkers' own: lengths in leg lengths and time in ``sqrt(leg / g)`` when ``g = leg = 1``
(the defaults, as in the publications).

**Rimless wheel** (McGeer 1990; Coleman, Chatterjee & Ruina 1997): spokes of length
``leg`` at angles ``2 alpha`` apart around a point mass at the hub. State ``(theta,
omega)``: the stance spoke's angle from the slope's normal, positive downhill (the walking
direction), and its rate; in stance the hub is an inverted pendulum,
``theta'' = (g / leg) sin(theta + slope)``. The next spoke hits the ground when
``theta = alpha``: event ``h = theta - alpha``. The impact conserves the angular momentum
about the new contact point: ``omega -> cos(2 alpha) omega``, and the new stance spoke is
the one at ``theta - 2 alpha`` (``-alpha`` on the surface): the reset
``(theta, omega) -> (theta - 2 alpha, cos(2 alpha) omega)`` lands at ``h = -2 alpha``,
back where the step began, so the event's bit stays clear and every step ends with an
upward crossing of the same surface. The section of the gait is mid-stance,
``theta = 0`` (:func:`wheel_section`). Closed forms (energy balance from ``-alpha`` to
``alpha``): the map on ``u = omega^2`` after the impact is ``u -> c^2 (u + K)``, ``c =
cos(2 alpha)``, ``K = 4 (g / leg) sin(alpha) sin(slope)``; its fixed point is
``u* = c^2 K / (1 - c^2)`` and the multiplier of the gait is ``c^2 = cos(2 alpha)^2``.
The model does not describe a wheel too slow to roll over the top of a spoke (``omega``
reaching 0 before the vertical; the trailing spoke is no event).

**Compass gait** (McGeer 1990; Goswami, Thuilot & Espiau 1998; Garcia, Chatterjee, Ruina &
Coleman 1998): two straight legs of length ``leg`` with point feet, a point mass
``hip_mass`` at the hip and ``leg_mass`` on each leg at ``leg_com`` (as a fraction of the
leg, from the hip: 1 puts it at the foot, as in Garcia et al.; 0.5 in the middle, as in
Goswami et al.). The coordinates are Garcia et al.'s: state ``(theta, phi, theta', phi')``,
``theta`` the stance leg's angle from the slope's normal (positive uphill: a step runs from
``theta > 0`` to ``theta < 0``), ``phi`` the angle from the stance leg to the swing leg
(the swing leg's angle from the normal is ``theta - phi``). The swing foot is on the
ground when ``phi = 0`` or ``phi = 2 theta``; event ``h = phi - 2 theta``. The heel strike
is its upward crossing with the swing leg ahead (``phi < 0``); the reset swaps the legs,
``theta -> theta - phi`` and ``phi -> -phi`` (``-theta`` and ``-2 theta`` on the surface),
and gives the velocities from the conservation of the angular momentum of the whole walker
about the new stance foot and of the new swing leg about the hip. Just after the heel
strike the state is on the surface again, moving into ``h > 0``: the bit is set (flipped).
**Scuffing**: with point feet on a straight slope the swing foot dips under the ground near
mid-stance, where the legs pass each other. As in the literature (Garcia et al., McGeer),
that contact is ignored: the surface ``h = 0`` is crossed downward there (the bit is
cleared, no reset: the fields of the two regions are the same), and only the next upward
crossing, once the swing leg is past the stance leg, is the heel strike (the reset refuses
an upward crossing with ``phi >= 0``). Each step thus has two events of the same index:
the scuff (downward, no jump) and the heel strike (upward, leg swap). The section of the
gait is mid-stance, ``theta = 0`` crossed downward (:func:`compass_section`).
**Its gaits**: :func:`compass_gait` starts on the long-period gait of Garcia et al.'s walker
at the slope given (:func:`long_gait_start`), which :func:`compass_gait_orbit` then finds
(from Garcia et al.'s fixed point at 0.009, the start at every slope before, Newton's method
found another, unstable, orbit at slope 0.012, its scuff after mid-stance). The long-period
gait is stable up to slope :data:`STABLE_SLOPE` = 0.015088 and loses its stability there by a
period doubling (Garcia et al.: 0.0151): beyond, the orbit found is that gait, unstable, as
its stability says (the stable gait there has period two, then longer periods).

**Published numbers** compared in the tests: Garcia, Chatterjee, Ruina & Coleman, "The
simplest walking model: stability, complexity, and scaling", ASME J. Biomech. Eng. 120(2),
281-288 (1998), the limit ``leg_mass / hip_mass -> 0`` (``leg_mass = 0`` here), slope
0.009, ``g = leg = 1``: the stable (long-period) gait just after heel strike has
``theta* = 0.20031090049483``, ``theta'* = -0.19983247291764``, and its stride map's
nonzero eigenvalues are ``-0.19120868949940 +- 0.55633363687106 i`` (the digits of the
simulation code published with the paper, M. Garcia 1998, integrated to 1e-10:
:data:`GARCIA_FIXED_POINT`, :data:`GARCIA_EIGENVALUES`). The fixed point agrees to 1e-10;
the eigenvalues to 1.7e-3 only: the return map's B-derivative gives ``-0.1900998 +-
0.5575988 i`` (modulus 0.58911, Garcia's 0.58827), and so do central differences of the
stride map of Garcia's equations integrated by scipy at rtol 1e-13 (tests/test_bounces.py),
to 1e-8. The two computations here agree with each other, not with the code's comment
beyond the second decimal (whose integration and differencing steps the code does not say).
"""

from ._compass import (
    GARCIA_EIGENVALUES,
    GARCIA_FIXED_POINT,
    STABLE_SLOPE,
    compass_gait,
    compass_gait_orbit,
    compass_section,
    compass_section_gradient,
    long_gait_start,
)
from ._wheel import rimless_wheel, rimless_wheel_orbit, wheel_section, wheel_section_gradient

__all__ = [
    "GARCIA_EIGENVALUES",
    "GARCIA_FIXED_POINT",
    "STABLE_SLOPE",
    "compass_gait",
    "compass_gait_orbit",
    "compass_section",
    "compass_section_gradient",
    "long_gait_start",
    "rimless_wheel",
    "rimless_wheel_orbit",
    "wheel_section",
    "wheel_section_gradient",
]
