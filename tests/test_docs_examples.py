"""Every Python example of docs/components.md runs on its own, as a reader would paste it: alone in a fresh
namespace and an empty folder, it writes no file there and prints only what its own ``print`` calls print.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest
import torchrl  # noqa: F401  (imported at collection: see below)

DOCS = Path(__file__).resolve().parents[1] / "docs" / "components.md"
# torchrl's log handler keeps the sys.stdout of torchrl's first import. Imported here, at collection (as it is
# when the whole suite runs), its INFO lines (check_env_specs's "succeeded!") go to pytest's own capture, not
# into the lines an example prints; imported first inside an example, they would be counted there.


def _doc_blocks() -> list[str]:
    return re.findall(r"```python\n(.*?)```", DOCS.read_text(), flags=re.S)


@pytest.mark.slow
@pytest.mark.parametrize("index", range(9))
def test_docs_example_runs_on_its_own(index: int, tmp_path, monkeypatch, capfd) -> None:
    """Every example of docs/components.md, alone in a fresh namespace and folder (as a reader would paste it):
    it writes nothing into the current folder and prints only what it prints itself (no library chatter)."""
    blocks = _doc_blocks()
    assert len(blocks) == 9  # a new example: add it to the range above
    monkeypatch.chdir(tmp_path)
    exec(compile(blocks[index], f"{DOCS.name}[block {index}]", "exec"), {"__name__": "__docs__"})  # noqa: S102
    assert sorted(p.name for p in tmp_path.iterdir()) == []
    printed = capfd.readouterr().out.splitlines()
    assert len(printed) == blocks[index].count("print("), printed
