"""Write the benchmark tables of the docs from the recorded results.

Usage::

    python tools/render_benchmarks.py            # rewrite the docs' tables
    python tools/render_benchmarks.py --check    # exit 1 if a page differs from its JSON

A table in a docs page sits between two markers::

    <!-- results: compiled_path -->
    ...
    <!-- /results -->

``compiled_path`` names ``benchmarks/results/compiled_path.json`` (written by the
benchmark's ``--record``, ``benchmarks/_record.py``); a record with several tables is named
with the table, ``<!-- results: dense eval -->``. Between the markers go the table, in
the layout of ``benchmarks/_layouts.py``, and a line with the run's date, machine, load
and command. Everything outside the markers is left as it is.
"""

from __future__ import annotations

import argparse
import difflib
import importlib.util
import json
import pathlib
import re
import sys

ROOT = pathlib.Path(__file__).resolve().parents[1]
BLOCK = re.compile(r"(<!-- results: (?P<name>[\w.-]+)(?: (?P<table>[\w.-]+))? -->\n)"
                   r"(?P<body>.*?)(<!-- /results -->)", re.DOTALL)


def layouts(root: pathlib.Path = ROOT):
    """``benchmarks/_layouts.py`` of the checkout ``root``, as a module."""
    spec = importlib.util.spec_from_file_location("bderiv_bench_layouts",
                                                  root / "benchmarks" / "_layouts.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up there
    spec.loader.exec_module(module)
    return module


def caption(meta: dict, file: str) -> str:
    """Under a table: when, where, at what load and by which command it was measured."""
    machine = meta.get("machine") or {}
    where = machine.get("cpu", "machine not stated") + (
        f" ({machine['cores']} cores)" if machine.get("cores") else "")
    load = meta.get("load")
    if isinstance(load, dict):  # os.getloadavg() at start and end: the 1-minute averages
        start, end = ((f"{v[0]:.1f}" if v else "?") for v in (load["start"], load["end"]))
        load = f"load {start} at the start, {end} at the end"
    else:
        load = f"load {load}" if load else "load not recorded"
    parts = [f"{meta.get('date') or '(date not stated)'} on {where}, {load}",
             meta.get("note"), f"`{meta['command']}`"]
    if meta.get("converted_from"):
        parts.append(f"converted from {meta['converted_from']}")
    parts.append(f"`{file}`")
    return f"*Measured {'; '.join(p for p in parts if p)}.*"


def render_block(name: str, table_name: str | None, results: pathlib.Path, spec) -> str:
    path = results / f"{name}.json"
    data = json.loads(path.read_text(encoding="utf-8"))
    tables = data["tables"]
    if table_name is None:
        if len(tables) != 1:
            raise ValueError(f"{path}: {len(tables)} tables; name one in the marker "
                             f"(<!-- results: {name} TABLE -->, TABLE in {sorted(tables)})")
        (table_name,) = tables
    if table_name not in tables:
        raise ValueError(f"{path}: no table {table_name!r} (has {sorted(tables)})")
    columns = spec.LAYOUTS[data["benchmark"]][table_name]
    lines = ["", *spec.markdown_table(columns, tables[table_name]), "",
             caption(data["meta"], f"benchmarks/results/{name}.json"), ""]
    return "\n".join(lines) + "\n"


def render_page(text: str, results: pathlib.Path, spec) -> str:
    """``text`` with every block between markers rendered from ``results``."""
    def fill(m):
        return m.group(1) + render_block(m["name"], m["table"], results, spec) + m.group(5)
    return BLOCK.sub(fill, text)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--check", action="store_true",
                   help="write nothing; exit 1 (with a diff) if a page differs from its JSON")
    p.add_argument("--root", type=pathlib.Path, default=ROOT,
                   help="the checkout (docs/, benchmarks/results/); default this one")
    args = p.parse_args(argv)
    results = args.root / "benchmarks" / "results"
    spec = layouts(args.root)
    stale = []
    for page in sorted((args.root / "docs").glob("*.md")) + [args.root / "README.md"]:
        if not page.exists():
            continue
        text = page.read_text(encoding="utf-8")
        new = render_page(text, results, spec)
        if new == text:
            continue
        stale.append(page)
        if args.check:
            sys.stdout.writelines(difflib.unified_diff(
                text.splitlines(True), new.splitlines(True), str(page), "rendered"))
        else:
            page.write_text(new, encoding="utf-8")
            print(f"wrote {page.relative_to(args.root)}")
    if args.check and stale:
        print(f"{len(stale)} page(s) differ from benchmarks/results: run "
              f"python tools/render_benchmarks.py", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
