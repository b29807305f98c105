"""Pool several studies (e.g. the default study at seeds 0, 1, 2) into one paired comparison with 95 % CIs.

Shows how to judge a learner: on the same episodes, over seeds, with intervals. Takes a few seconds (it reads
results.json files; run the studies first).

Learner results are bitwise reproducible on one machine but only statistically across machines (the
closed loop amplifies floating-point differences), so a claim about a learner should rest on pooled seeds.

It also counts the online rounds where adaptation lowered adapt's held-out L-step loss (``regret.adaptation``),
and where recorded the same for the paper's fixed step (studies whose ``U`` backtracks).

Run: .venv/bin/python recipes/pool_seeds.py runs/seed0 runs/seed1 runs/seed2 [--json pooled.json]
(a study folder or its results.json, e.g. a copy kept under docs/figures/)

``--against B0 B1 B2`` pairs each method with the same method of other studies at the same seeds (two protocols
compared on the same episodes: explore's episodes must be bitwise the same, or it exits 2):
.venv/bin/python recipes/pool_seeds.py runs/tau6_{0,1,2} --against runs/default_{0,1,2} [--method adapt]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from pernav.study.compare import compare
from pernav.study.report import comparison_table
from pernav.study.stats import paired_difference


def adaptation_share(results: list[dict]) -> dict[str, list[int]]:
    """[rounds where the adapted held-out loss is below the unadapted, rounds] for ``adapted`` and, where every
    study recorded it, ``adapted_fixed_step``.

    >>> adaptation_share([{"regret": {"Town1": {"adaptation": {"Online 0": {"unadapted": 2.0, "adapted": 1.0}}}}}])
    {'adapted': [1, 1]}
    """
    rounds = [v for r in results for t in r.get("regret", {}).values() for v in t["adaptation"].values()]
    keys = ["adapted"] + (["adapted_fixed_step"] if rounds and all("adapted_fixed_step" in v for v in rounds) else [])
    return {k: [sum(v[k] < v["unadapted"] for v in rounds), len(rounds)] for k in keys}


def episode_costs(results: list[dict], method: str) -> dict[tuple, float]:
    """Every online episode's tracking cost of ``method``, keyed by (study seed, round, town, route)."""
    return {(r["config"].get("seed"), it["label"], town, ep["route"]): ep["tracking_cost"]
            for r in results for it in r["iterations"] if it["phase"] == "online"
            for town, methods in it["towns"].items() if method in methods for ep in methods[method]["episodes"]}


def paired_against(results: list[dict], others: list[dict], method: str) -> dict[str, dict[str, float]]:
    """Per town, ``method`` in ``results`` minus ``method`` in ``others`` over the same episodes, with its
    95 % bootstrap CI (< 0: ``results`` is cheaper). Raises ``ValueError`` unless both hold the same episodes
    and explore drove them identically (the two sets must be the same seeds and schedule's evaluation)."""
    explore, explore_other = episode_costs(results, "explore"), episode_costs(others, "explore")
    if explore.keys() != explore_other.keys():
        raise ValueError("the two sets of studies do not hold the same episodes (same seeds, rounds, towns and routes)")
    differ = [k for k in sorted(explore, key=str) if explore[k] != explore_other[k]]
    if differ:
        seed, label, town, route = differ[0]
        raise ValueError(f"explore's episodes differ between the two sets in {len(differ)} of {len(explore)} episodes "
                         f"(first: seed {seed}, {label}, {town}, route {route}: {explore[differ[0]]} vs "
                         f"{explore_other[differ[0]]}): they are not paired (other seeds or settings, or another "
                         "install: explore reproduces bitwise only with the same installed versions)")
    mine, theirs = episode_costs(results, method), episode_costs(others, method)
    if not mine or mine.keys() != theirs.keys():
        raise ValueError(f"method {method!r} is not in every episode of both sets")
    out = {}
    for town in sorted({k[2] for k in mine}):
        keys = sorted(k for k in mine if k[2] == town)
        out[town] = paired_difference([mine[k] for k in keys], [theirs[k] for k in keys])  # mine - theirs
    return out


def _load(folders: list[str]) -> list[dict]:
    results = []
    for folder in folders:
        path = Path(folder) if Path(folder).is_file() else Path(folder) / "results.json"
        if not path.is_file():
            print(f"error: {path} does not exist (run the study first)", file=sys.stderr)
            sys.exit(2)
        results.append(json.loads(path.read_text()))
    return results


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("studies", nargs="+", help="study output folders (with results.json), or results.json files")
    ap.add_argument("--json", help="write the pooled comparison here")
    ap.add_argument("--against", nargs="+", metavar="STUDY", help="other studies at the same seeds: pair with them")
    ap.add_argument("--method", default="adapt", help="the method --against compares (default adapt)")
    args = ap.parse_args()
    results = _load(args.studies)
    extra = {}
    if args.against:  # before any output: unpaired sets fail at once, with nothing printed or written
        try:
            extra["paired_against"] = {"method": args.method, "against": args.against,
                                       "towns": paired_against(results, _load(args.against), args.method)}
        except ValueError as err:
            print(f"error: --against: {err}", file=sys.stderr)
            sys.exit(2)
    pooled = compare([r["iterations"] for r in results])
    print(comparison_table(pooled))
    share = adaptation_share(results)
    for key, (lowered, n) in share.items():
        print(f"{key}: lowers the held-out loss in {lowered} of {n} online rounds")
    for town, d in extra.get("paired_against", {}).get("towns", {}).items():
        print(f"{town}: {args.method} here - {args.method} in --against = {d['mean']:+.0f} "
              f"[{d['low']:+.0f}, {d['high']:+.0f}] over {d['n']} paired episodes (< 0: cheaper here)")
    if args.json:
        Path(args.json).write_text(json.dumps({**pooled, "adaptation_lowers_held_out_loss": share, **extra}, indent=1))


if __name__ == "__main__":
    main()
