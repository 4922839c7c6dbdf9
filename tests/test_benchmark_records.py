"""The docs' benchmark tables are what ``benchmarks/results/*.json`` render to
(``tools/render_benchmarks.py --check``), a changed number is caught, and the writer
``benchmarks/_record.py`` records every field of where and how a run was measured."""

from __future__ import annotations

import importlib.util
import json
import pathlib
import shutil
import sys

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"


def load(name: str, path: pathlib.Path):
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="module")
def render():
    return load("bderiv_render_benchmarks", ROOT / "tools" / "render_benchmarks.py")


@pytest.fixture(scope="module")
def record():
    return load("bderiv_bench_record", ROOT / "benchmarks" / "_record.py")


def test_the_pages_are_their_records(render, capsys):
    assert render.main(["--check"]) == 0, capsys.readouterr().out


def copy_of_the_repo(tmp_path: pathlib.Path) -> pathlib.Path:
    root = tmp_path / "repo"
    shutil.copytree(ROOT / "docs", root / "docs", ignore=shutil.ignore_patterns("*.png",
                                                                                  "_build"))
    shutil.copytree(RESULTS, root / "benchmarks" / "results")
    shutil.copy(ROOT / "benchmarks" / "_layouts.py", root / "benchmarks")
    return root


def test_a_changed_number_fails_the_check(render, tmp_path, capsys):
    root = copy_of_the_repo(tmp_path)
    assert render.main(["--check", "--root", str(root)]) == 0
    path = root / "benchmarks" / "results" / "compiled_path.json"
    data = json.loads(path.read_text(encoding="utf-8"))
    assert data["tables"]["main"][0]["sim_py"] == pytest.approx(0.0217)
    data["tables"]["main"][0]["sim_py"] = 0.0227  # 21.7 ms -> 22.7 ms
    path.write_text(json.dumps(data), encoding="utf-8")
    capsys.readouterr()
    assert render.main(["--check", "--root", str(root)]) == 1
    diff = capsys.readouterr().out
    assert "-| 2 | 0 | 8 | 0.20 | 21.7 |" in diff and "+| 2 | 0 | 8 | 0.20 | 22.7 |" in diff
    # rendering writes the new number into the page, and then the check passes
    assert render.main(["--root", str(root)]) == 0
    assert "| 2 | 0 | 8 | 0.20 | 22.7 | 107x |" in (root / "docs" / "benchmarks.md").read_text()
    assert render.main(["--check", "--root", str(root)]) == 0


def test_a_hand_edited_cell_fails_the_check(render, tmp_path):
    root = copy_of_the_repo(tmp_path)
    page = root / "docs" / "control.md"
    text = page.read_text(encoding="utf-8")
    # the last row of the first rendered table, one digit changed
    block = text[text.index("<!-- results:"):]
    row = [line for line in block[:block.index("<!-- /results")].splitlines()
           if line.startswith("| ") and any(c.isdigit() for c in line)][-1]
    k = next(i for i, c in enumerate(row) if c.isdigit())
    edited = row[:k] + str((int(row[k]) + 1) % 10) + row[k + 1:]
    page.write_text(text.replace(row, edited, 1), encoding="utf-8")
    assert render.main(["--check", "--root", str(root)]) == 1


def test_every_record_is_shown_and_says_where_it_comes_from(record):
    pages = "".join(p.read_text(encoding="utf-8") for p in (ROOT / "docs").glob("*.md"))
    for path in sorted(RESULTS.glob("*.json")):
        data = json.loads(path.read_text(encoding="utf-8"))
        record.check_tables(data["benchmark"], data["tables"])
        meta = data["meta"]
        assert meta["command"].startswith("python "), path
        assert "converted_from" in meta or set(record.FIELDS) <= set(meta), path
        for table in data["tables"]:
            name = path.stem if len(data["tables"]) == 1 else f"{path.stem} {table}"
            assert f"<!-- results: {name} -->" in pages, f"{path.name} {table} is on no page"


def test_the_writer_records_every_field(record, tmp_path):
    rows = [{"n": 8, "copy": 3.19e-9, "apply": 27.9e-9, "inverse": 26.7e-9, "apply_copy": 8.8,
             "target": 5}]
    path = record.record("copy_ratio", {"main": rows}, path=tmp_path / "copy_ratio.json",
                         argv=["benchmarks/copy_ratio.py", "--ns", "8", "--record"])
    data = json.loads(path.read_text(encoding="utf-8"))
    assert data["benchmark"] == "copy_ratio" and data["tables"]["main"] == rows
    meta = data["meta"]
    assert set(meta) == set(record.FIELDS)
    assert meta["command"] == "python benchmarks/copy_ratio.py --ns 8 --record"
    assert meta["date"].endswith(" UTC") and meta["date"][:2] == "20"
    assert meta["machine"]["cpu"] and meta["machine"]["cores"] >= 1
    assert len(meta["load"]["start"]) == 3 and len(meta["load"]["end"]) == 3
    assert all(meta["versions"][k] for k in ("python", "numpy", "numba"))
    assert meta["commit"] and len(meta["commit"].rstrip("+")) >= 7


def test_the_writer_refuses_rows_off_the_layout(record, tmp_path):
    with pytest.raises(ValueError, match=r"copy_ratio/main row 0: missing \['target'\]"):
        record.record("copy_ratio", {"main": [{"n": 8, "copy": 1e-9, "apply": 1e-8,
                                               "inverse": 1e-8, "apply_copy": 10.0}]},
                      path=tmp_path / "x.json")
    with pytest.raises(ValueError, match="no layout"):
        record.record("no_such_benchmark", {"main": []}, path=tmp_path / "x.json")
    assert not (tmp_path / "x.json").exists()
