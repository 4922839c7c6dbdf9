"""What a run records: the samples it is asked for, its events, groups and sensitivities.

:class:`RunLog` is what :func:`bderiv.models.integrate.run.run` accumulates stretch by
stretch. The samples are what the caller asks for (``record``): every accepted step
(``STEPS``, ``simulate``'s default: a record that grows with the steps, held to the memory
the process may still take before it grows, :func:`bderiv._support._validate.check_record`), the
start and the end only (``ENDS``: what the flow map, the return map and the finite
differences read; two samples whatever the span), or the states at given times
(``t_eval``, :func:`check_t_eval`), each on the dense output of the stretch that holds it
(:func:`dense_state`). The event log, the groups and the stretches' (d, d) sensitivities
are always kept (their number is bounded by ``max_groups``).
"""

from __future__ import annotations

from dataclasses import dataclass
from dataclasses import field as dc_field
from typing import NamedTuple

import numpy as np

from ..._support._tables import human_bytes, mask_dtype
from ..._support._validate import check_real_array, check_record

__all__ = ["ENDS", "STEPS", "RunLog", "Samples", "check_t_eval", "dense_state"]

#: what a run records (``run``'s ``record``, besides an array of times): every accepted
#: step, or the start and the end only
STEPS, ENDS = "steps", "ends"
#: the words of a refusal of the record of every step: what to pass instead
_INSTEAD = ("pass t_eval (the times to sample: a bounded record), t_eval=() for the final "
            "state and the events only, or a shorter t_final")

class Samples(NamedTuple):
    """What a run kept of its states (:meth:`RunLog.finish`): the Trajectory's ``t``
    (k,), ``x`` (k, d) and ``masks`` (k,)."""

    t: np.ndarray
    x: np.ndarray
    masks: np.ndarray


@dataclass
class RunLog:
    """What :func:`~bderiv.models.integrate.run.run` accumulates, stretch by stretch: the
    samples ``record`` asks for (``STEPS``, ``ENDS`` or the sorted times ``t_eval``, of
    which ``taken`` are sampled), the events, the groups and the stretches' sensitivities.
    The masks are int64, or Python ints for a model of more than 63 events
    (``n_events``)."""

    record: object = STEPS
    n_events: int = 0
    t: list = dc_field(default_factory=list)
    x: list = dc_field(default_factory=list)
    masks: list = dc_field(default_factory=list)
    records: list = dc_field(default_factory=list)
    groups: list = dc_field(default_factory=list)
    linear: list = dc_field(default_factory=list)
    first_mask: int = -1
    taken: int = 0
    held: int = 0
    next_check: int = 0

    def _masks(self, count, mask):
        """``count`` copies of ``mask``, of the run's mask dtype."""
        return np.full(count, mask, dtype=mask_dtype(self.n_events))

    def add_steps(self, T, X, M):
        """The samples of recorded stretches: times (N,), states (N, d), masks (N,); kept
        with ``STEPS`` (held to the memory the process may take), else only the first
        mask (the start's region)."""
        if self.first_mask < 0 and M.size:
            self.first_mask = int(M[0])
        if self.record is not STEPS:
            return
        self.t.append(T)
        self.x.append(X)
        self.masks.append(M)
        self.held += T.nbytes + X.nbytes + M.nbytes
        if self.held >= self.next_check:
            # checked again when it has grown by half; joined at the end: one more copy
            self.next_check = self.held + self.held // 2
            count = sum(part.size for part in self.t)
            check_record(self.held, 2 * self.held,
                         f"the trajectory's record of every accepted step (Trajectory.t, "
                         f"x, masks: {count} samples to t = {float(T[-1])!r})", _INSTEAD)

    def add_stretch(self, sol, mask, d, variational, last):
        """A stretch of the Python loop (solve_ivp's fields; ``last``: the run ends with
        it): its samples as ``record`` asks, and its sensitivity at its end."""
        if isinstance(self.record, np.ndarray):
            if self.first_mask < 0:
                self.first_mask = mask
            self.sample(sol, mask, d, last)
        else:
            self.add_steps(sol.t, sol.y[:d].T, self._masks(sol.t.size, mask))
        if variational:
            self.linear.append(np.array(sol.y[d:, -1].reshape(d, d)))

    def sample(self, sol, mask, d, last):
        """The times of ``t_eval`` on this stretch (before its end; up to it when ``last``),
        on its dense output."""
        times, end = self.record, float(sol.t[-1])
        stop = int(np.searchsorted(times, end, side="right" if last else "left"))
        if stop > self.taken:
            here = self._take(stop)
            self._keep(here, dense_state(sol, here, d), self._masks(here.size, mask))

    def _take(self, stop):
        """The times of ``t_eval`` from the next to ``stop``: the run's own copy (a view
        made every run of a batch share one array), counted as sampled."""
        here = self.record[self.taken:stop].copy()
        self.taken = stop
        return here

    def _keep(self, times, states, masks):
        """Samples kept: their times (k,), states (k, d) and masks (k,)."""
        self.t.append(times)
        self.x.append(states)
        self.masks.append(masks)

    def sampling(self):
        """The compiled run's arguments for the times still to sample: ``times`` and
        ``taken`` (none without ``t_eval``)."""
        if isinstance(self.record, np.ndarray):
            return {"times": self.record, "taken": self.taken}
        return {}

    def add_samples(self, S, SM):
        """The states (k, d) and masks (k,) the compiled run sampled at the next ``k`` of
        ``t_eval``."""
        if S.shape[0]:
            if self.first_mask < 0:
                self.first_mask = int(SM[0])
            self._keep(self._take(self.taken + S.shape[0]), S,
                       SM.astype(mask_dtype(self.n_events), copy=False))

    def finish(self, x0, now) -> Samples:
        """The :class:`Samples` of the Trajectory."""
        if self.record is ENDS:
            return Samples(np.array([0.0, now.t]), np.array([x0, now.x]),
                           np.array([self.first_mask, now.mask],
                                    dtype=mask_dtype(self.n_events)))
        if isinstance(self.record, np.ndarray):  # times at the end after the last stretch
            stop = int(np.searchsorted(self.record, now.t, side="right"))
            if stop > self.taken:
                here = self._take(stop)
                self._keep(here, np.tile(now.x, (here.size, 1)),
                           self._masks(here.size, now.mask))
            if not self.t:
                return Samples(np.empty(0), np.empty((0, x0.size)),
                               self._masks(0, 0))
        return Samples(_joined(self.t), _joined(self.x), _joined(self.masks))


def dense_state(sol, times, d):
    """The states (len(times), d) at ``times`` on a stretch's dense output: each on the
    last integration of the stretch that starts at or before it (``sol.pieces``: a stretch
    integrated again from a step end to find a crossing inside a step is several)."""
    pieces = getattr(sol, "pieces", None) or [(float(sol.t[0]), sol.sol)]
    starts = np.array([start for start, _ in pieces])
    which = np.maximum(np.searchsorted(starts, times, side="right") - 1, 0)
    out = np.empty((times.size, d))
    for j in np.unique(which):
        at = which == j
        out[at] = np.asarray(pieces[j][1](times[at]))[:d].T
    return out


def check_t_eval(t_eval, t_final, d):
    """``t_eval`` checked: a 1-D array of finite times, ascending, in ``[0, t_final]``
    (the samples' memory held to what the process may take); float64."""
    times = check_real_array(t_eval, "t_eval").astype(np.float64).ravel()
    if np.ndim(t_eval) > 1:
        raise ValueError(f"t_eval must be 1-D, got shape {np.shape(t_eval)}")
    if not np.isfinite(times).all():
        raise ValueError(f"t_eval must be finite, got {times[~np.isfinite(times)][:3]}")
    if times.size and (times[0] < 0.0 or times[-1] > t_final):
        raise ValueError(f"t_eval must lie in [0, t_final={t_final!r}], got times from "
                         f"{times[0]!r} to {times[-1]!r}")
    if (np.diff(times) < 0).any():
        raise ValueError("t_eval must be ascending")
    need = times.size * (16 + 8 * d)
    check_record(0, 2 * need, f"t_eval's {times.size} samples ({human_bytes(need)})",
                 "pass fewer times")
    return times


def _joined(parts):
    """The arrays ``parts`` joined along their first axis (the one part itself)."""
    return parts[0] if len(parts) == 1 else np.concatenate(parts)
