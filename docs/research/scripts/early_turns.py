"""What does a "turn" said early cost in the simulator? ``adapt_driver``'s model imagines an early "turn" as free (in
effect until its junction), and its prompts come 1.5-2 s earlier than explore's on average (the paper look). Here the
true simulator drives explore's rule shifted earlier by whole steps (``ShiftedExplore``: every prompt ``shift`` steps
sooner, the family ``best_shift`` picks from, extended past its +3) for drivers of several reaction times on several
routes, and counts missed turns, wrong turns and edge strikes per episode, with the mean tracking cost. Explore's own
timing is shift 0. Data for the model's structure: whether, and from how early, a "turn" is lost.

    .venv/bin/python docs/research/scripts/early_turns.py --towns Town1 Town5 --shifts 0 2 4 6 8
"""

from __future__ import annotations

import argparse
import json

import numpy as np
import torch

from pernav.planner.retiming import ShiftedExplore
from pernav.trainer.collect import drive, history_env
from pernav.world.drivers import Context, DriverProfile


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--towns", nargs="+", default=["Town1", "Town5"])
    ap.add_argument("--shifts", nargs="+", type=int, default=[0, 2, 4, 6, 8])
    ap.add_argument("--reaction-times", nargs="+", type=float, default=[0.8, 1.4, 2.2])
    ap.add_argument("--routes", type=int, default=6)
    ap.add_argument("--json", default=None)
    args = ap.parse_args()
    torch.set_num_threads(1)
    out = {}
    for town in args.towns:
        for shift in args.shifts:
            rows = []
            for r in args.reaction_times:
                for route in range(args.routes):
                    env = history_env(town, {"route": route, "user": DriverProfile(reaction_time=r),
                                             "context": Context()}, config={"n_traffic": 2}, seed=500 + route)
                    info = drive(env, ShiftedExplore(shift))[-1]["next"]
                    rows.append([float(info[k]) for k in ("missed_turns", "wrong_turns", "edge_strikes",
                                                          "tracking_cost")])
            m = np.asarray(rows).mean(0)
            out[f"{town} {shift}"] = dict(zip(("missed", "wrong", "edge", "cost"), m.round(3).tolist(), strict=True))
            print(f"{town} shift {shift:+d} s ({len(rows)} episodes): per episode missed {m[0]:.2f}, wrong {m[1]:.2f}, "
                  f"edge strikes {m[2]:.2f}, cost {m[3]:.0f}", flush=True)
    if args.json:
        with open(args.json, "w") as f:
            json.dump(out, f, indent=1)


if __name__ == "__main__":
    main()
