"""Numba kernels: ``_core`` (jit options, the task driver), ``steps`` (shared arithmetic),
``linear`` (what is linear once an order is known) and one module per corner representation
(``dense`` and ``lanes``, ``structured`` and ``structured_chains``, ``function``,
``resets``). No validation here."""
