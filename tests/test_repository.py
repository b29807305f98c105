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
            if p.name not in ("test_repository.py", "test_words.py")  # their own patterns
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
    # the file's lines split once, as ast.get_source_segment splits them (on \n, \r\n and \r, ends kept), which
    # splits the whole source again at every call: 10 of the 12 s this took over the repository
    lines = [line.encode() for line in io.StringIO(source, newline="").readlines()]
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Module | ast.ClassDef | ast.FunctionDef | ast.AsyncFunctionDef) and node.body:
            first = node.body[0]
            if isinstance(first, ast.Expr) and isinstance(first.value, ast.Constant) \
                    and isinstance(first.value.value, str):
                # the offsets are UTF-8 byte columns
                span = lines[first.lineno - 1:first.end_lineno]
                span[-1] = span[-1][:first.end_col_offset]  # the end first: on one line both cut the same line
                span[0] = span[0][first.col_offset:]
                found.append((first.lineno, b"".join(span).decode()))
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


@pytest.mark.slow
def test_every_path_named_in_a_python_comment_or_docstring_exists() -> None:
    gone = [f"{where}: {path}" for where, commit, path in python_pointers(ROOT) if commit is None
            and missing(ROOT, path)]
    assert not gone, "point these at where the file lives now (or at <commit>:path):\n" + "\n".join(gone)


@pytest.mark.slow
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


# ----- the layers: world → env → transforms → model → planner → trainer → learners → study, then play, diagnostics --
# A module imports only from its own layer or a lower one. play and diagnostics sit side by side on top (either may
# import any layer, not each other); the package's entry points (pernav/__init__.py and the cli package) sit above
# them all, and pernav/_lazy.py (the packages' lazy exports) below them all.
LAYERS = {"_lazy": -1, "world": 0, "env": 1, "transforms": 2, "model": 3, "planner": 4, "trainer": 5, "learners": 6,
          "study": 7, "play": 8, "diagnostics": 8, "cli": 9, "entry points": 9}
_MODULE = re.compile(r"pernav(?:\.\w+)+")  # a module named in a string: a lazy export, importlib, an entry point


def module_name(root: Path, path: Path) -> str:
    parts = path.relative_to(root).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def layer(module: str) -> str:
    """The layer of a pernav ``module``: its sub-package; a top-level module other than ``_lazy`` is an entry point."""
    parts = module.split(".")
    return parts[1] if len(parts) > 1 and parts[1] in LAYERS else "entry points"


def imported_modules(source: str) -> list[tuple[int, str]]:
    """Every pernav module ``source`` imports, with its line: import statements at any depth (a function's lazy
    import included) and module names in strings (lazy exports, ``importlib``, entry points)."""
    found = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.ImportFrom) and node.module:
            found.append((node.lineno, node.module))
        elif isinstance(node, ast.Import):
            found += [(node.lineno, alias.name) for alias in node.names]
        elif isinstance(node, ast.Constant) and isinstance(node.value, str) \
                and (m := _MODULE.fullmatch(node.value.split(":")[0])):
            found.append((node.lineno, m[0]))
    return sorted((line, module) for line, module in found if module.split(".")[0] == "pernav")


def upward_imports(root: Path) -> list[str]:
    """``file:line: importer -> imported`` for each import of pernav (under ``root``) that runs up the layers."""
    found = []
    for path in sorted((root / "pernav").rglob("*.py")):
        mine = layer(module_name(root, path))
        for line, module in imported_modules(path.read_text(encoding="utf-8")):
            theirs = layer(module)
            if theirs != mine and LAYERS.get(theirs, 8) >= LAYERS[mine]:
                found.append(f"{path.relative_to(root)}:{line}: {mine} -> {module}")
    return found


def test_the_layer_reader_finds_lazy_and_string_imports(tmp_path: Path) -> None:
    (tmp_path / "pernav" / "model").mkdir(parents=True)
    (tmp_path / "pernav" / "model" / "m.py").write_text(
        "from pernav.world.towns import Town\nimport pernav.env.layout\n\n\ndef f():\n"
        "    from pernav.study.stats import bootstrap_ci\n    return importlib.import_module('pernav.planner.x')\n\n"
        "LAZY = {'a': 'pernav.diagnostics.panel'}\nfrom pernav._lazy import lazy_exports\nimport numpy\n")
    assert upward_imports(tmp_path) == ["pernav/model/m.py:6: model -> pernav.study.stats",
                                        "pernav/model/m.py:7: model -> pernav.planner.x",
                                        "pernav/model/m.py:9: model -> pernav.diagnostics.panel"]
    (tmp_path / "pernav" / "play").mkdir()
    (tmp_path / "pernav" / "play" / "p.py").write_text("from pernav.diagnostics import stats\nimport pernav.cli\n")
    assert upward_imports(tmp_path)[3:] == ["pernav/play/p.py:1: play -> pernav.diagnostics",
                                            "pernav/play/p.py:2: play -> pernav.cli"]
    (tmp_path / "pernav" / "cli").mkdir()
    (tmp_path / "pernav" / "cli" / "m.py").write_text("from pernav.cli.bench import run\n"
                                                       "from pernav.study import run_study\n")
    assert len(upward_imports(tmp_path)) == 5  # the entry points import one another and every layer


def test_no_module_imports_from_a_higher_layer() -> None:
    assert {p.name for p in (ROOT / "pernav").iterdir() if (p / "__init__.py").exists()} <= set(LAYERS), \
        "place the new package in LAYERS"
    up = upward_imports(ROOT)
    assert not up, "move what these need down to their layer (or the import up to the caller):\n" + "\n".join(up)


# ----- names are imported from the module that defines them, not through one that imports them -------------------
# A package's __init__ is its public API, and these modules gather the public names of their package for readers
# (docs/components.md imports from them); pernav itself imports from where a name is defined.
_GATHERING = ("pernav.planner.navigation", "pernav.diagnostics.stats")


def defined_names(tree: ast.Module) -> set[str]:
    """The names a module defines at its top level (functions, classes, assignments), not those it imports."""
    names = set()
    for statement in tree.body:
        nested = isinstance(statement, ast.If | ast.Try | ast.For | ast.With)
        for node in ast.walk(statement) if nested else [statement]:
            if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef | ast.ClassDef):
                names.add(node.name)
            elif isinstance(node, ast.Assign | ast.AnnAssign | ast.For):
                targets = node.targets if isinstance(node, ast.Assign) else [node.target]
                names |= {n.id for t in targets for n in ast.walk(t) if isinstance(n, ast.Name)}
    return names


def lazy_exports_of(tree: ast.Module) -> dict[str, str]:
    """``name -> module`` of the lazy exports a package's ``__init__`` declares: its top-level dicts (literals or
    comprehensions of literals) whose values are pernav modules."""
    exports: dict[str, str] = {}
    for node in tree.body:
        if isinstance(node, ast.Assign) and isinstance(node.value, ast.Dict | ast.DictComp):
            value = eval(compile(ast.Expression(node.value), "<exports>", "eval"), {})  # data only: strings, tuples
            exports |= {k: v for k, v in value.items() if isinstance(v, str) and _MODULE.fullmatch(v)}
    return exports


def imports_through(root: Path, folders: tuple[str, ...]) -> list[str]:
    """``file:line: name via module`` for each name imported (at any depth) from a pernav module that does not
    define it, and for each lazy export of a package that names such a module. A package (its public API) may be
    imported from; the gathering modules too, from outside pernav."""
    trees = {module_name(root, p): ast.parse(p.read_text(encoding="utf-8")) for p in (root / "pernav").rglob("*.py")}
    packages = {module_name(root, p) for p in (root / "pernav").rglob("__init__.py")}
    defined = {m: defined_names(tree) for m, tree in trees.items()}
    found = []
    for folder in folders:
        for path in sorted((root / folder).rglob("*.py")):
            tree = ast.parse(path.read_text(encoding="utf-8"))
            pairs = [(node.lineno, node.module, alias.name) for node in ast.walk(tree)
                     if isinstance(node, ast.ImportFrom) and node.module in trees for alias in node.names]
            if module_name(root, path) in packages:
                pairs += [(1, module, name) for name, module in lazy_exports_of(tree).items() if module in trees]
            found += [f"{path.relative_to(root)}:{line}: {name} via {module}" for line, module, name in pairs
                      if module not in packages and name not in defined[module] and f"{module}.{name}" not in trees
                      and not (module in _GATHERING and folder != "pernav")]
    return found


def test_the_import_reader_finds_names_imported_through_another_module(tmp_path: Path) -> None:
    (tmp_path / "pernav" / "a").mkdir(parents=True)
    (tmp_path / "pernav" / "a" / "__init__.py").write_text("X = {'Town': 'pernav.a.m', 'f': 'pernav.a.m'}\n")
    (tmp_path / "pernav" / "a" / "n.py").write_text("def f():\n    pass\n")
    (tmp_path / "pernav" / "a" / "m.py").write_text("from pernav.a.n import f\n\n\nclass Town:\n    pass\n")
    (tmp_path / "tests").mkdir()
    (tmp_path / "tests" / "t.py").write_text("from pernav.a.m import Town, f\n\n\ndef g():\n"
                                             "    from pernav.a import Town, f\n    from pernav.a.m import f\n")
    assert imports_through(tmp_path, ("pernav", "tests")) == [
        "pernav/a/__init__.py:1: f via pernav.a.m", "tests/t.py:1: f via pernav.a.m", "tests/t.py:6: f via pernav.a.m"]


@pytest.mark.slow
def test_names_are_imported_from_the_module_that_defines_them() -> None:
    through = imports_through(ROOT, ("pernav", "tests", "recipes", "docs/research/scripts"))
    assert not through, "import these from the module that defines them:\n" + "\n".join(through)


# ----- no circles between files; imports at the top of a module unless a comment says why one waits ---------------
def _type_checking_only(tree: ast.Module) -> set[int]:
    """The ids of the import nodes under ``if TYPE_CHECKING:`` (they never run, so they make no circle)."""
    guarded = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
            guarded |= {id(n) for child in node.body for n in ast.walk(child)}
    return guarded


def import_graph(root: Path) -> dict[str, set[str]]:
    """``module -> the pernav modules it imports`` (at any depth, ``from package import submodule`` as the submodule),
    for every module under ``root/pernav``."""
    paths = {module_name(root, p): p for p in (root / "pernav").rglob("*.py")}
    graph: dict[str, set[str]] = {}
    for module, path in paths.items():
        tree = ast.parse(path.read_text(encoding="utf-8"))
        skip, found = _type_checking_only(tree), set()
        for node in ast.walk(tree):
            if id(node) in skip:
                continue
            if isinstance(node, ast.ImportFrom) and node.module and node.module.split(".")[0] == "pernav":
                found |= {f"{node.module}.{a.name}" if f"{node.module}.{a.name}" in paths else node.module
                          for a in node.names}
            elif isinstance(node, ast.Import):
                found |= {a.name for a in node.names if a.name.split(".")[0] == "pernav"}
        graph[module] = {m for m in found if m in paths and m != module}
    return graph


def circles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The import circles of ``graph``: its strongly connected components of more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    found: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        for w in sorted(graph[v]):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return found


def test_the_circle_reader_finds_a_circle_through_a_lazy_import_and_not_through_type_checking(tmp_path: Path) -> None:
    (tmp_path / "pernav" / "a").mkdir(parents=True)
    (tmp_path / "pernav" / "a" / "x.py").write_text("from pernav.a import y\n")
    (tmp_path / "pernav" / "a" / "y.py").write_text("def f():\n    from pernav.a.z import g\n")
    (tmp_path / "pernav" / "a" / "z.py").write_text("import pernav.a.x\n")
    (tmp_path / "pernav" / "a" / "w.py").write_text("from typing import TYPE_CHECKING\n"
                                                    "if TYPE_CHECKING:\n    from pernav.a.x import X\n")
    (tmp_path / "pernav" / "a" / "v.py").write_text("from pernav.a.w import W\n")
    assert circles(import_graph(tmp_path)) == [["pernav.a.x", "pernav.a.y", "pernav.a.z"]]


def test_no_two_files_import_each_other_even_through_others() -> None:
    found = circles(import_graph(ROOT))
    assert not found, "move what these share into the module that owns it:\n" + "\n".join(map(str, found))


def _said_why(lines: list[str], lineno: int) -> bool:
    """Whether the import at ``lineno`` (1-based) carries a ``# lazy:`` comment: on its line, or on a line of the run
    of imports and comments just above it (one comment may speak for a block of imports)."""
    at = lineno - 1
    while at >= 0 and (at == lineno - 1 or lines[at].strip().startswith(("#", "import ", "from "))):
        if "# lazy:" in lines[at]:
            return True
        at -= 1
    return False


def late_imports(root: Path) -> list[str]:
    """``file:line`` of each import inside a function or class of pernav without a ``# lazy: why`` comment (on its
    line, or above it in its block of imports)."""
    found = []
    for path in sorted((root / "pernav").rglob("*.py")):
        source = path.read_text(encoding="utf-8")
        tree, lines = ast.parse(source), source.splitlines()
        top, skip = {id(n) for n in tree.body}, _type_checking_only(tree)
        for node in ast.walk(tree):
            if isinstance(node, ast.Import | ast.ImportFrom) and id(node) not in top and id(node) not in skip:
                if not _said_why(lines, node.lineno):
                    found.append(f"{path.relative_to(root)}:{node.lineno}")
    return found


def test_imports_sit_at_the_top_of_modules_unless_a_comment_says_why_one_waits() -> None:
    late = late_imports(ROOT)
    assert not late, "move these imports to the top of their module (or say why one waits: # lazy: ...):\n" + \
        "\n".join(late)


MAX_CONSTRUCTOR_PARAMETERS = 10  # more: group them in an options dataclass (PlayOptions, SessionOptions, Departure)


def constructor_sizes(root: Path) -> dict[str, int]:
    """``file:line Class`` -> how many parameters its ``__init__`` takes besides ``self`` (``*args``, ``**kwargs``
    count one each), for every class of pernav."""
    sizes = {}
    for path in sorted((root / "pernav").rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.ClassDef):
                for f in node.body:
                    if isinstance(f, ast.FunctionDef) and f.name == "__init__":
                        a = f.args
                        n = len(a.posonlyargs) + len(a.args) + len(a.kwonlyargs) - 1 + (a.vararg is not None) + \
                            (a.kwarg is not None)
                        sizes[f"{path.relative_to(root)}:{f.lineno} {node.name}"] = n
    return sizes


def test_no_constructor_takes_more_than_ten_parameters() -> None:
    sizes = constructor_sizes(ROOT)
    assert max(sizes.values()) <= MAX_CONSTRUCTOR_PARAMETERS, \
        {k: v for k, v in sizes.items() if v > MAX_CONSTRUCTOR_PARAMETERS}
    assert sizes and all(v >= 0 for v in sizes.values())
