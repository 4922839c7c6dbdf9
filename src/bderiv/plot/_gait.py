"""Figures of a gait: the periodic orbit with its event points, and the return map's growth."""

from __future__ import annotations

import numpy as np

from ..stability import log_growth
from ._axes import PALETTE, figure_axes

#: marker of an event group by its directions: all upward, all downward, mixed.
_MARKERS = {1: "^", -1: "v", 0: "D"}


def _group_kind(directions):
    return directions[0] if len(set(directions)) == 1 else 0


def gait_orbit(orbit, axes=None, *, components=(0, 2), labels=None):
    """One period of a periodic orbit, with its event groups and the fixed point.

    Left: the chosen state components against time, a vertical line at every event group
    (marker ``^``: crossed upward, ``v``: downward, ``D``: mixed). Right: the phase plane
    of the two components, the event points marked the same way and the fixed point on
    the section as a star.

    Parameters
    ----------
    orbit : PeriodicOrbit
    axes : sequence of 2 matplotlib Axes, optional
    components : (int, int)
        State components shown.
    labels : sequence of str, optional
        Names of the d state components (default ``x_0 .. x_{d-1}``).

    Returns
    -------
    matplotlib.figure.Figure
    """
    traj = orbit.sample()
    d = traj.x.shape[1]
    i, j = (int(c) for c in components)
    if not (0 <= i < d and 0 <= j < d):
        raise ValueError(f"components must be two state indices in [0, {d}), got "
                         f"{components}")
    labels = [f"x_{k}" for k in range(d)] if labels is None else list(labels)
    if len(labels) != d:
        raise ValueError(f"labels must name the {d} state components, got {len(labels)}")
    fig, (ax_t, ax_p) = figure_axes(axes, ncols=2, figsize=(10.0, 4.2))
    for c, k in enumerate((i, j)):
        ax_t.plot(traj.t, traj.x[:, k], color=PALETTE[c], label=labels[k])
    ax_p.plot(traj.x[:, i], traj.x[:, j], color="0.4", lw=1.2)
    for g in traj.groups:
        kind = _group_kind(g.directions)
        name = f"events {g.events} {'up' if kind > 0 else 'down' if kind < 0 else 'mixed'}"
        ax_t.axvline(g.time, color="0.7", lw=0.8, zorder=0)
        for c, k in enumerate((i, j)):
            ax_t.plot(g.time, g.state[k], _MARKERS[kind], color=PALETTE[c], ms=7)
        ax_p.plot(g.state[i], g.state[j], _MARKERS[kind], ms=9, color=PALETTE[2 + kind % 3],
                  label=f"{name} at t = {g.time:.4g}")
    ax_p.plot(orbit.x0[i], orbit.x0[j], "*", ms=14, color=PALETTE[5],
              label="fixed point on the section")
    ax_t.set(xlabel="time", title=f"one period, T = {orbit.period:.6g}")
    ax_t.legend(loc="best", fontsize=8)
    ax_p.set(xlabel=labels[i], ylabel=labels[j], title="phase plane, event points marked")
    ax_p.legend(loc="best", fontsize=8)
    return fig


def gait_growth(orbit, ax=None, *, n_directions=200, iterations=40, stability=None,
                decay=None, seed=0):
    """The return map's growth along iterations, for a batch of directions.

    Thin lines: ``|A^k v| / |v|`` for ``n_directions`` random directions tangent to the
    section (A the return map's B-derivative). The dashed line is the growth rate
    ``lambda^k``; with ``decay`` (a :class:`~bderiv.checks.DecayCheck`) the simulated
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
    fig, (ax,) = figure_axes(ax, ncols=1, figsize=(6.0, 4.5))
    st = orbit.stability() if stability is None else stability
    R = orbit.return_map
    V0 = np.random.default_rng(seed).standard_normal((n_directions, R.tangent_basis.shape[1]))
    logs, _ = log_growth(R, V0 @ R.tangent_basis.T, iterations)
    k = np.arange(iterations + 1)
    growth = np.exp(np.vstack((np.zeros((1, n_directions)), np.cumsum(logs, axis=0))))
    ax.semilogy(k, growth, color=PALETTE[0], lw=0.5, alpha=0.3)
    ax.semilogy(k, st.growth_rate ** k.astype(float), "--", color="k", lw=1.5,
                label=f"growth rate {st.growth_rate:.4g}^k "
                      f"({'stable' if st.stable else 'unstable'})")
    if decay is not None:
        dev = decay.deviations / decay.deviations[:, :1]
        kk = np.arange(dev.shape[1])
        for c, row in enumerate(dev):
            ax.semilogy(kk, row, "o", ms=3, color=PALETTE[1],
                        label="simulated |P^k(x0 + eps v) - x0| / |eps v|" if c == 0 else None)
    ax.plot([], [], color=PALETTE[0], label=f"|A^k v| / |v|, {n_directions} directions")
    ax.set(xlabel="iteration k (strides)", ylabel="growth", xlim=(0, iterations),
           title="return map: growth of perturbations")
    ax.legend(loc="best", fontsize=8)
    return fig
