"""Does ``adapt_driver``'s model read which side the route turns to at a junction? On explore's own drives, every
step at which explore says a sided prompt ("turn" or "prepare", left or right) for a junction the route turns at (not
a ring): whether that side is the one the model reads from the route's shape (``_other_side`` must not name it).

    .venv/bin/python docs/research/scripts/prompt_sides.py --towns Town1 Town2 Town3 Town4 Town5
"""

from __future__ import annotations

import argparse
import collections
import dataclasses

import torch

from pernav.env.torchrl_env import explore_module
from pernav.model.driver import FAR, _junction_ahead, _other_side
from pernav.study.config import preset
from pernav.study.episodes import study_env
from pernav.trainer.collect import drive
from pernav.world.constants import PREPARES, TURNS


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--towns", nargs="+", default=["Town1", "Town2", "Town3", "Town4", "Town5"])
    ap.add_argument("--routes", type=int, default=3)
    args = ap.parse_args()
    torch.set_num_threads(1)
    counts: collections.Counter = collections.Counter()
    for town in args.towns:
        cfg = dataclasses.replace(preset("default"), towns=[town])
        for route in range(args.routes):
            trajectory = drive(study_env(cfg, town, cfg.schedule[0], route, 1000 + route), explore_module())
            for t in range(trajectory.shape[0]):
                td = trajectory[t]
                said = int(td["explore_action"])
                if said not in (*TURNS, *PREPARES):
                    continue
                route_ahead = td["route_ahead"].double()
                _, s_junction, _, ring, _ = _junction_ahead(td, route_ahead)
                if ring or s_junction >= FAR:
                    counts[(town, "ring or none ahead")] += 1
                    continue
                counts[(town, "other side" if said in _other_side(route_ahead, s_junction) else "route's side")] += 1
    for (town, what), n in sorted(counts.items()):
        print(f"{town}: {what} {n}")


if __name__ == "__main__":
    main()
