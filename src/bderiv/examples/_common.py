"""The :class:`Example` record and helpers shared by the examples."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.integrate import solve_ivp

from ..models.system import HybridSystem

__all__ = ["Example", "complex_step_jacobian", "flow_back"]


@dataclass(frozen=True, eq=False)
class Example:
    """A ready example.

    Attributes
    ----------
    system : HybridSystem
    rho : ndarray, shape (d,)
        Event point: ``system.events(rho)`` vanishes (all n events at once).
    x0 : ndarray, shape (d,)
        Start point before every event; its trajectory reaches ``rho`` at ``t_event``.
    t_event : float
        Time at which the trajectory from ``x0`` meets all events together.
    t_final : float
        A final time after ``t_event`` (no further event before it).
    name : str
    description : str
    """

    system: HybridSystem
    rho: np.ndarray
    x0: np.ndarray
    t_event: float
    t_final: float
    name: str
    description: str

    @classmethod
    def from_model(cls, model, *, n_events, dim, rho, x0, t_event, t_after, name, description):
        """Wrap a model object (``field``, ``events``, ``event_jacobian``,
        ``field_jacobian`` and optionally ``corner_field`` methods) into an example."""
        system = HybridSystem(
            model.field,
            model.events,
            n_events=n_events,
            dim=dim,
            event_jacobian=model.event_jacobian,
            field_jacobian=model.field_jacobian,
            corner_field=getattr(model, "corner_field", None),
        )
        return cls(
            system=system,
            rho=np.asarray(rho, dtype=np.float64),
            x0=np.asarray(x0, dtype=np.float64),
            t_event=float(t_event),
            # to float64's 15 significant digits: 0.1 + 0.05 reads 0.15, as asked for
            t_final=float(f"{float(t_event) + float(t_after):.15g}"),
            name=name,
            description=description,
        )


def complex_step_jacobian(fun, x, n_out):
    """Jacobian of a complex-safe ``fun`` at real ``x`` by the complex step, (n_out, d).

    Exact to rounding (no subtraction), d evaluations; used by examples whose formulas are
    written with complex-safe numpy functions.
    """
    x = np.asarray(x, dtype=np.float64)
    d = x.size
    h = 1e-30
    J = np.empty((n_out, d))
    xc = x.astype(np.complex128)
    for j in range(d):
        xc[j] += 1j * h
        J[:, j] = np.imag(fun(xc)) / h
        xc[j] = x[j]
    return J


def flow_back(field0, rho, t_event, rtol=1e-13, atol=1e-14):
    """Integrate the pre-event field ``field0(x)`` backward from ``rho`` for ``t_event``."""
    sol = solve_ivp(
        lambda _t, x: field0(x),
        (t_event, 0.0),
        np.asarray(rho, dtype=np.float64),
        method="DOP853",
        rtol=rtol,
        atol=atol,
    )
    if sol.status != 0:  # pragma: no cover - the examples are built to integrate
        raise RuntimeError(sol.message)
    return np.array(sol.y[:, -1])
