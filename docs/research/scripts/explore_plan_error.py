"""How far is explore's plan (the env's ``explore_future``, imagined at the car's speed now) from what explore then says?

The re-timing planner compares its candidates with explore's plan. The plan advances the car along the route at its
speed now and records what explore's rule would say; explore itself re-applies the rule every step at the car's real
speed (its leads grow with the speed). This script drives explore through a preset's evaluation episodes (its
online rounds, the study's own seeds) and, for every step and every prompt the plan says ``h`` steps ahead (a new
"turn" or "prepare" in the plan), finds when explore actually said it: ``error = actual - h`` steps (> 0: explore
said it later than its plan, < 0: earlier). Per town: how often the plan is right, the errors' distribution by ``h``,
and by whether the car sped up or slowed meanwhile.

With ``--closed-loop`` the same for the re-timing planner's ``closed_loop`` reading of explore (twentieth session):
explore's rule read off the env's explore table closed loop, on the car's real positions over the next 16 steps
(``table_on_real_car``: does the table and its said-once rule give explore's prompts?) and on the car the hybrid
model imagines (``table_on_imagined_car``: the model's default driver, its cruise the drive's fastest speed so far,
the median row).

    .venv/bin/python docs/research/scripts/explore_plan_error.py Town3 [--preset paper] [--seed 10] [--rounds 5]
        [--closed-loop] [--json FILE]
"""

from __future__ import annotations

import argparse
import collections
import dataclasses
import json
import statistics

import torch

from pernav.env.torchrl_env import explore_module
from pernav.model.driver import DriverImaginedEnv, DriverParams
from pernav.model.egocentric import VX, VY, X, Y
from pernav.planner.retiming import RetimingPlanner
from pernav.study.config import preset
from pernav.study.episodes import study_env
from pernav.trainer.collect import derive_seed, drive
from pernav.world.constants import PREPARES, TURNS


def plan_errors(trajectory, futures: list[list[int]] | None = None) -> list[dict]:
    """Each (step, prompt the plan says ``h`` steps ahead): the steps explore actually took to say it, minus ``h``.
    ``futures``: each step's plan (default: the env's ``explore_future``)."""
    said = trajectory["explore_action"].reshape(-1).tolist()
    futures = trajectory["explore_future"].long().tolist() if futures is None else futures
    obs = trajectory["observation"]
    speed = torch.hypot(obs[:, VX], obs[:, VY]).tolist()
    prompts = set(TURNS) | set(PREPARES)
    new = [a in prompts and (t == 0 or said[t - 1] != a) for t, a in enumerate(said)]  # a prompt said anew at t
    out = []
    for t, future in enumerate(futures):
        h = next((h for h in range(1, len(future)) if future[h] in prompts and future[h] != future[h - 1]), None)
        if h is None or future[0] == future[h]:
            continue
        p = future[h]
        actual = next((u - t for u in range(t + 1, len(said)) if new[u] and said[u] == p), None)
        if actual is None:  # the drive ended (or re-routed) before explore said it
            continue
        out.append({"h": h, "error": actual - h, "prompt": int(p),
                    "speed_change": round(speed[min(t + actual, len(speed) - 1)] - speed[t], 2)})
    return out


def closed_futures(trajectory, horizon: int = 16) -> tuple[list[list[int]], list[list[int]]]:
    """Each step's explore read closed loop off the explore table: on the car's real next positions, and on the car
    the hybrid model imagines (its median row). Steps with no prompt in the plan keep the plan."""
    planner = RetimingPlanner(DriverImaginedEnv(), horizon=horizon, advance=0)
    obs = trajectory["next", "observation"]
    T = obs.shape[0]
    speed = torch.hypot(trajectory["observation"][:, VX], trajectory["observation"][:, VY])
    real, imagined = [], []
    for t in range(T):
        root = trajectory[t]
        future = root["explore_future"].long()
        plan = future[:horizon]
        if not bool(future.any()):
            real.append(future.tolist())
            imagined.append(future.tolist())
            continue
        idx = torch.arange(t, t + horizon).clamp(max=T - 1)
        pos = obs[idx][:, [X, Y]][None, None]
        shift = torch.zeros(1, dtype=torch.long)
        real.append(planner.closed_sequences(root, plan[None], pos, shift)[0, 0].tolist())
        planner.env.drivers = [DriverParams(cruise=max(float(speed[: t + 1].max()), 5.0))]
        _, _, played = planner.imagine_closed(root, plan[None])
        imagined.append(played[played.shape[0] // 2 + 2, 0].tolist())  # follow a "prepare", median reaction
    return real, imagined


def summary(rows: list[dict]) -> dict:
    def block(rs: list[dict]) -> dict:
        e = [r["error"] for r in rs]
        return {"n": len(e), "exact": round(sum(x == 0 for x in e) / len(e), 3) if e else None,
                "later": round(sum(x > 0 for x in e) / len(e), 3) if e else None,
                "earlier": round(sum(x < 0 for x in e) / len(e), 3) if e else None,
                "mean_error": round(statistics.mean(e), 2) if e else None}
    by_h = collections.defaultdict(list)
    for r in rows:
        by_h[min(r["h"], 12)].append(r)
    return {"all": block(rows), "by_h": {str(h): block(by_h[h]) for h in sorted(by_h)},
            "sped_up_by_over_2": block([r for r in rows if r["speed_change"] > 2]),
            "slowed_by_over_2": block([r for r in rows if r["speed_change"] < -2]),
            "speed_within_2": block([r for r in rows if abs(r["speed_change"]) <= 2])}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("town")
    parser.add_argument("--preset", default="paper")
    parser.add_argument("--seed", type=int, default=10)
    parser.add_argument("--rounds", type=int, default=5, help="the first N online rounds (default 5)")
    parser.add_argument("--closed-loop", action="store_true", help="also explore read closed loop off its table")
    parser.add_argument("--json", default=None)
    args = parser.parse_args()
    torch.set_num_threads(1)
    cfg = dataclasses.replace(preset(args.preset), seed=args.seed, towns=[args.town])
    entries = [e for e in cfg.schedule if e.phase != "offline"][: args.rounds]
    rows, real, imagined = [], [], []
    for entry in entries:
        for route in range(cfg.routes):
            seed = derive_seed(cfg.seed, args.town, entry.label, "eval", route)
            trajectory = drive(study_env(cfg, args.town, entry, route, seed, explore_table=args.closed_loop),
                               explore_module())
            rows += plan_errors(trajectory)
            if args.closed_loop:
                on_real, on_imagined = closed_futures(trajectory)
                real += plan_errors(trajectory, on_real)
                imagined += plan_errors(trajectory, on_imagined)
        print(entry.label, json.dumps(summary(rows)["all"]), flush=True)
    out = {"town": args.town, "preset": args.preset, "seed": args.seed, "rounds": [e.label for e in entries],
           **summary(rows)}
    if args.closed_loop:
        out |= {"table_on_real_car": summary(real), "table_on_imagined_car": summary(imagined)}
    print(json.dumps(out, indent=1))
    if args.json:
        with open(args.json, "w") as f:
            json.dump(out, f, indent=1)


if __name__ == "__main__":
    main()
