"""Pool several studies (e.g. the default study at seeds 0, 1, 2) into one paired comparison with 95 % CIs.

Learner results are bitwise reproducible on one machine but only statistically across machines (the
closed loop amplifies floating-point differences), so a claim about a learner should rest on pooled seeds.

Run: .venv/bin/python recipes/pool_seeds.py runs/seed0 runs/seed1 runs/seed2 [--json pooled.json]
(a study folder or its results.json, e.g. a copy kept under docs/figures/)
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from pernav.study.compare import compare
from pernav.study.report import comparison_table


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("studies", nargs="+", help="study output folders (with results.json), or results.json files")
    ap.add_argument("--json", help="write the pooled comparison here")
    args = ap.parse_args()
    iterations = []
    for folder in args.studies:
        path = Path(folder) if Path(folder).is_file() else Path(folder) / "results.json"
        if not path.is_file():
            print(f"error: {path} does not exist (run the study first)", file=sys.stderr)
            sys.exit(2)
        iterations.append(json.loads(path.read_text())["iterations"])
    pooled = compare(iterations)
    print(comparison_table(pooled))
    if args.json:
        Path(args.json).write_text(json.dumps(pooled, indent=1))


if __name__ == "__main__":
    main()
