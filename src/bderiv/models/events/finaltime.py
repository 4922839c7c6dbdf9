"""FinalTimeMap: the map of an event group at the final time of a flow map.

When an event group of a trajectory lies at ``t_final`` (within ``simultaneity_tol``, on
either side), ``x -> Phi(t_final, x)`` is piecewise linear there: a perturbation whose
events come before ``t_final`` meets their jumps, one whose events come after does not
(mathematics.md section 7, "A group at the final time"). The final time is then one more event
of the group: ``h_T = s (t - t_final)`` in the state augmented by the time, with rate
``s`` in every region. The group's corner table is extended to the augmented state:

- regions before the final time (time bit clear): ``(F[mask], s)``, the group's corners;
- regions after it (time bit set): ``(F[full], s)`` in every one of them, so that the
  events still pending at ``t_final`` move nothing (their jumps ``F[B] - F[B']`` vanish).

The augmented :class:`~bderiv.engine.bderivative.BDerivative` applied to ``(u, -s dt)`` puts the
final-time event at virtual time ``dt`` (the time coordinate stays ``-s dt``: every
region's time rate is ``s``); the first d coordinates of its result plus ``dt F[full]``
are the position at ``t_final + dt``, and for ``dt = 0`` they are the group's map stopped
at the final time. Everything runs on the ordinary engine; the final time is local event
``n`` (the last) of the augmented map.
"""

from __future__ import annotations

import numpy as np

from ..._support._validate import check_bool, check_points
from ...engine.bderivative import BDerivative

__all__ = ["FinalTimeMap", "pending_at_final_time"]


def pending_at_final_time(h, rate, simultaneity_tol) -> list:
    """Events that cross within ``simultaneity_tol`` after the final time (first order).

    Parameters
    ----------
    h, rate : ndarray, shape (n,)
        Event values and rates at the final point, in the local orientation of its region
        (pending events have ``h < 0``).
    simultaneity_tol : float

    Returns
    -------
    list of int
        The events with ``rate > 0`` and ``-h <= simultaneity_tol * rate``: with the final
        time they form a group at the final time.

    Examples
    --------
    >>> pending_at_final_time(np.array([-1e-12, -1.0, 0.0]), np.array([1.0, 1.0, -1.0]), 1e-7)
    [0]
    """
    return [k for k in range(h.size) if rate[k] > 0 and -h[k] <= simultaneity_tol * rate[k]]


class FinalTimeMap:
    """An event group's B-derivative stopped at the final time (a stage of a flow map).

    Parameters
    ----------
    group : BDerivative
        The group's map at its event point (a dense corner table, no resets), dimension d,
        n events.

    Attributes
    ----------
    group : BDerivative
        The group's map (every event applied).
    augmented : BDerivative
        The map of the n events and the final time in the state augmented by the time:
        ``Dh`` (n + 1, d + 1), corners ``(2**(n + 1), d + 1)``.
    n_events : int
        n + 1: the group's events (local 0..n-1) and the final time (local n).
    dim : int
        d.
    time_scale : float
        ``s``, the rate of the final-time event (the largest corner entry, so that the
        time column is of the size of the others).

    Raises
    ------
    ValueError
        If the group has resets (the state jumps at the final time: ``Phi(t_final, .)``
        is discontinuous, with no B-derivative) or is given as a corner model.
    """

    def __init__(self, group):
        if not isinstance(group, BDerivative):
            raise TypeError(f"group must be a BDerivative, got {type(group).__name__}")
        if group.resets is not None:
            raise ValueError(
                "an event group with resets at the final time: the state jumps at t_final, "
                "so the flow map x -> Phi(t_final, x) is discontinuous there and has no "
                "B-derivative; choose a final time away from the group"
            )
        if group.F is None:
            raise ValueError("an event group at the final time needs a dense corner table")
        n, d = group.n_events, group.dim
        F = group.F
        s = float(np.abs(F).max()) or 1.0
        Dh = np.zeros((n + 1, d + 1))
        Dh[:n, :d] = group.Dh
        Dh[n, d] = 1.0
        corners = np.empty((2 << n, d + 1))
        corners[: 1 << n, :d] = F
        corners[1 << n :, :d] = F[-1]  # after the final time: one field, no more jumps
        corners[:, d] = s
        self.group = group
        self.augmented = BDerivative(Dh, corners)
        self.n_events, self.dim, self.time_scale = n + 1, d, s

    def __repr__(self):
        return f"FinalTimeMap(n_events={self.n_events}, dim={self.dim})"

    def _augment(self, V, dt=None) -> np.ndarray:
        """Rows (m, d) with the time coordinate ``-s dt`` (0 without dt): (m, d + 1)."""
        X = np.zeros((V.shape[0], self.dim + 1))
        X[:, : self.dim] = V
        if dt is not None:
            X[:, self.dim] = -self.time_scale * dt
        return X

    def apply(self, V, dt=None) -> np.ndarray:
        """The group's map stopped at the final time ``t_final + dt``.

        Parameters
        ----------
        V : array_like, shape (..., d)
            Vectors entering the group.
        dt : ndarray, shape (m,), optional
            Final-time perturbation of each row (V then of shape (m, d)); it decides
            which events come before the final time. The flow map adds ``dt`` times the
            field after the group.

        Returns
        -------
        ndarray, shape (..., d)
            The virtual position at the final time of the region the row ends in (the
            actual position at ``t_final``, for ``dt = 0``).
        """
        flat, lead = check_points(V, self.dim)
        out = self.augmented(self._augment(flat, dt))[:, : self.dim]
        return out.reshape(lead + (self.dim,))

    __call__ = apply

    def inverse(self, W) -> np.ndarray:
        """The inverse: positions at the final time to vectors entering the group."""
        flat, lead = check_points(W, self.dim, "W")
        out = self.augmented.inverse(self._augment(flat))[:, : self.dim]
        return out.reshape(lead + (self.dim,))

    def event_times(self, V):
        """Event times and order, the final time (local event n) included.

        Returns
        -------
        times : ndarray, shape (..., n + 1)
            Times relative to the group's point; ``times[..., n]`` is 0 (the final time).
            Events after the final time do not happen before it: their times are those
            of the flow continued with the field after the group.
        order : ndarray of int64, shape (..., n + 1)
        """
        flat, lead = check_points(V, self.dim)
        times, order = self.augmented.event_times(self._augment(flat))
        n = self.n_events
        return times.reshape(lead + (n,)), order.reshape(lead + (n,))

    def orders(self, V) -> np.ndarray:
        """``event_times(V)[1]``."""
        return self.event_times(V)[1]

    def _tangent_rows(self, V, T, res, transpose: bool, offset: int, name: str) -> None:
        """jvp/vjp rows: the augmented piece restricted to the state (time input 0, time
        output dropped), or its transpose."""
        out = np.empty((V.shape[0], self.dim + 1))
        self.augmented._tangent_rows(self._augment(V), self._augment(T), out, transpose,
                                     offset, name)
        res[...] = out[:, : self.dim]

    def piece(self, order, *, with_time: bool = False) -> np.ndarray:
        """The piece of one order of the n + 1 local events (the final time is n).

        Returns
        -------
        ndarray, shape (d, d), or (d, d + 1) with ``with_time``
            Column d: the derivative in the final time, less the field after the group
            (the flow map adds it).
        """
        with_time = check_bool(with_time, "with_time")
        P = self.augmented.piece(order)
        d = self.dim
        if with_time:
            return np.column_stack((P[:d, :d], -self.time_scale * P[:d, d]))
        return np.array(P[:d, :d])
