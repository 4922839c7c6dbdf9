"""Numba kernels: ``_core`` (jit options, the task driver, shared steps) and one module per
corner representation (``dense``, ``structured``, ``function``). No validation here."""
