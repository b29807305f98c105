"""What adapt_driver's planner does where it leaves explore: replay a finished study's adapt_driver episodes (the same
seeds and the estimates the study recorded, with this tree's planner) and count each departure by the instruction
said and how many steps before explore would say it ("silence for X": explore's X not said now).

    .venv/bin/python docs/research/scripts/departure_kinds.py runs/STUDY Town1
"""

from __future__ import annotations

import argparse
import collections
import dataclasses
import math

import torch

from pernav.learners.driver import Estimate, Response
from pernav.study.config import preset
from pernav.study.episodes import EpisodeJob, make_policy, study_env
from pernav.study.finished import FinishedStudy
from pernav.trainer.collect import derive_seed, drive, episode_metrics
from pernav.world.constants import Instruction


def kind(action: int, explore: int, future: list[int]) -> str:
    """One departure: ``action`` played where explore played ``explore``; ``future`` is explore's plan from now."""
    if action == Instruction.NONE:
        return f"silence for {Instruction(explore).name}"
    if action in future:
        return f"{Instruction(action).name} said {future.index(action)} early"
    return f"{Instruction(action).name} (not in explore's plan)"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("study")
    parser.add_argument("town")
    args = parser.parse_args()
    torch.set_num_threads(1)
    study = FinishedStudy.open(args.study)
    cfg = dataclasses.replace(preset(study.config["preset"]), seed=study.config["seed"], towns=[args.town])
    state = study.driver_state(args.town)
    kinds: collections.Counter[str] = collections.Counter()
    for entry in cfg.schedule:
        read = state.data["rounds"].get(entry.label, {}).get("adapt_driver")
        if entry.phase == "offline" or read is None:
            continue
        estimate = Estimate((math.log(read["reaction_time"]), read["decision_time"]), tuple(read["sd"]))
        response = Response(**{k: read[k] for k in ("cruise", "turn_speed", "brake", "accel")})
        for route in range(cfg.routes):
            seed = derive_seed(cfg.seed, args.town, entry.label, "eval", route)
            tracker = state.tracker("adapt_driver", estimate, response)
            policy = make_policy(EpisodeJob(cfg, args.town, entry, route, seed, "driver", params=tracker))
            trajectory = drive(study_env(cfg, args.town, entry, route, seed), policy)
            actions = trajectory["action"].reshape(-1).tolist()
            explore = trajectory["explore_action"].reshape(-1).tolist()
            futures = trajectory["explore_future"].long().tolist()
            kinds.update(kind(a, e, f) for a, e, f in zip(actions, explore, futures, strict=True) if a != e)
            print(entry.label, route, round(episode_metrics(trajectory)["tracking_cost"], 1), flush=True)
    for name, n in kinds.most_common():
        print(f"{n:5d}  {name}")


if __name__ == "__main__":
    main()
