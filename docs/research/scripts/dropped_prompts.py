"""Does the timing learner's re-timed rule make drivers drop prompts? (research check, world v2; docs/personal.md)

Development drivers of the population prior (never the benchmark's) each drive one explore tau; the study's timing
model (``pernav.study.runner._fit_timing``, study seed 900) reads a belief from it; then each driver drives two
evaluation routes (same seed for every policy: paired episodes) with each of the variants:

- ``explore``, ``oracle``;
- ``belief``: the learner as the code now runs it (the guard with the box wait and the ring speed);
- ``first``: the learner with the first guard only (no box wait, the exit guard at the approach speed);
- ``turn_only``: the learner re-timing its "turn" prompts only: a "prepare" no earlier than explore's (a next step
  measured here, not in the package).

It prints per class (late / on time, from the profile) the mean tracking cost and the prompts dropped on entering a
junction box per route (``Events.discarded``), the gap closed (late) and the cost ratio to explore (on time) with
95 % paired bootstrap CIs (:mod:`pernav.diagnostics.stats`).

Run (one town per process; about 10 min for 60 drivers on one core; docs/personal.md used population seeds 5252 for
Town1 and 5151 for Town3):
    .venv/bin/python docs/research/scripts/dropped_prompts.py Town1 60 5252 [--out rows.json]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
import torch

import pernav.env.policies as rules
from pernav.env.navigation import NavigationEnv
from pernav.env.policies import PromptPolicy, explore_policy, lateness
from pernav.study import runner
from pernav.study.config import preset
from pernav.study.schedule import Entry
from pernav.study.stats import gap_closed, paired_ratio
from pernav.world.drivers import resolve

sys.path.insert(0, str(Path(__file__).resolve().parent))
from within_drive import development_drivers  # noqa: E402  (one loop over development drivers)

VARIANTS = ("explore", "oracle", "belief", "first", "turn_only")
_PREPARE_LEAD = PromptPolicy.prepare_lead


def _prepare_no_earlier_than_explore(self: PromptPolicy, v: float, lead: float) -> float:
    if self.fastest is None:  # explore and the oracle: their own rule
        return _PREPARE_LEAD(self, v, lead)
    explore = explore_policy()
    return min(_PREPARE_LEAD(self, v, lead), explore.prepare_lead(v, explore.turn_lead(v)))


def drive(town: str, entry: Entry, route: int, seed: int, belief: dict, variant: str) -> dict:
    """One paired episode; ``first`` switches the guard's box wait and ring speed off for its duration,
    ``turn_only`` holds the learner's "prepare" to explore's lead."""
    saved = rules.DROPPED, rules.GUARD_RING_SPEED
    if variant == "first":
        rules.DROPPED, rules.GUARD_RING_SPEED = (), float("inf")
    if variant == "turn_only":
        PromptPolicy.prepare_lead = _prepare_no_earlier_than_explore
    try:
        env = NavigationEnv(town, config={"n_traffic": preset("personal").n_traffic, "belief": belief})
        _, info = env.reset(seed=seed, options={"route": route, "user": entry.profile(), "context": entry.context()})
        key = {"explore": "explore_action", "oracle": "oracle_action"}.get(variant, "belief_action")
        done = False
        while not done:
            _, _, terminated, truncated, info = env.step(info[key])
            done = terminated or truncated
    finally:
        rules.DROPPED, rules.GUARD_RING_SPEED = saved
        PromptPolicy.prepare_lead = _PREPARE_LEAD
    return {"cost": info["tracking_cost"], "collisions": info["collisions"], "dropped": env.world.events.discarded}


def development_setup(description: str):
    """``(args, cfg, model)`` of a development-driver check: its arguments (town, drivers, population seed, --out), the
    personal preset at study seed 900 and the timing model the study fits for the town (shared by the scripts
    that drive development drivers with the learner's variants)."""
    ap = argparse.ArgumentParser(description=description)
    ap.add_argument("town")
    ap.add_argument("drivers", type=int)
    ap.add_argument("population_seed", type=int)
    ap.add_argument("--out")
    args = ap.parse_args()
    torch.set_num_threads(1)
    cfg = preset("personal")
    cfg.seed = 900
    return args, cfg, runner._fit_timing(cfg, args.town)


def main() -> None:
    args, cfg, model = development_setup(__doc__.splitlines()[0])
    rows = []
    for k, profile, context, entry, tau, rng in development_drivers(cfg, args.town, args.drivers,
                                                                     args.population_seed):
        belief = model.belief(tau)
        late = lateness(resolve(profile, context))["excess"] >= 0.05
        for r in range(2):
            route, seed = rng.randrange(10), 2000 + 10 * k + r
            row = {"driver": k, "route": route, "late": late, "left_explore": bool(belief)}
            for v in VARIANTS:
                row.update({f"{v}_{key}": value for key, value in drive(args.town, entry, route, seed, belief, v).items()})
            rows.append(row)
    if args.out:
        with open(args.out, "w") as f:
            json.dump(rows, f)
    for label, want in (("late", True), ("on time", False)):
        sel = [r for r in rows if r["late"] == want]
        if not sel:
            continue
        cost = {v: np.array([r[f"{v}_cost"] for r in sel]) for v in VARIANTS}
        dropped = {v: float(np.mean([r[f"{v}_dropped"] for r in sel])) for v in VARIANTS}
        print(f"{label} ({len(sel)} episodes): " + ", ".join(f"{v} {cost[v].mean():.0f} (dropped {dropped[v]:.2f})"
                                                             for v in VARIANTS))
        for v in ("belief", "first", "turn_only"):
            est = gap_closed(cost["explore"], cost[v], cost["oracle"]) if want else paired_ratio(cost[v],
                                                                                                 cost["explore"])
            print(f"   {v}: {'gap closed' if want else '/ explore'} {est['mean']:.3f} [{est['low']:.3f}, "
                  f"{est['high']:.3f}]")


if __name__ == "__main__":
    main()
