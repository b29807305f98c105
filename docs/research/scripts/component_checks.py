"""Does adaptation help? Does planning help? (an early acceptance check, world v1)

Usage:
    .venv/bin/python docs/research/scripts/component_checks.py [OUT.json] [--town Town1] [--seed 0]

1. Adaptation: a meta model trained (warm start + FTML) on explore data from user1 in the paper's offline and
   early online contexts is adapted with ONE gradient step U(P, tau) on ONE explore trajectory of an unseen
   user (user3, slow, in fog, in the cybertruck); its L-step loss on that user's held-out trajectories is
   compared with the unadapted model's.
2. Planning: a model trained on the atypical user's own data (explore trajectories, then a round of
   MPC/explore trajectories, like SysID) drives the town's 10 routes with the tree-search MPC; its tracking
   cost is compared with the explore policy's on the same routes and seeds.
"""

from __future__ import annotations

import argparse
import json
import logging
import statistics
import time

import torch

from pernav.env.torchrl_env import explore_module
from pernav.model import DynamicsModel, adapt, multistep_loss
from pernav.model.navigation import ImaginedNavigationEnv, make_world_model
from pernav.planner import TreeSearchPlanner
from pernav.trainer.buffers import RoundBuffers
from pernav.trainer.collect import derive_seed, drive, episode_metrics, history_env
from pernav.trainer.ftml import FTMLTrainer, TrainConfig

USER1_CONTEXTS = [
    {"vehicle": "camaro", "camera": "first_person"},
    {"vehicle": "camaro", "camera": "third_person"},
    {"vehicle": "cybertruck", "camera": "first_person"},
    {"vehicle": "cybertruck", "camera": "third_person"},
    {"vehicle": "camaro", "camera": "first_person", "visual": "rgb"},
    {"vehicle": "camaro", "camera": "third_person", "visual": "foggy"},
]
UNSEEN = {"user": "user3", "context": {"vehicle": "cybertruck", "visual": "foggy"}}
CONFIG = {"n_traffic": 4}


def _trajectory(town: str, route: int, user: str, context: dict, seed: int, policy=None):
    env = history_env(town, {"route": route, "user": user, "context": context}, config=CONFIG, seed=seed)
    return drive(env, policy or explore_module())


def adaptation_check(town: str, seed: int, meta_updates: int = 300) -> dict:
    torch.manual_seed(seed)
    buffers = RoundBuffers(L=5, seed=seed)
    for r, ctx in enumerate(USER1_CONTEXTS):
        for k in range(3):
            buffers.add(r, _trajectory(town, (3 * r + k) % 10, "user1", ctx, derive_seed(seed, "a", r, k)), tau=k == 0)
    trainer = FTMLTrainer(DynamicsModel(), buffers, TrainConfig(), seed=seed)
    trainer.fit_normalization()
    trainer.train(300, meta=False)  # warm start (Eq. 1)
    trainer.train(meta_updates, meta=True)  # FTML over the user1 contexts (Eq. 3)
    held = RoundBuffers(L=5, seed=seed + 1)
    tau = _trajectory(town, 0, UNSEEN["user"], UNSEEN["context"], derive_seed(seed, "tau"))
    for k in range(3):
        held.add(0, _trajectory(town, 4 + k, UNSEEN["user"], UNSEEN["context"], derive_seed(seed, "held", k)))
    batch = held.sample(0, 512)
    with torch.no_grad():
        before = float(multistep_loss(trainer.model, batch))
    adapted = adapt(trainer.model, tau, alpha=0.01, first_order=True).detach()
    with torch.no_grad():
        after = float(multistep_loss(trainer.model, batch, params=adapted))
    return {"seed": seed, "meta_updates": meta_updates, "unseen_user": UNSEEN, "heldout_windows": 512,
            "loss_without_adaptation": round(before, 4),
            "loss_with_adaptation": round(after, 4), "adaptation_helps": after < before}


def planning_check(town: str, seed: int) -> dict:
    torch.manual_seed(seed)
    user, ctx = UNSEEN["user"], UNSEEN["context"]
    buffers = RoundBuffers(L=5, seed=seed)
    for k in range(8):
        buffers.add(0, _trajectory(town, k % 10, user, ctx, derive_seed(seed, "p", k)))
    model = DynamicsModel()
    trainer = FTMLTrainer(model, buffers, TrainConfig(), seed=seed)
    trainer.fit_normalization()
    trainer.train(400, meta=False)
    planner = TreeSearchPlanner(ImaginedNavigationEnv(make_world_model(model)))
    for k in range(4):  # one round of on-policy data, as SysID collects it
        policy = planner if k % 2 == 0 else None
        buffers.add(1, _trajectory(town, (k + 3) % 10, user, ctx, derive_seed(seed, "q", k), policy))
    trainer.train(200, meta=False)
    rows = []
    for route in range(10):
        s = derive_seed(seed, "eval", route)
        mpc = episode_metrics(_trajectory(town, route, user, ctx, s, planner))
        exp = episode_metrics(_trajectory(town, route, user, ctx, s))
        rows.append({"route": route, "mpc": mpc, "explore": exp})
    mean = {p: statistics.fmean(r[p]["tracking_cost"] for r in rows) for p in ("mpc", "explore")}
    coll = {p: sum(r[p]["collisions"] for r in rows) for p in ("mpc", "explore")}
    return {"user": UNSEEN, "town": town, "routes": 10, "mean_tracking_cost": mean, "collisions": coll,
            "planning_helps": mean["mpc"] < mean["explore"], "episodes": rows}


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", nargs="?", default="component_checks.json")
    parser.add_argument("--town", default="Town1")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--adaptation-seeds", type=int, default=3, help="seeds of the adaptation check (all reported)")
    parser.add_argument("--only", choices=["adaptation", "planning"], help="run one check only")
    args = parser.parse_args()
    logging.getLogger("torchrl").setLevel(logging.WARNING)
    torch.set_num_threads(1)
    t0 = time.perf_counter()
    result: dict = {}
    if args.only in (None, "adaptation"):
        runs = [adaptation_check(args.town, args.seed + k) for k in range(args.adaptation_seeds)]
        result["adaptation"] = {"runs": runs, "helps_in": f"{sum(r['adaptation_helps'] for r in runs)}/{len(runs)}"}
    if args.only in (None, "planning"):
        result["planning"] = planning_check(args.town, args.seed)
    result["wall_s"] = round(time.perf_counter() - t0, 1)
    with open(args.out, "w") as f:
        json.dump(result, f, indent=1)
    brief = {k: {kk: vv for kk, vv in v.items() if kk != "episodes"} for k, v in result.items() if isinstance(v, dict)}
    print(json.dumps(brief, indent=1))
