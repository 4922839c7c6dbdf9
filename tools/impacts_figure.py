"""The figure of where a reset lands (docs/impacts_semantics.png): h along three impacts.

    python tools/impacts_figure.py docs/impacts_semantics.png

Three simulations by bderiv, one panel each, the event function ``h`` against time with
the impact's reset drawn as a jump (dashed) and the region mask after it:

- a bounce (:func:`bderiv.examples.bouncing_ball`, ``h = -q``): the reset lands on the
  surface and the free flight takes the ball back to ``h < 0``: the bit is kept;
- a leg swap (:func:`bderiv.examples.rimless_wheel`, ``h = theta - alpha``): the reset
  lands at ``h = -2 alpha``, back on the side the step came from: the bit is kept;
- a plastic impact that stays in contact (a ball landing on compliant ground that
  absorbs half its speed at the impact, ``h = -q``): the reset lands on the surface and
  the flow of the region beyond carries the state into ``h > 0``: the bit is set, and the
  lift-off is a later downward crossing.
"""

from __future__ import annotations

import argparse

import numpy as np
from scipy.integrate import quad

from bderiv import HybridSystem
from bderiv.examples import bouncing_ball, rimless_wheel

#: the compliant ground of the third panel (per unit mass) and its impact's restitution
STIFFNESS, DAMPING, KEEP = 400.0, 4.0, 0.5


def compliant_landing():
    """A ball landing on a spring-damper ground; the impact keeps KEEP of the speed."""

    def field(x, mask):
        push = -STIFFNESS * x[0] - DAMPING * x[1] if mask & 1 else 0.0
        return np.array([x[1], -9.81 + push])

    system = HybridSystem(field, lambda x: np.array([-x[0]]), n_events=1, dim=2,
                          reset=lambda x, mask, k: np.array([x[0], KEEP * x[1]])
                          if not mask & 1 else x)
    return system, np.array([0.3, 0.0]), 0.5


def _panel(ax, system, x0, t_final, h, title, ylabel, bottom=1.25):
    traj = system.simulate(x0, t_final, max_step=t_final / 200, simultaneity_tol=1e-9)
    values = np.array([h(x) for x in traj.x])
    cuts = [0, *(int(i) + 1 for i in np.flatnonzero(np.diff(traj.t) == 0)), len(traj.t)]
    for a, b in zip(cuts[:-1], cuts[1:], strict=True):  # the stretches between jumps
        ax.plot(traj.t[a:b], values[a:b], color="#4477AA", lw=1.6,
                label="$h$ along the flow" if a == 0 else None)
    ax.axhline(0.0, color="black", lw=0.8)
    top = max(values.max(), 0.1 * np.abs(values).max())
    ax.axhspan(0.0, 1.5 * top, color="#EEEEEE", zorder=0)
    for i, g in enumerate(traj.groups):
        before, after = h(g.state), h(g.state_after)
        ax.plot([g.time, g.time], [before, after], ls="--", color="#EE6677", lw=1.4,
                label="reset (the jump)" if i == 0 else None)
        ax.plot([g.time], [after], "o", color="#EE6677", ms=4,
                label="state after the reset" if i == 0 else None)
        if (g.mask_before ^ g.mask_after) & 1:
            label = "bit set" if g.directions[0] > 0 else "bit cleared"
        else:
            label = "bit kept"
        way = "up" if g.directions[0] > 0 else "down"
        ax.annotate(f"{way}: {label}", (g.time, after), textcoords="offset points",
                    xytext=(-9, -11), ha="right", fontsize=7)
    ax.set_ylim(bottom * values.min(), 1.5 * top)
    ax.set_title(title, fontsize=9)
    ax.set_xlabel("time")
    ax.set_ylabel(ylabel)


def _wheel_speed(wheel, theta):
    """The wheel's speed at theta on its gait, from its energy at mid-stance (g = leg =
    1, slope 0.08: the example's defaults)."""
    return np.sqrt(wheel.x0[1] ** 2 + 2.0 * (np.cos(0.08) - np.cos(theta + 0.08)))


def draw(path):
    from matplotlib.figure import Figure

    fig = Figure(figsize=(11.0, 3.4), layout="constrained")
    axes = fig.subplots(1, 3)
    ball = bouncing_ball(e=0.6, height=0.5)
    _panel(axes[0], ball.system, ball.x0, 0.85, lambda x: -x[0],
           "a bounce (ball, $e = 0.6$): lands on $h = 0$,\nleaves it downward", "$h = -q$")
    wheel = rimless_wheel()
    x0 = wheel.x0
    alpha = wheel.rho[0]
    period = quad(lambda th: 1.0 / _wheel_speed(wheel, th), -alpha, alpha)[0]
    _panel(axes[1], wheel.system, x0, wheel.t_event + 1.15 * period, lambda x: x[0] - alpha,
           "a leg swap (rimless wheel): lands at\n$h = -2\\alpha$, back where the step began",
           "$h = \\theta - \\alpha$", bottom=1.5)
    system, x0, t_final = compliant_landing()
    _panel(axes[2], system, x0, t_final, lambda x: -x[0],
           "a plastic impact that stays in contact:\nlands on $h = 0$, moves into $h > 0$",
           "$h = -q$")
    axes[0].legend(loc="lower right", fontsize=7, frameon=False)
    notes = (((0.97, 0.3, "right"), "reset $(q, v) \\to (q, -0.6\\,v)$:\n"
              "$h$ keeps its value, its rate\nchanges sign"),
             ((0.5, 0.03, "center"), "reset $(\\theta, \\omega) \\to$\n"
              "$(\\theta - 2\\alpha,\\ \\cos(2\\alpha)\\,\\omega)$"),
             ((0.97, 0.06, "right"), f"reset $(q, v) \\to (q, {KEEP:g}\\,v)$:\n"
              f"$h$ keeps its value, its rate\nhalved; the ground's spring\npushes the ball "
              f"back out"))
    for ax, ((x, y, ha), text) in zip(axes, notes, strict=True):
        ax.text(x, y, text, transform=ax.transAxes, ha=ha, va="bottom", fontsize=7,
                color="#333333")
    for ax in axes:
        ax.text(0.99, 0.97, "$h > 0$ (bit set)", transform=ax.transAxes, ha="right",
                va="top", fontsize=7, color="#555555")
    fig.savefig(path, dpi=120)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("path", nargs="?", default="docs/impacts_semantics.png")
    draw(parser.parse_args(argv).path)


if __name__ == "__main__":
    main()
