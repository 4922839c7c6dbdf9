"""HybridSystem: a nonlinear event-selected model, as data.

A model is a family of smooth vector fields ``field(x, mask)`` (one per region, bit k of
``mask`` set iff ``h_k(x) > 0``, mathematics.md section 1) and the event functions
``events(x)``. Along a trajectory a surface may be crossed upward (the bit is set) or
downward (cleared), any number of times; a group crossed downward is handled in its local
orientation (:mod:`bderiv.models.events.crossings`). :class:`HybridSystem` is the frozen
description of a model (its functions, sizes, parameters, compiled or not) holding its
checked calls (:class:`bderiv.models.calls.ModelCalls`, as ``calls``: every output checked,
Jacobians analytic when given, else numerical). The algorithms are functions over it, which
its methods call:

- :mod:`bderiv.analysis.flows`: ``bderivative`` at an event point, ``simulate`` and
  ``simulate_many`` (event-detecting integration), ``flow_bderivative`` (the flow map's
  B-derivative), ``flow_fd`` (forward differences of the simulated flow);
- :mod:`bderiv.analysis.poincare`: ``return_map`` (the B-derivative of a Poincare map) and
  ``periodic_orbit`` (a gait found by Newton's method with it, with its stability).

Missing Jacobians are computed by central differences with Richardson extrapolation
(:mod:`bderiv._support._numdiff`: adaptive step, error estimate), on a compiled model in
compiled code; the user functions need not be vectorised, they are wrapped.
"""

from __future__ import annotations

import dataclasses
from dataclasses import KW_ONLY

import numpy as np

from .._limits import (
    DEFAULT_T_MAX,
    MAX_GROUPS,
    ON_SURFACE_TOL,
    ORBIT_MAX_ITER,
    ORBIT_TOL,
)
from .._support._validate import check_bool, check_value
from .._support._validate_ints import check_positive_int
from ..models.calls import ModelCalls
from ..models.compiled import CompiledModel
from ..models.integrate.many import Trajectories
from ..models.integrate.options import SolverOptions
from ..models.integrate.run import EventGroup, EventRecord
from ..models.integrate.trajectory import Trajectory
from ..models.user_functions import check_callable, check_params
from . import flows, poincare
from .assembly import flow_map_along

# EventGroup, EventRecord, Trajectory live in models.integrate.run: the types the methods
# return, re-exported beside the model
__all__ = ["EventGroup", "EventRecord", "HybridSystem", "SolverOptions", "Trajectories",
           "Trajectory"]

#: the model's functions, as they are called
_FUNCTIONS = {"field": "field(x, mask)", "events": "events(x)",
              "event_jacobian": "event_jacobian(x)", "field_jacobian": "field_jacobian(x, mask)",
              "corner_field": "corner_field(x)", "reset": "reset(x, mask, k)",
              "reset_jacobian": "reset_jacobian(x, mask, k)",
              "reset_guard": "reset_guard(x, mask, k)"}


@dataclasses.dataclass(frozen=True, eq=False, repr=False)
class HybridSystem:
    """A nonlinear event-selected system: region vector fields and event functions.

    Parameters
    ----------
    field : callable
        ``field(x, mask) -> (d,)``: the smooth vector field of region ``mask`` at ``x``
        (shape ``(d,)``), defined on a neighbourhood of the surfaces, across them. Bit k of
        ``mask`` is set iff event k has happened.
    events : callable
        ``events(x) -> (n,)``: the event values h(x); the region's bit k is set iff
        ``h_k(x) > 0``, and a crossing of ``h_k = 0`` in either direction is an event.
    n_events : int
        Number of events n.
    dim : int
        State dimension d.
    event_jacobian : callable, optional
        ``event_jacobian(x) -> (n, d)``. Default: numerical (see Notes); on a compiled
        model the complex step of ``events`` where they compile for complex input.
    field_jacobian : callable, optional
        ``field_jacobian(x, mask) -> (d, d)``. Default: numerical (slow inside the
        variational equations of a Python model; give it when you can); on a compiled
        model computed in compiled code (complex step, else central differences).
    corner_field : callable, optional
        ``corner_field(x) -> (2**n, d)``: all region fields at ``x`` at once, row ``mask``
        equal to ``field(x, mask)``. Used to sample the corner table without a Python loop
        over the 2**n masks (needed for n around 16 to 20).
    reset : callable, optional
        ``reset(x, mask, k) -> (d,)``: the state right after event k is crossed at ``x``
        from region ``mask`` (an impact; mathematics.md section 9; bit k of ``mask`` set: a
        downward crossing, return ``x`` for no jump). The state may land on the far side
        (its bit flips) or back on the side it came from: a bounce (``[q, -e v]`` for a
        ball) or a leg swap keeps the bit, and the next crossing of that surface is a new
        event (:func:`bderiv.models.events.crossings.landing` decides; ``EventGroup.bounced``).
        Simultaneous events are reset one after the other, in ascending order, each with
        the mask before the group with the bits of the events already reset flipped;
        their resets must commute (checked, :func:`bderiv.models.events.crossings.apply_resets`)
        and
        must not move the surfaces still pending. Default: no jump.
    reset_jacobian : callable, optional
        ``reset_jacobian(x, mask, k) -> (d, d)``. Default: numerical.
    check_jacobians : bool
        Compare each given Jacobian (and a ``section_gradient``) with a central difference
        of its function along a random direction the first time it is used for each mask
        (and event), and refuse a mismatch (default True; the cost is one numerical
        directional derivative per mask). :func:`bderiv.check_jacobians` reports them
        all at a point.
    params : array_like, shape (m,), optional
        Parameter values: every function above then takes ``x`` of shape (d + m,), the
        state followed by ``params`` (Jacobians are still by the state: (n, d), (d, d));
        the methods and a Poincare section take the state alone. With compiled functions
        a model with other values is another ``HybridSystem`` over the same dispatchers,
        not another compilation (a stability map builds one per grid point).
    use_compiled : bool
        Integrate on the compiled integrator when ``field`` is a numba dispatcher
        (default True); False: on :func:`scipy.integrate.solve_ivp` through the Python
        calls of the same functions.
    reset_guard : callable, optional
        ``reset_guard(x, mask, k)``, called (on ``x`` as the functions above are) before
        each ``reset``: raises a ValueError where that reset must be refused (the
        contacts of :func:`bderiv.symbolic.contact_system`: simultaneous impacts that do
        not commute). The stops of a model with one are decided in Python.
    source : object, optional
        Where the model came from, as data the runs never read: for the builders of
        :mod:`bderiv.symbolic` a :class:`bderiv.symbolic.SymbolicSource` (the kernels, the
        generated module, how they were built, the contacts); None for a model written
        by hand. Its ``param_names``, if it has them, name ``params``
        (:meth:`with_params`, :attr:`param_values`).

    Attributes
    ----------
    calls : bderiv.models.calls.ModelCalls
        The model's checked calls (every output checked, numerical Jacobians), what the
        runs and the analyses evaluate it through.

    Notes
    -----
    A model is a frozen description: its fields are read-only, and the algorithms are
    functions over it (:mod:`bderiv.analysis.flows`: :func:`~bderiv.analysis.flows.simulate`,
    :func:`~bderiv.analysis.flows.flow_bderivative`, ...; :mod:`bderiv.analysis.poincare`:
    :func:`~bderiv.analysis.poincare.return_map`,
    :func:`~bderiv.analysis.poincare.periodic_orbit`), which its methods call. Every
    output of the user functions is checked (shape and finiteness) by :attr:`calls`;
    errors say which function, which mask, the expected and the received shape.

    Compiled models: when ``field`` is a ``numba.njit`` dispatcher, every run is
    integrated by the compiled DOP853 (``method`` must be ``"DOP853"``); ``events`` and a
    given ``field_jacobian`` must then be compiled too, and so must a Poincare section
    (:meth:`return_map`, :meth:`periodic_orbit`). With ``event_jacobian`` compiled (or
    none, and ``events`` compiling for complex input) and ``reset`` compiled if given, the
    stops are decided in compiled code as well: a run is one compiled call. ``repr()``
    says how a model runs after its first run; the tutorial (section 12) says how to write
    one. A model pickles as its constructor's arguments (pickle takes module-level and
    numba functions, cloudpickle, which Dask uses, closures too); the copy starts afresh.

    A Jacobian not given is computed by the complex step where the function takes complex
    input (:func:`bderiv.complex_step_jacobian`: d calls, exact to rounding), held to a
    central difference at its first use for each mask (and event): a function that is
    not complex-analytic (``abs``, ``x.real``) fails that. Otherwise by central
    differences with Richardson extrapolation (:mod:`bderiv._support._numdiff`: steps from an
    eighth of each variable's magnitude, smaller and larger ones tried until each entry's
    error estimate is below 1e-7 of the entry), refused, naming the function, mask, entry
    and estimated error, where no step reaches that. These cost 10 to 100 calls of the
    function per variable; inside the variational equations of :meth:`flow_bderivative`
    that is one Jacobian per right-hand side evaluation, typically 90 % of the time: pass
    ``field_jacobian``. :attr:`numerical_jacobian_cost` says what they cost so far, the
    first one of each kind is logged (logger ``"bderiv"``, level INFO) with how it is
    computed, and a build (flow map, return map, orbit) of over 2 s spent mostly in them
    is reported at WARNING with their count, calls and time, once per model.

    Examples
    --------
    Two events of a constant field that both happen at t = 1 from the origin:

    >>> import numpy as np
    >>> from bderiv.analysis.system import HybridSystem
    >>> F = np.array([[1.0, 1.0], [1.0, 2.0], [2.0, 1.0], [1.5, 1.5]])
    >>> sys = HybridSystem(lambda x, mask: F[mask], lambda x: x - 1.0, n_events=2, dim=2)
    >>> sys.bderivative(np.ones(2))(np.array([-1.0, -2.0]))
    array([-1.75, -2.25])
    >>> traj = sys.simulate(np.zeros(2), 2.0, simultaneity_tol=1e-9)
    >>> [(round(g.time, 9), g.events) for g in traj.groups]
    [(1.0, (0, 1))]
    >>> D = sys.flow_bderivative(np.zeros(2), 2.0)
    >>> D(np.array([-1.0, -2.0])).round(9)
    array([-1.75, -2.25])
    """

    field: object
    events: object
    _: KW_ONLY
    n_events: int
    dim: int
    event_jacobian: object = None
    field_jacobian: object = None
    corner_field: object = None
    reset: object = None
    reset_jacobian: object = None
    check_jacobians: bool = True
    params: object = None
    use_compiled: bool = True
    reset_guard: object = None
    source: object = None
    calls: ModelCalls = dataclasses.field(init=False, compare=False)

    def __post_init__(self):
        for name, call in _FUNCTIONS.items():
            check_callable(getattr(self, name), name, call)
        if self.field is None or self.events is None:
            raise TypeError("field and events are required callables")
        if self.reset is None and self.reset_jacobian is not None:
            raise TypeError("reset_jacobian was given without reset; pass reset=f(x, mask, k)")
        checked = {"n_events": check_positive_int(self.n_events, "n_events"),
                   "dim": check_positive_int(self.dim, "dim"),
                   "check_jacobians": check_bool(self.check_jacobians, "check_jacobians"),
                   "use_compiled": check_bool(self.use_compiled, "use_compiled"),
                   "params": check_params(self.params)}
        for name, value in checked.items():
            object.__setattr__(self, name, value)
        object.__setattr__(self, "calls", ModelCalls(self))

    def __reduce__(self):
        """Pickled as its constructor's arguments, the checked calls made again where it
        is read (pickle takes module-level functions and numba's, cloudpickle closures)."""
        kwargs = {f.name: getattr(self, f.name) for f in dataclasses.fields(self) if f.init}
        return _made, (type(self), kwargs)

    def __repr__(self):
        calls = self.calls
        values = ", ".join(f"{k}={v:g}" for k, v in self.param_values.items())
        params = f", params: {values}" if values else ""
        head = f"{type(self).__name__}(n_events={self.n_events}, dim={self.dim}"
        reset_jac = ["reset_jacobian"] if self.reset is not None and \
            self.reset_jacobian is None else []
        if self.on_compiled_path:  # the compiled path says how it runs
            how = ("functions checked at the first use" if calls._compiled is None
                   else calls._compiled.describe())
            numerical = f", numerical: {reset_jac[0]}" if reset_jac else ""
            return f"{head}, compiled: {how}{numerical}{params})"
        missing = [name for name in ("event_jacobian", "field_jacobian")
                   if getattr(self, name) is None] + reset_jac
        numerical = f", numerical: {', '.join(missing)}" if missing else ""
        return f"{head}{numerical}{params})"

    @property
    def param_values(self) -> dict:
        """``{name: value}`` of ``params``, named by the ``source``'s ``param_names``
        (``{}`` when it names none)."""
        names = getattr(self.source, "param_names", ())
        return {} if self.params is None or not names else dict(
            zip(names, self.params.tolist(), strict=True))

    def with_params(self, values=None, /, **by_name) -> HybridSystem:
        """The same model with other values of its named parameters (:attr:`param_values`;
        the symbolic builders name them): the same functions, so no derivation and no
        compilation.

        Parameters
        ----------
        values : mapping, optional
            ``{name (or a sympy symbol of that name): value}``.
        **by_name
            ``name=value``.

        Returns
        -------
        HybridSystem
            A new model with the same functions and ``source`` (on the same path);
            parameters not named keep their value.

        Raises
        ------
        TypeError
            If a value is not a real number, or ``values`` not a mapping.
        ValueError
            If a name is not a parameter of the model (the parameters are listed), a
            value is not finite, or the model's ``source`` refuses the values (its
            ``check_params``: :func:`bderiv.symbolic.contact_system`'s restitution outside
            [0, 1], a mass matrix that is not positive definite).
        """
        if values is not None and not hasattr(values, "items"):
            raise TypeError(f"values must be a mapping parameter -> value, got "
                            f"{type(values).__name__}")
        names = tuple(self.param_values)
        index = {name: j for j, name in enumerate(names)}
        new = np.array(self.params if names else (), dtype=np.float64)
        for name, value in [*(values or {}).items(), *by_name.items()]:
            if str(name) not in index:
                raise ValueError(f"{name} is not a parameter of this model (its parameters: "
                                 f"{', '.join(names) or 'none'})")
            new[index[str(name)]] = check_value(value, f"the value of {name}")
        check = getattr(self.source, "check_params", None)
        if check is not None and names:
            check(new)
        return dataclasses.replace(self, params=new) if names else self

    def scipy_path(self) -> HybridSystem:
        """The same model integrated by :func:`scipy.integrate.solve_ivp` through the
        Python calls of its functions (``use_compiled=False``): for a Python section,
        another method than DOP853, or to compare the two integrators."""
        return dataclasses.replace(self, use_compiled=False)

    @property
    def compiled(self) -> CompiledModel | None:
        """The compiled path's model (:attr:`bderiv.models.calls.ModelCalls.compiled`):
        None on the scipy path and while the compiled integrator compiles."""
        return self.calls.compiled

    @property
    def on_compiled_path(self) -> bool:
        """Whether the runs go on the compiled integrator (the functions are numba
        dispatchers and ``use_compiled``)."""
        return self.calls.on_compiled_path

    @property
    def numerical_jacobian_cost(self) -> dict:
        """What the numerical Jacobians cost so far, per missing parameter: ``{name:
        (jacobians, calls, seconds)}``, how many were computed, the calls of the user's
        function they made and the seconds they took (passing the Jacobian saves nearly
        all of it; :attr:`bderiv.models.calls.ModelCalls.numerical_jacobian_cost`)."""
        return self.calls.numerical_jacobian_cost

    # the algorithms, functions over the model (bderiv.analysis.flows, .poincare)
    def bderivative(self, rho, *, tol=ON_SURFACE_TOL):
        """The B-derivative at a point where all n events are 0:
        :func:`bderiv.analysis.flows.bderivative`."""
        return flows.bderivative(self, rho, tol=tol)

    def simulate(self, x0, t_final, *, simultaneity_tol=None,
                 options=None, rtol=None, atol=None, method=None, max_step=None,
                 max_groups=MAX_GROUPS, section=None, t_eval=None):
        """Integrate from ``x0`` at time 0 to ``t_final`` with event detection:
        :func:`bderiv.analysis.flows.simulate`."""
        return flows.simulate(self, x0, t_final, simultaneity_tol=simultaneity_tol,
                              options=options, rtol=rtol, atol=atol, method=method,
                              max_step=max_step, max_groups=max_groups, section=section,
                              t_eval=t_eval)

    def simulate_many(self, X0, t_final, *, simultaneity_tol=None,
                      options=None, rtol=None, atol=None, method=None, max_step=None,
                      max_groups=MAX_GROUPS, section=None, progress=None, t_eval=None):
        """:meth:`simulate` from every start state of a batch:
        :func:`bderiv.analysis.flows.simulate_many`."""
        return flows.simulate_many(self, X0, t_final, simultaneity_tol=simultaneity_tol,
                                   options=options, rtol=rtol, atol=atol, method=method,
                                   max_step=max_step, max_groups=max_groups,
                                   section=section, progress=progress, t_eval=t_eval)

    def flow_bderivative(self, x0, t_final, *, simultaneity_tol=None,
                         options=None, rtol=None, atol=None, method=None, max_step=None):
        """The B-derivative of ``x -> Phi(t_final, x)`` at ``x0``:
        :func:`bderiv.analysis.flows.flow_bderivative`."""
        return flows.flow_bderivative(self, x0, t_final, simultaneity_tol=simultaneity_tol,
                                      options=options, rtol=rtol, atol=atol, method=method,
                                      max_step=max_step)

    def flow_map_along(self, traj):
        """The :class:`~bderiv.analysis.flowmap.FlowBDerivative` along a trajectory
        integrated with its variational equations:
        :func:`bderiv.analysis.assembly.flow_map_along`."""
        return flow_map_along(self, traj)

    def flow_fd(self, x0, t_final, V, eps, *, simultaneity_tol=None,
                options=None, rtol=None, atol=None, method=None, max_step=None):
        """Forward finite differences of the simulated flow:
        :func:`bderiv.analysis.flows.flow_fd`."""
        return flows.flow_fd(self, x0, t_final, V, eps, simultaneity_tol=simultaneity_tol,
                             options=options, rtol=rtol, atol=atol, method=method,
                             max_step=max_step)

    def return_map(self, x0, section, *, section_gradient=None, t_max=DEFAULT_T_MAX,
                   tol=ON_SURFACE_TOL, simultaneity_tol=None,
                   options=None, rtol=None, atol=None, method=None, max_step=None):
        """The B-derivative of the Poincare map of ``section(x) = 0`` at ``x0``:
        :func:`bderiv.analysis.poincare.return_map`."""
        return poincare.return_map(self, x0, section, section_gradient=section_gradient,
                                   t_max=t_max, tol=tol, simultaneity_tol=simultaneity_tol,
                                   options=options, rtol=rtol, atol=atol, method=method,
                                   max_step=max_step)

    def periodic_orbit(self, x_guess, section, period_guess=None, *, section_gradient=None,
                       tol=ORBIT_TOL, max_iter=ORBIT_MAX_ITER,
                       simultaneity_tol=None, options=None, cyclic=()):
        """A periodic orbit through ``section(x) = 0``, ``P(x) = x``:
        :func:`bderiv.analysis.poincare.periodic_orbit`."""
        return poincare.periodic_orbit(self, x_guess, section, period_guess,
                                       section_gradient=section_gradient, tol=tol,
                                       max_iter=max_iter, simultaneity_tol=simultaneity_tol,
                                       options=options, cyclic=cyclic)


def _made(cls, kwargs):
    """A pickled model made again (:meth:`HybridSystem.__reduce__`)."""
    return cls(**kwargs)
