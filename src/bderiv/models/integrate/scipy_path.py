"""One stretch of a region by :func:`scipy.integrate.solve_ivp`: the Python integrator.

:class:`ScipyStretches` integrates a model whose functions are Python callables (each
called through :class:`~bderiv.models.calls.ModelCalls`, checked) from a state to the final
time or the first crossing, with the variational equations when asked; its compiled twin is
:class:`bderiv.models.integrate.compiled_path.CompiledStretches`. Both return a stretch with
solve_ivp's
fields (``t``, ``y``, ``t_events``, ``status``, ``sol``) and leave everything that happens
at a stop to :func:`bderiv.models.integrate.run.run`.
"""

from __future__ import annotations

import sys
import warnings

import numpy as np

from ..._support._format import blown_up, format_region, note_time, step_underflow
from ..._support._validate import all_finite, check_record
from ..events.excursions import without_lost_crossings
from ..events.sides import on_side_at_start

#: evaluations of the right-hand side per accepted step of the explicit methods (DOP853:
#: 12, and 3 more for its dense output); an implicit method's steps are counted as one
#: evaluation each (an over-count: refused early rather than late)
EVALUATIONS_PER_STEP = {"DOP853": 15, "RK45": 6, "RK23": 3}
#: bytes solve_ivp keeps per accepted step besides 80 per component of the integrated
#: vector (its time and state, the dense output's coefficients and objects: measured on
#: DOP853 with dense output, 595 B at m = 2, 1.9 KiB at m = 20, 30 KiB at m = 420)
SOLVE_IVP_STEP_BYTES = 600


class _EventValues:
    """``events(x)`` cached on the last state (solve_ivp calls every event function)."""

    def __init__(self, system, section=None):
        self.system, self.key, self.value = system, None, None
        self.section = section

    def __call__(self, y):
        x = y[: self.system.dim]
        key = x.tobytes()  # the same bits: the same values (a NaN too, -0.0 apart from 0.0)
        if key != self.key:
            self.key, self.value = key, self.system.eval_events(x)
        return self.value

    def terminal_events(self, mask):
        """One terminal solve_ivp event per event, each looking for the crossing that
        flips its bit; then the section (upward) if any."""
        funcs = []
        for k in range(self.system.n_events):

            def ev(t, y, k=k):
                try:
                    return self(y)[k]
                except Exception as exc:  # the model's events: at this time, in this region
                    note_time(exc, t, format_region(mask, self.system.n_events))
                    raise

            ev.terminal = True
            ev.direction = -1 if mask >> k & 1 else 1
            funcs.append(ev)
        if self.section is not None:
            section, d = self.section, self.system.dim

            def sec(t, y):
                # the run starts on the section: read it as positive there, so that only
                # a return from below counts (solve_ivp counts 0 -> positive as a crossing)
                try:
                    return 1.0 if t == 0.0 else section(y[:d])
                except Exception as exc:
                    note_time(exc, t, format_region(mask, self.system.n_events))
                    raise

            sec.terminal = True
            sec.direction = 1
            funcs.append(sec)
        return funcs


class ScipyStretches:
    """The stretches of a run by solve_ivp: ``stretches(x, t, t_final, mask, options,
    variational) -> OdeResult``.

    Parameters
    ----------
    system : ModelCalls (``HybridSystem.calls``)
        Its checked evaluations are used.
    section : callable ``section(x) -> float``, optional
        Watched upward after the events (solve_ivp's event ``n``).
    watch : SimulationProgress, optional
        Told the time of each evaluation of the field (a progress bar; Ctrl-C is seen
        there).
    stops : StopCalls, optional
        The run's evaluations at the stops
        (:class:`bderiv.models.events.stopcalls.StopCalls`), for the search of crossings
        inside the steps; default ``system``.
    """

    def __init__(self, system, section=None, watch=None, stops=None):
        self.system, self.events = system, _EventValues(system, section)
        self.watch, self.stops = watch, system if stops is None else stops

    def __call__(self, x, t, t_final, mask, options, variational):
        """Integrate region ``mask`` from ``(t, x)`` until ``t_final``, an event or the
        section; the state and its (d, d) sensitivity (row-major) with ``variational``."""
        system, d = self.system, self.system.dim
        if variational:

            def rhs(_t, y):
                J = system.eval_field_jacobian(y[:d], mask)
                return np.concatenate((system.eval_field(y[:d], mask),
                                       (J @ y[d:].reshape(d, d)).ravel()))

            y0 = np.concatenate((x, np.eye(d).ravel()))
        else:

            def rhs(_t, y):
                return system.eval_field(y, mask)

            y0 = x
        funcs = on_side_at_start(self.events.terminal_events(mask), t, mask, system.n_events)
        pieces = []  # each integration's start and dense output (record.dense_state)

        from scipy.integrate import solve_ivp  # here: the compiled path never imports it

        def solve(start, y_start, stop):
            held = _HeldWarnings()
            counted = _Counted(rhs, y_start.size, options.method, mask, system.n_events, d,
                               start, held)
            field = counted if self.watch is None else self.watch.wrap(counted)
            with held:
                sol = solve_ivp(field, (start, stop), y_start, events=funcs, dense_output=True,
                                **options.solve_ivp_kwargs())
            if sol.status == -1:  # its one failure: the step below 10 ulp of t
                raise RuntimeError(step_underflow(format_region(mask, system.n_events),
                                                  sol.y[:d, -1], sol.t[-1]))
            # the end of the first step (beyond the stop when an event stopped it there)
            sol.first_step_end = float(sol.sol.interpolants[0].t)
            pieces.append((start, sol.sol))
            return sol

        # solve_ivp compares signs at step ends only: look inside the steps too
        sol = without_lost_crossings(self.stops, mask, options, solve, t, y0, t_final)
        sol.pieces = pieces
        return sol


class _Counted:
    """The right-hand side of one solve_ivp call, counting its evaluations: solve_ivp keeps
    every step (its time, its vector and its dense output), so the record it grows is held
    to what the process may still take (:func:`bderiv._support._validate.check_record`), its size
    estimated from the evaluations (``EVALUATIONS_PER_STEP`` of the method, at least one)
    and ``SOLVE_IVP_STEP_BYTES`` per step; checked each time it has doubled."""

    def __init__(self, rhs, m, method, mask, n, d, start, held):
        self.rhs, self.calls, self.next_check, self.d = rhs, 0, 1 << 12, d
        self.per_call = (SOLVE_IVP_STEP_BYTES + 80 * m) / EVALUATIONS_PER_STEP.get(method, 1)
        self.mask, self.n, self.start, self.held = mask, n, start, held

    def __call__(self, t, y):
        self.calls += 1
        if self.calls >= self.next_check:
            self.next_check *= 2
            held = int(self.calls * self.per_call)
            check_record(held, 2 * held,
                         f"solve_ivp's record of the stretch of "
                         f"{format_region(self.mask, self.n)} from t = "
                         f"{self.start!r} (every accepted step's state and dense output, "
                         f"about {self.calls} evaluations to t = {t!r})",
                         "pass a shorter t_final and go on from the run's x_final, or a "
                         "larger rtol and atol (fewer steps)")
        try:
            return self.rhs(t, y)
        except Exception as exc:
            region = format_region(self.mask, self.n)
            if not isinstance(exc, ValueError) or all_finite(y):
                note_time(exc, t, region)  # a model's function raised: at this time
                raise
            # at a state beyond float64: the run's, not the model's; scipy's warnings of
            # its overflow on the way are dropped (the user sees this error alone)
            self.held.blew_up = True
            raise ValueError(blown_up(region, y[:self.d], t)) from exc


class _HeldWarnings:
    """NumPy's floating-point warnings of scipy's own arithmetic in one solve_ivp call (an
    overflow in its dot products as the state nears the end of float64), held: dropped
    when the call ends in the blow-up error (``blew_up``, set by :class:`_Counted`: the
    user sees that error alone), else given when it ends, as NumPy would have given them
    (the same text, place and filters). Those of other code (the model's functions) are
    given at once, as NumPy gives them. NumPy's ``log`` mode brings them here
    (``np.errstate``: the thread's and context's own), for the kinds NumPy warns of, and
    only where no ``np.seterrcall`` handler is set (a user's own is left alone)."""

    def __init__(self):
        call, modes = np.geterrcall(), np.geterr()
        if isinstance(call, _HeldWarnings):  # a run inside a model's function: as outside
            self.kinds = call.kinds
        else:
            self.kinds = () if call is not None else tuple(
                k for k in ("divide", "over", "invalid") if modes[k] == "warn")
        self.held, self.blew_up, self._state = [], False, None

    def write(self, text):
        """NumPy's ``log`` of a floating-point error, from the frame that made it."""
        frame = sys._getframe(1)
        message = text.strip().removeprefix("Warning: ")
        caller = frame  # scipy's, or numpy's code called by scipy's
        while caller is not None and caller.f_globals.get("__name__", "").startswith("numpy"):
            caller = caller.f_back
        if caller is None or not caller.f_globals.get("__name__", "").startswith(
                "scipy.integrate"):
            warnings.warn(message, RuntimeWarning, stacklevel=2)
            return
        self.held.append((message, frame.f_code.co_filename, frame.f_lineno, frame.f_globals))

    def __enter__(self):
        if self.kinds:
            self._state = np.errstate(**dict.fromkeys(self.kinds, "log"), call=self)
            self._state.__enter__()
        return self

    def __exit__(self, kind, exc, tb):
        if self._state is not None:
            self._state.__exit__(kind, exc, tb)
        if self.blew_up:
            return
        for message, filename, lineno, module_globals in self.held:
            try:
                warnings.warn_explicit(message, RuntimeWarning, filename, lineno,
                                       module_globals.get("__name__"),
                                       module_globals.setdefault("__warningregistry__", {}),
                                       module_globals)
            except Warning:  # an error by the filters: unless the call raised its own
                if exc is None:
                    raise
