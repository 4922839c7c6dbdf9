"""The hybrid Kalman filter: mean by simulation, covariance through the flow's
B-derivative, every event order of the prior taken into account.

Away from simultaneous events the flow's B-derivative is one linear map, the product of
the fundamental matrices and saltation matrices along the mean's trajectory, and the
filter is the salted Kalman filter. Where the mean's trajectory meets events within the
filter's ``window`` of each other, the prior's perturbations take different event orders,
each through its own piece, and the covariance is pushed through the piecewise-linear
map (:mod:`bderiv.estimate.pushforward`); docs/estimation.md gives the assumptions.
"""

from __future__ import annotations

import math
import warnings
from typing import NamedTuple

import numpy as np

from ..analysis.assembly import ResetAtStart
from ._checks import (
    PSD_RTOL,
    check_covariance,
    check_priority,
    check_time,
    check_vector,
    measurement_model,
)
from .localmap import END_SDS, LocalMap, derived_window, end_gap, end_sds, group_offsets
from .pushforward import METHODS, push_auto, push_mixture, push_piece, push_sigma

#: the integrator settings a filter passes on to ``flow_bderivative`` (every run of a step)
SOLVER_KEYWORDS = ("options", "rtol", "atol", "max_step")


class ModeEstimate(NamedTuple):
    """The discrete state of the estimate after a step.

    Attributes
    ----------
    mask : int
        Region mask of the mean (bit k set: ``h_k > 0``; after a bounce a bit stays clear).
    groups : list of tuple
        Per event group of the last predict step: ``(time, events, order_probabilities)``,
        ``time`` from the step's start, ``events`` the global event indices (tuple),
        ``order_probabilities`` a dict local order (tuple) -> probability.
    window : float or None
        The window of the last predict step (derived from the prior, or given, and shrunk
        where the step ended within it of an event); None before the first.
    method : str or None
        The method the last predict step used (``"auto"`` resolved).
    split : float or None
        The share of the prior (first order) that met an event of the mean's trajectory
        on the other side of the last step's end, where above 1e-3 (the step warned of it:
        :class:`SplitPriorWarning`); None below.
    """

    mask: int
    groups: list
    window: float | None = None
    method: str | None = None
    split: float | None = None


class SplitPriorWarning(UserWarning):
    """A predict step ended within :data:`~bderiv.estimate.localmap.END_SDS` standard
    deviations of an event's time under the prior: part of the prior met the event on the
    other side of the end, which the Gaussian step does not hold."""


class HybridKalmanFilter:
    """A Kalman filter over a bderiv model, through simultaneous events.

    Parameters
    ----------
    model : HybridSystem
        Any bderiv model (Python, compiled, symbolic), dimension d.
    mean : array_like, shape (d,)
        Initial mean; not on an event surface (its region comes from the event signs).
    cov : array_like, shape (d, d)
        Initial covariance, symmetric positive semi-definite.
    method : {"auto", "mixture", "sigma", "piece"}
        How the covariance crosses a group of events (:mod:`.pushforward`): the exact
        mixture of the two pieces of one group, sigma directions through the map, or one
        piece (the salted filter; ``priority`` fixes which). ``"auto"`` (default): the
        mixture where it applies (at most one group of two pieces per step), else sigma.
    window : float, optional
        Time within which events of the mean's trajectory form one group (the flow map's
        ``simultaneity_tol``). Default: derived at each step from the prior,
        :data:`~bderiv.estimate.localmap.WINDOW_SDS` (5) times the largest standard
        deviation of the step's event times under it (first order). A given window should
        hold that spread and be small against the time between unrelated events. Either
        way, a step that ends within the window of an event of the mean's trajectory
        takes that event on the mean's side (the window shrunk to half their distance for
        the step; ``mode.window`` reports it). That is right while few perturbations meet the
        event on the other side of the end: a step that ends within
        :data:`~bderiv.estimate.localmap.END_SDS` (3) standard deviations of an event's
        time under the prior warns (:class:`SplitPriorWarning`, naming ``dt``) and
        ``mode.split`` says the share of the prior it leaves out.
    priority : sequence of int, optional
        With ``method="piece"``: the global event indices in the order assumed whenever
        several cross in one group (a salted filter that assumes which contact comes
        first); default the order of the mean's own trajectory.
    mean_correction : bool
        Add the mean of the pushed perturbation, ``E[M(delta)]``, to the simulated mean
        (default True; off: the mean is ``Phi(dt, m)`` as in a salted filter).
    **solver
        Integrator settings passed to ``flow_bderivative`` (every run of a step):
        ``options``, ``rtol``, ``atol``, ``max_step`` (the integration method through
        ``options``).

    Attributes
    ----------
    mean : ndarray (d,), cov : ndarray (d, d), time : float, mode : ModeEstimate
    """

    def __init__(self, model, mean, cov, *, method="auto", window=None,
                 priority=None, mean_correction=True, **solver):
        if not (hasattr(model, "flow_bderivative") and hasattr(model, "dim")):
            raise TypeError(f"model must be a bderiv HybridSystem, got {type(model).__name__}")
        if method not in METHODS:
            raise ValueError(f"method must be one of {METHODS}, got {method!r}")
        if priority is not None and method != "piece":
            raise ValueError(f"priority fixes the piece of method='piece', got "
                             f"method={method!r}")
        priority = check_priority(priority, model.n_events)
        self.model, self.method, self.priority = model, method, priority
        self.window = None if window is None else check_time(window, "window")
        self.mean_correction = bool(mean_correction)
        unknown = sorted(set(solver) - set(SOLVER_KEYWORDS))
        if unknown:
            raise TypeError(f"unexpected keyword(s) {unknown}: the integrator settings "
                            f"are {SOLVER_KEYWORDS}")
        self.solver = solver
        d = model.dim
        self.mean = check_vector(mean, "mean", d)
        self.cov = check_covariance(cov, "cov", d)
        self.time = 0.0
        h = np.asarray(model.calls.eval_events(self.mean))
        if (h == 0).any():  # (start_mask's words name x0, which the filter does not take)
            raise ValueError(f"mean lies on the surface of event(s) "
                             f"{np.flatnonzero(h == 0).tolist()} (events(mean) = {h}), where "
                             f"its region is ambiguous: start the filter from a mean off it")
        self.mode = ModeEstimate(model.calls.start_mask(self.mean), [])

    def predict(self, dt, Q=None):
        """Propagate over ``dt``: the mean by simulation, the covariance through the flow.

        Parameters
        ----------
        dt : float
            Time step, > 0.
        Q : array_like, shape (d, d), optional
            Process noise covariance added at the end of the step (symmetric positive
            semi-definite).

        Returns
        -------
        mean : ndarray, shape (d,)
        cov : ndarray, shape (d, d)
        """
        dt = check_time(dt)
        d = self.model.dim
        Q = None if Q is None else check_covariance(Q, "Q", d)
        self._straddled()
        try:
            D, window, split = self._flow_map(dt)
        except ResetAtStart as exc:  # (its advice is in simulate's terms, not the filter's)
            raise ValueError(
                f"the step of dt={dt!r} starts {exc.time:.3g} s before an impact of event(s) "
                f"{exc.events}, within the step's event window: a perturbation of the mean "
                f"larger than that is past it already, where the step's map jumps (no "
                f"B-derivative). Start the step from a mean farther from the surface, or "
                f"pass window= below {exc.time:.3g} (the filter is left as it was)") from exc
        # the run switches each event at its own time: D.x_final is the simulated mean,
        # and a merged group's offsets are measured at its first crossing's state
        local = LocalMap(D, group_offsets(self.model, D))
        push = {"auto": push_auto, "sigma": push_sigma, "mixture": push_mixture,
                "piece": lambda m, P: push_piece(m, P, self.priority)}[self.method](
                    local, self.cov)
        mean = D.x_final + (push.mean if self.mean_correction else 0.0)
        cov = push.cov if Q is None else push.cov + Q
        groups = [(t, ev, probs) for t, ev, probs in
                  zip(D.group_times, D.group_events, push.order_probabilities, strict=True)]
        mask = self._region(mean, f"the step of dt={dt!r} ends at t = {self.time + dt!r}",
                            "take a step that ends before or after the event")
        self.mean, self.cov, self.time = mean, 0.5 * (cov + cov.T), self.time + dt
        self.mode = ModeEstimate(mask, groups, window, push.method, split)
        return self.mean.copy(), self.cov.copy()

    def _region(self, mean, what, advice):
        """The region mask of a new ``mean``; a ValueError saying ``what`` put it on an
        event surface (the filter unchanged: the next step could not start there)."""
        try:
            return self.model.calls.start_mask(mean)
        except ValueError as exc:  # on a surface: its region is ambiguous
            h = np.asarray(self.model.calls.eval_events(mean))
            raise ValueError(f"{what} with the mean on the surface of event(s) "
                             f"{np.flatnonzero(h == 0).tolist()} (events(mean) = {h}), where "
                             f"its region is ambiguous and the next step could not start: "
                             f"{advice} (the filter is left as it was)") from exc

    def _flow_map(self, dt):
        """The step's B-derivative at the mean and its window (class docstring).

        Derived window: the flow map with each event its own group gives the event times'
        spread; it is the step's map unless two events lie within the window of each
        other. Either window: an event within it of the step's end would form a group
        at the final time, which has no offset (and, with resets, no B-derivative), so
        the window shrinks to half the event's distance from the end. An end within
        ``END_SDS`` standard deviations of an event's time is warned of (:meth:`_split`).
        """
        model, m, kw = self.model, self.mean, self.solver
        base = None
        if self.window is None:
            base = model.flow_bderivative(m, dt, **kw)  # each event its own group
            window = min(derived_window(base, self.cov), 0.5 * end_gap(model, base, dt))
            if not np.any(np.diff(base.group_times) < window):
                return base, window, self._split(base, dt)
        else:
            window = self.window
        try:
            D = model.flow_bderivative(m, dt, simultaneity_tol=window, **kw)
            if not D.stops_at_group:  # (one of exactly simultaneous events too: spread 0)
                return D, window, self._split(D, dt)
            refused = None
        except ValueError as exc:  # an event group with resets at the final time
            refused = exc
        base = model.flow_bderivative(m, dt, **kw) if base is None else base
        split = self._split(base, dt)
        half = 0.5 * end_gap(model, base, dt)
        if not half < window:
            if refused is not None:
                raise refused
            return D, window, split  # group_offsets names the group
        return model.flow_bderivative(m, dt, simultaneity_tol=half, **kw), half, split

    def _straddled(self):
        """Warn (:class:`SplitPriorWarning`) where the prior straddles an event surface at
        the step's start: the share beyond the surface, first order (the event's value at
        the mean in standard deviations of it under the prior), above 1e-3. The step
        takes the whole prior in the mean's region, as it takes an event near its end on
        the mean's side (a review: a ball 1e-6 above the floor, sd 1e-3, half of the prior
        below it, got a velocity spread 50 times too small, without a word)."""
        calls = self.model.calls
        h = np.asarray(calls.eval_events(self.mean))
        Dh = np.asarray(calls.eval_event_jacobian(self.mean))
        sd = np.sqrt(np.einsum("ki,ij,kj->k", Dh, self.cov, Dh))
        with np.errstate(divide="ignore", invalid="ignore"):
            sds = np.where(sd > 0, np.abs(h) / sd, np.inf)
        k = int(np.argmin(sds))
        if not sds[k] < END_SDS:
            return
        share = 0.5 * math.erfc(sds[k] / math.sqrt(2.0))
        warnings.warn(SplitPriorWarning(
            f"the step starts with the mean {sds[k]:.2g} standard deviations of event "
            f"{k}'s value under the prior from its surface (events(mean)[{k}] = "
            f"{h[k]:.3g}, sd {sd[k]:.3g}): {share:.2g} of the prior lies on the other side, "
            f"in another region, which the step does not hold (it takes the whole prior in "
            f"the mean's region: the covariance can be far off); start the step when the "
            f"mean is at least {END_SDS:g} standard deviations from the surface, or "
            f"shrink the prior"), stacklevel=3)

    def _split(self, D, dt):
        """The share of the prior beyond the step's end from the nearest event of the
        mean's trajectory (first order: its distance in event-time standard deviations,
        :func:`~bderiv.estimate.localmap.end_sds`), warned of where above 1e-3; else
        None."""
        near = end_sds(self.model, D, dt, self.cov)
        if near is None or not near[0] < END_SDS:
            return None
        share = 0.5 * math.erfc(near[0] / math.sqrt(2.0))
        warnings.warn(SplitPriorWarning(
            f"dt={dt!r} ends the step {near[1]:.3g} s from an event of the mean's "
            f"trajectory, {near[0]:.2g} standard deviations of its time under the prior "
            f"({near[2]:.3g} s): {share:.2g} of the prior meets it on the other side of the "
            f"end, which the step does not hold (it takes the event on the mean's side: "
            f"the covariance can be far off, a bouncing ball's velocity spread 1,000 times "
            f"too small 1e-5 s after its impact); end the step at least {END_SDS:g} "
            f"standard deviations ({END_SDS * near[2]:.3g} s) before or after the event"),
            stacklevel=3)
        return share

    def update(self, z, R, *, H, h=None):
        """The measurement update ``z = h(x) + v``, ``v ~ N(0, R)``.

        Parameters
        ----------
        z : array_like, shape (p,)
            The measurement.
        R : array_like, shape (p, p)
            Measurement noise covariance, positive definite.
        H : array_like (p, d), or callable ``H(x) -> (p, d)``
            The measurement matrix, or the Jacobian of ``h``.
        h : callable ``h(x) -> (p,)``, optional
            The measurement function (default: ``H x``, a linear measurement).

        Returns
        -------
        mean : ndarray, shape (d,)
        cov : ndarray, shape (d, d)
            Joseph form, symmetric.
        """
        d = self.model.dim
        hx, Hx = measurement_model(h, H, self.mean, d)
        p = hx.shape[0]
        if np.size(z) != p:  # either may be the wrong one: both named
            raise ValueError(f"z must have shape ({p},), as H has {p} rows (one per "
                             f"measured quantity), got {np.size(z)} entries")
        z = check_vector(z, "z", p)
        R = check_covariance(R, "R", p, definite=True)
        S = Hx @ self.cov @ Hx.T + R
        K = np.linalg.solve(S, Hx @ self.cov).T  # P H^T S^-1 (S, P symmetric)
        mean = self.mean + K @ (z - hx)
        IKH = np.eye(d) - K @ Hx
        cov = IKH @ self.cov @ IKH.T + K @ R @ K.T
        mask = self._region(mean, "the update", "a measurement this exact leaves the mean "
                            "nowhere to go; perturb z or R")
        self.mean, self.cov = mean, 0.5 * (cov + cov.T)
        self.mode = self.mode._replace(mask=mask)
        return self.mean.copy(), self.cov.copy()

    def nees(self, x_true):
        """Normalised estimation error squared ``(x - m)^T P^-1 (x - m)`` of a true state
        (d,): chi-square with d degrees of freedom for a consistent filter."""
        x_true = check_vector(x_true, "x_true", self.model.dim)
        w = np.linalg.eigvalsh(self.cov)
        if not w[0] > PSD_RTOL * w[-1]:
            raise ValueError(f"the filter's covariance is singular (smallest eigenvalue "
                             f"{w[0]:.3g}, largest {w[-1]:.3g}): the NEES needs it positive "
                             f"definite")
        e = x_true - self.mean
        return float(e @ np.linalg.solve(self.cov, e))
