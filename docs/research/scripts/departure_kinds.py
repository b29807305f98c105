"""What adapt_driver's planner does where it leaves explore: replay a finished study's adapt_driver episodes (the same
seeds and the estimates the study recorded, with this tree's planner) and count each departure by the instruction
said and how many steps before explore would say it ("silence for X": explore's X not said now).

With ``--json``, also each departure kind's episodes and their paired cost (95 % CI): explore's cost in the study (the same
episode) minus the replayed adapt_driver drive's, over the episodes where that kind occurs, and over those where it
is the only kind (an episode's departures decide its difference: one with none is explore's drive). The replayed
cost is checked against the study's own (``replay_matches``): the replay restores each round's estimate and response
as the study recorded them (rounded to 4 digits), but not that round's meta model P (the study keeps the last one),
which the drive's own updates and the imagination's spread read, so a replay is not always the study's drive.

    .venv/bin/python docs/research/scripts/departure_kinds.py runs/STUDY Town1 [--json FILE] [--by-distance]
"""

from __future__ import annotations

import argparse
import collections
import dataclasses
import json
import math
from pathlib import Path

import torch

from pernav.learners.driver import Estimate, Response
from pernav.study.config import preset
from pernav.study.episodes import EpisodeJob, make_policy, study_env
from pernav.study.finished import FinishedStudy
from pernav.study.stats import paired_difference
from pernav.trainer.collect import derive_seed, drive, episode_metrics
from pernav.world.constants import Instruction


def kind(action: int, explore: int, future: list[int]) -> str:
    """One departure: ``action`` played where explore played ``explore``; ``future`` is explore's plan from now."""
    if action == Instruction.NONE:
        return f"silence for {Instruction(explore).name}"
    if action in future:
        return f"{Instruction(action).name} said {future.index(action)} early"
    return f"{Instruction(action).name} (not in explore's plan)"


def summary(episodes: list[dict]) -> dict:
    """From the replayed ``episodes`` (each with its departures' ``kinds`` and both costs): how many replays are the
    study's own drive, and explore − adapt_driver (paired, 95 % CI) over the episodes with no departure, with each
    kind, with it alone, with only early "prepare"s, and with a "turn" held back."""
    def paired(rows: list[dict]) -> dict:
        if not rows:
            return {"episodes": 0, "explore_minus_adapt_driver": None}
        d = paired_difference([r["explore"] for r in rows], [r["adapt_driver"] for r in rows])
        return {"episodes": len(rows), "explore_minus_adapt_driver": [round(d[k], 2) for k in ("mean", "low", "high")]}

    kinds = collections.Counter(k for r in episodes for k in r["kinds"])
    matches = sum(abs(r["adapt_driver"] - r["study_adapt_driver"]) < 1e-6 * max(1.0, abs(r["study_adapt_driver"]))
                  for r in episodes)
    return {"replay_matches": [matches, len(episodes)], "no_departure": paired([r for r in episodes if not r["kinds"]]),
            "only_early_prepares": paired([r for r in episodes if r["kinds"] and all(
                k.startswith("PREPARE") and k.endswith("early") for k in r["kinds"])]),
            "a_turn_held_back": paired([r for r in episodes if any(k.startswith("silence for TURN") for k in r["kinds"])]),
            "kinds": {name: {"departures": n, "where_it_occurs": paired([r for r in episodes if name in r["kinds"]]),
                             "where_alone": paired([r for r in episodes if set(r["kinds"]) == {name}])}
                      for name, n in kinds.most_common()}}


def replays(folder: str, town: str, policy_hook=None, explore_table: bool = False):
    """Each adapt_driver episode of the study at ``folder`` in ``town``, replayed: yields ``(label, route, trajectory,
    explore_cost, study_cost)`` with explore's and adapt_driver's costs as the study recorded them. ``policy_hook(policy,
    env)`` (optional) may wrap the episode's policy (a :class:`~pernav.learners.driver.DriverPlanner`) before the drive
    and returns the policy to drive; ``explore_table``: the env writes explore's table (for ``closed_loop``)."""
    study = FinishedStudy.open(folder)
    results = json.loads((study.folder / "results.json").read_text())
    recorded = {(it["label"], e["route"]): (e["tracking_cost"], a["tracking_cost"])
                for it in results["iterations"] if town in it["towns"]
                and "adapt_driver" in it["towns"][town]
                for e, a in zip(it["towns"][town]["explore"]["episodes"],
                                it["towns"][town]["adapt_driver"]["episodes"], strict=True)}
    cfg = dataclasses.replace(preset(study.config["preset"]), seed=study.config["seed"], towns=[town])
    state = study.driver_state(town)
    for entry in cfg.schedule:
        read = state.data["rounds"].get(entry.label, {}).get("adapt_driver")
        if entry.phase == "offline" or read is None:
            continue
        estimate = Estimate((math.log(read["reaction_time"]), read["decision_time"]), tuple(read["sd"]),
                            read.get("stepped", True))
        # every field the round recorded (a "prepare"'s slowing among them: left out, the replay planned with the default)
        response = Response(**{f.name: read[f.name] for f in dataclasses.fields(Response) if f.name in read})
        for route in range(cfg.routes):
            seed = derive_seed(cfg.seed, town, entry.label, "eval", route)
            tracker = state.tracker("adapt_driver", estimate, response)
            policy = make_policy(EpisodeJob(cfg, town, entry, route, seed, "driver", params=tracker))
            env = study_env(cfg, town, entry, route, seed, explore_table=explore_table)
            if policy_hook is not None:
                policy = policy_hook(policy, env)
            yield (entry.label, route, drive(env, policy), *recorded[(entry.label, route)])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("study")
    parser.add_argument("town")
    parser.add_argument("--json", default=None, help="each kind's episodes and paired cost (explore - adapt_driver)")
    parser.add_argument("--by-distance", action="store_true",
                        help="replay with the planner's by_distance option (RetimingPlanner; off in the study)")
    parser.add_argument("--closed-loop", action="store_true",
                        help="replay with the planner's closed_loop option (RetimingPlanner; off in the study)")
    args = parser.parse_args()
    torch.set_num_threads(1)

    def option(policy, env):
        policy.planner.by_distance, policy.planner.closed_loop = args.by_distance, args.closed_loop
        return policy

    episodes: list[dict] = []
    for label, route, trajectory, explore_cost, study_cost in replays(args.study, args.town, option, args.closed_loop):
        actions = trajectory["action"].reshape(-1).tolist()
        explore = trajectory["explore_action"].reshape(-1).tolist()
        futures = trajectory["explore_future"].long().tolist()
        these = [kind(a, e, f) for a, e, f in zip(actions, explore, futures, strict=True) if a != e]
        cost = episode_metrics(trajectory)["tracking_cost"]
        episodes.append({"label": label, "route": route, "kinds": these, "explore": explore_cost,
                         "adapt_driver": cost, "study_adapt_driver": study_cost})
        print(label, route, round(cost, 1), flush=True)
    for name, n in collections.Counter(k for r in episodes for k in r["kinds"]).most_common():
        print(f"{n:5d}  {name}")
    if args.json:
        with open(args.json, "w") as f:
            json.dump({"study": Path(args.study).name, "town": args.town, "by_distance": args.by_distance,
                       "closed_loop": args.closed_loop,
                       **summary(episodes), "episodes": episodes}, f, indent=1)


if __name__ == "__main__":
    main()
