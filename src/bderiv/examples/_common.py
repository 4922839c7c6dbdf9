"""The :class:`Example` record and helpers shared by the examples.

Models with a compiled version write their equations once, as plain functions that numba
compiles (closures over constant numbers and arrays, loop style, no Python objects):
:meth:`Example.from_functions` passes them to :class:`~bderiv.models.system.HybridSystem` as
they are (the Python version) or each compiled by :func:`compile_function` (the compiled
version, ``compiled=True``): one code path for both.
"""

from __future__ import annotations

import hashlib
import pathlib
import pickle
from dataclasses import dataclass
from functools import cache

import numba
import numpy as np
from scipy.integrate import solve_ivp

from .._kernels._cache import DriverCache, harden
from .._validate import check_bool
from ..models.system import HybridSystem

__all__ = ["Example", "compile_function", "complex_step_jacobian", "flow_back"]

#: the functions of a model that the compiled version compiles (corner_field stays Python:
#: it is called at the event points only, with the whole table at once)
COMPILED_FUNCTIONS = ("field", "events", "field_jacobian", "event_jacobian", "reset",
                      "reset_jacobian")


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
    compiled: bool = False

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

    @classmethod
    def from_functions(cls, functions, *, compiled, n_events, dim, rho, x0, t_event,
                       t_after, name, description):
        """An example from its model's functions, compiled or not.

        Parameters
        ----------
        functions : dict
            ``field``, ``events``, ``event_jacobian`` and optionally ``field_jacobian``,
            ``corner_field``, ``reset``, ``reset_jacobian``: plain functions that numba
            can compile (except ``corner_field``, always called as Python).
        compiled : bool
            Compile them (:func:`compile_function`): the model then runs on the compiled
            integrator. Without ``field_jacobian`` the Jacobian is taken by complex step
            in either version (in compiled code when compiled).
        """
        compiled = check_bool(compiled, "compiled")
        fns = dict(functions)
        if compiled:
            fns.update({k: compile_function(f) for k, f in fns.items()
                        if k in COMPILED_FUNCTIONS})
        elif "field_jacobian" not in fns:
            field = fns["field"]
            fns["field_jacobian"] = lambda x, mask: complex_step_jacobian(
                lambda y: field(y, mask), x, dim)
        system = HybridSystem(fns.pop("field"), fns.pop("events"), n_events=n_events,
                              dim=dim, **fns)
        return cls(system=system, rho=np.asarray(rho, dtype=np.float64),
                   x0=np.asarray(x0, dtype=np.float64), t_event=float(t_event),
                   t_final=float(f"{float(t_event) + float(t_after):.15g}"), name=name,
                   description=description + (", numba-compiled" if compiled else ""),
                   compiled=compiled)


@cache
def _sources_digest() -> str:
    """sha256 of the examples' sources (a compiled function may inline helpers of other
    files of the package: any edit invalidates every cached example function)."""
    h = hashlib.sha256()
    for path in sorted(pathlib.Path(__file__).parent.glob("*.py")):
        h.update(path.name.encode() + path.read_bytes())
    return h.hexdigest()


def compile_function(fn):
    """``numba.njit(fn)``, cached on disk under the examples' sources and the values ``fn``
    closes over (compiled at its first call; later processes load it in milliseconds).

    Numba would key a closure's cache by its values alone and invalidate it only when its
    own file changes; the key here also changes when a helper it inlines does.
    """
    cells = tuple(c.cell_contents for c in fn.__closure__ or ())
    values = hashlib.sha256(pickle.dumps(cells)).hexdigest()
    key = f"{fn.__module__}.{fn.__qualname__}:{_sources_digest()}:{values}"
    return harden(numba.njit(fn), DriverCache(fn, key))


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
