"""How regions, event orders and transversality failures are written in every message.

One style everywhere (errors, the CLI, figures): a region is ``0b0101``, its bits read
right to left (bit k set = event k happened, event 0 rightmost); an event order is
``(2,0,1)``, the events in the order they happen.
"""

from __future__ import annotations

import contextlib
import os
import re
import sys

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


def format_region(mask: int, n: int) -> str:
    """``region mask 0b...`` with the reminder of what its bits mean, as messages name a
    region.

    Examples
    --------
    >>> format_region(2, 2)
    'region mask 0b10 (bit k set = event k happened)'
    """
    return f"region mask {format_mask(mask, n)} ({MASK_MEANING})"


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


def transversality_message(event: int, region: str, rate: float, where: str = "",
                           threshold: float = 0.0) -> str:
    """The one wording of a rate <= 0 (or below ``threshold``, the grazing threshold of a
    stop: a positive rate too small to tell): ``region`` is a formatted mask, ``where`` a
    prefix.

    Examples
    --------
    >>> transversality_message(1, "0b01", -0.5, "on the chain of V[3]")[:80]
    'transversality violated on the chain of V[3]: event 1 has rate -0.5 <= 0 in regi'
    """
    at = f" {where}" if where else ""
    low = (f"{rate:.3g}, below the grazing threshold {threshold:.3g} (GRAZING_RTOL |Dh_k| "
           f"|F|: too small to tell from 0)" if rate > 0 else f"{rate:.3g} <= 0")
    return (
        f"transversality violated{at}: event {event} has rate {low} in region mask "
        f"{region} ({MASK_MEANING}); the flow must cross every event surface from h_k < 0 "
        f"to h_k > 0 in every region"
    )


#: arrays of more entries are shown by their first and last few in messages
SHOWN_ENTRIES = 32


def format_steps(eps, errors) -> list:
    """The lines ``  eps = <step>: <error>`` of a finite-difference check, each step as
    given in scientific notation (``1e-04``, ``1.5e-04``: ``.0e`` printed 1.5e-4 as 2e-04,
    a step the check did not take)."""
    return [f"  eps = {np.format_float_scientific(e, trim='-', exp_digits=2)}: {err:.3e}"
            for e, err in zip(eps, errors, strict=True)]


def format_state(x) -> str:
    """A state (or any array, read flat) in a message, every digit kept: ``[0.5, -1.25]``;
    of more than :data:`SHOWN_ENTRIES` entries, the first and last eight and the count
    (a message stays short whatever the array).

    Examples
    --------
    >>> format_state([0.5, -1.25])
    '[0.5, -1.25]'
    >>> format_state(range(100)).endswith("97.0, 98.0, 99.0] (100 entries)")
    True
    """
    flat = np.asarray(x).ravel()
    if flat.size <= SHOWN_ENTRIES:
        return "[" + ", ".join(repr(float(v)) for v in flat) + "]"
    ends = [repr(float(v)) for v in flat[:8]] + ["..."] + [repr(float(v)) for v in flat[-8:]]
    return "[" + ", ".join(ends) + f"] ({flat.size} entries)"


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


def step_underflow(region: str, x, t) -> str:
    """The message of a run whose step the tolerances need fell below 10 ulp of ``t``
    (scipy's "Required step size is less than spacing between numbers"), at the state
    ``x`` in ``region`` (its words), on either integrator."""
    return (f"step size underflow at t = {float(t)!r} in {region}, x = {format_state(x)}: "
            f"the step the tolerances need is below 10 ulp of t (a singular or very stiff "
            f"field, or a solution that escapes to infinity near this t, as x' = x**2 does?)")


#: whether exceptions take notes (``add_note``, Python 3.11+): an exception raised in a
#: model's function then says where (:func:`note_call`); on 3.10 it is left as it is
NOTES = hasattr(BaseException, "add_note")
#: the package's folder: a ValueError or TypeError raised in its code is bderiv's own
_PACKAGE = os.path.dirname(os.path.dirname(os.path.abspath(__file__))) + os.sep


def _argument(x) -> str:
    """A function's argument ``x`` as :func:`format_state` writes a state (complex entries,
    a complex step's, as complex numbers)."""
    try:
        x = np.asarray(x)
        if x.dtype.kind == "c":
            return "[" + ", ".join(repr(complex(v)) for v in x.ravel()) + "]"
        return format_state(x.ravel())
    except Exception:  # noqa: BLE001 - a note never replaces the exception it is on
        return repr(x)


def _note_text(where: dict) -> str:
    when = "" if where["t"] is None else f" at t = {where['t']!r}"
    region = "" if where["region"] is None else f" in {where['region']}"
    return (f"bderiv: raised by the model's {where['call']}, called with "
            f"{where['args']}{when}{region}")


def _bderivs_own(exc: BaseException) -> bool:
    """Whether ``exc`` is a ValueError or TypeError raised in bderiv's code (a check, a
    refusal, a guard of its own: its message names what it is about)."""
    if not isinstance(exc, (ValueError, TypeError)) or exc.__traceback__ is None:
        return False
    tb = exc.__traceback__
    while tb.tb_next is not None:
        tb = tb.tb_next
    return tb.tb_frame.f_code.co_filename.startswith(_PACKAGE)


def note_call(exc: BaseException, call: str, x, args=(), n: int = 1) -> None:
    """Note on ``exc``, raised by a model's function, which function it was (``call``, its
    role: ``"field(x, mask)"``) and its arguments: ``x``, then ``args`` (the ints ``call``
    names after x: a mask of ``n`` events, an event k). Once, by the innermost call the
    exception passes; its type, message and traceback are kept (users catch their own
    exceptions). bderiv's own errors (:func:`_bderivs_own`) are left as they are, and every
    exception on Python 3.10 (no notes); the caller leaves out those that are not the
    function's (``KeyboardInterrupt``, a batch's cancellation). :func:`note_time` adds the
    time. The note reads ``bderiv: raised by the model's field(x, mask), called with x =
    [0.0, 1.0], mask = 0b01 (bit k set = event k happened) at t = 0.25``.
    """
    caller = sys._getframe(1)  # the call of the function (its wrapper's frame)
    if not NOTES or _noted_inside(exc, caller) or _bderivs_own(exc):
        return
    names = call[call.index("(") + 1:-1].split(", ")[1:]
    try:  # a note never replaces the exception it is on
        words = [f"x = {_argument(x)}"] + [
            f"mask = {format_mask(v, n)} ({MASK_MEANING})" if name == "mask" else
            f"{name} = {v}" for name, v in zip(names, args, strict=False)]
        where = {"call": call, "args": ", ".join(words), "t": None,
                 "region": None, "has_mask": "mask" in names, "frame": caller}
        exc.add_note(_note_text(where))
        exc._bderiv_call = where
    except Exception:  # noqa: BLE001 - a mask that is no integer, notes that are no list
        pass


def _noted_inside(exc: BaseException, caller) -> bool:
    """Whether ``exc`` was noted by a call made inside ``caller`` (a nested model's, in this
    raise: the note stands). A note of an earlier raise of the same exception object (a
    function that raises one it keeps) is taken off, to be made again for this call."""
    where = getattr(exc, "_bderiv_call", None)
    if where is None:
        return False
    frame = where["frame"]
    while frame is not None:
        if frame is caller:
            return True
        frame = frame.f_back
    notes = getattr(exc, "__notes__", None)
    if isinstance(notes, list) and _note_text(where) in notes:
        notes.remove(_note_text(where))
    del exc._bderiv_call
    return False


def note_more(exc: BaseException, words: str) -> None:
    """Add ``words`` as one more note (``bderiv: words``) to an exception that
    :func:`note_call` noted (a model's function's; none to others)."""
    if NOTES and getattr(exc, "_bderiv_call", None) is not None:
        exc.add_note(f"bderiv: {words}")


def note_time(exc: BaseException, t, region=None) -> None:
    """Add the time ``t`` (and ``region``, words, for a function called without a mask)
    to the note :func:`note_call` put on ``exc``, where it has none yet."""
    where = getattr(exc, "_bderiv_call", None)
    if where is None or where["t"] is not None:
        return
    old = _note_text(where)
    where["t"] = float(t)
    if not where["has_mask"]:
        where["region"] = region
    notes = getattr(exc, "__notes__", None)
    if isinstance(notes, list) and old in notes:
        notes[notes.index(old)] = _note_text(where)


@contextlib.contextmanager
def noted_at(t, region=None):
    """A block at time ``t`` (a run's stop): the note of an exception a model's function
    raised in it gets the time (:func:`note_time`)."""
    try:
        yield
    except Exception as exc:
        note_time(exc, t, region)
        raise
