"""Notices on the logger ``bderiv``: the compiled integrator compiled rather than loaded
(once per process), and a model whose stops are the Python loop's (once per model).

The driver and the compiled run are compiled at their first use on a machine (about one
to two minutes together on a 2-core VM; later processes load them from numba's disk cache
in a fraction of a second). Without a word a first ``simulate`` looks hung, so numba's
compile event for either (``numba:compile``, which a cache hit does not fire) logs a
warning on the logger ``bderiv`` (shown on stderr by default), once per process.
"""

from __future__ import annotations

import logging

from numba.core import event

from ._stops import EVENT_JAC_NONE

_log = logging.getLogger("bderiv")


class _CompileNotice(event.Listener):
    """Logs the notice when one of ``dispatchers`` starts compiling, the first time."""

    def __init__(self, dispatchers):
        self.dispatchers, self.said = dispatchers, False

    def on_start(self, ev):
        if self.said or ev.data is None or ev.data.get("dispatcher") not in self.dispatchers:
            return
        self.said = True
        _log.warning("bderiv: compiling the compiled integrator for this machine (once: "
                     "about one to two minutes; later runs load it from numba's disk cache)")

    def on_end(self, ev):
        pass


def notice_compilation(*dispatchers) -> _CompileNotice:
    """Register the notice for ``dispatchers`` (numba's event API); returns the listener."""
    listener = _CompileNotice(dispatchers)
    event.register("numba:compile", listener)
    return listener


#: the models told that their stops are the Python loop's: the ids of their functions
#: (a copy with other parameters, or a sweep's model per point, is told once)
_TOLD = set()


def tell_python_stops(model, functions) -> None:
    """Warn, once per ``functions`` (the user's field, events, reset, event_jacobian),
    when one of them leaves every stop of the compiled ``model``'s runs to the Python loop
    (10-20x slower per run: a ball between two walls, 1.9 against 0.1 ms), naming it."""
    if model.event_jac_mode == EVENT_JAC_NONE:
        cause = ("its event_jacobian is not compiled for float64[::1] -> float64[:, ::1]"
                 if model.event_jacobian_given else "its events are not complex-analytic "
                 "(their complex step is wrong, or they do not compile for complex input) "
                 "and no compiled event_jacobian is given")
    elif model.has_python_reset:
        cause = "its reset is not compiled for (float64[::1], int64, int64) -> float64[::1]"
    else:
        return
    key = tuple(map(id, functions))
    if key in _TOLD:
        return
    _TOLD.add(key)
    _log.warning("the model's field and events are numba-compiled, but %s: every stop of "
                 "its runs is decided in the Python loop, 10-20x slower per run; compile it "
                 "with numba.njit", cause)

