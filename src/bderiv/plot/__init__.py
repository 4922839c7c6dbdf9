"""Figures of a B-derivative (matplotlib, the optional extra ``plot``).

matplotlib is imported inside each function, so ``import bderiv.plot`` works without it.
Every function returns a ``matplotlib.figure.Figure`` built without pyplot (no global
state, no window); save it with ``fig.savefig("name.png")``. Pass ``ax=`` (or ``axes=``)
to draw into an existing figure instead.

- :func:`corner_field`: 2-D systems, the corner-limit field with the event lines and a
  few sampled trajectories;
- :func:`triangulation`: 2-D systems, the pre-event and post-event fans of simplices;
- :func:`carried_fan`: 2 events in the plane, the source note's picture: the simplices
  carried through the corner-limit flow, in state and in impact-time coordinates;
- :func:`tangent_circle`: 2-D systems, a circle of tangent vectors and its image;
- :func:`pieces`: any n, determinant and gain of the linear pieces;
- :func:`scaling`: time per query against n from a benchmark sweep;
- :func:`gait_orbit`, :func:`gait_growth`: a periodic orbit with its event groups, and the
  growth of a batch of directions through its piecewise-linear return map;
- :func:`stability_map`: a gait's growth rate over a grid of two parameters.

The figures live in private modules by subject (``_planar``, ``_carried_fan``,
``_pieces``, ``_scaling``, ``_gait``, ``_stability_map``, all on the figure set-up of
``_axes``); this package is their one public name.
"""

from ._carried_fan import carried_fan
from ._gait import gait_growth, gait_orbit
from ._pieces import pieces
from ._planar import corner_field, tangent_circle, triangulation
from ._scaling import scaling
from ._stability_map import stability_map

__all__ = ["carried_fan", "corner_field", "gait_growth", "gait_orbit", "pieces", "scaling",
           "stability_map", "tangent_circle", "triangulation"]
