"""What a run returns (:class:`Trajectory`): its samples, event log and groups, final state
and region, and (with the variational equations) the linear stages and the group at the
final time; and the two ends of a run that return nothing (:class:`NoReturn`,
:class:`TooManyGroups`)."""

from __future__ import annotations

from dataclasses import dataclass
from dataclasses import field as dc_field

import numpy as np

from ..events.crossings import EventGroup

__all__ = ["NoReturn", "TooManyGroups", "Trajectory"]


class NoReturn(ValueError):
    """A run with a section that did not return to it in the time it waited: a caller
    names its own argument for that time (``t_max``, ``period_guess``)."""


class TooManyGroups(RuntimeError):
    """A run that met more than ``max_groups`` event groups, by time ``t`` (a caller that
    sets no ``max_groups`` names its own reason)."""

    def __init__(self, max_groups: int, t: float):
        self.max_groups, self.t = max_groups, t
        super().__init__(f"more than max_groups={max_groups} event groups before t={t:.10g}: "
                         f"a long run (pass a larger max_groups) or a trajectory that "
                         f"chatters (Zeno)")


@dataclass(frozen=True, eq=False)
class Trajectory:
    """Result of :meth:`HybridSystem.simulate <bderiv.analysis.system.HybridSystem.simulate>`.

    Attributes
    ----------
    t : ndarray, shape (N,)
        Output times, ascending. By default every accepted step, from 0 to ``t_final``;
        an event time appears twice (end of one stretch, start of the next). With
        ``t_eval``: those times (up to the return, with a section), each state on the
        dense output of the stretch that holds it (at an event time, the one after it).
    x : ndarray, shape (N, d)
        States at ``t``.
    masks : ndarray, shape (N,), int64
        Region mask in effect on the stretch each sample belongs to (Python ints, dtype
        object, for a model of more than 63 events: an int64 holds 63 bits).
    events : tuple of EventRecord
        The event log ``(time, event, mask after)`` in order of switching.
    groups : tuple of EventGroup
        The same events grouped by the integrator stop at which they switched.
    x_final : ndarray, shape (d,)
        State at ``t_final``.
    mask_final : int
        Region mask at ``t_final``.
    linear : tuple of ndarray, each (d, d)
        Classical derivatives of the smooth stretches (variational equations); filled only
        when integrated with ``variational=True`` (for the flow's B-derivative).
    final_group : EventGroup or None
        The event group within ``simultaneity_tol`` of ``t_final`` (either side), whose
        map the flow's B-derivative stops at the final time (mathematics.md section 7); filled
        only with ``variational=True``. Either the last of ``groups`` (switched at or
        just before ``t_final``) or, when ``final_pending``, events about to cross just
        after it: not switched, so in neither ``groups`` nor ``events``, and
        ``mask_final`` is the mask before them.
    final_pending : bool
        Whether ``final_group`` lies just after ``t_final`` (not switched).
    final_times : tuple of float
        With ``final_pending``, the first-order time at which each event of
        ``final_group`` crosses (``t_final - h_k / rate_k``); else empty.
    simultaneity_tol : float
        The tolerance of the run (the flow map merges groups within it).
    """

    t: np.ndarray
    x: np.ndarray
    masks: np.ndarray
    events: tuple
    groups: tuple
    x_final: np.ndarray
    mask_final: int
    linear: tuple = dc_field(default=(), repr=False)
    final_group: EventGroup | None = None
    final_pending: bool = False
    final_times: tuple = ()
    simultaneity_tol: float = 0.0

    @property
    def mask_start(self) -> int:
        """Region mask of the start point (bit k set: ``h_k(x0) > 0``, event k counted as
        happened): the first sample's, else the first group's before it, else the final."""
        if self.masks.size:
            return int(self.masks[0])
        return self.groups[0].mask_before if self.groups else self.mask_final

    def __repr__(self):
        shown = ", ".join(f"t={g.time:.6g}: {list(g.events)} {g.mask_before:#b} -> "
                          f"{g.mask_after:#b}" for g in self.groups[:3])
        more = f", ... ({len(self.groups) - 3} more)" if len(self.groups) > 3 else ""
        span = (f"t {self.t[0]:.6g} to {self.t[-1]:.6g}, " if self.t.size else "")
        return (f"Trajectory({span}{self.t.size} samples, d={self.x_final.size}, start "
                f"region {self.mask_start:#b}, {len(self.groups)} event groups [{shown}{more}]"
                f", final region {self.mask_final:#b})")
