"""Does ``adapt_driver``'s model read which exit of a ring the route takes? On explore's own drives, every step on a
ring (the navigation's ``in_roundabout``) whose next manoeuvre is an exit or a pass within the model's reach: the
navigation's label (``next_manoeuvre``: "exit" is the route's, "pass" is not) against the model's reading from the
route's shape (``_stays_on_ring``) and against the earlier reading from explore's plan (a "turn" anywhere in it).

    .venv/bin/python docs/research/scripts/ring_exits.py --towns Town3 Town4
"""

from __future__ import annotations

import argparse
import collections

import torch

from pernav.env.torchrl_env import explore_module, navigation_of
from pernav.model.driver import RING_REACH, _bend, _stays_on_ring
from pernav.study.config import preset
from pernav.study.episodes import study_env
from pernav.world.constants import TURNS


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--towns", nargs="+", default=["Town3", "Town4"])
    ap.add_argument("--routes", type=int, default=10)
    args = ap.parse_args()
    torch.set_num_threads(1)
    cfg = preset("paper")
    entry = cfg.schedule[5]  # Online 2: user1 in fog on the keyboard (any driver: the route's shape is the question)
    counts: collections.Counter = collections.Counter()
    bends: dict[str, list[float]] = {"pass": [], "exit": []}
    for town in args.towns:
        for route in range(args.routes):
            env = study_env(cfg, town, entry, route, 1000 + route)
            td, policy = env.reset(), explore_module()
            nav = navigation_of(env)
            for _ in range(400):
                kind = nav.junction_info()["next_manoeuvre"]
                s_first = float(td["distance_to_junction"])
                if bool(td["in_roundabout"]) and s_first < RING_REACH and kind in bends:
                    route_ahead = td["route_ahead"].double()
                    plan_reads_pass = not bool(torch.isin(td["explore_future"].long(), torch.tensor(TURNS)).any())
                    counts[(kind, "shape: pass" if _stays_on_ring(route_ahead, s_first) else "shape: exit")] += 1
                    counts[(kind, "plan: pass" if plan_reads_pass else "plan: exit")] += 1
                    bends[kind].append(_bend(route_ahead, s_first + 5.0, s_first + 20.0))
                td = env.step(policy(td))
                if bool(td["next", "done"]):
                    break
                td = td["next"]
    for (kind, reading), n in sorted(counts.items()):
        print(f"{kind:5s} states read as {reading}: {n}")
    for kind, values in bends.items():
        if values:
            print(f"{kind}: the route's bend 5-20 m past the exit {min(values):.1f} to {max(values):.1f} degrees")


if __name__ == "__main__":
    main()
