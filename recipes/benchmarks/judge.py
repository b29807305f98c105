"""The headroom benchmark's pre-registered figures of a learner from finished studies of the ``personal`` preset
(seconds): ``python -m recipes.benchmarks.judge runs/personal/s* --out judged/ [--learner belief] [--sweep ...]``.

It writes ``judged.json`` and ``judged.md`` (and ``sweep.png`` with ``--sweep``: studies of the ``personal_sweep``
preset) into ``--out``, refusing to overwrite anything, and prints the Markdown table. Bad input exits 2 with one line.

Example:
    >>> main(["missing", "--out", "judged"])  # doctest: +SKIP
    2
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from recipes.benchmarks.headroom import judge, judge_markdown, plot_sweep

__all__ = ["JudgeError", "judge_studies", "main"]


class JudgeError(ValueError):
    """A study folder or output that cannot be judged."""


def load(paths: Sequence[str]) -> list[dict[str, Any]]:
    """Each study folder's (or file's) ``results.json``."""
    out = []
    for path in paths:
        file = Path(path) / "results.json" if Path(path).is_dir() else Path(path)
        if not file.is_file():
            raise JudgeError(f"{path!r} holds no results.json (run pernav study first)")
        try:
            out.append(json.loads(file.read_text()))
        except json.JSONDecodeError:
            raise JudgeError(f"{str(file)!r} is not a results.json (not JSON)") from None
    return out


def judge_studies(studies: Sequence[str], out: str | Path, learner: str = "timing",
                  sweep: Sequence[str] | None = None) -> dict[str, Any]:
    """Judge ``learner`` on ``studies`` and write the figures into the new files of folder ``out``."""
    target = Path(out)
    files = [target / "judged.json", target / "judged.md", *([target / "sweep.png"] if sweep else [])]
    taken = [str(f) for f in files if f.exists()]
    if taken:
        raise JudgeError(f"{taken[0]!r} exists; choose another --out (nothing is overwritten)")
    try:
        figures = judge(load(studies), learner=learner)
    except KeyError as exc:
        raise JudgeError(f"a study is not of the personal benchmark (round {exc} is not one of its cells)") from None
    target.mkdir(parents=True, exist_ok=True)
    if sweep:
        figures["sweep"] = plot_sweep(load(sweep), str(target / "sweep.png"))
    (target / "judged.json").write_text(json.dumps(figures, indent=1) + "\n")
    (target / "judged.md").write_text(judge_markdown(figures))
    return figures


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m recipes.benchmarks.judge", description=__doc__.split("\n")[0])
    p.add_argument("studies", nargs="+", help="study folders (or results.json files) of the personal preset; "
                                              "several per seed merge (the same episodes)")
    p.add_argument("--out", required=True, help="folder for judged.json, judged.md (and sweep.png)")
    p.add_argument("--learner", default="timing", help="the method judged (default: timing)")
    p.add_argument("--sweep", nargs="+", help="study folders of the personal_sweep preset: draw sweep.png")
    args = p.parse_args(argv)
    try:
        figures = judge_studies(args.studies, args.out, args.learner, args.sweep)
    except (JudgeError, OSError) as exc:
        print(f"judge: error: {' '.join(str(exc).split())}", file=sys.stderr)
        return 2
    print(judge_markdown(figures))
    return 0


if __name__ == "__main__":
    sys.exit(main())
