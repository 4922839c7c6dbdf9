"""Figures of a gait: the periodic orbit with its event points, and the return map's growth."""

from __future__ import annotations

import numpy as np

from .._support._format import format_mask
from ..analysis.stability import Stability, log_growth
from ._axes import PALETTE, check_type, figure_axes, new_figure

#: marker of an event group by its directions: all upward, all downward, mixed.
_MARKERS = {1: "^", -1: "v", 0: "D"}
#: its colour, the same in the time panels and the phase plane
_COLORS = {1: PALETTE[3], -1: PALETTE[4], 0: PALETTE[2]}


def _group_kind(directions):
    return directions[0] if len(set(directions)) == 1 else 0


def _check_orbit(orbit):
    """Refuse an ``orbit`` that is not a :class:`~bderiv.analysis.orbit.PeriodicOrbit`."""
    from ..analysis.orbit import PeriodicOrbit

    check_type(orbit, "orbit", (PeriodicOrbit,),
               hint=" (HybridSystem.periodic_orbit finds one)")


def gait_orbit(orbit, axes=None, *, components=None, phase=(0, 2), labels=None,
               time_label="time", phases=None):
    """One period of a periodic orbit, with its event groups, phases and fixed point.

    Left: each of the chosen state components against time in a panel of its own (own
    axis, own units), a vertical line at every event group (marker ``^``: crossed upward,
    ``v``: downward, ``D``: mixed; one colour per kind in every panel) and the stretches
    of each region other than mask 0 shaded grey (named by ``phases``, for example a
    gait's stance). Right: the phase plane of two components, the event points marked the
    same way and the fixed point on the section as a star.

    Parameters
    ----------
    orbit : PeriodicOrbit
    axes : sequence of ``len(components) + 1`` matplotlib Axes, optional
        The time panels, then the phase plane.
    components : sequence of int, optional
        State components shown against time (default: all d).
    phase : (int, int)
        The components of the phase plane (horizontal, vertical).
    labels : sequence of str, optional
        Names of the d state components, with their units (default ``x_0 .. x_{d-1}``).
    time_label : str
        Label of the time axis, with its unit.
    phases : dict of int to str, optional
        Names of the regions (by mask) shaded on the time panels (default ``mask 0b..``).

    Returns
    -------
    matplotlib.figure.Figure
    """
    _check_orbit(orbit)
    d, n = orbit.system.dim, orbit.system.n_events
    components = list(range(d)) if components is None else [int(c) for c in components]
    if not components or not all(0 <= c < d for c in components):
        raise ValueError(f"components must be state indices in [0, {d}), got {components}")
    if len(phase) != 2 or not all(0 <= int(c) < d for c in phase):
        raise ValueError(f"phase must be two state indices in [0, {d}), got {phase}")
    i, j = (int(c) for c in phase)
    labels = [f"$x_{k}$" for k in range(d)] if labels is None else list(labels)
    if len(labels) != d:
        raise ValueError(f"labels must name the {d} state components, got {len(labels)}")
    phases = {} if phases is None else dict(phases)
    traj = orbit.sample()
    if axes is None:
        fig = new_figure((10.0, 1.6 * len(components) + 1.2))
        grid = fig.add_gridspec(len(components), 2)
        ax_ts = [fig.add_subplot(grid[r, 0]) for r in range(len(components))]
        for ax in ax_ts[1:]:
            ax.sharex(ax_ts[0])
        ax_p = fig.add_subplot(grid[:, 1])
    else:
        fig, (*ax_ts, ax_p) = figure_axes(axes, ncols=len(components) + 1)
    shaded = _shade_phases(ax_ts, traj, n, phases)
    for ax, k in zip(ax_ts, components, strict=True):
        ax.plot(traj.t, traj.x[:, k], color=PALETTE[0], lw=1.3)
        for g in traj.groups:
            ax.axvline(g.time, color="0.45", lw=0.8, zorder=0)
            kind = _group_kind(g.directions)
            ax.plot(g.time, g.state[k], _MARKERS[kind], color=_COLORS[kind], ms=6)
        ax.set_ylabel(labels[k], fontsize=9)
        ax.margins(x=0)
        _constant_to_rounding(ax, traj.x[:, k], np.abs(traj.x).max())
    for ax in ax_ts[:-1]:
        ax.tick_params(labelbottom=False)
    ax_ts[-1].set_xlabel(time_label)
    ax_ts[0].set_title(f"one period, T = {orbit.period:.6g}", fontsize=10)
    if shaded:
        ax_ts[0].legend(handles=shaded, loc="upper right", fontsize=7, framealpha=0.9)
    ax_p.plot(traj.x[:, i], traj.x[:, j], color="0.4", lw=1.2)
    for g in traj.groups:
        kind = _group_kind(g.directions)
        name = f"events {g.events} {'up' if kind > 0 else 'down' if kind < 0 else 'mixed'}"
        ax_p.plot(g.state[i], g.state[j], _MARKERS[kind], ms=9, color=_COLORS[kind],
                  label=f"{name} at t = {g.time:.4g}")
    ax_p.plot(orbit.x0[i], orbit.x0[j], "*", ms=14, color=PALETTE[5],
              label="fixed point on the section")
    ax_p.set(xlabel=labels[i], ylabel=labels[j])
    ax_p.set_title("phase plane, event points marked", fontsize=10)
    ax_p.legend(loc="best", fontsize=8)
    return fig


def _constant_to_rounding(ax, values, scale):
    """A component that does not move on the orbit (its spread is rounding, below 1e-9 of
    the state's ``scale``) is shown flat, on a unit scale, and said to be constant: its
    own autoscaling would magnify the rounding into a curve."""
    spread = np.ptp(values)
    if spread <= 1e-9 * scale:
        mid = float(np.mean(values))
        ax.set_ylim(mid - 1.0, mid + 1.0)
        ax.text(0.02, 0.9, f"constant to rounding (spread {spread:.1g})", fontsize=7,
                transform=ax.transAxes, va="top")


def _shade_phases(axes, traj, n, phases):
    """Shade on ``axes`` the stretches of ``traj`` in each region other than mask 0, a grey
    per region; return the legend patches, named by ``phases`` (mask to name)."""
    from matplotlib.patches import Patch

    masks = np.asarray(traj.masks)
    starts = np.flatnonzero(np.r_[True, masks[1:] != masks[:-1]])
    ends = np.r_[starts[1:] - 1, masks.size - 1]
    shown = [int(m) for m in dict.fromkeys(masks[starts].tolist()) if m != 0]
    greys = {m: str(0.88 - 0.1 * (r % 4)) for r, m in enumerate(sorted(shown))}
    for a, b in zip(starts, ends, strict=True):
        if masks[a]:
            for ax in axes:
                ax.axvspan(traj.t[a], traj.t[b], color=greys[int(masks[a])], lw=0, zorder=-1)
    return [Patch(color=greys[m], label=phases.get(m, f"region mask {format_mask(m, n)}"))
            for m in sorted(shown)]


def gait_growth(orbit, ax=None, *, n_directions=200, iterations=40, stability=None,
                decay=None, seed=0):
    """The return map's growth along iterations, for a batch of directions.

    Thin lines: ``|A^k v| / |v|`` for ``n_directions`` random directions tangent to the
    section (A the return map's B-derivative). The dashed line is the growth rate
    ``lambda^k``; with ``decay`` (a :class:`~bderiv.analysis.checks.DecayCheck`) the simulated
    deviations of the nonlinear system, ``|P^k(x0 + eps v) - x0| / eps``, are dots.

    Parameters
    ----------
    orbit : PeriodicOrbit
    ax : matplotlib Axes, optional
    n_directions, iterations : int
        Directions drawn and iterations of the map.
    stability : Stability, optional
        Its growth rate is drawn (default: ``orbit.stability()``).
    decay : DecayCheck, optional
    seed : int

    Returns
    -------
    matplotlib.figure.Figure
    """
    from ..analysis.checks import DecayCheck

    _check_orbit(orbit)
    check_type(stability, "stability", (Stability,), optional=True)
    check_type(decay, "decay", (DecayCheck,), optional=True)
    fig, (ax,) = figure_axes(ax, ncols=1, figsize=(6.0, 4.5))
    st = orbit.stability() if stability is None else stability
    R = orbit.return_map
    V0 = np.random.default_rng(seed).standard_normal((n_directions, R.tangent_basis.shape[1]))
    logs, _ = log_growth(R, V0 @ R.tangent_basis.T, iterations)
    k = np.arange(iterations + 1)
    growth = np.exp(np.vstack((np.zeros((1, n_directions)), np.cumsum(logs, axis=0))))
    ax.semilogy(k, growth, color=PALETTE[0], lw=0.5, alpha=0.3)
    ax.semilogy(k, st.growth_rate ** k.astype(float), "--", color="k", lw=1.5,
                label=f"$\\lambda^k$, growth rate $\\lambda$ = {st.growth_rate:.4g} "
                      f"({st.verdict_word})")
    if decay is not None:
        dev = decay.deviations / decay.deviations[:, :1]
        kk = np.arange(dev.shape[1])
        for c, row in enumerate(dev):
            ax.semilogy(kk, row, "o", ms=3, color=PALETTE[1],
                        label=f"simulated $|P^k(x_0 + \\epsilon v) - x_0| / |\\epsilon v|$, "
                              f"{dev.shape[0]} directions" if c == 0 else None)
    ax.plot([], [], color=PALETTE[0], lw=0.5,
            label=f"$|A^k v| / |v|$, {n_directions} random directions $v$")
    ax.set(xlabel="iteration k (strides)", ylabel="growth of a perturbation",
           xlim=(0, iterations),
           title="return map: growth of perturbations")
    ax.legend(loc="best", fontsize=8)
    return fig
