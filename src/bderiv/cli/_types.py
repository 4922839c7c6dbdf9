"""The types of ``bderiv``'s options (argparse ``type=``): integers, also written in
scientific notation and read exactly; the finite-difference steps; the figures' dpi."""

from __future__ import annotations

import argparse
import decimal

from .._limits import EPS_RANGE
from .names import MIN_DPI


def argument_type(convert, accept, expected: str):
    """An argparse ``type``: ``convert(text)``, refused unless ``accept(value)``."""

    def parse(text):
        try:
            value = convert(text)  # int and float accept 1_000_000
        except ValueError:
            value = None
        if value is None or not accept(value):
            raise argparse.ArgumentTypeError(f"expected {expected}, got {text!r}")
        return value

    return parse


def integer(text: str) -> int | None:
    """``int(text)``, also for integral values in scientific notation (``1e6``, ``1e20``:
    read exactly, as a decimal, up to 1e30); None when not integral."""
    try:
        return int(text)
    except ValueError:
        pass
    try:
        value = decimal.Decimal(text.replace("_", ""))
    except decimal.InvalidOperation:
        return None
    if not value.is_finite() or value.adjusted() > 30 or value != value.to_integral_value():
        return None  # (1e1000000000 would be a billion digits)
    return int(value)


positive_int = argument_type(integer, lambda v: v >= 1, "a positive integer")
nonneg_int = argument_type(integer, lambda v: v >= 0, "an integer >= 0")
eps_step = argument_type(float, lambda v: EPS_RANGE[0] <= v <= EPS_RANGE[1],
                         f"a step between {EPS_RANGE[0]:g} and {EPS_RANGE[1]:g}")
dpi = argument_type(integer, lambda v: v >= MIN_DPI, f"an integer >= {MIN_DPI} (below, "
                    f"the figures' text would be under a pixel high)")
