"""Impacts or crossings that accumulate (a Zeno trajectory): refused, with the time.

A ball dropped from height ``h`` with restitution ``e < 1`` hits the ground at ``t_1 =
sqrt(2 h / g)`` and then at intervals ``2 e^k v_1 / g`` (``v_1 = g t_1``): infinitely many
impacts before ``t_1 (1 + 2 e / (1 - e))``. A run past that time would need infinitely
many stops; it would end on a rebound too small to follow, on the wrong side of the
ground (mathematics.md section 9, "Impacts that accumulate, and landings nothing
holds").

:class:`ImpactWatch` is shown a run's event groups in order (by the run loop, after each
stretch of the Python loop and after each call of the compiled run: the same groups,
so both refuse alike). For each event and direction it keeps the times of its last
``ZENO_IMPACTS`` bounces (the event's bit kept: the state sent back, the surface met
again in the same direction), and apart from them of its last ``ZENO_IMPACTS``
crossings (the bit flipped). When their intervals shrink as a geometric sequence to
zero, they accumulate at ``t + Delta r / (1 - r)`` (``Delta`` the last interval, ``r``
the last ratio). An accumulation at or before the final time is refused, with that time:

- bounces, where nothing holds the state on the surface after them: the region beyond
  the surface has the same flow as the one before it
  (:func:`bderiv.models.events.crossings.holds`: a ball whose ground is the same free
  fall). Where the region beyond holds it (a compliant or constrained contact), the
  bounces are followed to the end: just before the accumulation time a rebound is too
  small to tell (``GRAZING_RTOL``) and the state lands in that region
  (:func:`bderiv.models.events.crossings.landing`), which then holds it;
- crossings, always: the trajectory turns around the intersection of two or more
  surfaces and spirals into it in finite time, every crossing transversal (mathematics.md
  section 9). Past the accumulation no region's flow is the motion, and a run that goes
  on loses a crossing once the turns are below the integration accuracy (the state left
  a rounding across a surface, carried further across unseen).
"""

from __future__ import annotations

import numpy as np

from ..._format import format_mask
from ..._limits import ZENO_IMPACTS, ZENO_LIMIT_RTOL
from .crossings import holds

__all__ = ["ImpactWatch", "accumulation_time"]


def accumulation_time(times):
    """The time at which impacts at ``times`` (ascending, ``ZENO_IMPACTS`` of them)
    accumulate, or None when their intervals do not shrink geometrically to zero.

    The intervals must decrease, and the limit of each three consecutive ones by Aitken's
    extrapolation (``Delta_c - (Delta_c - Delta_b)^2 / (Delta_c - 2 Delta_b + Delta_a)``,
    exactly 0 for a geometric sequence) be within ``ZENO_LIMIT_RTOL`` of the last of them
    from zero: a gait whose steps converge to its period has a limit near its step time.

    Examples
    --------
    A ball's impacts with restitution 0.5, every interval half the one before:

    >>> accumulation_time([0.0, 1.0, 1.5, 1.75, 1.875])
    2.0
    >>> accumulation_time([0.0, 1.0, 1.9, 2.75, 3.58]) is None  # converging to steps of 0.8
    True
    """
    delta = np.diff(np.asarray(times, dtype=np.float64))
    if not (delta[-1] > 0.0 and (np.diff(delta) < 0.0).all()):
        return None
    for a, b, c in zip(delta, delta[1:], delta[2:], strict=False):
        curve = c - 2.0 * b + a
        if not curve > 0.0 or abs(c - (c - b) ** 2 / curve) > ZENO_LIMIT_RTOL * c:
            return None
    r = delta[-1] / delta[-2]
    return float(times[-1] + delta[-1] * r / (1.0 - r))


class ImpactWatch:
    """Watches a run's event groups for bounces, or crossings, of one event that accumulate.

    Parameters
    ----------
    system : HybridSystem
        The model (its checked evaluations: ``eval_field``, ``eval_field_jacobian``).
    t_final : float
        The run's final time: an accumulation at or before it is refused (bounces where
        nothing holds the state on the surface; crossings always).
    """

    def __init__(self, system, t_final):
        self.system, self.t_final = system, float(t_final)
        self.times = {}  # (event, direction, bounced) -> its last times, ascending
        self.seen = 0

    def see(self, groups):
        """Look at the groups of ``groups`` (a run's log, in order) not seen yet.

        Raises
        ------
        ValueError
            At the first bounce or crossing that makes an accumulation at or before the
            final time: the event, its last impacts or crossings, the ratio of their
            intervals, the accumulation time and what to do.
        """
        for i in range(self.seen, len(groups)):
            group = groups[i]
            bounced = group.bounced
            for k, direction in zip(group.events, group.directions, strict=True):
                key = (k, direction, k in bounced)
                kept = self.times.setdefault(key, [])
                kept.append(group.time)
                if len(kept) > ZENO_IMPACTS:
                    del kept[0]
                if len(kept) == ZENO_IMPACTS:
                    self._check(key, kept, groups, i)
        self.seen = len(groups)

    def _check(self, key, times, groups, i):
        t_acc = accumulation_time(times)
        if t_acc is None or t_acc > self.t_final:
            return
        k, direction, bounced = key
        if not bounced:
            _refuse_crossings(k, direction, times, groups, i, t_acc, self.t_final)
        group = groups[i]
        near = group.mask_after  # the bit of k as before the bounce
        if holds(self.system, group.state_after, near ^ 1 << k, near):
            return  # the contact region takes the state over at the end
        raise ValueError(
            f"the impacts of event {k} accumulate (a Zeno trajectory): its last "
            f"{len(times)} bounces, at t={_times(times)}, come at intervals that shrink "
            f"geometrically to zero (ratio {_ratio(times):.4g}), so infinitely many more "
            f"would come before about t={t_acc:.10g} (the accumulation time, estimated by "
            f"that geometric sequence), which is not after t_final={self.t_final:.10g}, and "
            f"nothing holds the state on the surface after it (the field beyond it, of "
            f"region {format_mask(near ^ 1 << k, self.system.n_events)}, is the same as "
            f"before it): the run cannot pass it. End the run before the accumulation time "
            f"(t_final below {t_acc:.10g}), or model the resting contact that follows it as "
            f"a region whose field holds the body on the surface (a compliant or "
            f"constrained stance)"
        )


def _refuse_crossings(k, direction, times, groups, i, t_acc, t_final):
    """Refuse crossings of event k in ``direction`` at ``times`` (the last at group ``i``
    of ``groups``) that accumulate at ``t_acc``: name the events crossed in turn since
    the first of them."""
    turn = sorted({j for g in groups[: i + 1] if g.time >= times[0] for j in g.events})
    way = "upward" if direction > 0 else "downward"
    raise ValueError(
        f"the crossings of event {k} accumulate (a Zeno trajectory): its last "
        f"{len(times)} {way} crossings, at t={_times(times)}, come at intervals that shrink "
        f"geometrically to zero (ratio {_ratio(times):.4g}), events {turn} crossing in "
        f"turn, so infinitely many more would come before about t={t_acc:.10g} (the "
        f"accumulation time, estimated by that geometric sequence), which is not after "
        f"t_final={t_final:.10g}: the trajectory spirals into the intersection of their "
        f"surfaces in finite time, and no region's flow is the motion after it. End the "
        f"run before the accumulation time (t_final below {t_acc:.10g})"
    )


def _times(times):
    return ", ".join(f"{t:.10g}" for t in times)


def _ratio(times):
    """The ratio of the last two intervals of ``times``."""
    return (times[-1] - times[-2]) / (times[-2] - times[-3])
