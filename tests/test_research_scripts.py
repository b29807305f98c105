"""The research log's scripts (docs/research/scripts) still import: each names modules of the package, which move
(one of them imported a module renamed months before anybody ran it again)."""

import importlib.util
import re
from pathlib import Path

import pytest

SCRIPTS = sorted((Path(__file__).parents[1] / "docs" / "research" / "scripts").glob("*.py"))


@pytest.mark.parametrize("script", SCRIPTS, ids=[s.stem for s in SCRIPTS])
def test_a_research_script_imports(script: Path) -> None:
    spec = importlib.util.spec_from_file_location(f"research_{script.stem}", script)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)  # runs the imports and definitions, not the script's main part
    assert module.__doc__, f"{script.name} does not say what it checks"


def test_the_research_readme_lists_every_script_and_no_other() -> None:
    readme = (Path(__file__).parents[1] / "docs" / "research" / "README.md").read_text(encoding="utf-8")
    listed = set(re.findall(r"^\| `(\w+\.py)` \|", readme, flags=re.MULTILINE))
    assert listed == {s.name for s in SCRIPTS}, "docs/research/README.md's Scripts table: one row per script"
