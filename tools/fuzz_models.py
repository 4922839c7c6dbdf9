"""The ``models`` families of ``tools/fuzz.py``: compiled models against their Python twins.

Each model is drawn once (seeded) as the parameter vector of five plain functions written in
the loop style numba accepts (``field``, ``field_jacobian``, ``events``, ``event_jacobian``,
``reset``, ``reset_jacobian`` below: every one takes ``x`` of shape (d + m,), the state
followed by the parameters, whose last two entries are n and d). The same functions run

- ``python``: as Python functions (``HybridSystem`` on scipy's ``solve_ivp``, DOP853);
- ``compiled``: ``numba.njit`` of them (the compiled DOP853 and the compiled run of the
  stops), compiled once per process whatever the model (the coefficients are ``params``);
  in about a third of the models without the field's or the events' Jacobian, which the
  compiled path then takes by complex step (exact to rounding, as the given ones);
- ``compiled-python-stops``: the compiled model with ``run.compiled_stops`` off, so that
  the Python loop decides every stop on the same compiled stretches.

and must give the same answer or the same refusal: ``compiled`` and
``compiled-python-stops`` to the bit (docs/design.md, the compiled run), and ``python``
against ``compiled`` within the integration accuracy (``STATE_RTOL``, ``FLOW_RTOL``).
What is compared: ``simulate`` (``run``; the event log: events, directions, masks after; the group
times and the final state; and in each arm, every sample on its mask's side of every
surface) and ``flow_bderivative`` at the run's end applied to random
directions (its two steps: ``run`` with the variational equations, ``flow_map_along``; the
maps' event orders per group too, away from ties), or the refusal's kind
(``kind``: the first line's cause).

Families (keys of ``FAMILIES``): ``models-plain`` (fields ``A_mask x + b_mask + c_mask
sin(x_next)``, events affine or quadratic, the first crossing at a drawn point), ``-sim``
(two or three events through one point of the trajectory: simultaneous to rounding;
constant fields in half of them: exactly), ``-near`` (their crossings ``gap`` = 1e-12..1e-6
apart), ``-graze`` (an event whose value peaks at ``delta`` = 0 or +-1e-14..1e-6 of its
surface), ``-resets`` (event k reads coordinate k alone; its reset jumps that coordinate
across (or not) and maps a coordinate of its own affinely: the resets commute; a fifth of
the models share that coordinate between two events: they do not), ``-final`` (a ``-sim``
or ``-near`` model stopped within 1e-7 of its group). A disagreement whose model puts a
designed gap within a factor 3 of the time the stop resolves (``window_time``) or within
1e-3 of ``simultaneity_tol`` is a decision at the accuracy's edge: counted as
``borderline``, not as a wrong answer.
"""

from __future__ import annotations

import numba
import numpy as np
from numba.extending import register_jitable
from scipy.integrate import solve_ivp

from bderiv import HybridSystem
from bderiv._limits import DERIVATIVE_SIMULTANEITY_TOL, SIMULATION_SIMULTANEITY_TOL
from bderiv.models.integrate import run as run_module

#: both integrators run with these (the defaults): DOP853's step control keeps each step's
#: error below ``ATOL + RTOL |x|``
RTOL, ATOL = 1e-10, 1e-12
OPTIONS = run_module.SolverOptions(rtol=RTOL, atol=ATOL)
#: a run of more groups is refused (Zeno): the models meet a few; a chattering one would
#: cost minutes at the default 10,000 (the Python loop, group by group)
MAX_GROUPS = 200
#: python against compiled: states and group times within ``STATE_RTOL (1 + |x|)`` (or
#: ``(1 + t)``). Each integrator's global error is at most its steps' errors carried along,
#: about ``steps * (ATOL + RTOL |x|) * exp(L T)``: under 100 steps and ``L T <= 2`` here,
#: at most ~1e3 RTOL; the two runs stop at event times located by different root finders, so
#: their errors are independent. Measured: see the report of the tool's long run.
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
         ("cannot be decided", "grazing peak"), ("not located", "inside a step"),
         ("transversality violated", "transversality violated"), ("Zeno", "Zeno"),
         ("x0 lies on", "start on a surface"), ("on a surface", "start on a surface"))


def kind(exc) -> str:
    """The refusal's kind: its type and the cause its first line names."""
    msg = str(exc).split("\n")[0]
    for word, name in KINDS:
        if word in msg:
            return name
    return f"{type(exc).__name__}: {msg[:70]}"


# -- the model's functions, written once (Python calls them as they are) -------------------
@register_jitable
def _sizes(x):
    """(n, d, first entry of the events' block, of rho, of the resets' block)."""
    d, n = int(x[x.size - 1].real), int(x[x.size - 2].real)
    events = d + (1 << n) * (d * d + 2 * d)
    rho = events + n * (2 * d + 2)
    return n, d, events, rho, rho + d


def field(x, mask):
    """``A x + b + c_i sin(x_{i+1})`` of region ``mask`` (its block of d d + 2 d values)."""
    n, d, _, _, _ = _sizes(x)
    base = d + mask * (d * d + 2 * d)
    out = np.zeros_like(x[:d])
    for i in range(d):
        s = x[base + d * d + i] + x[base + d * d + d + i] * np.sin(x[(i + 1) % d])
        for j in range(d):
            s += x[base + i * d + j] * x[j]
        out[i] = s
    return out


def field_jacobian(x, mask):
    n, d, _, _, _ = _sizes(x)
    base = d + mask * (d * d + 2 * d)
    J = np.zeros((d, d))
    for i in range(d):
        for j in range(d):
            J[i, j] = x[base + i * d + j].real
        k = (i + 1) % d
        J[i, k] += (x[base + d * d + d + i] * np.cos(x[k])).real
    return J


def events(x):
    """``h_k = D_k (x - rho) + q_k sum_j W_kj (x_j - rho_j)^2 + e_k``."""
    n, d, ev, rho, _ = _sizes(x)
    out = np.zeros_like(x[:n])
    for k in range(n):
        base = ev + k * (2 * d + 2)
        s = x[base + 2 * d + 1]
        for j in range(d):
            dx = x[j] - x[rho + j]
            s += x[base + j] * dx + x[base + 2 * d] * x[base + d + j] * dx * dx
        out[k] = s
    return out


def event_jacobian(x):
    n, d, ev, rho, _ = _sizes(x)
    J = np.zeros((n, d))
    for k in range(n):
        base = ev + k * (2 * d + 2)
        for j in range(d):
            J[k, j] = (x[base + j] + 2.0 * x[base + 2 * d] * x[base + d + j]
                       * (x[j] - x[rho + j])).real
    return J


def reset(x, mask, k):
    """Event k's reset: coordinate p_k moves by s_k across the surface (the crossing's
    direction), coordinate v_k -> a_k x_{v_k} + b_k (block (s, a, b, p, v) of event k)."""
    n, d, _, _, rs = _sizes(x)
    base = rs + 5 * k
    out = x[:d].copy()
    p, v = int(x[base + 3].real), int(x[base + 4].real)
    out[p] += -x[base] if mask >> k & 1 else x[base]
    out[v] = x[base + 1] * x[v] + x[base + 2]
    return out


def reset_jacobian(x, mask, k):
    n, d, _, _, rs = _sizes(x)
    J = np.eye(d)
    v = int(x[rs + 5 * k + 4].real)
    J[v, v] = x[rs + 5 * k + 1].real
    return J


FUNCTIONS = (field, field_jacobian, events, event_jacobian, reset, reset_jacobian)
_COMPILED = []


def compiled():
    """The njit of the six functions, made once per process (compiled at the first run,
    cached on disk beside this file)."""
    if not _COMPILED:
        _COMPILED.extend(numba.njit(f, cache=True) for f in FUNCTIONS)
    return tuple(_COMPILED)


# -- drawing a model ------------------------------------------------------------------------
class Model:
    """A drawn model: ``p`` (the parameters), sizes, start, final time, the designed gaps
    (time between the crossings of the designed events) and the time each designed
    event's stop resolves (``window_time``)."""

    def __init__(self, family, n, d, p, x0, t_final, resets, gaps, window_time, rng,
                 final_gaps=()):
        self.family, self.n, self.d, self.p = family, n, d, p
        self.final_gaps = final_gaps
        self.x0, self.t_final, self.resets = x0, t_final, resets
        self.gaps, self.window_time = gaps, window_time
        self.V = rng.standard_normal((0, d))
        self.complex_step = (False, False)

    def systems(self):
        """``(python, compiled)`` HybridSystems of the model (fresh: nothing checked); the
        compiled one without the field's or the events' Jacobian where ``complex_step``
        says (its complex step then: exact to rounding, as the given ones)."""
        out = []
        for fns, drop in ((FUNCTIONS, (False, False)), (compiled(), self.complex_step)):
            f, fj, ev, ej, r, rj = fns
            kw = dict(reset=r, reset_jacobian=rj) if self.resets else {}
            out.append(HybridSystem(f, ev, n_events=self.n, dim=self.d,
                                    field_jacobian=None if drop[0] else fj,
                                    event_jacobian=None if drop[1] else ej, params=self.p,
                                    **kw))
        return out

    def borderline(self, tol) -> bool:
        """Whether a designed gap is at the edge of a decision: within a factor 3 of the
        time the stop resolves, or within 1e-3 of ``tol`` (simultaneity_tol); the gap
        between the designed group and a final time near it too (0 included)."""
        w = max(self.window_time)
        if any(g <= 3 * w or abs(g - tol) <= 1e-3 * tol for g in self.final_gaps):
            return True
        return any(g > 0 and (w / 3 <= g <= 3 * w or abs(g - tol) <= 1e-3 * tol)
                   for g, w in zip(self.gaps, self.window_time, strict=True))


def _flow_back(fn, p, mask, rho, t):
    """The state from which region ``mask``'s field reaches ``rho`` after time t."""
    sol = solve_ivp(lambda _, y: -fn(np.concatenate((y, p)), mask), (0.0, t), rho,
                    method="DOP853", rtol=1e-13, atol=1e-15)
    return sol.y[:, -1]


def draw(rng, family, m):
    """One model of ``family`` (a key of ``FAMILIES``) and ``m`` directions."""
    final = family == "models-final"
    if final:
        family = "models-sim" if rng.random() < 0.5 else "models-near"
    with_resets = family == "models-resets"
    n = int(rng.integers(1, 4)) if with_resets else int(rng.integers(1, 5))
    d = 2 * n if with_resets else int(rng.integers(max(2, n), 7))
    if family in ("models-sim", "models-near") and n == 1:
        n, d = 2, max(d, 2)
    N = 1 << n
    # fields: a common one plus a per-region perturbation, so that rates keep their signs
    # across surfaces often (else most crossings are refused as crossing back)
    spread = 10.0 ** rng.uniform(-1.5, -0.3)
    constant = family == "models-sim" and rng.random() < 0.5
    A = (0.3 * rng.standard_normal((d, d)) + spread * rng.standard_normal((N, d, d))) \
        * (not constant)
    b = rng.standard_normal(d) + spread * rng.standard_normal((N, d))
    c = (0.3 * rng.standard_normal(d) + spread * rng.standard_normal((N, d))) \
        * (not constant and rng.random() < 0.6)
    D = rng.standard_normal((n, d))
    W = rng.standard_normal((n, d))
    q = 0.3 * rng.standard_normal(n) * (rng.random(n) < 0.5)
    e = np.zeros(n)
    rho = rng.standard_normal(d)
    mask0 = int(rng.integers(0, N))
    designed = (1 if family in ("models-plain", "models-graze") else
                int(rng.integers(1, n + 1)) if with_resets else
                int(rng.integers(2, min(n, 3) + 1)))
    S = rng.choice(n, designed, replace=False)
    if family == "models-graze":
        S = [k for k in range(n) if not mask0 >> k & 1][:1]
        if not S:
            mask0 &= ~1
            S = [0]
    reset_block = np.zeros((n, 5))
    if with_resets:
        D = np.diag(rng.choice([-1.0, 1.0], n) * rng.uniform(0.5, 2.0, n)) @ np.eye(n, d)
        W = np.eye(n, d)
        for k in range(n):  # the field moves coordinate k clearly at rho
            f0 = field(np.concatenate((rho, _params(A, b, c, D, W, q, e, rho, reset_block,
                                                     n, d))), mask0)
            b[mask0, k] += rng.choice([-1.0, 1.0]) * rng.uniform(0.5, 1.5) - f0[k]
        reset_block[:, 1] = rng.uniform(-0.9, 0.9, n)
        reset_block[:, 2] = 0.3 * rng.standard_normal(n)
        reset_block[:, 3] = np.arange(n)
        reset_block[:, 4] = n + np.arange(n)
        if n > 1 and rng.random() < 0.2:  # two events' resets on one coordinate
            reset_block[1, 4] = n
    p = _params(A, b, c, D, W, q, e, rho, reset_block, n, d)
    f0 = field(np.concatenate((rho, p)), mask0)
    J0 = field_jacobian(np.concatenate((rho, p)), mask0)
    t_star = rng.uniform(0.3, 1.0)
    gaps = np.zeros(len(S))
    for i, k in enumerate(S):
        up = 1.0 if not mask0 >> k & 1 else -1.0
        if family == "models-graze":  # D_k . f0 = 0, d^2 h / dt^2 = D_k J0 f0 < 0
            for _ in range(50):
                r = rng.standard_normal(d)
                r -= (r @ f0) / (f0 @ f0) * f0
                curv = r @ J0 @ f0
                if abs(curv) > 0.1 * np.linalg.norm(r) * np.linalg.norm(J0 @ f0):
                    break
            D[k], q[k] = -np.sign(curv) * r, 0.0
            e[k] = rng.choice([0.0, 1.0, -1.0]) * 10.0 ** rng.uniform(-14, -6)
            continue
        if not with_resets:  # rate D_k . f0 of the crossing's sign, clearly
            u = f0 / np.linalg.norm(f0)
            for _ in range(50):
                D[k] = up * rng.uniform(0.4, 1.0) * u + 0.5 * rng.standard_normal(d)
                if up * (D[k] @ f0) > 0.3 * np.linalg.norm(D[k]) * np.linalg.norm(f0):
                    break
        if with_resets and up * (D[k] @ f0) < 0:
            D[k] = -D[k]
        rate = D[k] @ f0
        if family == "models-near" and i > 0:
            gaps[i] = 10.0 ** rng.uniform(-12, -6)
            e[k] = -rate * gaps[i]  # crosses gaps[i] after the others (first order)
    if with_resets:  # a jump across the surface in 70 %: upward, along +D_kk
        jump = rng.uniform(0.01, 0.1, n) * (rng.random(n) < 0.7)
        reset_block[:, 0] = np.sign(D[np.arange(n), np.arange(n)]) * jump
    p = _params(A, b, c, D, W, q, e, rho, reset_block, n, d)
    x0 = _flow_back(field, p, mask0, rho, t_star)
    h0 = events(np.concatenate((x0, p)))
    for k in range(n):  # the other events well away from x0, on mask0's side
        if k not in S:
            e[k] += (1.0 if mask0 >> k & 1 else -1.0) * rng.uniform(0.2, 1.5) - h0[k]
    p = _params(A, b, c, D, W, q, e, rho, reset_block, n, d)
    t_final = t_star + rng.uniform(0.2, 1.5)
    if final:
        t_final = t_star + rng.choice([0.0, 1.0, -1.0]) * 10.0 ** rng.uniform(-12, -7)
    # the time a stop resolves: err = 10 (atol + rtol |x|) per coordinate, read by |D_k|
    err = 10 * (ATOL + RTOL * np.maximum(np.abs(x0), np.abs(rho)))
    sigma = np.abs(D[S]) @ err / np.maximum(np.abs(D[S] @ f0), 1e-300)
    window = sigma + sigma.max()
    model = Model(family if not final else "models-final", n, d, p, x0, t_final, with_resets,
                  np.abs(gaps - gaps.min()), window, rng,
                  np.abs(t_final - t_star - gaps) if final else ())
    model.V = rng.standard_normal((m, d))
    model.complex_step = tuple(rng.random(2) < 0.3)
    return model


def _params(A, b, c, D, W, q, e, rho, resets, n, d):
    blocks = np.concatenate((A.reshape(1 << n, d * d), b, c), axis=1)
    ev = np.concatenate((D, W, q[:, None], e[:, None]), axis=1)
    return np.concatenate((blocks.ravel(), ev.ravel(), rho, resets.ravel(), [n, d]))


FAMILIES = ("models-plain", "models-sim", "models-near", "models-graze", "models-resets",
            "models-final")


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
    except (ValueError, RuntimeError) as exc:
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
            traj = run_module.run(s, model.x0, model.t_final, simultaneity_tol=tol,
                                  options=OPTIONS, variational=what == "flow",
                                  max_groups=MAX_GROUPS)
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
    if ep is not None or ec is not None:
        if ep is None or ec is None:
            who, exc = ("python", ep) if ep is not None else ("compiled", ec)
            note(f"only {who} refuses ({kind(exc)})", str(exc))
        elif kind(ep) == kind(ec):
            tally.refused[fam][f"{what}: {kind(ep)}"] += 1
        else:
            note(f"other refusals ({kind(ep)} / {kind(ec)})", f"python: {ep}; compiled: {ec}")
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


def draw_seeded(rng, family, m):
    """A model drawn from its own seed (``model.seed``: ``repro`` draws it again)."""
    seed = int(rng.integers(2**62))
    model = draw(np.random.default_rng(seed), family, m)
    model.seed = seed
    return model


def repro(family, seed, m=8) -> None:
    """Print the three arms' outcomes of one model (``python tools/fuzz_models.py FAMILY
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
                s, model.x0, model.t_final, options=OPTIONS, max_groups=MAX_GROUPS,
                variational=what == "flow_bderivative",
                simultaneity_tol=(SIMULATION_SIMULTANEITY_TOL if what == "simulate" else
                                  DERIVATIVE_SIMULTANEITY_TOL)), system, stops)
            if exc is not None:
                print(f"{what} [{name}]: refused: {exc}")
            else:
                print(f"{what} [{name}]: {[(g.time, g.events, g.mask_after) for g in res.groups]}"
                      f" x_final={res.x_final.tolist()}")
                print(f"    samples across a surface: {lost_crossing(res, model.p)}")


if __name__ == "__main__":
    import sys
    repro(sys.argv[1], int(sys.argv[2]))
