"""Command line: ``bderiv demo`` (also ``python -m bderiv``)."""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np

from .bderivative import BDerivative


def three_event_table():
    """A 3-event system in R^3 whose event order can be overtaken (MATH.md section 3)."""
    F = np.ones((8, 3))
    F[0b001] = (1.0, 0.1, 1.0)  # after event 0 alone, h_1 grows ten times slower
    F[0b011] = (1.0, 0.5, 2.0)
    F[0b111] = (1.5, 1.0, 2.0)
    return np.eye(3), F


def demo(out=sys.stdout) -> int:
    Dh, F = three_event_table()
    t0 = time.perf_counter()
    bd = BDerivative(Dh, F)
    V = np.array([[-1.0, -2.0, -3.0], [-3.0, -1.0, -2.0], [0.5, -0.2, 0.1]])
    times, order = bd.event_times(V)
    W = bd(V)
    compile_s = time.perf_counter() - t0
    p = print
    p(f"{bd}: Dh = I, corner table F (2**3 rows, bit k set = event k happened)", file=out)
    p("vector u -> event order, event times, M(u):", file=out)
    for u, o, t, w in zip(V, order, times, W, strict=True):
        p(f"  u={u}  order={o.tolist()}  times={np.round(t[o], 4)}  M(u)={w}", file=out)
    o = order[0]
    p(f"piece of order {o.tolist()}:\n{bd.piece(o)}", file=out)
    err = np.abs(bd.inverse(W) - V).max()
    p(f"inverse round trip max |M^-1(M(u)) - u| = {err:.2e}", file=out)
    rng = np.random.default_rng(0)
    batch = rng.standard_normal((1_000_000, 3))
    bd(batch[:2000])
    t0 = time.perf_counter()
    bd(batch)
    dt = time.perf_counter() - t0
    p(
        f"batch of {len(batch):,} vectors: {dt * 1e9 / len(batch):.0f} ns per vector "
        f"(first call with compilation took {compile_s:.2f} s)",
        file=out,
    )
    return 0


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="bderiv", description=__doc__)
    sub = parser.add_subparsers(dest="command")
    sub.add_parser("demo", help="a worked example on a built-in 3-event system")
    args = parser.parse_args(argv)
    if args.command in (None, "demo"):
        return demo()
    parser.error(f"unknown command {args.command!r}")  # pragma: no cover
    return 2
