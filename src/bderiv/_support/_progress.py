"""Progress reporting: turn ``progress=`` arguments into ``callback(done, total)``.

The engine reports progress through a plain callable ``progress(done, total)`` (work units
done so far, total units). This module turns the user-facing values into such a callable:
``None``/``False`` (no reporting), ``True`` (a tqdm bar; tqdm is the optional extra
``progress``) or any callable (guarded: an exception it raises stops the work as a
:class:`ProgressCallbackError` that says how far the work got, with the callback's own
exception as its cause). tqdm is imported only when a bar is asked for.
:class:`SimulationProgress` is the integrator's: a bar of the simulated time for long runs.
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


class TqdmCallback:
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

    def close(self) -> None:
        """Close the bar (idempotent)."""
        if self._bar is not None:
            self._bar.close()
            self._bar = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
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


#: a simulation shows its progress bar once it has run this long (seconds of wall time),
#: and redraws it at most this often: short runs (nearly all) never draw one
SIMULATION_BAR_DELAY, SIMULATION_BAR_REFRESH = 2.0, 0.2
#: keyword arguments of the simulations' tqdm bars (tests draw them into a buffer);
#: ``disable=None``: only on a terminal, so that logs and captured output stay clean
SIMULATION_BAR = {"disable": None, "leave": False}


class SimulationProgress:
    """The progress of one simulation over ``[0, t_final]``, in simulated time.

    The integrator calls it with the time it has reached, or integrates the field that
    :meth:`wrap` returns (it calls it with each evaluation's time). Once the run has
    lasted :data:`SIMULATION_BAR_DELAY` seconds, a tqdm bar of the simulated time with an
    estimate of the time left is drawn (on a terminal; tqdm is the extra ``progress``, and
    without it nothing is drawn). Each call costs a clock reading, and returns to Python:
    Ctrl-C (``KeyboardInterrupt``) stops the run at the next field evaluation. A compiled
    driver that calls it must return to Python every few tenths of a second for the same.

    Parameters
    ----------
    t_final : float
        The end of the simulated interval (> 0).
    desc : str
        Label of the bar.
    delay : float, optional
        Seconds before the bar is drawn (default :data:`SIMULATION_BAR_DELAY`).
    **bar
        Passed to ``tqdm`` over :data:`SIMULATION_BAR` (``file=``, ``disable=``, ...).

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
        self.t_final = float(t_final)
        self.desc = desc
        delay = SIMULATION_BAR_DELAY if delay is None else delay
        self._next = time.monotonic() + delay
        self._options = {**SIMULATION_BAR, **bar}
        self._bar = None

    def __call__(self, t: float) -> None:
        now = time.monotonic()
        if now < self._next:
            return
        self._next = now + SIMULATION_BAR_REFRESH
        if self._bar is None:
            try:
                from tqdm.auto import tqdm
            except ImportError:  # the bar is a nicety: without tqdm, run silently
                self._next = float("inf")
                return
            self._bar = tqdm(total=self.t_final, desc=self.desc, **{
                "bar_format": "{desc}: {percentage:3.0f}%|{bar}| t = {n:.4g} of {total:.4g} "
                              "[{elapsed}<{remaining}]", **self._options})
        self._bar.n = min(float(t), self.t_final)
        self._bar.refresh()

    def bar_text(self) -> str:
        """The bar as drawn now ("" before it is drawn)."""
        return "" if self._bar is None else str(self._bar)

    def wrap(self, field):
        """``field(t, y)`` that reports ``t`` before each evaluation."""

        def watched(t, y):
            self(t)
            return field(t, y)

        return watched

    def close(self) -> None:
        """Remove the bar, if one was drawn (idempotent)."""
        if self._bar is not None:
            self._bar.close()
            self._bar = None
