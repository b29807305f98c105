"""How much of an episode's tracking cost, and of a paired difference between two timings, is its arrival step?

The env's goal is "where the car would be a step on at its speed", clamped to the route's end: on the step that
arrives, a car that drives on past the destination is charged the squared distance it overshoots by, a few metres
squared, and whether the last step ends just before or just past the destination depends on the phase of the whole
drive's timing. This measures that term on the default preset's towns and routes with the named users, for explore
and for explore's rule said one step earlier (a best_shift candidate), on the same seeds: the arrival step's share of
the cost, and the paired difference with and without it.

    .venv/bin/python docs/research/scripts/arrival_step.py --seeds 0 1 --json out.json
"""

from __future__ import annotations

import argparse
import json
import statistics

from pernav.env.torchrl_env import explore_module
from pernav.planner.factory import env_planning_config
from pernav.planner.retiming import ShiftedExplore
from pernav.study.driver_rounds import DRIVER_PLANNER
from pernav.study.stats import paired_difference
from pernav.trainer.collect import drive, history_env
from pernav.world.drivers import NAMED_USERS, Context

OPTIONS = {k: v for k, v in DRIVER_PLANNER.items() if k != "departure"}
CONFIG = {"n_traffic": 4, **env_planning_config({"kind": "retime", **OPTIONS})}  # the default preset's traffic
TOWNS, ROUTES = ("Town1", "Town3"), range(3)


def costs(town: str, route: int, user: str, seed: int, policy) -> tuple[float, float, bool]:
    """The episode's tracking cost, its last step's, and whether it arrived."""
    env = history_env(town, {"route": route, "user": NAMED_USERS[user], "context": Context()}, config=CONFIG,
                      seed=seed)
    trajectory = drive(env, policy)
    step = -trajectory["next", "reward"].reshape(-1)
    return float(step.sum()), float(step[-1]), bool(trajectory["next", "terminated"].reshape(-1)[-1])


def _ci(d: dict[str, float]) -> list[float]:
    return [round(d["mean"], 2), round(d["low"], 2), round(d["high"], 2)]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1])
    parser.add_argument("--json", default=None)
    args = parser.parse_args()
    rows = []
    for town in TOWNS:
        for route in ROUTES:
            for user in NAMED_USERS:
                for seed in args.seeds:
                    e, e_last, arrived = costs(town, route, user, seed, explore_module())
                    s, s_last, _ = costs(town, route, user, seed, ShiftedExplore(1))
                    rows.append({"town": town, "route": route, "user": user, "seed": seed, "arrived": arrived,
                                 "explore": e, "explore_last": e_last, "shift1": s, "shift1_last": s_last})
    report = {"episodes": len(rows), "arrived": sum(r["arrived"] for r in rows)}
    last = [r["explore_last"] for r in rows]
    report["explore_cost_mean"] = round(statistics.mean(r["explore"] for r in rows), 2)
    report["arrival_step_cost"] = {"mean": round(statistics.mean(last), 2), "sd": round(statistics.stdev(last), 2),
                                   "max": round(max(last), 2)}
    full = paired_difference([r["explore"] for r in rows], [r["shift1"] for r in rows])
    without = paired_difference([r["explore"] - r["explore_last"] for r in rows],
                                [r["shift1"] - r["shift1_last"] for r in rows])
    diffs = [r["explore"] - r["shift1"] for r in rows]
    diffs_wo = [(r["explore"] - r["explore_last"]) - (r["shift1"] - r["shift1_last"]) for r in rows]
    last_diffs = [r["explore_last"] - r["shift1_last"] for r in rows]
    report["explore_minus_shift1"] = {"with_arrival_step": _ci(full), "without": _ci(without),
                                      "sd_per_episode": [round(statistics.stdev(diffs), 2),
                                                         round(statistics.stdev(diffs_wo), 2)],
                                      "sd_of_the_arrival_steps_difference": round(statistics.stdev(last_diffs), 2)}
    print(json.dumps(report, indent=1))
    if args.json:
        with open(args.json, "w") as f:
            json.dump({"seeds": args.seeds, "report": report, "episodes": rows}, f, indent=1)


if __name__ == "__main__":
    main()
