"""Ready-made event-selected systems with a simultaneous-event point.

Each function returns an :class:`Example`: the :class:`~bderiv.analysis.system.HybridSystem`, the
event point ``rho`` where all its events happen at once, a start point ``x0`` that reaches
``rho`` at time ``t_event`` (all events simultaneously) and a final time ``t_final`` after it.

- :func:`chair`: planar rigid body, two legs touch compliant ground together (d = 6, n = 2);
- :func:`network`: first-order network for any n (d = n or d = 2n) whose events change each
  other's rates, so perturbations overtake (usable up to n = 20);
- :func:`table`: 3-D rigid body landing flat on 4 legs (n = 4 > rank of Dh = 3);
- :func:`pronking`: a planar body pronking on compliant legs (d = 4, n = 2 legs or more), a
  gait whose legs land and lift off together (module :mod:`~bderiv.examples.gaits`: its
  section, periodic orbit and summary);
- :func:`running`: the same body advancing, its speed driven toward a target in stance
  (d = 6; the forward position is a cyclic coordinate; module
  :mod:`~bderiv.examples.runner`);
- :func:`landing`: a body on two massive feet landing together, resets at the touchdown
  (d = 10, n = 2); the coupled variant (``coupling > 0``) is refused (module
  :mod:`~bderiv.examples.impacts`);
- :func:`bouncing_ball` (d = 2, n = 1) and :func:`ball_in_corner` (d = 4, n = 2, both
  walls hit at once; refused unless the corner is a right angle): resets that send the
  state back to the side it came from (module :mod:`~bderiv.examples.bounces`);
- :func:`rimless_wheel` (d = 2) and :func:`compass_gait` (d = 4), passive walkers whose
  every step ends with a leg swap (module :mod:`~bderiv.examples.walkers`: their sections
  and periodic orbits, checked against closed forms and Garcia et al. 1998).

Two corner tables without a model, ``(Dh, F)`` pairs: :func:`three_event_table` (n = d = 3,
event orders that overtake) and :func:`planar_table` (n = d = 2, for the 2-D figures).
"""

from . import bounces, gaits, impacts, runner, walkers
from ._common import Example
from .bounces import ball_in_corner, bouncing_ball
from .chair import chair
from .gaits import pronking
from .impacts import landing
from .network import network
from .runner import running
from .table import table
from .tables import planar_table, three_event_table
from .walkers import compass_gait, rimless_wheel

__all__ = ["Example", "ball_in_corner", "bounces", "bouncing_ball", "chair", "compass_gait",
           "gaits", "impacts", "landing", "network", "planar_table", "pronking",
           "rimless_wheel", "runner", "running", "table", "three_event_table", "walkers"]
