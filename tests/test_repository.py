"""The repository's own rules: short modules and functions, ruff clean, names that do not cite the issue tracker."""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
MAX_MODULE_LINES = 600


def test_no_module_of_pernav_is_longer_than_600_lines() -> None:
    long = {str(p.relative_to(ROOT)): n for p in (ROOT / "pernav").rglob("*.py")
            if (n := len(p.read_text().splitlines())) > MAX_MODULE_LINES}
    assert not long, f"split these modules by concept: {long}"


def test_ruff_is_clean_including_the_60_statement_limit() -> None:
    ruff = shutil.which("ruff") or str(Path(sys.executable).parent / "ruff")
    if not Path(ruff).exists():
        pytest.skip("ruff is not installed")
    run = subprocess.run([ruff, "check", "pernav", "recipes", "tests", "docs/research/scripts"], cwd=ROOT,
                         capture_output=True, text=True)
    assert run.returncode == 0, run.stdout[-3000:]
    assert "PLR0915" in (ROOT / "pyproject.toml").read_text()  # the function-length rule is one of ruff's checks


def test_code_and_tests_name_what_they_do_not_the_issue_that_asked() -> None:
    cited = re.compile(r"issue #?\d+", re.IGNORECASE)
    hits = [f"{p.relative_to(ROOT)}:{i}" for folder in ("pernav", "tests") for p in (ROOT / folder).rglob("*.py")
            if p.name != "test_repository.py"
            for i, line in enumerate(p.read_text().splitlines(), 1) if cited.search(line)]
    assert not hits, hits
