"""How many specialisations each numba dispatcher of bderiv compiled (or loaded): issue 36.

Every signature a dispatcher holds beyond its first is a compilation on a cold cache (one
to two seconds each for a kernel, more for a driver): a read-only or non-contiguous array,
an int where a float was compiled, a literal, another ndim. The table this tool prints
lists, for every dispatcher of the package, the signatures it holds after a workload.

The workload that counts is the test suite. Run it with ``BDERIV_SPECIALIZATIONS=<folder>``
(``tests/conftest.py``: at the end of the session every process, each pytest-xdist worker,
writes its table to ``<folder>/<worker>-<pid>.json``; without the variable nothing is
done), then merge and print::

    BDERIV_SPECIALIZATIONS=/tmp/spec PYTHONPATH=src python -m pytest -q -p no:cacheprovider
    python tools/specializations.py /tmp/spec [--all] [--json merged.json]

Which dispatchers. Every ``numba.core.dispatcher.Dispatcher`` alive in the process whose
function belongs to a module under ``bderiv`` (``gc.get_objects``: the module-level kernels
of ``vars(module)`` for each module of ``sys.modules`` and those made by factories, the
drivers of :class:`bderiv._kernels._drivers.Batch` and the lane kernels of
``_kernels.lanes.kernels``). A kernel cached under a keyed name (``name.k<digest>``) is
listed by its plain name; a serial driver (``_drivers._serial``) by the qualified name of its
block (the parallel driver ``_drivers._tasks`` is one for all blocks with one signature; its
launcher ``_drivers._launch`` has a signature per type of the tables and outputs it runs, and
a trampoline per type, ``_core._trampoline_<digest>``); several dispatchers of one name
(a factory's, per user function) are merged (their signatures' union; ``instances``
counts them). The union over the processes is taken per name.

``cached``: whether the dispatcher caches on disk (an entry point called from Python, or
since 2026-11-29 a step of ``_kernels`` that its callers load and link: its signatures
count whether they were compiled or loaded). An uncached one (a step compiled into its
callers) lists only the signatures compiled in the process, so on a warm
cache it shows fewer than a cold run compiles. By default the table lists the dispatchers
with more than one signature, then a one-line total; ``--all`` lists every one.
"""

from __future__ import annotations

import argparse
import gc
import json
import os
import pathlib
import re
import sys

#: the suffix of a kernel cached under a sources key (``_kernels._cache.keyed``)
_KEY = re.compile(r"\.k[0-9a-f]{16}$")


def _name(dispatcher) -> str:
    """``module:qualname`` of a dispatcher, without its cache key; a driver of a block
    (``_drivers._serial``, uncached) by its block's name."""
    fn = dispatcher.py_func
    qualname = _KEY.sub("", fn.__qualname__)
    block = fn.__globals__.get("block") if fn.__qualname__ == "_serial" else None
    if block is not None and hasattr(block, "py_func"):
        qualname = f"{block.py_func.__module__}.{block.py_func.__qualname__}.{qualname}"
    return f"{fn.__module__}:{qualname}"


def collect() -> dict:
    """``{name: {"signatures": [...], "instances": k, "cached": bool}}`` of every bderiv
    dispatcher alive in this process."""
    from numba.core.dispatcher import Dispatcher

    table: dict = {}
    for obj in gc.get_objects():
        # type(), not isinstance: a dead weak proxy among the objects raises on __class__
        if not issubclass(type(obj), Dispatcher):
            continue
        module = getattr(obj.py_func, "__module__", None) or ""
        if module != "bderiv" and not module.startswith("bderiv."):
            continue
        entry = table.setdefault(_name(obj), {"signatures": set(), "instances": 0,
                                              "cached": False})
        entry["signatures"].update(str(sig) for sig in obj.signatures)
        entry["instances"] += 1
        entry["cached"] |= getattr(obj.stats, "cache_path", None) is not None
    return {name: {**e, "signatures": sorted(e["signatures"])} for name, e in table.items()}


def write(folder) -> pathlib.Path:
    """Write this process's :func:`collect` to ``folder/<worker>-<pid>.json``."""
    folder = pathlib.Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    worker = os.environ.get("PYTEST_XDIST_WORKER", "main")
    path = folder / f"{worker}-{os.getpid()}.json"
    path.write_text(json.dumps(collect(), indent=1, sort_keys=True))
    return path


def merge(paths) -> dict:
    """The union of the tables of ``paths`` (JSON files of :func:`write`)."""
    table: dict = {}
    for path in paths:
        for name, e in json.loads(pathlib.Path(path).read_text()).items():
            m = table.setdefault(name, {"signatures": set(), "instances": 0, "cached": False})
            m["signatures"].update(e["signatures"])
            m["instances"] = max(m["instances"], e["instances"])
            m["cached"] |= e["cached"]
    return {name: {**e, "signatures": sorted(e["signatures"])} for name, e in table.items()}


def render(table: dict, everything: bool = False) -> str:
    """Markdown: dispatchers by descending signature count (only those with more than one
    unless ``everything``), their signatures, then the totals."""
    rows = sorted(table.items(), key=lambda kv: (-len(kv[1]["signatures"]), kv[0]))
    lines = ["| dispatcher | cached | instances | signatures |", "|---|---|---|---|"]
    for name, e in rows:
        if len(e["signatures"]) > 1 or everything:
            lines.append(f"| `{name}` | {'yes' if e['cached'] else 'no'} | "
                         f"{e['instances']} | {len(e['signatures'])} |")
    detail = [f"\n{name} ({len(e['signatures'])}):\n" + "\n".join(
        f"    {sig}" for sig in e["signatures"])
        for name, e in rows if len(e["signatures"]) > 1 or everything]
    cached = [e for e in table.values() if e["cached"]]
    total = (f"\n{len(table)} dispatchers, {sum(len(e['signatures']) for e in table.values())}"
             f" signatures; cached (entry points): {len(cached)} dispatchers, "
             f"{sum(len(e['signatures']) for e in cached)} signatures, "
             f"{sum(len(e['signatures']) > 1 for e in cached)} with more than one")
    return "\n".join(lines) + "\n" + "\n".join(detail) + "\n" + total


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("folder", type=pathlib.Path,
                        help="the folder of BDERIV_SPECIALIZATIONS (its *.json files)")
    parser.add_argument("--all", action="store_true", help="list every dispatcher")
    parser.add_argument("--json", type=pathlib.Path, help="write the merged table here")
    args = parser.parse_args(argv)
    paths = sorted(args.folder.glob("*.json"))
    if not paths:
        sys.exit(f"no tables (*.json) in {args.folder}")
    table = merge(paths)
    if args.json:
        args.json.write_text(json.dumps(table, indent=1, sort_keys=True))
    print(f"{len(paths)} processes")
    print(render(table, args.all))


if __name__ == "__main__":
    main()
