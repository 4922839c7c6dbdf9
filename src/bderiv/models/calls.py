"""Checked calls of a user's model functions: outputs validated, numerical Jacobians.

:class:`ModelCalls` evaluates a model's functions checked (``HybridSystem.calls``), by
the wrappers and checks of :mod:`.user_functions`; :class:`~bderiv.models.section.Section`
does the same for a Poincare section.
"""

from __future__ import annotations

import contextlib
import logging
import time
from functools import partial

import numpy as np

from .. import _limits
from .._limits import RESET_TOL, RESET_TOL_NUMERICAL
from .._support._format import format_mask
from .._support._validate import check_mask, check_masks, check_memory, check_state
from .compiled import (
    EVENT_JAC_COMPLEX_STEP,
    JACOBIAN_MODES,
    CompiledModel,
    check_compiled_functions,
    is_compiled,
    tell_python_stops,
)
from .numerical_jacobians import NumericalJacobians, matches_near
from .python_first import NotAsCompiled, PythonTime, starts_in_python
from .readiness import ready_now
from .user_functions import (
    _appending,
    _contiguous_args,
    check_given_jacobian,
    check_mask_width,
    check_output,
    check_rows,
    compiled_or_refused,
    noted_functions,
)

_log = logging.getLogger("bderiv")

class ModelCalls:
    """A model's user functions, evaluated with every output checked.

    Built from a model's description (:class:`~bderiv.analysis.system.HybridSystem`, which
    documents and checks its fields), held by it as ``model.calls``: the runs and the
    analyses evaluate the model through it. Every output is checked (shape and
    finiteness); errors say which function, which mask, the expected and the received
    shape. A given Jacobian is compared with a central difference the first time it is
    used for each mask (and event), unless ``check_jacobians`` is False; a missing one is
    computed numerically, its cost counted in :attr:`numerical_jacobian_cost`. With
    ``params`` the functions are called on the state followed by the parameter values;
    every ``eval_*`` method takes the state alone.
    """

    def __init__(self, model):
        params = self._params = model.params
        self.n_events, self.dim = model.n_events, model.dim
        self.check_jacobians = model.check_jacobians
        check_mask_width(model.n_events, **{name: getattr(model, name) for name in (
            "field", "field_jacobian", "reset", "reset_jacobian", "reset_guard")})
        # the compiled path's functions (None: the scipy path); it decides the use of the
        # event Jacobian and the reset (a guarded reset is the Python loop's)
        self._compiled_functions = (compiled_or_refused(model.field, model.events,
                                                        model.field_jacobian)
                                    if model.use_compiled else None)
        self._given_event_jacobian = model.event_jacobian
        self._functions = (model.field, model.events, model.reset, model.event_jacobian)
        self._given_reset = model.reset if model.reset_guard is None else self.eval_reset
        self._compiled = None
        functions = noted_functions(model)  # an exception of a Python one says where
        self._dispatched = tuple(_appending(_contiguous_args(f), params) for f in functions)
        # a new model of numba functions starts on their Python code (PYTHON_FIRST_SECONDS,
        # shared by the models of one field)
        self._on_python = self._compiled_functions is not None and \
            starts_in_python(functions)
        self._time = PythonTime(model.field if self._on_python else None)
        self._use(tuple(_appending(self._budgeted(f), params) for f in functions)
                  if self._on_python else self._dispatched)
        self._checked = set()  # (name, mask, k) of the given Jacobians compared so far
        self._numerical = NumericalJacobians()  # the Jacobians not given: how, and cost

    def _use(self, wrappers) -> None:
        """Evaluate the model by ``wrappers`` (its eight functions, ``__init__``'s order)."""
        self._field, self._events, self._event_jac, self._field_jac, self._corner_field, \
            self._reset, self._reset_jac, self._guard = wrappers

    def _budgeted(self, f):
        """A numba dispatcher ``f`` on its Python code (:meth:`PythonTime.budgeted`; what it
        raises outside a run decided compiled, from then on); anything else as it is."""
        if not is_compiled(f):
            return f
        compiled = _contiguous_args(f)

        def outside(exc, args):
            self.compile_from_now(exc)
            self.check_compiled_types()
            return compiled(*args)

        return self._time.budgeted(f.py_func, outside)

    @property
    def python_first(self) -> bool:
        """Whether the model's runs go on its numba functions' Python code now: a new model
        (:func:`starts_in_python`) until its runs have taken
        :data:`bderiv._limits.PYTHON_FIRST_SECONDS`, or until its field is compiled
        elsewhere (another model of the same functions, a parameter sweep's)."""
        if self._on_python and (self._compiled_functions[0].signatures or
                                self._time.left[0] <= 0):
            self._to_dispatchers("compiled meanwhile: by a direct call, or for another "
                                 "model of them" if self._time.left[0] > 0 else "their time on "
                                 "Python code spent, by this model's runs or another's")
        return self._on_python

    @contextlib.contextmanager
    def python_run(self):
        """A run on the model's Python code (:meth:`PythonTime.run`); compiled after it
        when it spent the last of the field's time (unless it ends by an exception: the
        caller decides then)."""
        if self._time.left[0] == _limits.PYTHON_FIRST_SECONDS:
            _log.info("bderiv: a new model of numba functions: its runs go on their Python "
                      "code for %g s, then compiled (BDERIV_INTEGRATOR=compiled compiles "
                      "them at the first use)", self._time.left[0])
        with self._time.run() as outermost:
            yield
        if outermost and self._time.left[0] <= 0:
            self.compile_from_now()

    def check_compiled_types(self) -> None:
        """Once it evaluates its numba functions compiled (on scipy too, while the integrator
        compiles): their types checked as the compiled path checks them."""
        if self._compiled_functions is not None and not self._on_python:
            check_compiled_functions(*self._compiled_functions)

    def compile_from_now(self, cause=None) -> None:
        """Evaluate the model by its numba functions from now on, and run it on the compiled
        integrator (``cause``: what their Python code raised, logged)."""
        # NotAsCompiled: the compiled call names the type it takes, no warning needed
        if cause is not None and not isinstance(cause, NotAsCompiled):
            _log.warning("bderiv: the Python code of the model's numba functions raised "
                         "%s: %s; the run is made again on them compiled, as every run from "
                         "now on (numba compiles code that Python refuses, but it also skips "
                         "checks that Python makes, such as array bounds: if the function is "
                         "wrong there, fix it)", type(cause).__name__, cause)
        self._to_dispatchers(
            str(cause) if isinstance(cause, NotAsCompiled)
            else f"their Python code raised {type(cause).__name__}" if cause is not None
            else f"its runs on their Python code took {_limits.PYTHON_FIRST_SECONDS:g} s"
            if self._time.left[0] <= 0 else "asked")

    def _to_dispatchers(self, reason: str) -> None:
        """Leave the Python code for the numba functions (``reason`` logged), once."""
        if not self._on_python:
            return
        _log.info("bderiv: the model's numba functions are compiled from now on (%s)", reason)
        self._on_python = False
        self._use(self._dispatched)
        self._numerical.forget()  # decided on the Python code: decided again compiled

    @property
    def on_compiled_path(self) -> bool:
        """Whether the model's functions are numba dispatchers: its runs go on the compiled
        integrator (on scipy while that compiles: :attr:`compiled`)."""
        return self._compiled_functions is not None

    @property
    def compiled(self) -> CompiledModel | None:
        """The compiled path's model when ``field`` is a numba dispatcher (its functions
        checked and compiled for the integrator's types at the first use; the time that
        took is logged once, logger ``"bderiv"``, level INFO), else None; None also while
        the compiled integrator is compiled in a background process
        (:mod:`bderiv.models.readiness`: the model's runs then go on scipy)."""
        if self._compiled is None and self._compiled_functions is not None and ready_now() \
                and not self._on_python:
            start = time.perf_counter()
            field, events, jac = self._compiled_functions
            self._compiled = CompiledModel(field, events, jac, n_events=self.n_events,
                                           dim=self.dim, params=self._params,
                                           event_jacobian=self._given_event_jacobian,
                                           reset=self._given_reset)
            _log.info("compiled the model's functions for the compiled integrator in %.2f s "
                      "(once per model; %s)", time.perf_counter() - start,
                      self._compiled.describe())
            if self._given_reset != self.eval_reset:  # (a guarded reset's stops: by design)
                tell_python_stops(self._compiled, self._functions)
        return self._compiled

    def check_compiled_jacobian(self, x, mask) -> None:
        """Before the compiled integrator carries the sensitivity in region ``mask``: the
        first time for each mask, compare its ``J`` at ``x`` with a central difference of
        the field (:func:`check_given_jacobian`): a given ``field_jacobian`` unless
        ``check_jacobians`` is False, and always a complex-step one (a field that compiles for
        complex input but is not complex-analytic, ``np.abs`` or ``x.real``, gives a wrong
        complex step: the model then uses central differences)."""
        model, key = self.compiled, ("compiled field_jacobian", int(mask))
        mode = JACOBIAN_MODES[model.jac_mode]
        given = mode == "given"
        if key in self._checked or mode == "central differences" or \
                (given and not self.check_jacobians):
            return
        x = check_state(x, self.dim)
        what = f"field(x, mask={self._mask_name(mask)})"
        field = partial(self.eval_field, mask=mask)
        try:
            check_given_jacobian(field, x, model.jacobian(x, mask), what, "field_jacobian")
            if not given and not matches_near(field, partial(model.jacobian, mask=mask), x):
                raise ValueError("the complex step does not match beside x")
        except ValueError:
            if given:
                raise
            _log.info("the complex-step Jacobian of %s does not match its central "
                      "differences (the field is not complex-analytic): central differences "
                      "are used", what)
            model.use_central_differences()
        self._checked.add(key)

    def checked_compiled_jacobians(self):
        """``(all, masks)``: whether the compiled ``J`` needs no check (central differences,
        or given with ``check_jacobians`` False), else where it is checked (int64 masks)."""
        mode = JACOBIAN_MODES[self.compiled.jac_mode]
        if mode == "central differences" or (mode == "given" and not self.check_jacobians):
            return True, np.empty(0, dtype=np.int64)
        masks = [key[1] for key in self._checked if key[0] == "compiled field_jacobian"]
        return False, np.array(masks, dtype=np.int64)

    def event_jacobian_checked(self) -> bool:
        """Whether the event Jacobian needs no more check: compared with a central difference
        once already, or given with ``check_jacobians`` False (a complex step: compared)."""
        given_unchecked = self._event_jac is not None and not self.check_jacobians
        return given_unchecked or ("event_jacobian",) in self._checked

    def _mask_name(self, mask) -> str:
        return format_mask(mask, self.n_events)

    def eval_field(self, x, mask):
        """The checked field of region ``mask`` at ``x``: (d,). Each function gets a copy."""
        return check_output(self._field(np.array(x), mask), (self.dim,),
                            lambda: f"field(x, mask={mask})")

    def eval_events(self, x):
        """The checked event values at ``x``: shape (n,)."""
        return check_output(self._events(np.array(x)), (self.n_events,), "events(x)")

    def _jacobian(self, given, key, fun, raw, x, shape, what, jac_name):
        """A Jacobian of ``fun`` at ``x``: the ``given`` one's output (checked the first
        time for ``key``, ``key[1:]`` its mask and event), else a numerical one (cost
        counted): the complex step of ``raw`` (the user's function, unchecked) where it
        matched a central difference of ``fun`` the first time for ``key``, else central
        differences. ``what`` gives the call's name for a message (formatted only then)."""
        if given is not None:
            J = check_output(given(), shape, lambda: jac_name + "(x" + "".join(
                f", {a}={b}" for a, b in zip(("mask", "k"), key[1:], strict=False)) + ")")
            if self.check_jacobians and key not in self._checked:
                check_given_jacobian(fun, x, J, what(), jac_name)
                self._checked.add(key)
            return J
        return self._numerical.jacobian(key, fun, raw, x, shape, what, jac_name)

    def numerical_jacobian_watch(self, what):
        """Around a build (``what``: the method's name): :meth:`NumericalJacobians.watch`."""
        return self._numerical.watch(what, python=self._compiled_functions is None)

    @property
    def numerical_jacobian_cost(self) -> dict:
        """What the numerical Jacobians cost so far, per missing parameter.

        Returns
        -------
        dict
            ``{"field_jacobian": (jacobians, calls, seconds), ...}``: the numerical Jacobians
            computed, the calls of the user's function they made (the checks that chose
            the method included) and their time, which passing the Jacobian saves.
        """
        return self._numerical.cost

    def eval_event_jacobian(self, x):
        """Jacobian of the events at ``x``, shape (n, d) (analytic if given, else numerical)."""
        return self.event_jacobian_at(check_state(x, self.dim))

    def event_jacobian_at(self, x):
        """:meth:`eval_event_jacobian` at a state known to be one (float64, shape (d,),
        finite: the integrator's stop), not checked again; the function gets a copy."""
        x = np.array(x, dtype=np.float64)
        if self._event_jac is None and self.compiled is not None and \
                self.compiled.event_jac_mode == EVENT_JAC_COMPLEX_STEP:
            return self._complex_step_event_jacobian(x)
        given = None if self._event_jac is None else (lambda: self._event_jac(np.array(x)))
        return self._jacobian(given, ("event_jacobian",), self.eval_events, self._events, x,
                              (self.n_events, self.dim), lambda: "events(x)", "event_jacobian")

    def _complex_step_event_jacobian(self, x):
        """The compiled complex step of ``events`` at ``x``: compared with a central
        difference the first time; events that are not complex-analytic (``abs``, a
        comparison of x) fail that, and the numerical Jacobian is used from then on."""
        J = self.compiled.event_jacobian_at(x)
        key = ("event_jacobian",)
        if key not in self._checked:
            try:
                check_given_jacobian(self.eval_events, x, J, "events(x)", "event_jacobian")
                if not matches_near(self.eval_events, self.compiled.event_jacobian_at, x):
                    raise ValueError("the complex step does not match beside x")
            except ValueError:
                self.compiled.use_python_event_jacobian()
                tell_python_stops(self.compiled, self._functions)
                return self.event_jacobian_at(x)
            self._checked.add(key)
        return J

    def eval_field_jacobian(self, x, mask):
        """Jacobian of ``field(., mask)`` at ``x``, shape (d, d)."""
        x = check_state(x, self.dim)
        mask = check_mask(mask, self.n_events)
        given = None if self._field_jac is None else (
            lambda: self._field_jac(np.array(x), mask))
        return self._jacobian(given, ("field_jacobian", mask),
                              lambda y: self.eval_field(y, mask),
                              lambda y: self._field(y, mask), x, (self.dim, self.dim),
                              lambda: f"field(x, mask={self._mask_name(mask)})",
                              "field_jacobian")

    @property
    def has_resets(self) -> bool:
        """Whether the state jumps at the events (a ``reset`` was given)."""
        return self._reset is not None

    def eval_reset(self, x, mask, k):
        """The checked state after crossing event k from region ``mask`` at ``x``: (d,)
        (``x`` itself without resets). The reset gets a copy: one editing its argument
        (``x[1] *= -e; return x``) changed the library's state, silently."""
        if self._reset is None:
            return x
        if self._guard is not None:  # (its own checks, on x as the run has it)
            self._guard(np.array(x), mask, k)
        return check_output(self._reset(np.array(x), mask, k), (self.dim,),
                            lambda: f"reset(x, mask={mask}, k={k})")

    def eval_reset_jacobian(self, x, mask, k):
        """Jacobian of ``reset(., mask, k)`` at ``x``, shape (d, d) (analytic if given)."""
        x = check_state(x, self.dim)
        given = self._reset_jac and (lambda: self._reset_jac(np.array(x), mask, k))
        return self._jacobian(given, ("reset_jacobian", int(mask), int(k)),
                              lambda y: self.eval_reset(y, mask, k),
                              lambda y: self._reset(np.array(y), mask, k), x, (self.dim,) * 2,
                              lambda: f"reset(x, mask={self._mask_name(mask)}, k={k})",
                              "reset_jacobian")

    @property
    def reset_tol(self) -> float:
        """Relative tolerance of the reset checks: looser with numerical Jacobians."""
        exact = self._reset_jac is not None and self._event_jac is not None
        return RESET_TOL if exact else RESET_TOL_NUMERICAL

    def sample_corners(self, x, masks=None):
        """Region fields ``F`` (m, d) at ``x`` (d,) for ``masks`` (m,), integers (default
        all 2**n, F (2**n, d)): ``F[i] = field(x, masks[i])``, from ``corner_field`` when
        given."""
        n = self.n_events
        if masks is None:
            check_memory((1 << n) * self.dim * 8, None, f"the fields of all 2**{n} regions "
                         f"(pass masks=, the regions to sample)")
            masks = np.arange(1 << n, dtype=np.int64)
        else:
            masks = check_masks(masks, n)
        return self.corners_at(check_state(x, self.dim), masks)

    def corners_at(self, x, masks):
        """:meth:`sample_corners` at a state known to be one (float64, shape (d,), finite:
        an event point of a run, a checked rho) for masks (m,) (int64, or Python ints beyond
        63 events), not checked again."""
        n, d = self.n_events, self.dim
        if self._corner_field is not None and (masks.size > 16 or masks.size == 1 << n):
            table = check_output(self._corner_field(np.array(x)), (1 << n, d),
                                 "corner_field(x)")
            if ("corner_field",) not in self._checked:  # its rows are the field's, once
                check_rows(table, masks, partial(self.eval_field, x), self._mask_name)
                self._checked.add(("corner_field",))
            return np.ascontiguousarray(table[masks])
        if self.compiled is not None:  # one compiled loop over the masks
            return self.compiled.fields(x, masks)
        out = np.empty((masks.size, d))
        for i, m in enumerate(masks.tolist()):
            out[i] = self.eval_field(x, m)
        return out

    def start_mask(self, x0):
        """Region mask of a start point from the signs of its event values (a
        ``ValueError`` when ``x0`` lies exactly on an event surface)."""
        x0 = check_state(x0, self.dim, "x0")
        h = self.eval_events(x0)
        values = h.tolist()
        on = [k for k, v in enumerate(values) if v == 0]
        if on:
            raise ValueError(
                f"x0 lies on the surface of event(s) {on} (events(x0) = {h}); the "
                f"region is ambiguous there: start slightly before or after the event"
            )
        return sum(1 << k for k, v in enumerate(values) if v > 0)
