"""Command line: ``bderiv demo | bench | plot | export`` (also ``python -m bderiv``).

- ``demo``: a built-in model (the chair by default): its trajectory's event groups, the
  B-derivative of its flow, the pieces (event orders, determinant, norm), a batch of
  tangent vectors with the time per vector, and the check against finite differences of
  the simulation. ``--json`` prints one JSON document instead.
- ``bench``: a dimension sweep of bderiv against the batched-NumPy baseline and a BLAS
  yardstick; a table, optionally a log-log plot.
- ``plot``: the figures of :mod:`bderiv.plot` to PNG, PDF or SVG files.
- ``export``: the triangulation of an example's B-derivative to ``.npz`` and ``.json``
  (read back with :func:`bderiv.load_triangulation`).

Bad arguments give a one-line error on stderr and exit status 2.

The modules, imports pointing down:

- :mod:`.parser`: argparse, dispatch, exit statuses;
- :mod:`.demo`, :mod:`.bench`, :mod:`.figures`, :mod:`.export`: one command's computation
  each, returning data; :mod:`.render`: that data as text or JSON;
- :mod:`.systems`: the examples by name; :mod:`.usage`: the checks of arguments that
  argparse cannot make, and :class:`~bderiv.cli.usage.UsageError`.
"""

from .parser import main

__all__ = ["main"]
