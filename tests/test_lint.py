"""``ruff check`` is clean (the rules of pyproject.toml's ``[tool.ruff]``): CI lints from
README's test command. Skipped where ruff is not installed."""

from __future__ import annotations

import pathlib
import subprocess
import sys

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1]


def test_ruff_check_is_clean():
    pytest.importorskip("ruff")
    paths = ["src", "tests", "tools", "benchmarks", "docs/conf.py", "docs/_ext"]
    out = subprocess.run([sys.executable, "-m", "ruff", "check", "--no-cache", *paths],
                         cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stdout[-8000:] + out.stderr[-2000:]
