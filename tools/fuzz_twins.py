"""Compiled models against their Python twins: the three arms and their comparison.

The models of ``tools/fuzz_models.py`` run

- ``python``: as Python functions (``HybridSystem`` on scipy's ``solve_ivp``, DOP853);
- ``compiled``: ``numba.njit`` of them (the compiled DOP853 and the compiled run of the
  stops); in about a third of the models without the field's or the events' Jacobian,
  which the compiled path then takes by complex step (exact to rounding, as the given ones);
- ``compiled-python-stops``: the compiled model with ``run.compiled_stops`` off, so that
  the Python loop decides every stop on the same compiled stretches;

and must give the same answer or the same refusal: ``compiled`` and
``compiled-python-stops`` to the bit (docs/design.md, the compiled run), and ``python``
against ``compiled`` within the integration accuracy (``STATE_RTOL``, ``FLOW_RTOL``).
What is compared: ``simulate`` (``run``; the event log: events, directions, masks after;
the group times and the final state; and in each arm, every sample on its mask's side of
every surface) and ``flow_bderivative`` applied to random directions (its two steps:
``run`` with the variational equations, ``flow_map_along``; the maps' event orders per
group too, away from ties), or the refusal's kind (``kind``: the first line's cause). A
disagreement whose model puts a designed gap within a factor 3 of the time the stop
resolves or within 1e-3 of ``simultaneity_tol`` (``Model.borderline``) is a decision at
the accuracy's edge: counted as ``borderline``, not as a wrong answer.

    python tools/fuzz_twins.py FAMILY SEED    # one model's three arms (a reproducer)
"""

from __future__ import annotations

import numpy as np
from fuzz_models import ATOL, RTOL, draw, events

from bderiv._limits import DERIVATIVE_SIMULTANEITY_TOL, SIMULATION_SIMULTANEITY_TOL
from bderiv.models.integrate import run as run_module
from bderiv.models.integrate.options import SolverOptions

OPTIONS = SolverOptions(rtol=RTOL, atol=ATOL)
#: a run of more groups is refused (Zeno): the models meet a few; a chattering one would
#: cost minutes at the default 10,000 (the Python loop, group by group)
MAX_GROUPS = 200
#: python against compiled: states and group times within ``STATE_RTOL (1 + |x|)`` (or
#: ``(1 + t)``). Each integrator's global error is at most its steps' errors carried along,
#: about ``steps * (ATOL + RTOL |x|) * exp(L T)``: under 100 steps and ``L T <= 2`` here,
#: at most ~1e3 RTOL; the two runs stop at event times located by different root finders, so
#: their errors are independent. Measured over 29,040 models (``fuzz.py --families models
#: --evaluations 800000 --seed 2026``, 2026-11-28): at most 0.09 of it on grazing models
#: (a crossing at a small rate moves in time by the state's error over the rate), 4e-5 of
#: it on the others, where the two integrators agree to about 1e-12.
STATE_RTOL = 1e-7
#: flow maps: ``FLOW_RTOL`` of ``|v| max |piece|`` per direction. The variational equations
#: are integrated with the state under the same error control (``STATE_RTOL``), and a
#: group's map is built from the fields and gradients at the group's state (Lipschitz in it,
#: slopes of order 1 here) and from the rates, divided by: 10x the states' tolerance
FLOW_RTOL = 1e-6
#: refusals by the cause their first line names (the first match)
KINDS = (("do not commute", "do not commute"), ("not at that point", "not at that point"),
         ("just after t_final", "final time: not of each other"),
         ("at the final time", "final time with resets"),
         ("slide along", "sliding"), ("carry the state across", "jump across"),
         ("landing is not an event", "sent straight back"),
         ("cannot be decided", "grazing peak"), ("not located", "inside a step"),
         ("crosses at once", "crossing at once"),
         ("transversality violated", "transversality violated"), ("Zeno", "Zeno"),
         ("x0 lies on", "start on a surface"), ("on a surface", "start on a surface"))


def kind(exc) -> str:
    """The refusal's kind: its type and the cause its first line names."""
    msg = str(exc).split("\n")[0]
    for word, name in KINDS:
        if word in msg:
            return name
    return f"{type(exc).__name__}: {msg[:70]}"


# -- the three arms and their comparison -------------------------------------------------
class _PythonStops:
    """Within it, the Python loop decides every stop (the compiled run is not used)."""

    def __enter__(self):
        self.saved = run_module.compiled_stops
        run_module.compiled_stops = lambda system, section: False

    def __exit__(self, *exc):
        run_module.compiled_stops = self.saved


def _outcome(call, system, python_stops=False):
    """``(result, None)`` or ``(None, exception)`` of ``call(system)``."""
    try:
        if python_stops:
            with _PythonStops():
                return call(system), None
        return call(system), None
    except Exception as exc:  # noqa: BLE001  (anything but a refusal is counted wrong)
        return None, exc


def bit_difference(a, b) -> str | None:
    """The first difference between two trajectories (arrays to the bit), or None."""
    for name in ("t", "x", "masks", "x_final"):
        if not np.array_equal(getattr(a, name), getattr(b, name)):
            return f"{name} differs"
    if a.events != b.events or a.mask_final != b.mask_final:
        return "event log differs"
    for g, h in zip(a.groups, b.groups, strict=True):
        if (g.time, g.events, g.mask_before, g.mask_after) != \
                (h.time, h.events, h.mask_before, h.mask_after):
            return f"group at t={g.time:.17g} differs"
        if not (np.array_equal(g.state, h.state) and np.array_equal(g.state_after, h.state_after)):
            return f"group state at t={g.time:.17g} differs"
    for p, q in zip(a.linear, b.linear, strict=True):
        if not np.array_equal(p, q):
            return "linear stage differs"
    return None


def log_of(traj):
    """The event log without times: (event, direction, mask after) per record."""
    return [(r.event, r.direction, r.mask) for r in traj.events]


def lost_crossing(traj, p) -> str | None:
    """The first sample of ``traj`` that lies across a surface, by more than ``STATE_RTOL
    (1 + |x|)``, from the side its region's mask says (a crossing lost), or None: an
    invariant of each run, whatever the other arm does."""
    for t, x, mask in zip(traj.t, traj.x, traj.masks, strict=True):
        h = events(np.concatenate((x, p)))
        side = (mask >> np.arange(h.size)) & 1
        across = np.where(side == 1, -h, h) > STATE_RTOL * (1 + np.abs(x).max())
        if across.any():
            return f"t={t:.17g}, mask {mask:#b}, h={h.tolist()}"
    return None


def state_excess(p, c) -> float:
    """The largest ratio of python's and compiled's differences (group times, group
    states, final state) to their tolerance (``STATE_RTOL``); the logs are equal."""
    worst = float(np.abs(p.x_final - c.x_final).max()
                  / (STATE_RTOL * (1 + np.abs(p.x_final).max())))
    for g, h in zip(p.groups, c.groups, strict=True):
        worst = max(worst, abs(g.time - h.time) / (STATE_RTOL * (1 + abs(g.time))),
                    float(np.abs(g.state - h.state).max()
                          / (STATE_RTOL * (1 + np.abs(g.state).max()))))
    return worst


def flow_excess(fp, fc, V):
    """Per direction, python's and compiled's flow maps apart over ``FLOW_RTOL |v| max
    |piece|`` (the row sums of the piece matrices), and the directions whose event orders
    differ where the times of no group are within 1e-6 of a tie."""
    P = np.abs(fp.piece_matrices(V)).sum(axis=2).max(axis=1)
    ratio = np.abs(fp(V) - fc(V)).max(axis=1) / (FLOW_RTOL * np.abs(V).max(axis=1) * P)
    orders_differ = np.zeros(V.shape[0], dtype=bool)
    for (tp, op), (_, oc) in zip(fp.event_times(V), fc.event_times(V), strict=True):
        if tp.shape[1] < 2:
            continue
        s = np.sort(tp, axis=1)
        clear = (np.diff(s, axis=1).min(axis=1) > 1e-6 * np.abs(s).max(axis=1))
        orders_differ |= clear & (op != oc).any(axis=1)
    return ratio, orders_differ


def check_model(model, tally) -> None:
    """Run the model on the three arms (``simulate``, then ``flow_bderivative`` on
    ``model.V``) and count agreements, refusals and disagreements in ``tally``."""
    tally.systems[model.family] += 1
    P, C = model.systems()
    for what, tol in (("simulate", SIMULATION_SIMULTANEITY_TOL),
                      ("flow", DERIVATIVE_SIMULTANEITY_TOL)):
        def call(s, what=what, tol=tol):  # flow_bderivative's two steps, the run kept
            traj = run_module.run(s.calls, model.x0, model.t_final,
                                  options=OPTIONS.with_overrides(simultaneity_tol=tol),
                                  variational=what == "flow", max_groups=MAX_GROUPS)
            return traj if what == "simulate" else (traj, s.flow_map_along(traj))
        c, cp, p = _outcome(call, C), _outcome(call, C, True), _outcome(call, P)
        note = _Note(tally, model, what, model.borderline(tol))
        _same_bits(note, what, c, cp, model.V)
        _same_answer(note, what, p, c, model.V)


class _Note:
    """Counts a disagreement of one model's call: a wrong answer unless ``borderline``
    (then only by kind, tagged)."""

    def __init__(self, tally, model, what, borderline):
        self.tally, self.model, self.what, self.borderline = tally, model, what, borderline

    def __call__(self, how, detail, borderline=None):
        fam, tag = self.model.family, ""
        if (self.borderline if borderline is None else borderline):
            tag = "borderline: "
        self.tally.disagreed[fam][f"{tag}{self.what}: {how}"] += 1
        if not tag and len(self.tally.seeds[fam]) < 20:  # every wrong model's seed, to rerun
            self.tally.seeds[fam].append(self.model.seed)
        line = f"{self.what}: {how}: {detail} [model seed {self.model.seed}]"
        if not tag:
            self.tally.bad(fam, line)
        elif len(self.tally.examples[fam]) < 6:  # a few, to look at
            self.tally.examples[fam].append(f"[{fam}] {tag}{line}")


def _same_bits(note, what, c, cp, V) -> None:
    """The compiled run against the Python loop on the same compiled stretches: the same
    bits, or the same refusal word for word (never borderline)."""
    (c, ec), (cp, ecp) = c, cp
    note.tally.evaluations[note.model.family] += 1
    how = None
    if (ec is None) != (ecp is None):
        how, detail = "one refuses", f"compiled: {ec}; python stops: {ecp}"
    elif ec is not None:
        if (type(ec), str(ec)) != (type(ecp), str(ecp)):
            how, detail = "other refusal", f"compiled: {ec}; python stops: {ecp}"
    elif what == "simulate" and bit_difference(c, cp):
        how, detail = "other bits", bit_difference(c, cp)
    elif what == "flow" and bit_difference(c[0], cp[0]):
        how, detail = "other bits", bit_difference(c[0], cp[0])
    elif what == "flow" and (c[1].group_events != cp[1].group_events
                             or not np.array_equal(c[1](V), cp[1](V))):
        how, detail = "other bits", "flow map"
    if how:
        note(f"compiled run vs Python stops: {how}", detail, borderline=False)


def _same_answer(note, what, p, c, V) -> None:
    """Python against compiled: the same refusal kind, or answers within the accuracy."""
    (p, ep), (c, ec) = p, c
    fam, tally = note.model.family, note.tally
    tally.evaluations[fam] += 1
    crashed = [(who, e) for who, e in (("python", ep), ("compiled", ec))
               if e is not None and not isinstance(e, (ValueError, RuntimeError))]
    if crashed:  # not a refusal: a TypeError, an IndexError, ...
        note(f"{crashed[0][0]} raised {type(crashed[0][1]).__name__}", repr(crashed[0][1]),
             borderline=False)
        return
    if ep is not None or ec is not None:
        if ep is None or ec is None:
            who, exc = ("python", ep) if ep is not None else ("compiled", ec)
            note(f"only {who} refuses ({kind(exc)})", str(exc))
        elif kind(ep) == kind(ec):
            tally.refused[fam][f"{what}: {kind(ep)}"] += 1
        else:
            note(f"other refusals ({kind(ep)} / {kind(ec)})", f"python: {ep}; compiled: {ec}",
                 borderline=note.borderline or _graze_seen_apart(note.model, ep, ec))
        return
    if what == "flow":
        (p_traj, p), (c_traj, c) = p, c
    for who, traj in (("python", p_traj if what == "flow" else p),
                      ("compiled", c_traj if what == "flow" else c)):
        lost = lost_crossing(traj, note.model.p)
        if lost:
            note(f"{who}: a sample across a surface its mask does not say", lost)
    if what == "simulate":
        groups = ([g.events for g in p.groups], [g.events for g in c.groups])
        if log_of(p) != log_of(c):
            note("event logs differ", f"python {log_of(p)}, compiled {log_of(c)}")
        elif groups[0] != groups[1]:
            note("groups differ", f"python {groups[0]}, compiled {groups[1]}")
        else:
            ratio = state_excess(p, c)
            tally.worst[fam] = max(tally.worst[fam], ratio)
            if not ratio <= 1:
                note("states apart", f"{ratio:.3g} x the tolerance")
        return
    if p.group_events != c.group_events or p.stops_at_group != c.stops_at_group:
        note("flow map's groups differ", f"python {p.group_events}, compiled {c.group_events}")
        return
    ratio, orders_differ = flow_excess(p, c, V)
    tally.evaluations[fam] += 2 * V.shape[0]
    tally.worst[fam] = max(tally.worst[fam], float(ratio.max(initial=0.0)))
    if not (ratio <= 1).all():
        note("flow maps apart", f"{ratio.max():.3g} x the tolerance")
    if orders_differ.any():
        note("event orders differ", f"{orders_differ.sum()} directions")
    tally.orders[fam] += sum(len({tuple(r) for r in o}) for o in c.orders(V))


def _graze_seen_apart(model, ep, ec) -> bool:
    """Whether two refusals are one undecidable graze, seen by the two integrators apart:
    the designed event peaks within the accuracy of its value (``model.graze``), one
    integrator's step ends straddle the peak by a rounding (the two states differ by about
    1e-12) and it locates a crossing there, at a rate near zero, that the region beyond
    sends back ("transversality violated ... after switching": refused), while the other's
    step ends are both below and its excursion screen finds the peak within the accuracy
    ("grazing peak": refused). Neither answers; which refusal is a rounding. Other pairs of
    kinds, or another event, or a peak clear of the accuracy, stay wrong."""
    if model.graze is None:
        return False
    k, peak, accuracy = model.graze
    named = {kind(ep), kind(ec)} == {"grazing peak", "transversality violated"}
    said = [f"event {k} comes within", f"after switching events [{k}]: event {k} has rate"]
    return named and abs(peak) <= accuracy and all(
        any(phrase in str(e).split("\n")[0] for phrase in said) for e in (ep, ec))


def draw_seeded(rng, family, m):
    """A model drawn from its own seed (``model.seed``: ``repro`` draws it again)."""
    seed = int(rng.integers(2**62))
    model = draw(np.random.default_rng(seed), family, m)
    model.seed = seed
    return model


def repro(family, seed, m=8) -> None:
    """Print the three arms' outcomes of one model (``python tools/fuzz_twins.py FAMILY
    SEED``)."""
    model = draw(np.random.default_rng(seed), family, m)
    print(f"n={model.n} d={model.d} x0={model.x0.tolist()} t_final={model.t_final!r}, "
          f"complex step (field, events): {model.complex_step}\n"
          f"gaps={model.gaps.tolist()} window_time={model.window_time.tolist()}")
    P, C = model.systems()
    for what in ("simulate", "flow_bderivative"):
        for name, system, stops in (("compiled", C, False), ("compiled, Python stops", C, True),
                                    ("python", P, False)):
            res, exc = _outcome(lambda s, what=what: run_module.run(
                s.calls, model.x0, model.t_final, max_groups=MAX_GROUPS,
                variational=what == "flow_bderivative",
                options=OPTIONS.with_overrides(simultaneity_tol=(
                    SIMULATION_SIMULTANEITY_TOL if what == "simulate" else
                    DERIVATIVE_SIMULTANEITY_TOL))), system, stops)
            if exc is not None:
                print(f"{what} [{name}]: refused: {exc}")
            else:
                print(f"{what} [{name}]: {[(g.time, g.events, g.mask_after) for g in res.groups]}"
                      f" x_final={res.x_final.tolist()}")
                print(f"    samples across a surface: {lost_crossing(res, model.p)}")


if __name__ == "__main__":
    import sys
    repro(sys.argv[1], int(sys.argv[2]))
