"""Progress reporting: turn ``progress=`` arguments into ``callback(done, total)``.

The engine reports progress through a plain callable ``progress(done, total)`` (work units
done so far, total units). This module turns the user-facing values into such a callable:
``None``/``False`` (no reporting), ``True`` (a tqdm bar; tqdm is the optional extra
``progress``) or any callable (guarded: an exception it raises stops the work as a
:class:`ProgressCallbackError` that says how far the work got, with the callback's own
exception as its cause). tqdm is imported only when a bar is asked for.
:class:`DelayedBar` is the bar of long work that no ``progress=`` asked for (drawn after a
few seconds, on a terminal); :class:`SimulationProgress`, the integrator's, is one of the
simulated time.
"""

from __future__ import annotations

import time

#: what ``progress=True`` needs, named in the error when it is missing.
_TQDM_HINT = (
    "progress=True needs the optional dependency tqdm: install it with "
    "`pip install 'bderiv[progress]'` (or `pip install tqdm`), or pass progress=None, or "
    "a callable progress(done, total)"
)


#: the plural of each tqdm unit, for messages
_UNITS = {"vec": "vectors", "point": "grid points", "run": "runs"}


class ProgressCallbackError(ValueError):
    """A ``progress(done, total)`` callback raised: the work stopped at that call.

    The callback's own exception is ``__cause__`` (shown above this one in a traceback).
    """


class GuardedCallback:
    """A user's ``progress(done, total)`` callable whose exceptions say where they came
    from: a :class:`ProgressCallbackError` naming the call and how far the work got,
    raised from the callback's exception.

    Examples
    --------
    >>> def stop(done, total):
    ...     if done > 10:
    ...         raise KeyError("enough")
    >>> guarded = GuardedCallback(stop)
    >>> guarded(10, 30)
    >>> guarded(20, 30)
    Traceback (most recent call last):
    ...
    bderiv._support._progress.ProgressCallbackError: the progress callback stop raised
    KeyError('enough') at progress(20, 30), after 20 of 30 vectors: the work stopped there
    (the callback's exception is the cause)
    """

    def __init__(self, callback, unit: str = "vec"):
        self.callback = callback
        self.units = _UNITS.get(unit, unit)

    def __call__(self, done: int, total: int) -> None:
        try:
            self.callback(done, total)
        except ProgressCallbackError:  # a guarded callback inside this one: said already
            raise
        except Exception as exc:
            name = getattr(self.callback, "__name__", type(self.callback).__name__)
            raise ProgressCallbackError(
                f"the progress callback {name} raised {exc!r} at progress({done}, {total}), "
                f"after {done} of {total} {self.units}: the work stopped there (the "
                f"callback's exception is the cause)"
            ) from exc


class _Bar:
    """What the bars share: a tqdm bar in ``_bar`` (None until drawn), closed once, and a
    context that closes it."""

    _bar = None

    def close(self) -> None:
        """Remove the bar, if one was drawn (idempotent)."""
        if self._bar is not None:
            self._bar.close()
            self._bar = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


class TqdmCallback(_Bar):
    """A ``progress(done, total)`` callable drawing a tqdm bar.

    Parameters
    ----------
    desc : str
        Label of the bar.
    unit : str
        Name of one unit of work (``"vec"`` for vectors).
    **kwargs
        Passed to ``tqdm.tqdm`` (for example ``file=``, ``disable=``, ``leave=``).

    Notes
    -----
    ``done`` is cumulative: the bar advances by the difference to the previous call. The
    bar closes itself when ``done`` reaches ``total``; :meth:`close` closes it earlier.

    Examples
    --------
    >>> import io
    >>> bar = TqdmCallback("demo", file=io.StringIO())
    >>> for done in (10, 60, 100):
    ...     bar(done, 100)
    >>> bar.done
    100
    """

    def __init__(self, desc: str = "bderiv", unit: str = "vec", **kwargs):
        try:
            from tqdm.auto import tqdm
        except ImportError as exc:  # pragma: no cover - exercised without tqdm only
            raise ImportError(_TQDM_HINT) from exc
        self._tqdm = tqdm
        self._kwargs = dict(desc=desc, unit=unit, dynamic_ncols=True, **kwargs)
        self._bar = None
        self.done = 0

    def __call__(self, done: int, total: int) -> None:
        if self._bar is None:  # counts scaled (1.2k) from a thousand on, else plain: 3/3
            kwargs = {"unit_scale": int(total) >= 1000, **self._kwargs}
            self._bar = self._tqdm(total=int(total), **kwargs)
        step = int(done) - self.done
        if step > 0:
            self._bar.update(step)
            self.done = int(done)
        if self.done >= int(total):
            self.close()


def resolve_progress(progress, desc: str = "bderiv", **kwargs):
    """Return a ``callback(done, total)`` or ``None`` for a ``progress=`` argument.

    Parameters
    ----------
    progress : None, bool or callable
        ``None``/``False``: no reporting; ``True``: a tqdm bar (needs tqdm, the extra
        ``progress``); a callable: called as it is, its exceptions raised as a
        :class:`ProgressCallbackError` (:class:`GuardedCallback`).
    desc : str
        Label of the tqdm bar.
    **kwargs
        Passed to :class:`TqdmCallback` (``unit`` also names the work in the message of
        a callback that raised).

    Raises
    ------
    ImportError
        ``progress=True`` without tqdm installed (the message names the extra).
    TypeError
        Anything else.

    Examples
    --------
    >>> resolve_progress(None) is None
    True
    >>> seen = []
    >>> cb = resolve_progress(lambda done, total: seen.append((done, total)))
    >>> cb(5, 10); seen
    [(5, 10)]
    """
    if progress is None or progress is False:
        return None
    if progress is True:
        return TqdmCallback(desc, **kwargs)
    if isinstance(progress, TqdmCallback | GuardedCallback):
        return progress
    if callable(progress):
        return GuardedCallback(progress, kwargs.get("unit", "vec"))
    raise TypeError(
        f"progress must be None, a bool or a callable progress(done, total), got "
        f"{type(progress).__name__}"
    )


#: long work (a simulation, a batch of runs, Newton's iterations, a growth rate) shows a
#: bar once it has run this long (seconds of wall time), redrawn at most this often: short
#: work (nearly all) never draws one
BAR_DELAY, BAR_REFRESH = 2.0, 0.2
#: keyword arguments of these tqdm bars (tests draw them into a buffer); ``disable=None``:
#: only on a terminal, so that logs and captured output stay clean
BAR_OPTIONS = {"disable": None, "leave": False}


class DelayedBar(_Bar):
    """The bar of long work that reports how far it got: drawn once the work has lasted
    :data:`BAR_DELAY` seconds (on a terminal; tqdm is the extra ``progress``, and without
    it nothing is drawn), redrawn at most every :data:`BAR_REFRESH` seconds. Each call
    costs a clock reading; work shorter than the delay draws nothing.

    Parameters
    ----------
    total : float
        The work's end, in its own units (simulated time, runs, iterations).
    desc : str
        Label of the bar.
    bar_format : str
        tqdm's ``bar_format`` (``{n}``, ``{total}``, ``{postfix}``: the note of the last
        call, ...).
    delay : float, optional
        Seconds before the bar is drawn (default :data:`BAR_DELAY`).
    **bar
        Passed to ``tqdm`` over :data:`BAR_OPTIONS` (``file=``, ``disable=``, ...).

    Examples
    --------
    >>> import io
    >>> bar = DelayedBar(10, "solve", "{desc}: {n:.0f} of {total:.0f}{postfix}", delay=0.0,
    ...                  file=io.StringIO(), disable=False)
    >>> bar(3, "residual 1e-05")
    >>> bar.bar_text()
    'solve: 3 of 10, residual 1e-05'
    >>> bar.close()
    """

    def __init__(self, total: float, desc: str, bar_format: str, delay: float | None = None,
                 **bar):
        self.total = float(total)
        self.desc = desc
        self._next = time.monotonic() + (BAR_DELAY if delay is None else delay)
        self._options = {**BAR_OPTIONS, "bar_format": bar_format, **bar}
        self._bar = None

    def __call__(self, done: float, note: str | None = None) -> None:
        """The work has reached ``done`` (of ``total``); ``note``: shown after the count."""
        now = time.monotonic()
        if now < self._next:
            return
        self._next = now + BAR_REFRESH
        if self._bar is None:
            try:
                from tqdm.auto import tqdm
            except ImportError:  # the bar is a nicety: without tqdm, run silently
                self._next = float("inf")
                return
            self._bar = tqdm(total=self.total, desc=self.desc, initial=min(done, self.total),
                             postfix=note, **self._options)  # drawn as it is made
            return
        self._bar.n = min(float(done), self.total)
        if note is not None:
            self._bar.set_postfix_str(note, refresh=False)
        self._bar.refresh()

    def bar_text(self) -> str:
        """The bar as drawn now ("" before it is drawn)."""
        return "" if self._bar is None else str(self._bar)


def count_bar(total: int, desc: str, units: str, delay: float | None = None, **bar):
    """A :class:`DelayedBar` of ``total`` steps of work counted in ``units`` (plural: "runs",
    "iterations"), with an estimate of the time left and the last call's note.

    Examples
    --------
    >>> import io
    >>> bar = count_bar(8, "stability", "iterations", delay=0.0, file=io.StringIO(),
    ...                 disable=False)
    >>> bar(2)
    >>> bar.bar_text().split("|")[-1]
    ' 2 of 8 iterations [00:00<?]'
    >>> bar.close()
    """
    return DelayedBar(total, desc, "{desc}: {percentage:3.0f}%|{bar}| {n:.0f} of {total:.0f} "
                      + units + "{postfix} [{elapsed}<{remaining}]", delay, **bar)


def search_bar(most: int, desc: str, step: str) -> DelayedBar:
    """A :class:`DelayedBar` of a search of at most ``most`` steps (``step``: the word for
    one, "Newton iterate"), with the last call's note (a residual, a cost) and no estimate
    of the time left (a search may end at any step).

    Examples
    --------
    >>> bar = search_bar(30, "ilqr", "iteration")
    >>> bar._options["bar_format"]
    '{desc}: iteration {n:.0f} (of at most {total:.0f}){postfix} [{elapsed}]'
    """
    return DelayedBar(most, desc, "{desc}: " + step + " {n:.0f} (of at most {total:.0f})"
                      "{postfix} [{elapsed}]")


#: a simulation's bar: the simulated time reached, and an estimate of the time left
_SIMULATION_FORMAT = ("{desc}: {percentage:3.0f}%|{bar}| t = {n:.4g} of {total:.4g} "
                      "[{elapsed}<{remaining}]")


class SimulationProgress(DelayedBar):
    """The progress of one simulation over ``[0, t_final]``, in simulated time: a
    :class:`DelayedBar` of the time reached, with an estimate of the time left.

    The integrator calls it with the time it has reached, or integrates the field that
    :meth:`wrap` returns (it calls it with each evaluation's time). Each call returns to
    Python: Ctrl-C (``KeyboardInterrupt``) stops the run at the next field evaluation. A
    compiled driver that calls it must return to Python every few tenths of a second for
    the same.

    Parameters
    ----------
    t_final : float
        The end of the simulated interval (> 0).
    desc : str
        Label of the bar.
    delay : float, optional
        Seconds before the bar is drawn (default :data:`BAR_DELAY`).
    **bar
        Passed to ``tqdm`` over :data:`BAR_OPTIONS` (``file=``, ``disable=``,
        ``bar_format=``, ...).

    Examples
    --------
    >>> import io
    >>> watch = SimulationProgress(2.0, delay=0.0, file=io.StringIO(), disable=False)
    >>> field = watch.wrap(lambda t, y: -y)
    >>> field(0.5, 1.0)
    -1.0
    >>> "t = 0.5 of 2" in watch.bar_text()
    True
    >>> watch.close()
    """

    def __init__(self, t_final: float, desc: str = "simulate", delay: float | None = None,
                 **bar):
        bar_format = bar.pop("bar_format", _SIMULATION_FORMAT)
        super().__init__(t_final, desc, bar_format, delay, **bar)
        self.t_final = self.total

    def wrap(self, field):
        """``field(t, y)`` that reports ``t`` before each evaluation."""

        def watched(t, y):
            self(t)
            return field(t, y)

        return watched
