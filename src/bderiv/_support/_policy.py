"""``BDERIV_INTEGRATOR``: what a process does while the compiled integrator is not compiled
(:mod:`bderiv.models.readiness` says what each value does). Here, apart from it, so that
the command line checks the variable before a command runs, without loading numba."""

from __future__ import annotations

import os

#: the environment variable, and its values
POLICY_VARIABLE = "BDERIV_INTEGRATOR"
POLICIES = ("auto", "compiled", "scipy")


def policy() -> str:
    """``BDERIV_INTEGRATOR``, checked: ``auto`` (unset), ``compiled`` or ``scipy``."""
    value = os.environ.get(POLICY_VARIABLE, "auto").strip().lower() or "auto"
    if value not in POLICIES:
        raise ValueError(f"the environment variable {POLICY_VARIABLE} must be one of "
                         f"{', '.join(POLICIES)}, got {value!r}")
    return value
