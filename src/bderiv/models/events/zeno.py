"""Impacts that accumulate (a Zeno trajectory): refused, with the accumulation time.

A ball dropped from height ``h`` with restitution ``e < 1`` hits the ground at ``t_1 =
sqrt(2 h / g)`` and then at intervals ``2 e^k v_1 / g`` (``v_1 = g t_1``): infinitely many
impacts before ``t_1 (1 + 2 e / (1 - e))``. A run past that time would need infinitely
many stops; it would end on a rebound too small to follow, on the wrong side of the
ground (mathematics.md section 9, "Impacts that accumulate, and landings nothing
holds").

:class:`ImpactWatch` is shown a run's event groups in order (by the run loop, after each
stretch of the Python loop and after each call of the compiled run: the same groups,
so both refuse alike). For each event it keeps the times of its last ``ZENO_IMPACTS``
bounces (the event's bit kept: the state sent back, the surface met again in the same
direction). When their intervals shrink as a geometric sequence to zero, the impacts
accumulate at ``t + Delta r / (1 - r)`` (``Delta`` the last interval, ``r`` the last
ratio). An accumulation at or before the final time is refused, with that time, where
nothing holds the state on the surface after it: the region beyond the surface has the
same flow as the one before it (:func:`bderiv.models.events.crossings.holds`: a ball whose
ground is the same free fall). Where the region beyond holds it (a compliant or
constrained contact), the bounces are followed to the end: just before the accumulation
time a rebound is too small to tell (``GRAZING_RTOL``) and the state lands in that region
(:func:`bderiv.models.events.crossings.landing`), which then holds it.

Crossings (the bit flipped) that come around again at one instant are refused too: an
event crossed twice in the same direction within ``AT_ONCE`` units of rounding of the time
crossed back in between, at that instant. That is where a trajectory that spirals into
the intersection of surfaces (events crossing in turn, each region's field carrying it to
the next) ends once its turns are below the integration accuracy: stops a rounding apart,
in a cycle that never ends (mathematics.md section 9).
"""

from __future__ import annotations

import numpy as np

from ..._limits import ZENO_IMPACTS, ZENO_LIMIT_RTOL
from ..._support._format import format_mask
from .crossings import holds

__all__ = ["ImpactWatch", "accumulation_time"]

#: crossings of one event in one direction this many units of rounding of the time apart
#: are at one instant (a judgement: a stop is placed to a few units; a cycle of four
#: crossings at rounding level was seen to move the time by about 13)
AT_ONCE = 64


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
    """Watches a run's event groups for bounces of one event that accumulate.

    Parameters
    ----------
    system : ModelCalls (``HybridSystem.calls``)
        The model (its checked evaluations: ``eval_field``, ``eval_field_jacobian``).
    t_final : float
        The run's final time: an accumulation at or before it is refused where nothing
        holds the state on the surface.
    """

    def __init__(self, system, t_final):
        self.system, self.t_final = system, float(t_final)
        self.times = [[] for _ in range(system.n_events)]
        self.crossed = {}  # (event, direction) -> the time of its last crossing
        self.seen = 0
        self.held = None  # (event, accumulation time) of bounces a contact region holds

    def see(self, groups):
        """Look at the groups of ``groups`` (a run's log, in order) not seen yet.

        Raises
        ------
        ValueError
            At the first bounce that makes an accumulation at or before the final time:
            the event, its last impacts, the ratio of their intervals, the accumulation
            time and what to do.
        """
        for group in groups[self.seen:]:
            self._at_once(group)
            for k in group.bounced:
                kept = self.times[k]
                kept.append(group.time)
                if len(kept) > ZENO_IMPACTS:
                    del kept[0]
                if len(kept) == ZENO_IMPACTS:
                    self._check(k, kept, group)
        self.seen = len(groups)

    def _at_once(self, group):
        """Refuse a crossing of ``group`` that the same event made in the same direction
        at the same time before (a cycle of crossings at one point)."""
        bounced = group.bounced
        for k, direction in zip(group.events, group.directions, strict=True):
            if k in bounced:
                continue
            last = self.crossed.get((k, direction))
            if last is not None and group.time - last <= AT_ONCE * np.spacing(group.time):
                way = "upward" if direction > 0 else "downward"
                raise ValueError(
                    f"event {k} crosses {way} twice at t={group.time:.10g} (to rounding): it "
                    f"crosses at once again after crossing back at the same instant, a cycle of "
                    f"crossings at one point that the integrator cannot order (the end of a "
                    f"trajectory that spirals into the intersection of surfaces, a Zeno "
                    f"accumulation, its turns below the integration accuracy; or a corner "
                    f"met within it); end the run before t={group.time:.10g}, or tighten "
                    f"rtol and atol"
                )
            self.crossed[(k, direction)] = group.time

    def _check(self, k, times, group):
        t_acc = accumulation_time(times)
        if t_acc is None or t_acc > self.t_final:
            return
        near = group.mask_after  # the bit of k as before the bounce
        if holds(self.system, group.state_after, near ^ 1 << k, near):
            self.held = (k, t_acc)  # the contact region takes the state over at the end
            return
        ratio = (times[-1] - times[-2]) / (times[-2] - times[-3])
        raise ValueError(
            f"the impacts of event {k} accumulate (a Zeno trajectory): its last "
            f"{len(times)} bounces, at t={', '.join(f'{t:.10g}' for t in times)}, come at "
            f"intervals that shrink geometrically to zero (ratio {ratio:.4g}), so infinitely "
            f"many more would come before about t={t_acc:.10g} (the accumulation time, "
            f"estimated by that geometric sequence), which is not after t_final="
            f"{self.t_final:.10g}, and nothing holds the state on the surface after it (the "
            f"field beyond it, of region {format_mask(near ^ 1 << k, self.system.n_events)}, "
            f"is the same as before it): the run cannot pass it. End the run before the "
            f"accumulation time (t_final below {t_acc:.10g}), or model the resting contact "
            f"that follows it as a region whose field holds the body on the surface (a "
            f"compliant or constrained stance)"
        )

    def explained(self, exc):
        """``exc``, a refusal of the run, with what it follows where the bounces of an
        event that a contact region holds were accumulating: near their accumulation time
        a rebound falls below what the run resolves (its rate below the grazing threshold
        on one integrator, a rounding above it on the other), and a graze there, not the
        model, is what was refused (a review: ``contact_system`` balls of e = 0.7 and 0.9
        refused a lift-off of 9e-9 m/s at the accumulation time)."""
        if self.held is None or type(exc) is not ValueError or \
                getattr(exc, "_bderiv_call", None) is not None:  # (a model's function's)
            return exc
        k, t_acc = self.held
        return ValueError(
            f"{exc}. This follows the impacts of event {k}, which accumulate at about "
            f"t={t_acc:.10g} (a Zeno trajectory, which the contact region holds after it): "
            f"so near that time the rebounds are below what the integrator resolves. End "
            f"the run before t={t_acc:.10g}, and start the resting contact that follows "
            f"from a state in it")

