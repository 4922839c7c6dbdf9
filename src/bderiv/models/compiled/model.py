"""A model's compiled functions, checked and bound once, and one stretch of one region.

:class:`CompiledModel` is what the model side (:mod:`bderiv.models.integrate.run`) integrates with:
the user's dispatchers checked (they compile for the integrator's types and return its
array types), the way ``J`` is had (given, complex step, central differences; see
:mod:`._rhs`), and the struct the driver takes; :meth:`CompiledModel.stretch` runs the
driver from a state to ``t_final`` or the first crossing and turns a failed run into an
error that names the function, the region and the state.
"""

from __future__ import annotations

import time
from typing import NamedTuple

import numpy as np

from ..._support._format import format_region, format_state
from ..._support._validate import RecordTooLarge
from ._checks import (
    check_compiled_functions,
    compiles_as,
    compiles_for_complex,
    is_compiled,
    raise_failed_run,
    raise_overflowed_run,
)
from ._dop853 import dense_rows
from ._integrate import EVENT, FINISHED, drive_stretch
from ._model import (
    COMPLEX_EVENTS_SIGNATURE,
    EVENT_JACOBIAN_SIGNATURE,
    RESET_SIGNATURE,
    bound_model,
    no_complex_events,
    no_event_jacobian,
    no_reset,
)
from ._notice import notice_compilation
from ._rhs import (
    JAC_CENTRAL,
    JAC_COMPLEX_STEP,
    JAC_GIVEN,
    OK,
    events_and_field,
    events_rows,
    field_rows,
    jacobian,
    no_complex_field,
    no_jacobian,
    no_section,
)
from ._run import run_stretches
from ._slices import Cancelled, Driven, _interrupted, drive, measured, slice_budget
from ._stops import EVENT_JAC_COMPLEX_STEP, EVENT_JAC_GIVEN, EVENT_JAC_NONE, event_jacobian
from .stretch import MAX_EVENTS

#: the warning when the driver or the compiled run compiles (their first use on a machine)
COMPILE_NOTICE = notice_compilation(drive_stretch, run_stretches)
#: no times to sample (a run without ``t_eval``)
_NO_TIMES = np.empty(0)
#: how ``J`` is had, by the code of :mod:`._rhs`
JACOBIAN_MODES = {JAC_GIVEN: "given", JAC_COMPLEX_STEP: "complex step",
                  JAC_CENTRAL: "central differences"}


class CompiledRun(NamedTuple):
    """What :meth:`CompiledModel.run_stretches` hands back: the compiled run's tuple
    (:func:`._run.run_stretches`, which documents each entry), named at the Python
    boundary."""

    code: int
    returned: bool
    t: float
    mask: int
    state: np.ndarray
    T: np.ndarray
    X: np.ndarray
    M: np.ndarray
    L: np.ndarray
    group_t: np.ndarray
    group_masks: np.ndarray
    group_x: np.ndarray
    group_J: np.ndarray
    S: np.ndarray
    SM: np.ndarray
    steps: int


class CompiledModel:
    """A model's ``field``, ``events`` (and ``field_jacobian``) as checked dispatchers.

    Parameters
    ----------
    field, events, field_jacobian : numba dispatchers
        ``field(x, mask) -> (d,)``, ``events(x) -> (n,)``, ``field_jacobian(x, mask) ->
        (d, d)`` (optional: complex step where ``field`` compiles for complex input, else
        central differences).
    n_events, dim : int
    event_jacobian : callable, optional
        The model's ``event_jacobian(x) -> (n, d)``: a dispatcher compiled for
        ``float64[::1]`` returning a C-contiguous float64 array is called in compiled
        code; none given, the Jacobian is had by complex step where ``events`` compiles
        for complex input (:meth:`event_jacobian_at`). Either way the run's plain stops
        are decided in compiled code too (:meth:`run_stretches`); otherwise (a Python
        ``event_jacobian``, or events that are not complex-analytic) every stop is the
        Python loop's (``event_jac_mode`` ``EVENT_JAC_NONE``).
    reset : callable, optional
        The model's ``reset(x, mask, k) -> (d,)``: a dispatcher compiled for
        ``(float64[::1], int64, int64)`` returning a C-contiguous float64 array is called
        in compiled code at the compiled run's stops (``self.reset``); a Python one
        leaves every stop to the Python loop (``has_python_reset``).
    params : array_like, shape (m,), optional
        Parameter values: the functions then take ``x`` of shape (d + m,), the state
        followed by ``params`` (the section takes the state alone), so that a model
        whose parameters change (``bderiv.symbolic``'s ``with_params``) is another
        ``CompiledModel`` over the same compiled functions, not another compilation.
        ``field_jacobian`` is the Jacobian by the state, (d, d).

    Raises
    ------
    TypeError
        A function that is not a dispatcher or does not compile for the integrator's types
        (:func:`._checks.check_compiled`).
    ValueError
        More than ``MAX_EVENTS`` events (the region mask is an int64).
    """

    def __init__(self, field, events, field_jacobian=None, *, n_events, dim, params=None,
                 event_jacobian=None, reset=None):
        if n_events > MAX_EVENTS:
            raise ValueError(f"the compiled integrator takes at most {MAX_EVENTS} events (one "
                             f"bit each of an int64 region mask), got n_events={n_events}")
        check_compiled_functions(field, events, field_jacobian)
        self.named = {"field": field, "events": events}
        if field_jacobian is not None:
            self.named["field_jacobian"] = field_jacobian
        if field_jacobian is not None:
            self.jac_mode = JAC_GIVEN
        elif compiles_for_complex(field):
            self.jac_mode = JAC_COMPLEX_STEP
        else:
            self.jac_mode = JAC_CENTRAL
        self.n_events, self.dim = n_events, dim
        self.event_jacobian = self.cevents = None
        self.event_jacobian_given = event_jacobian is not None
        if event_jacobian is None:
            self.cevents = events if compiles_as(events, COMPLEX_EVENTS_SIGNATURE) else None
        elif is_compiled(event_jacobian) and compiles_as(event_jacobian,
                                                         EVENT_JACOBIAN_SIGNATURE):
            self.event_jacobian = event_jacobian
        self.reset = (reset if is_compiled(reset) and compiles_as(reset, RESET_SIGNATURE)
                      else None)
        self.has_python_reset = reset is not None and self.reset is None
        self.event_jac_mode = (EVENT_JAC_GIVEN if self.event_jacobian is not None else
                               EVENT_JAC_COMPLEX_STEP if self.cevents is not None else
                               EVENT_JAC_NONE)
        self.params = None if params is None else np.array(params, dtype=np.float64).ravel()
        self._structs = {}
        self._atol = {}  # (length, atol) -> the driver's atol array

    def describe(self) -> str:
        """How the model runs on the compiled path, in words: how ``J`` and the event
        Jacobian are had, and whether the stops are decided in compiled code (and why not)."""
        event_jac = {EVENT_JAC_GIVEN: "given", EVENT_JAC_COMPLEX_STEP: "complex step",
                     EVENT_JAC_NONE: "Python"}[self.event_jac_mode]
        if self.event_jac_mode == EVENT_JAC_NONE:
            stops = ("in Python (event_jacobian is not compiled for float64[::1] -> "
                     "float64[:, ::1], or events do not compile for complex input)")
        elif self.has_python_reset:
            stops = ("in Python (the reset is a Python function: not compiled for "
                     "(float64[::1], int64, int64) -> float64[::1], or checked by the model's "
                     "reset_guard, a Python function)")
        else:
            stops = "compiled"
        return (f"field_jacobian: {JACOBIAN_MODES[self.jac_mode]}; event_jacobian: "
                f"{event_jac}; stops: {stops}")

    def struct(self, section=None):
        """The driver's struct of the functions (with ``section``, a checked dispatcher)
        and the parameters."""
        key = (section, self.jac_mode)
        if key not in self._structs:
            f = self.named
            self._structs[key] = bound_model(
                f["field"], f.get("field_jacobian", no_jacobian), f["events"],
                f["field"] if self.jac_mode == JAC_COMPLEX_STEP else no_complex_field,
                no_section if section is None else section, self.params,
                self.event_jacobian or no_event_jacobian, self.cevents or no_complex_events,
                self.reset or no_reset)
        return self._structs[key]

    def use_central_differences(self) -> None:
        """Compute ``J`` by central differences from now on (complex step found wrong)."""
        self.jac_mode = JAC_CENTRAL

    def jacobian(self, x, mask) -> np.ndarray:
        """The ``J`` the integrator uses at ``x`` in region ``mask``: shape (d, d)."""
        d = self.dim
        J = np.empty((d, d))
        x = np.array(x, dtype=np.float64)
        status = jacobian(self.struct(), self.jac_mode, x.copy(), int(mask), d, J)
        if status != OK:
            raise_failed_run(status, self.named, x, None, mask, d, self.n_events,
                             self.jac_mode, self.params)
        return J

    def event_jacobian_at(self, x) -> np.ndarray:
        """The event Jacobian the compiled run uses at ``x`` (d,): shape (n, d) (not with
        ``EVENT_JAC_NONE``). A failed check is a ValueError naming what came."""
        x = np.ascontiguousarray(x, dtype=np.float64)
        ok, J = event_jacobian(self.struct(), self.event_jac_mode, x.copy(), self.n_events,
                               self.dim)
        if not ok:
            how = ("event_jacobian(x)" if self.event_jac_mode == EVENT_JAC_GIVEN else
                   "the complex step of events(x)")
            shape = (self.n_events, self.dim)
            what = "a non-finite entry" if J.shape == shape else f"shape {J.shape}"
            raise ValueError(f"{how} must give a finite array of shape {shape}, got {what} at "
                             f"x = {format_state(x)}")
        return J

    def use_python_event_jacobian(self) -> None:
        """Leave the event Jacobian to the Python side from now on (its complex step was
        found wrong: events that are not complex-analytic)."""
        self.cevents = None
        self.event_jac_mode = EVENT_JAC_NONE

    def events_rows(self, X) -> np.ndarray:
        """``events`` at every row of ``X`` (m, d): shape (m, n), checked."""
        X = np.ascontiguousarray(X, dtype=np.float64)
        G = np.empty((X.shape[0], self.n_events))
        bad = np.zeros(self.dim)
        status = events_rows(self.struct(), X, self.n_events, G, bad)
        if status != OK:
            raise_failed_run(status, self.named, bad, None, 0, self.dim, self.n_events,
                             params=self.params)
        return G

    def events_and_field(self, x, mask) -> tuple[np.ndarray, np.ndarray]:
        """``events(x)`` (n,) and ``field(x, mask)`` (d,) in one compiled call, checked."""
        x = np.ascontiguousarray(x, dtype=np.float64)
        h, F = np.empty(self.n_events), np.empty(self.dim)
        status = events_and_field(self.struct(), x, int(mask), self.n_events, self.dim, h, F)
        if status != OK:
            raise_failed_run(status, self.named, x, None, mask, self.dim, self.n_events,
                             params=self.params)
        return h, F

    def fields(self, x, masks) -> np.ndarray:
        """``field(x, mask)`` for every mask of ``masks`` (m,): shape (m, d), checked."""
        x = np.ascontiguousarray(x, dtype=np.float64)
        masks = np.ascontiguousarray(masks, dtype=np.int64)
        out = np.empty((masks.size, self.dim))
        status, i = field_rows(self.struct(), x, masks, self.dim, out)
        if status != OK:
            raise_failed_run(status, self.named, x, None, int(masks[i]), self.dim,
                             self.n_events, params=self.params)
        return out

    def stretch(self, y0, t0, t_final, mask, *, rtol, atol, max_step, variational,
                section=None, forced=False, on_side=False, dense=True, watch=None) -> Driven:
        """Integrate region ``mask`` from ``(t0, y0)`` to ``t_final`` or the first crossing.

        Parameters
        ----------
        y0 : ndarray, shape (d,) or (d + d * d,)
            The state, and with ``variational`` the sensitivity (row-major) after it.
        rtol, atol : float
            Tolerances (``atol`` of every state component; the sensitivity's rows take
            their state component's).
        section : numba dispatcher, optional
            ``section(x) -> float``: watched upward after the events (event ``n``).
        forced : bool
            The section reads 1 at ``t0`` (a run that starts on it).
        on_side : bool
            An event at 0 at ``t0`` reads on the side its bit of ``mask`` says (a run's
            stretch: :func:`bderiv.models.events.sides.on_side_at_start`).
        dense : bool
            Record the state's dense output of every step.
        watch : callable, optional
            ``watch(t)`` with the time reached after each slice of steps (the run's bar:
            :class:`~bderiv._support._progress.SimulationProgress`).

        Returns
        -------
        Driven
            Status ``FINISHED`` or ``EVENT``.
        """
        d, n = self.dim, self.n_events
        m = d * (d + 1) if variational else d
        y0 = np.ascontiguousarray(y0, dtype=np.float64)
        watched = n + (section is not None)
        atols = self._atols(m, atol)
        try:
            out = drive(self.struct(section), self.jac_mode, variational, section is not None,
                        watched, int(mask), d, float(t0), y0, float(t_final), float(rtol),
                        atols, float(max_step), 0.0, n if forced else -1, bool(on_side),
                        dense, watch)
        except (RecordTooLarge, Cancelled):  # its record refused by name; its batch stopped
            raise
        except MemoryError as exc:  # an allocation of the driver's record failed
            raise RecordTooLarge(
                f"the record of the stretch of {format_region(mask, n)} "
                f"from t = {t0!r} (every accepted step's state and dense "
                f"output) did not fit in memory: pass a shorter t_final and go on from the "
                f"run's x_final, or a larger rtol and atol (fewer steps)"
            ) from exc
        except ArithmeticError as exc:  # the driver's own: the model's are status codes
            raise_overflowed_run(exc, y0[:d], t0, mask, n,
                                 lambda: self.events_and_field(y0[:d], mask)[1])
        except Exception as exc:  # raised inside a user function: say where
            raise ValueError(
                f"a compiled function of the model raised {type(exc).__name__}: {exc}; while "
                f"integrating {format_region(mask, n)} from "
                f"t = {t0!r}, x = {format_state(y0[:d])}"
            ) from exc
        if out.status not in (FINISHED, EVENT):
            named = dict(self.named, section=section)
            raise_failed_run(out.status, named, out.bad, out.t_bad, mask, d, n, self.jac_mode,
                             self.params)
        return out


    def run_stretches(self, t, x, mask, scale, err, t_final, *, rtol, atol, max_step,
                      simultaneity_tol, variational, all_checked, checked, groups_left,
                      section=None, times=_NO_TIMES, taken=0):
        """The run's stretches from ``(t, x)`` in region ``mask`` while their stops are plain
        (:func:`._run.run_stretches`: its tuple as a :class:`CompiledRun`, ``code``
        ``ENDED`` or ``HANDOFF``),
        for about ``SLICE_SECONDS`` of steps; None when a user function raised (the Python
        loop takes the stretch and says where). Needs ``event_jacobian``.

        ``scale``, ``err`` (d,): the run's largest ``|x_i|`` and the error bound carried into
        the stretch; ``checked``: the regions whose field Jacobian is checked (int64, with
        ``variational``, unless ``all_checked``); ``groups_left``: the event groups the run
        may still switch; ``times`` (ascending, C-contiguous float64) and ``taken``: the
        times to sample, from the ``taken``-th.
        """
        d, n = self.dim, self.n_events
        m = d * (d + 1) if variational else d
        model = self.struct(section)
        key = (id(model), m)
        start = time.perf_counter()
        try:
            out = run_stretches(model, self.jac_mode, self.event_jac_mode, variational,
                                section is not None, self.reset is not None, n, d,
                                float(t), np.ascontiguousarray(x, dtype=np.float64),
                                int(mask), scale, err, float(t_final), float(rtol),
                                self._atols(m, atol), float(max_step), float(simultaneity_tol),
                                bool(all_checked), checked, int(groups_left),
                                slice_budget(key), times, int(taken))
        except SystemError as exc:  # Ctrl-C seen while numba boxed the results
            _interrupted(exc)
            raise
        except Exception:  # noqa: BLE001 - a user function raised: the Python loop words it
            return None
        measured(key, time.perf_counter() - start, out[-1])
        return CompiledRun._make(out)

    def _atols(self, m, atol):
        """The driver's atol array (m,), the same for every stretch of a run (read only)."""
        key = (m, float(atol))
        atols = self._atol.get(key)
        if atols is None:
            if len(self._atol) >= 16:
                self._atol.clear()
            atols = self._atol[key] = np.full(m, key[1])
        return atols


def dense_at(t_old, h, F, y_old, T) -> np.ndarray:
    """The dense output of a stretch's recorded steps at the times ``T`` (m,): (m, d).

    ``t_old``, ``h`` (S,) start times and sizes, ``F`` (S, 7, d) coefficients, ``y_old``
    (S, d) start states (the record of :meth:`CompiledModel.stretch` with ``dense``:
    ``steps[:, 0]``, ``steps[:, 1]``, ``Fd``), all C-contiguous float64.
    """
    T = np.ascontiguousarray(T, dtype=np.float64)
    out = np.empty((T.size, y_old.shape[1]))
    dense_rows(t_old, h, F, y_old, T, out)
    return out
