"""How wrong is a study's model over the planner's whole horizon, with and without the route's goals?

Drives explore with named users on a town's first routes and, at the steps where the retime planner would
search, lets adapt's final meta ensemble (``--study DIR``, its checkpoint) imagine the drive's own next 12
actions, twice: with the goals the model predicts (the paper's model) and with the goals the env would set
from the known route (``route_goals``, ``route_goal`` (removed since, in commit d640b8a)). It reports the median
position error of the members' mean after 5 and 12 s (at 12 s also split into the error along the route, in
route progress, and the imagined car's distance across it), and the planner's miss alarm
(``RetimingPlanner.alarm_check``: every member more than ``--distance`` m off the route where the real car
was or was not).

Run (after a study): .venv/bin/python docs/research/scripts/horizon_error.py --study runs/default [--towns Town1 Town3]
[--users user1 user3 user4] [--routes 3] [--json FILE]
"""

from __future__ import annotations

import argparse
import json
import statistics
from pathlib import Path

import torch

from pernav.env.layout import ROUTE_SPACING
from pernav.env.torchrl_env import explore_module
from pernav.model.adapt import meta_parameters
from pernav.model.dynamics import DynamicsModel
from pernav.model.egocentric import X, Y
from pernav.model.navigation import ImaginedNavigationEnv, make_world_model
from pernav.planner import RetimingPlanner
from pernav.study.checkpoints import final_models
from pernav.study.errors import CheckpointError
from pernav.trainer.collect import drive, history_env
from pernav.world.drivers import NAMED_USERS, Context, named_user


def horizon_error(planner: RetimingPlanner, drives: list, every: int = 3) -> dict[str, float | int]:
    """The planner's alarm counts over ``drives`` and the median position error (m) of the rows' mean at 5 and
    12 s (``horizon`` 12) over every ``every``-th searched step."""
    out = {"steps": 0, "alarms": 0, "hits": 0, "false_alarms": 0, "real": 0}
    err5, err12, along, across = [], [], [], []
    H = planner.horizon
    for traj in drives:
        counts = planner.alarm_check(traj)
        for k in out:
            out[k] += counts[k]
        pos = traj["next", "observation"][:, [X, Y]]
        for t in range(0, traj.shape[0] - H, every):
            if planner.searches(traj[t]):
                _, imagined, _ = planner.costs(traj[t], traj["action"][t:t + H].reshape(1, H).long())  # [M, 1, H, 2]
                mean = imagined[:, 0].mean(0)
                e = (mean - pos[t:t + H]).norm(dim=-1)
                err5.append(float(e[4]))
                err12.append(float(e[H - 1]))
                # the 12-s error split: along the route (progress) and across it (distance from the route)
                d = torch.cdist(torch.stack([mean[H - 1], pos[t + H - 1]]), traj[t]["route_ahead"].float())
                along.append(ROUTE_SPACING * abs(int(d[0].argmin()) - int(d[1].argmin())))
                across.append(float(d[0].min()))
    return {**out, "error_5s_m": round(statistics.median(err5), 2) if err5 else None,
            "error_12s_m": round(statistics.median(err12), 2) if err12 else None,
            "along_12s_m": round(statistics.median(along), 2) if along else None,
            "across_12s_m": round(statistics.median(across), 2) if across else None, "positions": len(err5)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--study", required=True, help="a finished study folder (its checkpoints)")
    ap.add_argument("--towns", nargs="+", default=["Town1", "Town3"])
    ap.add_argument("--users", nargs="+", default=["user1", "user3", "user4"])
    ap.add_argument("--routes", type=int, default=3, help="the town's first N routes per user")
    ap.add_argument("--distance", type=float, default=8.0, help="the alarm's distance from the route (m)")
    ap.add_argument("--json", help="write the figures here")
    args = ap.parse_args()
    bad = [u for u in args.users if u not in NAMED_USERS]
    if bad or not 1 <= args.routes <= 10 or args.distance <= 0:
        ap.error(f"users must be among {', '.join(NAMED_USERS)}, routes in [1, 10], distance > 0")
    torch.set_num_threads(1)
    out = {}
    for town in args.towns:
        try:
            model, states = final_models(args.study, town, "adapt")
        except CheckpointError as exc:
            ap.error(str(exc))
        members = []
        for state in states:
            member = DynamicsModel(**model.config())
            member.load_state_dict(state)
            members.append(member)
        drives = [drive(history_env(town, {"route": r, "user": named_user(u), "context": Context()},
                                    config={"n_traffic": 4}, seed=100 + r, K=model.K), explore_module())
                  for u in args.users for r in range(args.routes)]
        for route_goals in (False, True):
            planner = RetimingPlanner(ImaginedNavigationEnv(make_world_model(members[0])), rescue=args.distance,
                                      route_goals=route_goals)
            planner.params = [meta_parameters(m).detach() for m in members]
            key = f"{town} {'route goals' if route_goals else 'model goals'}"
            out[key] = horizon_error(planner, drives)
            print(key, out[key], flush=True)
    if args.json:
        Path(args.json).write_text(json.dumps({"study": args.study, "users": args.users, "routes": args.routes,
                                               "distance": args.distance, "figures": out}, indent=1))


if __name__ == "__main__":
    main()
