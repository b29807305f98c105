"""The repository's own rules: short modules and functions, ruff clean, names that do not cite the issue tracker."""

from __future__ import annotations

import ast
import io
import re
import shutil
import subprocess
import sys
import tokenize
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


# A repository path in prose: it starts with a top-level folder and names a file (an extension) or a folder (a
# trailing slash); ``<commit>:`` before it points into that commit (``git show 4cd6bc4:docs/findings.md``).
# Paths under runs/, drives/ or /tmp are outputs, and are not matched: they start elsewhere.
_POINTER = re.compile(r"(?<![\w./~$-])(?:(?P<commit>[0-9a-f]{7,40}):)?(?P<path>(?:docs|pernav|recipes|tests)/[\w./-]*)")
_PATTERN_NEXT = tuple("*{<[")  # a glob or a template: docs/figures/*.json, seed{0,1}.json, figures/<town>.png
_PLACEHOLDER = re.compile(r"[A-Z][A-Z0-9_]*")  # a component such as NAME or OUT in presets/NAME.yaml
_PROSE_FOLDERS = ("pernav", "tests", "recipes", "docs/research/scripts")


def prose(source: str) -> list[tuple[int, str]]:
    """The comments and the module, class and function docstrings of a Python ``source``, each with its line,
    docstrings as written (so that a line counted inside one is the file's line)."""
    found = [(tok.start[0], tok.string) for tok in tokenize.generate_tokens(io.StringIO(source).readline)
             if tok.type == tokenize.COMMENT]
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Module | ast.ClassDef | ast.FunctionDef | ast.AsyncFunctionDef) and node.body:
            first = node.body[0]
            if isinstance(first, ast.Expr) and isinstance(first.value, ast.Constant) \
                    and isinstance(first.value.value, str):
                found.append((first.lineno, ast.get_source_segment(source, first)))
    return found


def pointers(text: str, line: int = 1) -> list[tuple[int, str | None, str]]:
    """The repository paths that ``text`` (starting at ``line``) names: ``(line, commit or None, path)``."""
    found = []
    for m in _POINTER.finditer(text):
        path = m["path"].rstrip(".")  # a sentence's full stop
        pattern = text[m.end():m.end() + 1] in _PATTERN_NEXT
        names = path.endswith("/") or re.search(r"\.[A-Za-z0-9]+$", path.rsplit("/", 1)[-1])
        if names and not pattern:
            found.append((line + text.count("\n", 0, m.start()), m["commit"], path))
    return found


def missing(root: Path, path: str) -> bool:
    """Whether ``path`` is absent from the working tree ``root``; a path with a placeholder (presets/NAME.yaml)
    is a pattern, not a pointer."""
    parts = Path(path).parts
    return not (root / path).exists() and not any(_PLACEHOLDER.fullmatch(Path(p).stem) for p in parts)


def python_pointers(root: Path) -> list[tuple[str, str | None, str]]:
    """Every path named in a comment or docstring of the ``.py`` files of pernav, tests, recipes and the
    research scripts: ``("file:line", commit or None, path)``."""
    files = sorted(p for folder in _PROSE_FOLDERS for p in (root / folder).rglob("*.py"))
    return [(f"{p.relative_to(root)}:{at}", commit, path) for p in files
            for line, text in prose(p.read_text(encoding="utf-8")) for at, commit, path in pointers(text, line)]


def test_the_pointer_reader_finds_paths_and_leaves_patterns_and_outputs(tmp_path: Path) -> None:
    source = ('"""See docs/guide.md and `pernav/model/`. Writes runs/x/out.json, /tmp/cal/docs/a.md,\n'
              'docs/figures/*.png, docs/figures/seed{0,1}.json; presets are pernav/presets/NAME.yaml.\n"""\n'
              "x = 'docs/not_prose.md'\n\n\ndef f():\n"
              '    """Old: git show 4cd6bc4:docs/findings.md. An env id: pernav/Town1-v0."""\n'
              "    return 1  # moved to tests/test_gone.py.\n")
    assert [(line, commit, path) for line, text in prose(source) for line, commit, path in pointers(text, line)] \
        == [(9, None, "tests/test_gone.py"), (1, None, "docs/guide.md"), (1, None, "pernav/model/"),
            (2, None, "pernav/presets/NAME.yaml"), (8, "4cd6bc4", "docs/findings.md")]
    (tmp_path / "pernav" / "presets").mkdir(parents=True)
    assert [missing(tmp_path, p) for p in ("pernav/presets/", "pernav/gone.py", "pernav/presets/NAME.yaml")] \
        == [False, True, False]


def test_every_path_named_in_a_python_comment_or_docstring_exists() -> None:
    gone = [f"{where}: {path}" for where, commit, path in python_pointers(ROOT) if commit is None
            and missing(ROOT, path)]
    assert not gone, "point these at where the file lives now (or at <commit>:path):\n" + "\n".join(gone)


def test_every_path_pointed_into_a_commit_is_in_that_commit() -> None:
    """``<commit>:path`` pointers in code prose and in the research README (its archive commands): a clone has the
    commit and the commit has the path."""
    if subprocess.run(["git", "rev-parse", "--is-shallow-repository"], cwd=ROOT, capture_output=True,
                      text=True).stdout.strip() != "false":
        pytest.skip("not a git clone with its full history")
    readme = ROOT / "docs" / "research" / "README.md"
    named = [(where, commit, path) for where, commit, path in python_pointers(ROOT) if commit] + \
        [(f"{readme.relative_to(ROOT)}:{at}", commit, path)
         for at, commit, path in pointers(readme.read_text(encoding="utf-8")) if commit]
    assert any(where.startswith("docs/research/README.md") for where, _, _ in named), "the archive commit is named"
    gone = [f"{where}: {commit}:{path}" for where, commit, path in named
            if subprocess.run(["git", "cat-file", "-e", f"{commit}:{path}"], cwd=ROOT,
                              capture_output=True).returncode != 0]
    assert not gone, gone
