"""The documentation's code runs: the python blocks of README.md and docs/*.md.

The blocks of one file run in order in one namespace (the tutorial builds on earlier
blocks), in a temporary directory; a failure points at the line in the markdown file.
"""

from __future__ import annotations

import pathlib
import re

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1]
DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
BLOCK = re.compile(r"^```python\n(.*?)^```", re.S | re.M)


def blocks(path):
    """(first line number, code) of every python block of a markdown file."""
    text = path.read_text(encoding="utf-8")
    return [
        (text[: m.start()].count("\n") + 2, m.group(1)) for m in BLOCK.finditer(text)
    ]


def test_docs_are_there():
    names = {p.name for p in DOCS}
    assert {"README.md", "tutorial.md", "mathematics.md"} <= names
    assert len(blocks(ROOT / "README.md")) >= 3


@pytest.mark.parametrize("path", DOCS, ids=lambda p: str(p.relative_to(ROOT)))
def test_python_blocks_run(path, tmp_path, monkeypatch):
    found = blocks(path)
    if not found:
        pytest.skip("no python blocks")
    if any("dask" in code for _, code in found):
        pytest.importorskip("dask.array")
    if any("plot" in code for _, code in found):
        pytest.importorskip("matplotlib")
    monkeypatch.chdir(tmp_path)  # blocks that write files write them here
    namespace = {"__name__": "__doc__"}
    for line, code in found:
        # pad with blank lines so that a traceback names the line in the markdown file
        exec(compile("\n" * (line - 1) + code, str(path), "exec"), namespace)


def test_modules_import_without_extras():
    """Every module of the package imports with matplotlib, tqdm and dask missing.

    (The doctests import them all; the extras are only needed inside the functions.)
    """
    import subprocess
    import sys

    code = (
        "import sys, importlib, pkgutil\n"
        "for name in ('matplotlib', 'tqdm', 'dask', 'distributed'):\n"
        "    sys.modules[name] = None\n"
        "import bderiv\n"
        "names = [m.name for m in pkgutil.walk_packages(bderiv.__path__, 'bderiv.')]\n"
        "for name in names:\n"
        "    if name != 'bderiv.__main__':\n"
        "        importlib.import_module(name)\n"
        "print(len(names))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    assert int(out.stdout) >= 10
