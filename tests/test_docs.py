"""The documentation's code runs: the python blocks of README.md and docs/*.md.

README.md is the front door (one example); the manual is the pages of docs/.

The blocks of one file run in order in one namespace (the tutorial builds on earlier
blocks), in a temporary directory; a failure points at the line in the markdown file.
"""

from __future__ import annotations

import argparse
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
    assert {"README.md", "tutorial.md", "mathematics.md", "cli.md", "benchmarks.md"} <= names
    assert len(blocks(ROOT / "README.md")) >= 1


@pytest.mark.parametrize("path", DOCS, ids=lambda p: str(p.relative_to(ROOT)))
def test_python_blocks_run(path, tmp_path, monkeypatch):
    found = blocks(path)
    if not found:
        pytest.skip("no python blocks")
    if any("dask" in code for _, code in found):
        pytest.importorskip("dask.array")
    if any("plot" in code for _, code in found):
        pytest.importorskip("matplotlib")
    if any("import jax" in code for _, code in found):
        pytest.importorskip("jax")
    if any("import diffrax" in code for _, code in found):
        pytest.importorskip("diffrax")
    monkeypatch.chdir(tmp_path)  # blocks that write files write them here
    # as a reader runs them: the default policy, whose new models of numba functions run
    # their first second on Python (the tutorial read `model.compiled`, None then, and
    # failed for readers while the suite's policy, compiled, hid it)
    monkeypatch.delenv("BDERIV_INTEGRATOR", raising=False)
    namespace = {"__name__": "__doc__"}
    for line, code in found:
        # pad with blank lines so that a traceback names the line in the markdown file
        exec(compile("\n" * (line - 1) + code, str(path), "exec"), namespace)


#: a command line in the docs: ``bderiv <command> ...`` or ``python -m bderiv <command> ...``
COMMAND_LINE = re.compile(r"(?:python -m )?bderiv (demo|bench|plot|export|compile)\b([^`\n]*)")
#: the files whose command lines are checked: every page that names a command
CLI_DOCS = [p for p in DOCS if COMMAND_LINE.search(p.read_text(encoding="utf-8"))]
#: the page whose table names every option of every command
CLI_PAGE = ROOT / "docs" / "cli.md"


def command_lines(path):
    """(command, list of (option, value or None)) of every command line of a markdown file,
    read from code spans, table cells and bash blocks."""
    found = []
    for match in COMMAND_LINE.finditer(path.read_text(encoding="utf-8")):
        tokens = match.group(2).replace("\\|", "|").replace("[", " ").replace("]", " ").split()
        pairs = []
        for i, tok in enumerate(tokens):
            if tok.startswith("--"):
                value = tokens[i + 1] if i + 1 < len(tokens) else None
                pairs.append((tok, None if value is None or value.startswith("--") else value))
        found.append((match.group(1), pairs))
    return found


@pytest.mark.parametrize("path", CLI_DOCS, ids=lambda p: p.name)
def test_every_command_and_option_in_the_docs_exists(path):
    """The docs name only commands, options and choices that the parser has
    (and the parser reads the command lines of the bash blocks without error)."""
    from bderiv.cli.parser import build_parser

    parser = build_parser()
    lines = command_lines(path)
    assert lines, "no command line found"
    named = set()
    for command, pairs in lines:
        sub = parser.commands[command]
        for option, value in pairs:
            action = sub._option_string_actions.get(option)
            assert action is not None, f"{path.name}: bderiv {command} has no option {option}"
            named.add((command, option))
            if action.choices is not None and value is not None and "|" in value:
                for choice in value.split("|"):  # a table's list of choices: a|b|c
                    typed = action.type(choice) if action.type else choice
                    assert typed in action.choices, f"{command} {option} {choice}"
    if path == CLI_PAGE:  # the command line's page names every option of every command
        for command, sub in parser.commands.items():
            options = {o for a in sub._actions for o in a.option_strings
                       if o.startswith("--") and a.help != argparse.SUPPRESS}  # not internal
            missing = options - {"--help"} - {o for c, o in named if c == command}
            assert not missing, f"cli.md does not name {sorted(missing)} of bderiv {command}"


def test_bash_blocks_parse():
    """Every ``bderiv ...`` line of a bash block in the docs parses as it is written."""
    from bderiv.cli.parser import build_parser

    parser = build_parser()
    for path in CLI_DOCS:
        text = path.read_text(encoding="utf-8")
        for block in re.findall(r"^```bash\n(.*?)^```", text, re.S | re.M):
            for line in block.splitlines():
                line = line.split("#")[0].split("&&")[-1].strip()
                if line.startswith(("bderiv ", "python -m bderiv ")):
                    argv = line.split()[2 if line.startswith("bderiv") else 4:]
                    args, extra = parser.parse_known_args([line.split()[
                        1 if line.startswith("bderiv") else 3], *argv])
                    assert not extra, (path.name, line)


def test_images_in_the_docs_exist():
    for path in [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]:
        for image in re.findall(r"!\[[^\]]*\]\(([^)]+)\)", path.read_text(encoding="utf-8")):
            assert (path.parent / image).is_file(), (path.name, image)


def test_public_namespace():
    """``import bderiv`` exposes its API and submodules, no helper it imported."""
    import types

    import bderiv

    leaked = [name for name in dir(bderiv) if not name.startswith("_")
              and name not in bderiv.__all__
              and not isinstance(getattr(bderiv, name), types.ModuleType)]
    assert leaked == []


def test_cited_documents_and_sections_exist():
    """The documentation is self-contained: every document a doc, docstring or comment
    cites by its file name is in the repository, and every numbered section of
    docs/mathematics.md cited (``mathematics.md section 9``, ``sections 3 and 6``) exists."""
    known = {p.name for p in DOCS}
    numbered = set(re.findall(r"^## (\d+)\.", (ROOT / "docs" / "mathematics.md").read_text(
        encoding="utf-8"), re.M))
    cites = re.compile(r"mathematics\.md\)?[\s,]+sections?\s+(\d+(?:\s*(?:,|and|or|to)\s*\d+)*)")
    files = [*DOCS, *sorted((ROOT / "src").rglob("*.py")), *sorted((ROOT / "tests").glob("*.py")),
             *sorted((ROOT / "benchmarks").glob("*.py")), *sorted((ROOT / "tools").glob("*.py"))]
    for path in files:
        text = path.read_text(encoding="utf-8")
        for name in re.findall(r"\b([A-Za-z][\w-]*\.md)\b", text):
            assert name in known, f"{path.relative_to(ROOT)} cites {name}, not in the repository"
        for match in cites.finditer(text):
            for number in re.findall(r"\d+", match.group(1)):
                assert number in numbered, (
                    f"{path.relative_to(ROOT)} cites docs/mathematics.md section {number}, "
                    f"which does not exist")
