"""The repository's words point only into the repository: no absolute path of a development machine, no reference
to a spec document or an issue tracker that a clone does not have, and no ``pernav.x.y`` name that does not import.

Scanned: the code (pernav/, recipes/, tests/, docs/research/scripts/: Python, YAML, Markdown, text and JSON files),
the docs (README.md, CHANGELOG.md, docs/**/*.md, docs/**/*.yaml) and the figures (docs/**/*.json, docs/**/*.txt).
tests/test_repository.py bans ``issue N`` in pernav/ and tests/ already; this extends it to every text a reader
meets. Each hit is reported as ``file:line: check: what``.
"""

from __future__ import annotations

import ast
import bisect
import importlib
import itertools
import re
from functools import cache
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
THIS = Path(__file__).resolve()  # its own patterns and planted lines are not hits

CODE_FOLDERS = ("pernav", "recipes", "tests", "docs/research/scripts")
CODE_SUFFIXES = {".py", ".yaml", ".yml", ".md", ".txt", ".json", ".toml"}
DOC_FILES = ("README.md", "CHANGELOG.md")
DOC_GLOBS = ("docs/**/*.md", "docs/**/*.yaml", "docs/**/*.yml", "docs/**/*.json", "docs/**/*.txt")

# (a) an absolute path of a development machine; a path inside the repository (runs, then home, then x) is not one: the
# folder must start the path. /tmp is left out on purpose: docs use it as an example output folder.
_MACHINE_PATH = re.compile(r"(?<![\w.~$/-])/(?:work|home|Users|root|opt)/")
# (b) a spec document the repository does not hold: the upper-case word (SPEC, SPEC.md, SPEC §6); a name such as
# ACTION_SPEC or the word "spec" is not one.
_SPEC = re.compile(r"(?<![\w-])SPEC(?![\w-])")
# (c) an issue of a tracker the repository does not hold: "issue 10", "issue #31", "issues #31/#33", "the issue's".
# "the issue tracker" names the tracker itself (tests/test_repository.py says it does not cite it) and is allowed.
_ISSUE = re.compile(r"\bissues? ?#?\d+|\bthe issue(?!\s+tracker)\b", re.IGNORECASE)
# (d) a dotted name of the package: a module, or an attribute of one. A file name such as runs/pernav.log or a
# URL's .../pernav.git is not one (a path character before it), nor a name inside a ``<commit>:path`` pointer.
_DOTTED = re.compile(r"(?<![\w./-])pernav(?:\.[A-Za-z_]\w*)+")
_COMMIT_POINTER = re.compile(r"\b[0-9a-f]{7,40}:\S+")
_CANDIDATE = re.compile(r"/(?:work|home|Users|root|opt)/|SPEC|issue|pernav\.", re.IGNORECASE)

# Clearly justified exceptions: (file, check) for a whole file, (file, check, word) for one word -> why.
ALLOWED = {
    ("CHANGELOG.md", "module"):
        "the changelog records each change in the names of its day, renames and moves among them: its history is "
        "not rewritten when a module moves",
    ("tests/test_repository.py", "module"):
        "its checkers' own tests plant made-up pernav trees in tmp folders (pernav.a.m, pernav.planner.x, ...)",
    ("tests/generic/test_other_tasks.py", "module", "pernav.world.not_a_name"):
        "the test asserts that this name raises AttributeError",
    ("tests/diagnostics/test_diagnostics.py", "module", "pernav.diagnostics.X"):
        "X stands for each diagnostic's module (python -m pernav.diagnostics.X)",
}


def files() -> list[Path]:
    """Every scanned file, once, in a stable order."""
    found = {p for folder in CODE_FOLDERS for p in (ROOT / folder).rglob("*")
             if p.is_file() and p.suffix in CODE_SUFFIXES and "__pycache__" not in p.parts}
    found |= {ROOT / name for name in DOC_FILES if (ROOT / name).exists()}
    found |= {p for pattern in DOC_GLOBS for p in ROOT.glob(pattern) if p.is_file()}
    return sorted(p for p in found if p.resolve() != THIS)


def _module_file(module: str, root: Path = ROOT) -> Path | None:
    """The source file of ``module`` under ``root`` (a module or a package's __init__), without importing it."""
    base = root.joinpath(*module.split("."))
    for path in (base.with_suffix(".py"), base / "__init__.py"):
        if path.is_file():
            return path
    return None


@cache
def _module(path: Path) -> tuple[dict[str, ast.AST], dict[str, str]]:
    """The names a module's source binds, and its lazy exports."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    return _members(tree), _lazy_exports(tree)


def _members(node: ast.Module | ast.ClassDef) -> dict[str, ast.AST]:
    """The names a module or class body binds (defs, classes, assignments, annotations, imports), each with the
    node that binds it; for a class also ``self.x = ...`` in its methods."""
    found: dict[str, ast.AST] = {}
    for statement in node.body:
        nested = isinstance(statement, ast.If | ast.Try | ast.With)
        for item in ast.walk(statement) if nested else [statement]:
            if isinstance(item, ast.FunctionDef | ast.AsyncFunctionDef | ast.ClassDef):
                found[item.name] = item
            elif isinstance(item, ast.Assign | ast.AnnAssign):
                for target in item.targets if isinstance(item, ast.Assign) else [item.target]:
                    for name in ast.walk(target):
                        if isinstance(name, ast.Name):
                            found[name.id] = item
            elif isinstance(item, ast.Import | ast.ImportFrom):
                for alias in item.names:
                    found[(alias.asname or alias.name).split(".")[0]] = item
    if isinstance(node, ast.ClassDef):
        for item in ast.walk(node):
            if isinstance(item, ast.Attribute) and isinstance(item.ctx, ast.Store) \
                    and isinstance(item.value, ast.Name) and item.value.id == "self":
                found.setdefault(item.attr, item)
    return found


def _lazy_exports(tree: ast.Module) -> dict[str, str]:
    """``name -> module`` of a package's lazy exports: its top-level dicts (literals or comprehensions of literals)
    whose values are pernav modules, as tests/test_repository.py reads them."""
    exports: dict[str, str] = {}
    for node in tree.body:
        if isinstance(node, ast.Assign) and isinstance(node.value, ast.Dict | ast.DictComp):
            try:
                value = eval(compile(ast.Expression(node.value), "<exports>", "eval"), {})  # noqa: S307 (literals)
            except Exception:  # noqa: BLE001 (a dict of anything but literals is no export table)
                continue
            exports |= {k: v for k, v in value.items() if isinstance(k, str) and isinstance(v, str)
                        and v.startswith("pernav.")}
    return exports


_ANY_OBJECT = {"__doc__", "__name__", "__module__", "__qualname__", "__file__", "__dict__", "__init__", "__call__"}


def _open(bound: dict[str, ast.AST]) -> bool:
    """Whether a module or class may have names its source does not bind: a star import, or a ``__getattr__`` other
    than the lazy exports' (whose names ``_lazy_exports`` reads)."""
    hook = bound.get("__getattr__")
    lazy_hook = isinstance(hook, ast.Assign) and "lazy_exports" in ast.unparse(hook.value)
    return "*" in bound or (hook is not None and not lazy_hook)


@cache
def _static(name: str, depth: int = 0) -> bool | str | None:
    """``name`` read from the sources alone, without importing: True when it resolves (a module file, then a name
    its module binds, followed through ``from pernav.x import y`` and lazy exports, then members of classes and of
    their bases); why not, when the sources settle that; None when they cannot (a function's or a value's attribute,
    a base class from another library): the importing check decides."""
    parts = name.split(".")
    for i in range(len(parts), 0, -1):
        module = ".".join(parts[:i])
        if (path := _module_file(module)) is not None:
            break
    else:
        return "no such module"
    if i == len(parts):
        return True
    first, rest, (bound, lazy) = parts[i], parts[i + 1:], _module(path)
    if first in _ANY_OBJECT or depth > 8:
        return True if first in _ANY_OBJECT else None
    if first in lazy:
        return _static(".".join([lazy[first], first, *rest]), depth + 1)
    if first not in bound:
        return None if _open(bound) else f"{module} has no {first}"
    node, owner = bound[first], f"{module}.{first}"
    if isinstance(node, ast.ImportFrom) and node.module and node.module.split(".")[0] == "pernav":
        original = next(a.name for a in node.names if (a.asname or a.name) == first)
        return _static(".".join([node.module, original, *rest]), depth + 1)
    for at, attr in enumerate(rest):
        if not isinstance(node, ast.ClassDef):
            return None
        members = _members(node)
        if attr in members or attr in _ANY_OBJECT:
            node, owner = members.get(attr), f"{owner}.{attr}"
            continue
        if _open(members) or node.keywords or any(not isinstance(b, ast.Name) for b in node.bases):
            return None  # a metaclass, a computed base or a __getattr__ may add it
        inherited = [_static(".".join([module, base.id, *rest[at:]]), depth + 1) for base in node.bases]
        if True in inherited:
            return True
        return None if None in inherited else f"{owner} has no {attr}"
    return True


@cache
def unresolved(name: str) -> str | None:
    """Why ``name`` (``pernav.x.y``) names neither a module nor an attribute of one; None when it does. Read from the
    sources first (fast: no torch is imported); what they cannot settle is imported: the longest prefix that imports
    is the module, and the rest must be its attributes, one after another (``hasattr``)."""
    static = _static(name)
    if static is not None:
        return None if static is True else static
    parts = name.split(".")
    for i in range(len(parts), 0, -1):
        module = ".".join(parts[:i])
        try:
            obj = importlib.import_module(module)
        except ModuleNotFoundError as error:
            if error.name and (module == error.name or module.startswith(error.name + ".")):
                continue  # not a module: a shorter prefix may be, with the rest its attributes
            return f"{module} does not import ({error})"
        except Exception as error:  # noqa: BLE001 (a module that exists but fails to import is a finding too)
            return f"{module} does not import ({type(error).__name__}: {error})"
        for at, attr in enumerate(parts[i:], i):
            try:
                obj = getattr(obj, attr)
            except Exception:  # noqa: BLE001 (a lazy export may fail with any error)
                if attr in getattr(obj, "__dataclass_fields__", {}):
                    return None  # a dataclass field without a default is no class attribute
                return f"{'.'.join(parts[:at])} has no {attr}"
        return None
    return "no such module"


def line_hits(line: str, skip=lambda check, found: False) -> list[str]:
    """What is wrong with one line: each hit as ``check: what``; ``skip(check, what)`` leaves an allowed one out
    (before a module name is resolved: resolving may import)."""
    found = [("path", m[0]) for m in _MACHINE_PATH.finditer(line)]
    found += [("spec", m[0]) for m in _SPEC.finditer(line)]
    found += [("issue", m[0]) for m in _ISSUE.finditer(line)]
    hits = [f"{check}: {what}" for check, what in found if not skip(check, what)]
    pointers = [m.span() for m in _COMMIT_POINTER.finditer(line)]
    for m in _DOTTED.finditer(line):
        if any(start <= m.start() < end for start, end in pointers) or skip("module", m[0]):
            continue
        if (why := unresolved(m[0])) is not None:
            hits.append(f"module: {m[0]} ({why})")
    return hits


def scan(paths: list[Path], root: Path = ROOT, allowed: dict | None = None) -> list[str]:
    """Every hit in ``paths`` as ``file:line: check: what``, less the allowed: ``(file, check)`` for a whole file
    or ``(file, check, what)`` for one word."""
    allowed = ALLOWED if allowed is None else allowed
    found = []
    for path in paths:
        where = path.relative_to(root).as_posix()
        def skip(check: str, what: str, where: str = where) -> bool:
            return (where, check) in allowed or (where, check, what) in allowed
        try:
            text = path.read_text(encoding="utf-8", errors="replace")
        except FileNotFoundError:  # moved while the scan ran
            continue
        lines = text.split("\n")
        starts = list(itertools.accumulate((len(line) + 1 for line in lines), initial=0))
        candidates = sorted({bisect.bisect_right(starts, m.start()) - 1 for m in _CANDIDATE.finditer(text)})
        for index in candidates:  # only the lines a check could hit (fast on 50,000 lines)
            found += [f"{where}:{index + 1}: {hit}" for hit in line_hits(lines[index], skip)]
    return found


def test_the_scanner_finds_planted_words_and_passes_clean_ones(tmp_path: Path) -> None:
    bad = tmp_path / "bad.md"
    work, home = "/" + "work", "/" + "home"  # built here, so that no machine path stands in the repository
    bad.write_text(
        f"Clean: runs{home}/x, ~{work}/y, /tmp/out, docs/spec.md, ACTION_SPEC, the issues list, pernav.world.towns.\n"
        "Clean: `git show 4cd6bc4:pernav.gone.module`, the issue tracker, pernav.learners.belief.ReactionBelief.\n"
        "Clean: pernav.planner.build_planner (a lazy export), pernav.world.driver_car.DriverCar.simulated_controls.\n"
        f"Bad: {work}/shared/x.txt and {home}/me/pernav\n"
        "Bad: SPEC §6 and SPEC.md\n"
        "Bad: issue #31, Issue 10, issues #31/#33 and the issue's targets\n"
        "Bad: pernav.study.no_such_module, pernav.world.towns.NoSuchName.\n")
    hits = scan([bad], root=tmp_path, allowed={})
    assert [h.split(": ", 1)[0] for h in hits] == ["bad.md:4"] * 2 + ["bad.md:5"] * 2 + ["bad.md:6"] * 4 \
        + ["bad.md:7"] * 2, hits
    assert "bad.md:7: module: pernav.world.towns.NoSuchName (pernav.world.towns has no NoSuchName)" in hits
    assert scan([bad], root=tmp_path, allowed={("bad.md", "module"): "planted"})[-1].startswith("bad.md:6: issue")


def test_the_scan_covers_code_docs_and_figures() -> None:
    scanned = {p.relative_to(ROOT).as_posix() for p in files()}
    for expected in ("README.md", "CHANGELOG.md", "docs/personal.md", "docs/figures/bench_all.json",
                     "pernav/__init__.py", "tests/test_repository.py", "docs/research/configs/headroom.yaml"):
        assert expected in scanned
    assert "tests/test_words.py" not in scanned


def test_no_machine_path_spec_issue_or_dangling_module_name() -> None:
    hits = scan(files())
    assert not hits, "words that point outside the repository (or nowhere):\n" + "\n".join(hits)
