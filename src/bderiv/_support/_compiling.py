"""Says what compiles, once per family and process: no silent minute on a fresh machine.

A kernel's first call on a machine compiles it (seconds; the integrator a minute or two),
later processes load it from numba's disk cache. Without a word such a call looks hung.
Numba's compile event (``numba:compile``, which a cache hit does not fire) for a
function of bderiv called from Python (not one compiled into another) logs one warning on
the logger ``bderiv.compiling`` per family below, naming the family, about how long it
takes, and how to compile ahead (``python -m bderiv compile``). The compiled integrator
says so itself (:mod:`bderiv.models.readiness`: it compiles in a background process).
"""

from __future__ import annotations

import logging
import threading

from numba.core import event

log = logging.getLogger("bderiv.compiling")

#: (module prefix, what compiles, how long it takes on two cores, whether ``python -m
#: bderiv compile`` compiles it ahead), the first match counts
FAMILIES = (
    # said once: a later operation's first call (event_times, jvp) compiles its own kernels
    ("bderiv._kernels", "the B-derivative kernels this call needs",
     "seconds; each other operation, as event_times or jvp, compiles its own at its first "
     "call", True),
    # the modules that from_sympy generates (bderiv.symbolic._cache names them so)
    ("bderiv_symbolic_", "a symbolic model's generated functions", "seconds", False),
    ("bderiv.robots", "a robot's contact kernels", "seconds", False),
)


class _Notice(event.Listener):
    """Logs the first top-level compilation of each family of :data:`FAMILIES`."""

    def __init__(self):
        self.said, self.depth = set(), threading.local()

    def on_start(self, ev):
        depth = getattr(self.depth, "n", 0)
        self.depth.n = depth + 1
        dispatcher = (ev.data or {}).get("dispatcher")
        module = getattr(getattr(dispatcher, "py_func", None), "__module__", "") or ""
        if depth:  # compiled into a function that compiles already
            return
        for prefix, what, how_long, ahead in FAMILIES:
            if module.startswith(prefix):
                if prefix not in self.said:
                    self.said.add(prefix)
                    log.warning("bderiv: compiling %s for this machine (their first use here, "
                                "%s; numba keeps them on disk for later processes%s)", what,
                                how_long, "; `python -m bderiv compile` compiles them ahead"
                                if ahead else "")
                return

    def on_end(self, ev):
        self.depth.n = getattr(self.depth, "n", 1) - 1


#: the listener, registered once, at the first import of the packages whose calls compile
#: (``bderiv.engine``, ``bderiv.models``: each imports this module) or of a public name
NOTICE = _Notice()
event.register("numba:compile", NOTICE)
