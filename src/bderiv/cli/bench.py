"""``bderiv bench``: the dimension sweep of :func:`bderiv.cli.sweep.sweep`, sized first."""

from __future__ import annotations

import os

from .._limits import BENCH_BATCH, BENCH_REPEAT
from .._support._tables import dense_table_bytes, human_bytes
from . import sweep, usage
from .figures import save_figure
from .machine import describe, machine_info
from .usage import (
    UsageError,
    check_figure_path,
    make_output_directory,
    require_memory,
    require_module,
)

#: the largest n whose bytes :func:`sweep_bytes` counts exactly: its 2**n rows are a Python
#: int of n bits (a megabit here); a larger n (up to 2**53 is accepted as an integer) is
#: refused by that count alone, 2**n bytes and more
EXACT_BYTES_N = 1 << 20


def sweep_bytes(n: int, d: int, batch: int) -> int:
    """Peak bytes of one row of the sweep: the random corner table, the tables
    :class:`~bderiv.BDerivative` keeps, and the batch with its image.

    Examples
    --------
    >>> round(sweep_bytes(26, 26, 100_000) / 2**30, 1)  # GiB: 13 of F, 48 of the records
    61.0
    """
    return (1 << n) * d * 8 + dense_table_bytes(n, d) + 2 * batch * d * 8


def run_bench(ns, *, d_factor=1, batch=BENCH_BATCH, repeat=BENCH_REPEAT, plot=None,
              progress=None) -> dict:
    """Run the sweep (and save its log-log plot to ``plot``); return its rows and setting.

    Parameters
    ----------
    ns : sequence of int
        Numbers of events; the dimension is ``d = d_factor * n``.
    d_factor : int
    batch : int
        Queries per batch.
    repeat : int
        Timed runs, best kept.
    plot : str, optional
        A ``.png``, ``.pdf`` or ``.svg`` file for :func:`bderiv.plot.scaling` (its
        directory made if missing).
    progress : callable ``progress(done, total)``, optional

    Returns
    -------
    dict
        ``d_factor``, ``batch``, ``repeat``, ``machine`` (:func:`~bderiv.cli.machine.
        machine_info`) and ``rows`` (those of :func:`bderiv.cli.sweep.sweep`): the JSON of
        ``bderiv bench --json``, which ``bderiv plot --bench-json`` reads; with ``plot``
        also ``plot`` (``path``, ``replaced``: whether it replaced an earlier file,
        ``created``: the topmost directory made, or None).
    """
    if plot is not None:  # "" too: refused by name, not skipped
        require_module("matplotlib", "--plot")
        check_figure_path(plot, "--plot")
    for n in ns:
        d = d_factor * n
        what = f"--n {n} (d = {d}) with --batch {batch}"
        if n > EXACT_BYTES_N:
            raise UsageError(f"{what} needs more than 2**{n} B of memory (a table of 2**n "
                             f"rows), but only {human_bytes(usage.memory_headroom())} is "
                             f"available; ask for less")
        require_memory(sweep_bytes(n, d, batch), what)
    rows = sweep.sweep(tuple(ns), d_factor=d_factor, batch=batch, repeat=repeat,
                        progress=progress)
    result = {"d_factor": d_factor, "batch": batch, "repeat": repeat,
              "machine": machine_info(), "rows": rows}
    if plot:
        from .. import plot as figures

        fig = figures.scaling(rows, machine=describe(result["machine"]))
        replaced = os.path.exists(plot)
        created = make_output_directory(os.path.dirname(plot) or ".", "--plot")
        save_figure(fig, plot, 120, "--plot")
        result["plot"] = {"path": plot, "replaced": replaced, "created": created}
    return result
