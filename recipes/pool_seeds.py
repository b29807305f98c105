"""Pool several studies (e.g. the default study at seeds 0, 1, 2) into one paired comparison with 95 % CIs.

Learner results are bitwise reproducible on one machine but only statistically across machines (the
closed loop amplifies floating-point differences), so a claim about a learner should rest on pooled seeds.

It also counts the online rounds where adaptation lowered adapt's held-out L-step loss (``regret.adaptation``),
and where recorded the same for the paper's fixed step (studies whose ``U`` backtracks).

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


def adaptation_share(results: list[dict]) -> dict[str, list[int]]:
    """[rounds where the adapted held-out loss is below the unadapted, rounds] for ``adapted`` and, where every
    study recorded it, ``adapted_fixed_step``.

    >>> adaptation_share([{"regret": {"Town1": {"adaptation": {"Online 0": {"unadapted": 2.0, "adapted": 1.0}}}}}])
    {'adapted': [1, 1]}
    """
    rounds = [v for r in results for t in r.get("regret", {}).values() for v in t["adaptation"].values()]
    keys = ["adapted"] + (["adapted_fixed_step"] if rounds and all("adapted_fixed_step" in v for v in rounds) else [])
    return {k: [sum(v[k] < v["unadapted"] for v in rounds), len(rounds)] for k in keys}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("studies", nargs="+", help="study output folders (with results.json), or results.json files")
    ap.add_argument("--json", help="write the pooled comparison here")
    args = ap.parse_args()
    iterations, results = [], []
    for folder in args.studies:
        path = Path(folder) if Path(folder).is_file() else Path(folder) / "results.json"
        if not path.is_file():
            print(f"error: {path} does not exist (run the study first)", file=sys.stderr)
            sys.exit(2)
        results.append(json.loads(path.read_text()))
        iterations.append(results[-1]["iterations"])
    pooled = compare(iterations)
    print(comparison_table(pooled))
    share = adaptation_share(results)
    for key, (lowered, n) in share.items():
        print(f"{key}: lowers the held-out loss in {lowered} of {n} online rounds")
    if args.json:
        Path(args.json).write_text(json.dumps({**pooled, "adaptation_lowers_held_out_loss": share}, indent=1))


if __name__ == "__main__":
    main()
