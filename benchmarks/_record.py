"""Write a benchmark's rows and where they were measured to ``benchmarks/results/<name>.json``.

The scripts whose tables the docs show call :func:`record` when run with ``--record``
(:func:`add_argument`); without it they only print. ``python tools/render_benchmarks.py``
then writes the tables into the docs from these files. A record is::

    {"benchmark": "<layout name in _layouts.LAYOUTS>",
     "meta": {"command", "date" (UTC), "machine": {"cpu", "cores"},
              "load": {"start", "end"} (os.getloadavg() when this module was imported and
              when the record is written), "versions": {"python", "numpy", "numba"},
              "commit" (git HEAD, "+" when the work tree differs)},
     "tables": {"<table>": [{"<column key>": value, ...}, ...]}}

Plain Python: importing it costs nothing, so the load at start is the load before the
benchmark's own imports.
"""

from __future__ import annotations

import json
import os
import pathlib
import platform
import subprocess
import sys
from datetime import datetime, timezone
from importlib import metadata

HERE = pathlib.Path(__file__).resolve().parent
RESULTS = HERE / "results"
sys.path.insert(0, str(HERE))
from _layouts import LAYOUTS  # noqa: E402


def load_average() -> list[float] | None:
    """The 1, 5 and 15 minute load averages (None where the OS has none)."""
    return [round(v, 2) for v in os.getloadavg()] if hasattr(os, "getloadavg") else None


_LOAD_AT_START = load_average()
FIELDS = ("command", "date", "machine", "load", "versions", "commit")


def cpu_model() -> str:
    try:
        with open("/proc/cpuinfo") as fh:
            for line in fh:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def _version(name: str) -> str | None:
    try:
        return metadata.version(name)
    except metadata.PackageNotFoundError:
        return None


def git_commit() -> str | None:
    """HEAD of the checkout holding this file, with "+" when tracked files differ."""
    def git(*args):
        return subprocess.run(["git", "-C", str(HERE), *args], capture_output=True,
                              text=True, timeout=30)
    try:
        head = git("rev-parse", "--short", "HEAD")
        dirty = git("status", "--porcelain", "--untracked-files=no")
    except (OSError, subprocess.TimeoutExpired):
        return None
    if head.returncode:
        return None
    return head.stdout.strip() + ("+" if dirty.stdout.strip() else "")


def metadata_now(argv: list[str] | None = None) -> dict:
    """Every field of ``FIELDS`` for a record written now, by the command ``argv``
    (default ``sys.argv``)."""
    argv = sys.argv if argv is None else argv
    script = pathlib.Path(argv[0])
    try:
        script = script.resolve().relative_to(HERE.parent)
    except ValueError:
        pass
    return {
        "command": " ".join(["python", str(script), *argv[1:]]),
        "date": datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M UTC"),
        "machine": {"cpu": cpu_model(), "cores": os.cpu_count()},
        "load": {"start": _LOAD_AT_START, "end": load_average()},
        "versions": {"python": platform.python_version(), "numpy": _version("numpy"),
                     "numba": _version("numba")},
        "commit": git_commit(),
    }


def check_tables(benchmark: str, tables: dict) -> None:
    """Each table is one of ``LAYOUTS[benchmark]`` and each row has its columns' keys."""
    if benchmark not in LAYOUTS:
        raise ValueError(f"benchmark {benchmark!r} has no layout in benchmarks/_layouts.py "
                         f"(known: {', '.join(sorted(LAYOUTS))})")
    for table, rows in tables.items():
        if table not in LAYOUTS[benchmark]:
            raise ValueError(f"{benchmark}: no table {table!r} in its layout, expected one "
                             f"of {sorted(LAYOUTS[benchmark])}")
        keys = {c.key for c in LAYOUTS[benchmark][table]}
        for i, row in enumerate(rows):
            if missing := keys - set(row):
                raise ValueError(f"{benchmark}/{table} row {i}: missing {sorted(missing)}")


def record(benchmark: str, tables: dict, *, path=None, meta: dict | None = None,
           argv: list[str] | None = None) -> pathlib.Path:
    """Write ``tables`` ({table: [row, ...]}) of ``benchmark`` with :func:`metadata_now`
    (updated by ``meta``) to ``path`` (default ``results/<benchmark>.json``)."""
    check_tables(benchmark, tables)
    path = pathlib.Path(path or RESULTS / f"{benchmark}.json")
    path.parent.mkdir(parents=True, exist_ok=True)
    data = {"benchmark": benchmark, "meta": {**metadata_now(argv), **(meta or {})},
            "tables": tables}
    path.write_text(dumps(data), encoding="utf-8")
    print(f"recorded {path}", file=sys.stderr)
    return path


def dumps(data: dict) -> str:
    """The record as JSON text: a line per metadata field and per row (diffs of a new run
    stay readable)."""
    def block(items, indent):
        pad = " " * indent
        return ",\n".join(f"{pad}{json.dumps(k)}: {v}" for k, v in items)

    meta = block(((k, json.dumps(v, ensure_ascii=False)) for k, v in data["meta"].items()), 2)
    tables = block(((name, "[\n" + ",\n".join(
        "   " + json.dumps(row, ensure_ascii=False) for row in rows) + "\n  ]")
        for name, rows in data["tables"].items()), 2)
    return (f'{{\n "benchmark": {json.dumps(data["benchmark"])},\n "meta": {{\n{meta}\n }},\n'
            f' "tables": {{\n{tables}\n }}\n}}\n')


def add_argument(parser, benchmark: str) -> None:
    """``--record [PATH]``: write the rows to PATH (default results/<benchmark>.json)."""
    parser.add_argument("--record", nargs="?", const=str(RESULTS / f"{benchmark}.json"),
                        metavar="PATH", help="write the table's rows and the run's machine, "
                        f"load, versions and commit to PATH (default "
                        f"benchmarks/results/{benchmark}.json) for the docs")
