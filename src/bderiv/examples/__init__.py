"""Ready-made event-selected systems with a simultaneous-event point.

Each function returns an :class:`Example`: the :class:`~bderiv.hybrid.HybridSystem`, the
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
  :mod:`~bderiv.examples.impacts`).

Two corner tables without a model, ``(Dh, F)`` pairs: :func:`three_event_table` (n = d = 3,
event orders that overtake) and :func:`planar_table` (n = d = 2, for the 2-D figures).
"""

from . import gaits, impacts, runner
from ._common import Example
from .chair import chair
from .gaits import pronking
from .impacts import landing
from .network import network
from .runner import running
from .table import table
from .tables import planar_table, three_event_table

__all__ = ["Example", "chair", "gaits", "impacts", "landing", "network", "planar_table",
           "pronking", "runner", "running", "table", "three_event_table"]
