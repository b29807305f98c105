"""How often does a method pass the end-to-end criterion of docs/research/findings.md on three study seeds?

Every ``--size``-seed subset (default 3, the criterion's) of the given per-seed studies is pooled as
``pool_seeds.py`` pools them (:func:`pernav.study.compare.compare`) and checked clause by clause, per town
(a subset passes a clause when both towns do):

* ``below``: the method's mean tracking cost is below explore's and sysid's (for sysid itself: explore's);
* ``ci``: the 95 % bootstrap CI of explore − method lies above zero;
* ``gap``: it closes at least half of the explore-to-oracle gap in the rounds where that gap exceeds 10 %;
* ``collisions``: no more collisions than explore;
* ``flat``: in the rounds without headroom its cost is within 10 % of explore's (pooled over those rounds,
  as the reports give it); ``flat_each``: within 10 % in *every* such round (the strict reading).

``all`` is every clause with ``flat``; ``all_strict`` with ``flat_each``. With ``--method oracle`` it gives the
ceiling: how often a planner that knows the driver (the true simulator as its model) would pass on three
seeds; the oracle closes 100 % of the gap by definition and has no sysid to beat, so there ``below`` is
against explore alone.

Run: .venv/bin/python docs/research/scripts/criterion_odds.py \\
     docs/figures/default/tau6/seed{0,1,2,3,4,5,6,7,8,9,10,11,12,13,14}.json --method oracle [--size 3] [--json FILE]
(the per-seed studies findings.md judged are in commit 4cd6bc4: ``git show 4cd6bc4:docs/figures/default/tau6/seed0.json``
and so on).
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from itertools import combinations
from pathlib import Path
from typing import Any

import numpy as np

from pernav.study.compare import HEADROOM, compare

sys.path.insert(0, str(Path(__file__).resolve().parents[3] / "recipes"))
from pool_seeds import _load  # noqa: E402  (a recipe: one loader for every script that reads studies)

CLAUSES = ("below", "ci", "gap", "collisions", "flat", "flat_each", "all", "all_strict")


def _flat_each(iterations: list[list[dict[str, Any]]], town: str, method: str) -> bool:
    """Every online round of ``town`` without headroom has the method within 10 % of explore (round means)."""
    for its in iterations:
        for it in its:
            methods = it["towns"].get(town, {})
            if it["phase"] != "online" or not {"explore", "oracle", method} <= set(methods):
                continue  # as compare(): a round without explore (or here the oracle) is not compared
            mean = {m: float(np.mean([e["tracking_cost"] for e in methods[m]["episodes"]]))
                    for m in ("explore", "oracle", method)}
            if mean["oracle"] >= (1 - HEADROOM) * mean["explore"] and mean[method] > 1.1 * mean["explore"]:
                return False
    return True


def clauses(iterations: list[list[dict[str, Any]]], method: str) -> dict[str, dict[str, bool]]:
    """town -> clause -> passes, for studies pooled (each a results.json ``iterations`` list).

    >>> ep = lambda c: {"tracking_cost": c, "collisions": 0}
    >>> rnd = {"phase": "online", "towns": {"T": {m: {"episodes": [ep(c), ep(c + 2)]} for m, c in
    ...        (("explore", 10.0), ("sysid", 9.0), ("adapt", 6.0), ("oracle", 2.0))}}}
    >>> clauses([[rnd]], "adapt")["T"]["all"]
    True
    """
    keep = {"explore", "oracle", "sysid", method}  # compare() bootstraps every method: only the ones checked
    iterations = [[{**it, "towns": {t: {m: v for m, v in ms.items() if m in keep} for t, ms in it["towns"].items()}}
                   for it in its] for its in iterations]
    out: dict[str, dict[str, bool]] = {}
    for town, methods in compare(iterations).items():
        needs = {method, "oracle"} | ({"sysid"} if method not in ("sysid", "oracle") else set())
        if not needs <= set(methods):
            raise ValueError(f"{town}: the criterion needs {', '.join(sorted(needs))}; the studies have "
                             f"{', '.join(sorted(methods)) or 'no method but explore'}")
        fig = methods[method]
        rivals = [fig["explore_tracking_cost"]] + ([methods["sysid"]["tracking_cost"]]
                                                   if method not in ("sysid", "oracle") else [])
        gap = fig.get("gap_closed_headroom", {"mean": float("nan")})["mean"]
        c = {"below": all(fig["tracking_cost"] < r for r in rivals),
             "ci": fig["explore_minus_method"]["low"] > 0,
             "gap": method == "oracle" or (fig.get("headroom_rounds", 0) > 0 and gap >= 0.5),
             "collisions": fig["collisions"] <= fig["explore_collisions"],
             "flat": fig.get("relative_cost_no_headroom", 1.0) <= 1.1,
             "flat_each": _flat_each(iterations, town, method)}
        c["all"] = all(c[k] for k in ("below", "ci", "gap", "collisions", "flat"))
        c["all_strict"] = c["all"] and c["flat_each"]
        out[town] = c
    return out


def odds(results: Sequence[dict[str, Any]], method: str, size: int = 3) -> dict[str, Any]:
    """Over every ``size``-subset of ``results`` (per-seed results.json dicts): the share of subsets passing each
    clause, per town and in both towns."""
    if not 1 <= size <= len(results):
        raise ValueError(f"--size must be between 1 and the number of studies ({len(results)}), got {size}")
    counts: dict[str, dict[str, int]] = {}
    subsets = list(combinations(range(len(results)), size))
    for subset in subsets:
        per_town = clauses([results[i]["iterations"] for i in subset], method)
        per_town["both towns"] = {k: all(t[k] for t in per_town.values()) for k in CLAUSES}
        for town, c in per_town.items():
            for k, ok in c.items():
                counts.setdefault(town, dict.fromkeys(CLAUSES, 0))[k] += int(ok)
    seeds = [r["config"].get("seed") for r in results]
    return {"method": method, "size": size, "seeds": seeds, "subsets": len(subsets),
            "share": {t: {k: v / len(subsets) for k, v in c.items()} for t, c in counts.items()}}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("studies", nargs="+", help="per-seed study folders (with results.json), or results.json files")
    ap.add_argument("--method", default="adapt", help="the method checked (default adapt; oracle: the ceiling)")
    ap.add_argument("--size", type=int, default=3, help="seeds per subset (default 3, as pre-registered)")
    ap.add_argument("--json", help="write the shares here")
    args = ap.parse_args()
    results = _load(args.studies)
    missing = [s for s, r in zip(args.studies, results, strict=True)
               if not all(args.method in t for it in r["iterations"] if it["phase"] == "online"
                          for t in it["towns"].values())]
    if missing:
        print(f"error: --method {args.method!r} is not in every online round of {', '.join(missing)}", file=sys.stderr)
        sys.exit(2)
    try:
        got = odds(results, args.method, args.size)
    except ValueError as err:
        print(f"error: {err}", file=sys.stderr)
        sys.exit(2)
    print(f"{args.method}: {got['subsets']} subsets of {args.size} of the seeds {got['seeds']}; share passing")
    print("| town | " + " | ".join(CLAUSES) + " |\n|---|" + "---|" * len(CLAUSES))
    for town, share in got["share"].items():
        print(f"| {town} | " + " | ".join(f"{100 * share[k]:.0f} %" for k in CLAUSES) + " |")
    if args.json:
        Path(args.json).write_text(json.dumps(got, indent=1))


if __name__ == "__main__":
    main()
