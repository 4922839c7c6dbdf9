"""The :class:`Example` record and helpers shared by the examples.

Models with a compiled version write their equations once, as plain functions that numba
compiles (loop style, no Python objects): :meth:`Example.from_functions` passes them to
:class:`~bderiv.analysis.system.HybridSystem` as they are (the Python version) or each
compiled by :func:`compile_function` (the compiled version, ``compiled=True``): one code
path for both. Their constants are either closed over (numbers and arrays: a compilation
per set of values) or, for the models that are swept over parameters (the gaits), read
from the state's tail as the system's ``params``: module-level functions compiled once per
process (:func:`compiled_once`) and loaded from numba's disk cache in later ones.
"""

from __future__ import annotations

import pathlib
from dataclasses import dataclass
from functools import cache

import numpy as np

from .._kernels._cache import keyed, sources_digest
from .._limits import ON_SURFACE_TOL
from .._support._format import format_mask
from .._support._numdiff import complex_step
from .._support._validate import check_bool, check_state
from ..analysis.system import HybridSystem

__all__ = ["Example", "check_start", "compile_function", "compiled_once", "finite_ratios",
           "flow_back", "perturbed_start"]

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
                       t_after, name, description, params=None):
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
        params : array_like, shape (m,), optional
            The system's parameter values (:class:`~bderiv.analysis.system.HybridSystem`):
            the functions take the state followed by them. The functions are then
            module-level ones holding no constants, compiled once per process
            (:func:`compiled_once`).
        """
        compiled = check_bool(compiled, "compiled")
        fns = dict(functions)
        if compiled:
            compile_ = compile_function if params is None else compiled_once
            fns.update({k: compile_(f) for k, f in fns.items() if k in COMPILED_FUNCTIONS})
        elif "field_jacobian" not in fns:
            field = fns["field"]
            # by the state (the first dim entries), the parameters held
            fns["field_jacobian"] = lambda x, mask: complex_step(
                lambda y: field(np.concatenate((y, x[dim:])), mask), x[:dim], dim, strict=False)
        system = HybridSystem(fns.pop("field"), fns.pop("events"), n_events=n_events,
                              dim=dim, params=params, **fns)
        return cls(system=system, rho=np.asarray(rho, dtype=np.float64),
                   x0=np.asarray(x0, dtype=np.float64), t_event=float(t_event),
                   t_final=float(f"{float(t_event) + float(t_after):.15g}"), name=name,
                   description=description + (", numba-compiled" if compiled else ""),
                   compiled=compiled)


def check_start(example, parameters, region=0, remedy="choose other parameters"):
    """``example`` itself when it starts where it says, else a ValueError naming
    ``parameters`` (dict, name -> value: those that placed the start) and ending with
    ``remedy`` (what to do instead).

    Where it says: ``t_event`` finite, > 0 and before ``t_final``, ``x0`` and ``rho``
    finite, ``x0`` strictly inside region ``region`` (every event's value of the sign its
    bit says: not on a surface, nor beyond one) and every event at ``rho``
    (``|events(rho)|`` at most ``ON_SURFACE_TOL`` relative to ``rho``), so that the
    trajectory from ``x0`` can meet them together there. (That it meets no surface on the
    way is the example's own argument or construction.)

    Examples
    --------
    >>> from bderiv.examples import bouncing_ball
    >>> ex = bouncing_ball()
    >>> check_start(ex, {}) is ex
    True
    """
    named = ", ".join(f"{k}={v:g}" for k, v in parameters.items())
    where = f"{example.name} with {named}" if named else example.name
    t_event, t_final, x0, rho = example.t_event, example.t_final, example.x0, example.rho
    if not (np.isfinite(t_event) and t_event > 0 and t_final > t_event):
        raise ValueError(f"{where}: the event time must be > 0 and before the final time, "
                         f"got t_event={t_event:.6g}, t_final={t_final:.6g}; {remedy}")
    if not (np.isfinite(x0).all() and np.isfinite(rho).all()):
        raise ValueError(f"{where}: the start or the event point it builds is not finite "
                         f"(x0 = {x0.tolist()}, rho = {rho.tolist()}); {remedy}")
    system = example.system
    h = system.calls.eval_events(x0)
    side = np.array([1.0 if region >> k & 1 else -1.0 for k in range(h.size)])
    wrong = np.flatnonzero(~(side * h > 0))
    if wrong.size:
        k = int(wrong[0])
        meet = "its event" if h.size == 1 else "the events together"
        raise ValueError(
            f"{where}: the start it builds, x0 = {np.round(x0, 6).tolist()}, is not in "
            f"region {format_mask(region, h.size)} where the example starts: event {k} has "
            f"h_{k}(x0) = {h[k]:.6g} (on the surface or beyond it), so the trajectory from x0 "
            f"does not meet {meet} at t_event={t_event:.6g}; {remedy}"
        )
    off = np.abs(system.calls.eval_events(rho))
    if not (off <= ON_SURFACE_TOL * max(1.0, float(np.abs(rho).max()))).all():
        k = int(np.argmax(off))
        raise ValueError(f"{where}: its event point rho = {np.round(rho, 6).tolist()} is "
                         f"not on the surface of event {k} (|h_{k}(rho)| = {off[k]:.3g}); "
                         f"{remedy}")
    return example


def finite_ratios(fd) -> list:
    """The ratios of an :class:`~bderiv.analysis.checks.FDCheck` for a JSON-friendly
    summary: None (JSON null) for NaN, the ratio to a step whose error is exactly 0."""
    return [float(r) if np.isfinite(r) else None for r in fd.ratios]


def perturbed_start(example, perturbation):
    """``example.x0 + perturbation``, the guess of a gait's ``*_orbit`` function, with the
    perturbation checked by name: finite, shape ``(d,)`` (not broadcast)."""
    return example.x0 + check_state(
        perturbation, example.x0.size, "perturbation",
        meaning=f"added to the example's start x0, a state of {example.name}")


@cache
def _sources_digest() -> str:
    """The digest of the examples' sources (a compiled function may inline helpers of other
    files of the package: any edit invalidates every cached example function)."""
    return sources_digest(pathlib.Path(__file__).parent)


def compile_function(fn):
    """``numba.njit(fn)``, cached on disk by numba (compiled at its first call; later
    processes load it in milliseconds) under a name that ends with the examples' sources
    digest (:func:`bderiv._kernels._cache.keyed`).

    Numba keys a closure's cache by the values it holds and invalidates it only when its
    own file changes; the name changes when a helper it inlines does.
    """
    return keyed(fn, _sources_digest())


@cache
def compiled_once(fn):
    """:func:`compile_function` of a module-level ``fn``, once per process: every model
    built on it shares the dispatcher (its constants are parameters), so a second model
    compiles nothing."""
    return compile_function(fn)


def flow_back(field0, rho, t_event, rtol=1e-13, atol=1e-14):
    """Integrate the pre-event field ``field0(x)`` backward from ``rho`` for ``t_event``."""
    from scipy.integrate import solve_ivp  # here: the compiled examples never need it

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
