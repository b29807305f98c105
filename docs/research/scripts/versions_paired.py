"""One method in two versions of the code, paired on the same episodes: ``results.json`` of a study run at one commit
(``--before``) and of the same study (preset, seed, methods) at another (``--after``).

Each online round's episodes are the same routes, seeds and traffic in both, so a method's episode in one is paired
with the same episode in the other; explore's episodes must be identical in both (checked: else the pairing is not
of the same episodes and the script says so). Prints, per town, ``before - after`` per episode with its 95 % CI
(> 0: cheaper after), and explore minus the method in each, with missed turns and collisions.

    .venv/bin/python docs/research/scripts/versions_paired.py --before runs/old/results.json \
        --after runs/new/results.json --method adapt_driver [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import sys

from pernav.study.stats import paired_difference


def episodes(results: dict, town: str, method: str) -> list[dict]:
    return [e for it in results["iterations"] if it["phase"] == "online" and town in it["towns"]
            for e in it["towns"][town][method]["episodes"]]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--before", required=True)
    ap.add_argument("--after", required=True)
    ap.add_argument("--method", default="adapt_driver")
    ap.add_argument("--json", default=None)
    args = ap.parse_args()
    before, after = (json.load(open(p)) for p in (args.before, args.after))
    towns = sorted({t for it in after["iterations"] for t in it["towns"]})
    report = {}
    for town in towns:
        ex_b, ex_a = episodes(before, town, "explore"), episodes(after, town, "explore")
        if [e["tracking_cost"] for e in ex_b] != [e["tracking_cost"] for e in ex_a]:
            print(f"error: {town}: explore's episodes differ between the two studies: not the same episodes",
                  file=sys.stderr)
            return 2
        b, a = episodes(before, town, args.method), episodes(after, town, args.method)
        cost = [e["tracking_cost"] for e in ex_a]

        def figures(m: list[dict], cost: list[float] = cost) -> dict:
            return {"explore_minus_method": paired_difference(cost, [e["tracking_cost"] for e in m]),
                    "missed_turns": sum(e["missed_turns"] for e in m), "collisions": sum(e["collisions"] for e in m)}

        report[town] = {"episodes": len(a), "explore_cost": sum(cost) / len(cost),
                        "explore_missed_turns": sum(e["missed_turns"] for e in ex_a),
                        "explore_collisions": sum(e["collisions"] for e in ex_a),
                        "before": figures(b), "after": figures(a),
                        "before_minus_after": paired_difference([e["tracking_cost"] for e in b],
                                                                [e["tracking_cost"] for e in a])}
        d = report[town]["before_minus_after"]
        print(f"{town} ({len(a)} episodes): before - after {d['mean']:+.1f} [{d['low']:+.1f}, {d['high']:+.1f}]; "
              + "; ".join(f"{k}: explore - method {v['explore_minus_method']['mean']:+.1f} "
                          f"[{v['explore_minus_method']['low']:+.1f}, {v['explore_minus_method']['high']:+.1f}], "
                          f"missed {v['missed_turns']}, collisions {v['collisions']}"
                          for k, v in (("before", report[town]["before"]), ("after", report[town]["after"])))
              + f" (explore missed {report[town]['explore_missed_turns']}, collisions "
                f"{report[town]['explore_collisions']})")
    if args.json:
        with open(args.json, "w") as f:
            json.dump(report, f, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
