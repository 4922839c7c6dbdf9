"""A notice, once per process, when the compiled integrator is compiled rather than loaded.

The driver and the compiled run are compiled at their first use on a machine (about one
to two minutes together on a 2-core VM; later processes load them from numba's disk cache
in a fraction of a second). Without a word a first ``simulate`` looks hung, so numba's
compile event for either (``numba:compile``, which a cache hit does not fire) logs a
warning on the logger ``bderiv`` (shown on stderr by default), once per process.
"""

from __future__ import annotations

import logging

from numba.core import event

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
