"""Differential fuzzing of bderiv: every answer against an independent oracle or an invariant.

    python tools/fuzz.py [--evaluations N] [--seed S] [--rows M] [--families NAME ...]

Draws seeded systems from the families of ``tests/fuzz_families.py`` (dense tables: random,
n > d, huge entries, mixed and extreme scales, tiny rates, own-rates and additive tables
near the fast-path boundary, exact ties, and ``scales``: entries over 1e-150..1e150 with
queries scaled by 2**-1000..2**900; structured corner models, also at extreme scales; a
corner function; reset tables) and checks every query:

- ``apply``, ``inverse`` (of the oracle's answer, back to the query) and ``event_times``
  against the oracle of ``tests/reference.py``, within the tolerance of
  ``tests/chain_tolerance.py`` (resets: ``ref_reset_flow``, the trajectory followed in
  physical time);
- homogeneity over powers of two, bit for bit wherever the scaled answer is a normal
  float: ``M(2**k v) = 2**k M(v)``, the same for ``inverse`` and the event times, and
  ``jvp(2**k v, t) = jvp(v, t)``;
- the events renamed (rows of Dh and bits of the masks permuted): the same ``M(v)``, the
  times permuted;
- exact ties (the ``ties`` family: queries on the boundaries between pieces);
- ``jvp`` against finite differences of the PL map at two steps (rows where the two agree:
  the step stayed in one piece), ``jvp(v, v) = M(v)``, and ``vjp`` against ``jvp`` by
  ``<w, jvp(v, t)> = <vjp(v, w), t>``.

Prints per family the evaluations (answers checked), the wrong answers (outside tolerance,
an invariant broken, or a refusal where the answer is a normal float) and the refusals by
kind, each checked to be justified:

- ``overflow``: the result is beyond float64 (the oracle's answer has an entry of at
  least 2**1023);
- ``time beyond float64``: an event time over- or underflows (the oracle's time is beyond
  the normal numbers); ``apply``, ``inverse`` and ``orders`` still answer there;
- ``rate <= 0 on the chain``: a corner model's rate that the query meets is not positive
  (the oracle's rate of the named event and region is <= 0 to rounding).

Systems refused when built are counted apart, by kind: ``transversality``, ``grazing`` and
``ill-conditioned`` are the documented ``transversality_tol`` contract (the families aim
at it on purpose), ``rate beyond float64`` a table whose rates span more than the float64
range even after scaling. Exit status 1 when any answer is wrong.

The ``models`` families (``--families models``, or ``all`` with the others, or one of
them: ``models-plain``,
``-sim``, ``-near``, ``-graze``, ``-resets``, ``-final``; ``tools/fuzz_models.py``,
compared by ``tools/fuzz_twins.py``) draw
seeded hybrid models instead, written once as plain functions, and require the Python
model (scipy's solve_ivp), the compiled one (numba.njit of the same functions) and the
compiled one with its stops decided by the Python loop to give the same answer or the same
refusal (the last two to the bit); a disagreement is counted as a wrong answer, by kind,
or as ``borderline`` where the model puts a decision at the edge of the accuracy.
"""

from __future__ import annotations

import argparse
import os
import pathlib
import sys
import time
from collections import Counter, defaultdict

import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1] / "tests"))
sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))

import fuzz_models  # noqa: E402  (tools/: the models families)
import fuzz_twins  # noqa: E402
from chain_tolerance import RTOL, chain_scale, excess, oracle  # noqa: E402
from fuzz_families import (  # noqa: E402
    FAMILIES,
    Case,
    fam_function,
    named_rate_is_not_positive,
    queries,
    scaled_reference,
    structured_corners,
)
from reference import random_reset_system, random_system, ref_reset_flow, relabel  # noqa: E402

from bderiv import BDerivative, StructuredCorners  # noqa: E402

os.environ.setdefault("BDERIV_INTEGRATOR", "compiled")  # compiled from the first run

#: a normal float64 is at least this in magnitude (below: subnormal, fewer digits)
TINY = np.finfo(np.float64).tiny
#: the tolerance of jvp against finite differences, relative to the chain's scale / step
FD_RTOL = 1e-7
#: powers of two per query for the homogeneity checks
SCALES = 4

BUILD_KINDS = (("transversality violated", "transversality"),
               ("transversality fails", "a row of zeros"), ("grazing", "grazing"),
               ("ill-conditioned", "ill-conditioned"),
               ("float64", "rate beyond float64"))
QUERY_KINDS = (("event times", "overflow"), ("time of event", "time beyond float64"),
               ("overflowed", "overflow"), ("transversality violated", "rate <= 0 on the chain"),
               ("non-finite value", "non-finite corner"))


def kind_of(msg: str, kinds) -> str:
    for word, kind in kinds:
        if word in msg:
            return kind
    return "unclear: " + msg[:60]


# -- families of this tool (the others: tests/fuzz_families.py) --------------------------
def fam_scales(rng, m):
    """A random table with rows of Dh and F scaled by powers of two up to about 1e+-150,
    queries scaled by 2**-1000..2**900 (``Case.exps``; the oracle runs unscaled)."""
    n = int(rng.integers(1, 6))
    d = int(rng.integers(n, 8))
    Dh, F = random_system(rng, n, d)
    Dh = np.ldexp(Dh, rng.integers(-500, 501, n)[:, None])
    exps = (0, int(rng.integers(-500, 501)), int(rng.integers(-1000, 901)))
    return Case("scales", Dh, F, F, queries(rng, m, d), exps)


def fam_scales_structured(rng, m):
    """Structured corners whose rows of Dh are scaled by up to 2**+-300 and queries by
    2**-1000..2**900 (the corners themselves at the oracle's scale)."""
    n = int(rng.integers(2, 8))
    d = int(rng.integers(2, 8))
    e = rng.standard_normal(d)
    e /= np.linalg.norm(e)
    Dh = e + 0.4 * rng.uniform(-1, 1, (n, d)) / np.sqrt(d)
    p = int(rng.integers(0, n + 1))
    pairs = np.array([rng.choice(n, 2, replace=False) for _ in range(p)],
                     dtype=np.int64).reshape(p, 2)
    F0, A, B = e * rng.uniform(0.5, 2.0), 0.3 * rng.standard_normal((n, d)) / n, \
        0.3 * rng.standard_normal((p, d)) / n
    Dh = np.ldexp(Dh, rng.integers(-300, 301, n)[:, None])
    return Case("scales-structured", Dh, StructuredCorners(F0, A, pairs, B),
                structured_corners(F0, A, pairs, B), queries(rng, m, d),
                (0, 0, int(rng.integers(-1000, 901))))


def fam_resets(rng, m):
    """Reset Jacobians commuting on the common tangent spaces (``random_reset_system``),
    queries scaled by 2**-1000..2**900."""
    n = int(rng.integers(1, 4))
    d = int(rng.integers(n + 1, 6))
    Dh, F, R = random_reset_system(rng, n, d)
    return Case("resets", Dh, F, F, queries(rng, m, d), (0, 0, int(rng.integers(-1000, 901))),
                resets=R)


ALL = {f.__name__[4:].replace("_", "-"): f for f in
       FAMILIES + (fam_function, fam_scales, fam_scales_structured, fam_resets)}
#: compiled models against their Python twins (tools/fuzz_models.py, fuzz_twins.py);
#: "models": all of them
MODELS = {name: (lambda rng, m, name=name: fuzz_twins.draw_seeded(rng, name, m))
          for name in fuzz_models.FAMILIES}


# -- the tally --------------------------------------------------------------------------
class Tally:
    """Evaluations, wrong answers and refusals per family (refusals per kind)."""

    def __init__(self):
        self.evaluations = Counter()
        self.wrong = Counter()
        self.systems = Counter()
        self.refused = defaultdict(Counter)  # family -> kind -> rows
        self.refused_systems = defaultdict(Counter)
        self.examples = defaultdict(list)  # the first wrong answers of each family
        self.disagreed = defaultdict(Counter)  # models: family -> kind -> count
        self.worst = defaultdict(float)  # models: the largest ratio to the tolerance
        self.orders = Counter()  # models: distinct event orders met (per group, summed)
        self.seeds = defaultdict(list)  # models: the seeds of the wrong ones (20 at most)

    def bad(self, fam: str, what: str) -> None:
        self.wrong[fam] += 1
        if len(self.examples[fam]) < 3:
            self.examples[fam].append(f"[{fam}] {what}")

    def report(self) -> str:
        lines = [f"{'family':<18}{'systems':>8}{'evaluations':>13}{'wrong':>7}  refusals"]
        for fam in sorted(self.systems):
            kinds = dict(self.refused[fam])
            kinds.update({f"system: {k}": v for k, v in self.refused_systems[fam].items()})
            lines.append(f"{fam:<18}{self.systems[fam]:>8}{self.evaluations[fam]:>13}"
                         f"{self.wrong[fam]:>7}  {kinds or ''}")
        lines.append(f"total: {sum(self.evaluations.values())} evaluations, "
                     f"{sum(self.wrong.values())} wrong")
        for fam in sorted(set(self.systems) & set(MODELS)):
            lines.append(f"{fam}: worst python/compiled difference {self.worst[fam]:.3g} x "
                         f"the tolerance, event orders met {self.orders[fam]}, "
                         f"disagreements {dict(self.disagreed[fam]) or 0}"
                         + (f", seeds {sorted(set(self.seeds[fam]))}" if self.seeds[fam] else ""))
        lines += [line for fam in sorted(self.examples) for line in self.examples[fam]]
        return "\n".join(lines)


# -- running a case ---------------------------------------------------------------------
def guarded(fn, X, width):
    """``fn(X)`` (m, width), or row by row when the batch is refused: (results with NaN
    rows where refused, {row: message})."""
    try:
        return np.asarray(fn(X), dtype=float).reshape(X.shape[0], width), {}
    except ValueError:
        pass
    out, refused = np.full((X.shape[0], width), np.nan), {}
    for i, x in enumerate(X):
        try:
            out[i] = np.asarray(fn(x), dtype=float).reshape(width)
        except ValueError as exc:
            refused[i] = str(exc)
    return out, refused


def beyond(x, shift=0) -> np.ndarray:
    """Rows of ``2**shift x`` with an entry that is not a normal float64 (inf, or nonzero
    below tiny, with a factor 2 of margin for rounding at the ends), judged on the
    exponents (nothing rounds on the way)."""
    x = np.asarray(x, dtype=float)
    with np.errstate(all="ignore"):
        e = np.frexp(x)[1] + shift
    return (~np.isfinite(x) | ((x != 0) & ((e >= 1024) | (e <= -1021)))).any(axis=1)


def raw_oracle(case: Case, u):
    """The oracle's (answer, times) of one unscaled query."""
    if case.resets is not None:
        return ref_reset_flow(case.Dh, case.F, case.resets, u)[:2]
    x, t, _ = oracle(case.Dh, case.ref, u[None])
    return x[0], t[0]


def judge_refusals(tally, case, refused, what) -> None:
    """Count each refused row by kind. A refusal is justified when the rate it names is
    <= 0 (a model's per-query check) or, for overflow and times beyond float64, when the
    oracle's answer (``what``: "apply", "times", or "inverse": the query itself) is not a
    normal float at the scale asked; any other is a wrong answer."""
    fam, (_, b, c) = case.family, case.exps
    for i, msg in refused.items():
        kind = kind_of(msg, QUERY_KINDS)
        if kind == "rate <= 0 on the chain":
            ok = named_rate_is_not_positive(case, msg)
        elif kind in ("overflow", "time beyond float64"):
            u = case.V[i]
            expected, shift = ((u, c) if what == "inverse" else
                               (raw_oracle(case, u)[what == "times"], c - b * (what == "times")))
            ok = bool(beyond(expected[None], shift)[0])
        else:
            ok = False
        if ok:
            tally.refused[fam][kind] += 1
        else:
            tally.bad(fam, f"{what}: refused without cause: {msg}")


def build(case: Case, perm=None):
    a, b, _ = case.exps
    Dh, F = case.Dh, case.F
    if perm is not None:
        Dh, F = relabel(Dh, F, perm)
    F = F if b == 0 or not isinstance(F, np.ndarray) else np.ldexp(F, b)
    return BDerivative(np.ldexp(Dh, a), F, resets=case.resets)


def reference(case: Case):
    """The oracle's answers at the scale bderiv works at (see ``scaled_reference``); for
    resets the trajectory in physical time, with a scale from its times."""
    if case.resets is None:
        return scaled_reference(case)
    c, R = case.exps[2], case.resets
    rows = [ref_reset_flow(case.Dh, case.F, R, u) for u in case.V]
    x = np.array([r[0] for r in rows])
    t = np.array([r[1] for r in rows])
    col = np.abs(case.F).max(axis=0)
    grow = (1 + np.abs(R).max()) ** case.Dh.shape[0]
    # the oracle starts 1 before the first event: its states are of that size too
    T = (np.abs(t).sum(axis=1) + 2 * np.abs(t).max(axis=1) + 1)[:, None]
    X = (np.abs(case.V) + np.abs(x) + 2 * T * col) * grow
    G = case.F @ case.Dh.T
    dt = (X @ np.abs(case.Dh).T) / np.abs(G).min(axis=0)
    S = X + 2 * col * dt.sum(axis=1)[:, None]
    return dict(V=np.ldexp(case.V, c), x=np.ldexp(x, c), S=np.ldexp(S, c),
                S_back=np.ldexp(S, c), t=np.ldexp(t, c), dt=np.ldexp(dt, c))


def check(case: Case, tally: Tally, rng) -> None:
    """Build the case's map, check apply, event times and inverse against the oracle,
    then the invariants (:func:`invariants`) on the rows that answered."""
    fam, (n, d) = case.family, case.Dh.shape
    tally.systems[fam] += 1
    try:
        bd = build(case)
    except ValueError as exc:
        tally.refused_systems[fam][kind_of(str(exc), BUILD_KINDS)] += 1
        if kind_of(str(exc), BUILD_KINDS).startswith("unclear"):
            tally.bad(fam, f"system refused without a clear cause: {exc}")
        return
    with np.errstate(all="ignore"):
        ref = reference(case)
    V, x, t = ref["V"], ref["x"], ref["t"]
    W, bad_w = guarded(bd, V, d)
    T, bad_t = guarded(lambda X: bd.event_times(X)[0], V, n)
    U, bad_u = guarded(bd.inverse, x, d)
    judge_refusals(tally, case, bad_w, "apply")
    judge_refusals(tally, case, bad_t, "times")
    judge_refusals(tally, case, bad_u, "inverse")
    ok = np.setdiff1d(np.arange(V.shape[0]), list({**bad_w, **bad_t, **bad_u}))
    if not ok.size:
        return
    scales = (ref["S"], ref["S_back"], np.abs(t) + ref["dt"])
    if case.resets is None:  # the larger of the two chains' scales
        orders = bd.orders(V[ok])
        (_, b, c) = case.exps
        with np.errstate(all="ignore"):
            S, S_back, dt, _ = chain_scale(case.Dh, case.corners, case.V[ok],
                                           np.ldexp(T[ok], b - c), orders)
        scales = tuple(np.maximum(s[ok], np.ldexp(o, e)) for s, o, e in
                       zip(scales, (S, S_back, dt), (c, c, c - b), strict=True))
        scales = (scales[0], scales[1], np.abs(t[ok]) + scales[2])
    else:
        scales = tuple(s[ok] for s in scales)
    for name, got, want, scale in (("apply", W, x, scales[0]), ("inverse", U, V, scales[1]),
                                   ("event_times", T, t, scales[2])):
        with np.errstate(all="ignore"):
            ratio = excess(got[ok], want[ok], scale)
        tally.evaluations[fam] += ok.size
        for i in np.flatnonzero(~(ratio <= 1)):
            tally.bad(fam, f"{name} off the oracle by {ratio[i]:.3g} x the tolerance: "
                           f"v = {V[ok[i]].tolist()}, got {got[ok[i]].tolist()}, want "
                           f"{want[ok[i]].tolist()}, exps {case.exps}")
    invariants(bd, case, tally, rng, V[ok], (W[ok], T[ok], U[ok], x[ok]), scales)


def same_bits(tally, fam, what, fn, X, raw, k, width) -> None:
    """``fn(X) == 2**k raw`` bit for bit on the rows where that is a normal float;
    refusals (overflow, times beyond float64) only where it is not."""
    got, refused = guarded(fn, X, width)
    normal = ~beyond(raw, k)
    with np.errstate(all="ignore"):
        expected = np.ldexp(raw, k)
    for i, msg in refused.items():
        kind = kind_of(msg, QUERY_KINDS)
        if normal[i] or kind not in ("overflow", "time beyond float64"):
            tally.bad(fam, f"{what}: refused although the answer is a normal float: {msg}")
        else:
            tally.refused[fam][kind] += 1
    rows = np.setdiff1d(np.flatnonzero(normal), list(refused))
    tally.evaluations[fam] += rows.size
    for i in rows[(got[rows] != expected[rows]).any(axis=1)]:
        tally.bad(fam, f"{what} not homogeneous: got {got[i].tolist()}, want "
                       f"{expected[i].tolist()}")


def invariants(bd, case, tally, rng, V, answers, scales) -> None:
    """The invariants of the module docstring on the rows V that the oracle checked:
    ``answers = (W, T, U, x)`` (apply, event times, inverse of the oracle's answer x),
    ``scales`` the tolerances' scales of apply and of the times."""
    fam, (n, d), m = case.family, case.Dh.shape, V.shape[0]
    (W, T, U, x), S, St = answers, scales[0], scales[2]
    # homogeneity over powers of two (SCALES per query), where the scaling of the query
    # itself is exact
    for _ in range(SCALES):
        k = rng.integers(-1000, 901, (m, 1))
        with np.errstate(all="ignore"):
            Vk, xk = np.ldexp(V, k), np.ldexp(x, k)
            exact = ((np.ldexp(Vk, -k) == V).all(axis=1) & (np.ldexp(xk, -k) == x).all(axis=1)
                     & ~beyond(W) & ~beyond(U))
        r = np.flatnonzero(exact)
        same_bits(tally, fam, "apply", bd, Vk[r], W[r], k[r], d)
        same_bits(tally, fam, "inverse", bd.inverse, xk[r], U[r], k[r], d)
        nz = r[~beyond(T[r])]
        same_bits(tally, fam, "event_times", lambda X: bd.event_times(X)[0], Vk[nz], T[nz],
                  k[nz], n)
    # jvp: the piece selected does not depend on the scale; jvp(v, v) = M(v); vjp its
    # transpose; finite differences of the PL map at two steps
    Tg = rng.standard_normal((m, d))
    J = bd.jvp(V, Tg)
    same_bits(tally, fam, "jvp", lambda X: bd.jvp(X, Tg[r].reshape(X.shape)), Vk[r], J[r], 0, d)
    live = np.flatnonzero(np.abs(V).max(axis=1) > 0)  # (v = 0: no piece to compare)
    tangent_checks(bd, case, tally, rng, V[live], W[live], S[live], Tg[live], J[live])
    # renamed events: the same map, the times permuted (dense tables without resets)
    if isinstance(case.F, np.ndarray) and case.resets is None and n > 1:
        perm = rng.permutation(n)
        try:
            bp = build(case, perm)
        except ValueError as exc:
            tally.bad(fam, f"renamed events refused, the original accepted: {exc}")
            return
        Wp, refused = guarded(bp, V, d)
        Tp, refused_t = guarded(lambda X: bp.event_times(X)[0], V, n)
        for msg in {**refused, **refused_t}.values():
            tally.bad(fam, f"renamed events: refused where the original answers: {msg}")
        rows = np.setdiff1d(np.arange(m), list({**refused, **refused_t}))
        tally.evaluations[fam] += 2 * rows.size
        for name, ratio in (("renamed events: apply", excess(Wp[rows], W[rows], 2 * S[rows])),
                            ("renamed events: event_times",
                             excess(Tp[rows], T[rows][:, perm], 2 * St[rows][:, perm]))):
            for i in np.flatnonzero(~(ratio <= 1))[:3]:
                tally.bad(fam, f"{name}: {ratio[i]:.3g} x the tolerance, perm {perm}")


def tangent_checks(bd, case, tally, rng, V, W, S, Tg, J) -> None:
    """jvp(v, v) = M(v), vjp against jvp (the adjoint identity) and jvp against finite
    differences of the PL map, on rows v != 0 (``S``: the scale of M(v), ``J = jvp(V,
    Tg)``)."""
    fam = case.family
    scale = S / np.abs(V).max(axis=1)[:, None]  # |M_sigma| along the chain
    Wc = rng.standard_normal(V.shape)
    lhs, rhs = (Wc * J).sum(axis=1), (bd.vjp(V, Wc) * Tg).sum(axis=1)
    # the rounding of both sides: of |w| |M_sigma| |t| (columns of very different scales
    # make the chain's scale of M(v) too small for it), or of the chain's scale
    P = np.abs(bd.piece_matrices(V))
    adj = np.abs(lhs - rhs) / (RTOL * (np.einsum("mi,mij,mj->m", np.abs(Wc), P, np.abs(Tg))
                                       + (np.abs(Wc) * scale).sum(axis=1)
                                       * np.abs(Tg).max(axis=1)))
    # the step stays in v's piece (a convex cone) when v + h t and v + h t / 2 select
    # v's order: then the difference quotient is M_sigma t exactly, up to rounding
    h = np.ldexp(1.0, np.frexp(np.abs(V).max(axis=1) / np.abs(Tg).max(axis=1))[1] - 20)
    steps = V + h[:, None] * Tg
    with np.errstate(all="ignore"):
        D = (bd(steps) - W) / h[:, None]
        tol = FD_RTOL * scale.max(axis=1) * np.abs(Tg).max(axis=1)
        fd = np.abs(J - D).max(axis=1) / tol
    orders = bd.orders(V)
    one_piece = ((bd.orders(steps) == orders).all(axis=1)
                 & (bd.orders(V + h[:, None] / 2 * Tg) == orders).all(axis=1))
    for name, ratio in (("jvp(v, v) = M(v)", excess(bd.jvp(V, V), W, S)),
                        ("vjp adjoint", np.where(lhs == rhs, 0.0, adj)),
                        ("jvp against finite differences", fd[one_piece])):
        tally.evaluations[fam] += ratio.size
        for i in np.flatnonzero(~(ratio <= 1)):
            tally.bad(fam, f"{name}: {ratio[i]:.3g} x the tolerance, exps {case.exps}, "
                           f"v = {V[i].tolist()}")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--evaluations", type=lambda s: int(s.replace("_", "")), default=100_000)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--rows", type=int, default=64, help="queries per system")
    ap.add_argument("--families", nargs="+",
                    choices=sorted(ALL) + sorted(MODELS) + ["models", "all"], default=sorted(ALL))
    ap.add_argument("--report-every", type=float, default=600.0, help="seconds")
    args = ap.parse_args(argv)
    families = [f for name in args.families for f in
                {"models": sorted(MODELS), "all": sorted(ALL) + sorted(MODELS)}.get(name, [name])]
    rng = np.random.default_rng(args.seed)
    tally, start, last = Tally(), time.time(), time.time()
    while sum(tally.evaluations.values()) < args.evaluations:
        for name in families:
            if name in MODELS:
                fuzz_twins.check_model(MODELS[name](rng, args.rows), tally)
                continue
            case = ALL[name](rng, args.rows)
            try:
                check(case, tally, rng)
            except AssertionError as exc:  # the families' own bitwise checks (fam_mixed)
                tally.bad(case.family, f"assertion: {exc}")
        if time.time() - last > args.report_every:
            last = time.time()
            print(f"after {last - start:.0f} s:\n{tally.report()}\n", flush=True)
    print(f"seed {args.seed}, {time.time() - start:.0f} s\n{tally.report()}", flush=True)
    return 1 if sum(tally.wrong.values()) else 0


if __name__ == "__main__":
    sys.exit(main())
