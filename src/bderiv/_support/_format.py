"""How regions, event orders and transversality failures are written in every message.

One style everywhere (errors, the CLI, figures): a region is ``0b0101``, its bits read
right to left (bit k set = event k happened, event 0 rightmost); an event order is
``(2,0,1)``, the events in the order they happen.
"""

from __future__ import annotations

import re

import numpy as np

#: the reminder that follows a region in messages.
MASK_MEANING = "bit k set = event k happened"


#: a terminal's colour codes (numba's error messages carry them)
ANSI = re.compile(r"\x1b\[[0-9;]*m")


def error_text(exc: BaseException) -> str:
    """``Type: message`` of an exception, its terminal colour codes left out."""
    return f"{type(exc).__name__}: {ANSI.sub('', str(exc)).strip()}"


def format_mask(mask: int, n: int) -> str:
    """``0b...`` string of ``n`` bits of an integer mask; the rightmost bit is event 0.

    Examples
    --------
    >>> format_mask(5, 4)
    '0b0101'
    """
    return "0b" + format(int(mask), f"0{n}b")


def format_happened(happened) -> str:
    """``0b...`` string of a 0/1 flag array (``happened[k]`` = event k); event 0 rightmost.

    Examples
    --------
    >>> format_happened([1, 0, 1, 0])
    '0b0101'
    """
    return "0b" + "".join("1" if h else "0" for h in np.asarray(happened)[::-1])


def format_order(order) -> str:
    """``(k_1,k_2,...)``: the events of an order in the order they happen.

    Examples
    --------
    >>> format_order([2, 0, 1])
    '(2,0,1)'
    """
    return "(" + ",".join(str(int(k)) for k in order) + ")"


def transversality_message(event: int, region: str, rate: float, where: str = "") -> str:
    """The one wording of a rate <= 0: ``region`` is a formatted mask, ``where`` a prefix.

    Examples
    --------
    >>> transversality_message(1, "0b01", -0.5, "on the chain of V[3]")[:80]
    'transversality violated on the chain of V[3]: event 1 has rate -0.5 <= 0 in regi'
    """
    at = f" {where}" if where else ""
    return (
        f"transversality violated{at}: event {event} has rate {rate:.3g} <= 0 in region mask "
        f"{region} ({MASK_MEANING}); the flow must cross every event surface from h_k < 0 "
        f"to h_k > 0 in every region"
    )


def format_state(x) -> str:
    """A state in a message, every digit kept: ``[0.5, -1.25]``."""
    return "[" + ", ".join(repr(float(v)) for v in x) + "]"


#: what to do about a run that left the floating-point range (the end of its messages)
BLOW_UP_HINT = (
    "the solution may escape to infinity in finite time (a blow-up, as x' = x**2), or the "
    "model's units make the state or its rate of change too large for float64: rescale "
    "them, or stop the run before the blow-up (a shorter t_final)"
)


def blown_up(region: str, x, t=None) -> str:
    """The message of a run whose state ``x`` left the floating-point range at ``t`` (None:
    not known) in ``region`` (its words), on either integrator.

    Examples
    --------
    >>> blown_up("region mask 0b0", [float("inf")], 0.5)[:60]
    'the integration blew up at t = 0.5 in region mask 0b0: the s'
    """
    when = "" if t is None else f" at t = {float(t)!r}"
    return (f"the integration blew up{when} in {region}: the state grew beyond the "
            f"floating-point range (float64 ends near 1.8e308), x = {format_state(x)}; "
            f"{BLOW_UP_HINT}")
