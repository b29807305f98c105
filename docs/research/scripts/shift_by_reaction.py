"""Which constant shift of explore's rule is cheapest at each point of the reaction-time sweep?

The sweep look asks that adapt_driver's "turn" lead rise with the driver's reaction time (Spearman ≥ 0.8), and the
product's promise that each driver gets the timing cheapest for them. This measures whether the two agree on the sweep
itself: the ``personal_sweep`` preset's drivers (the average driver with its reaction time shifted, 0.8 … 2.4 s),
its towns and routes, each driven by explore's rule shifted by every whole step of ``SHIFTS`` (> 0: earlier), on
the same episodes. Reports per town and reaction time each shift's mean tracking cost, its paired difference
with explore's (> 0: the shift is cheaper; 95 % bootstrap CI) and its mean "turn" lead, the cheapest shift, and
the Spearman of the cheapest shift (and of its lead) with the reaction time. No learner runs.

The seeds must not be a judged look's (the sweep look used 230-233).

    .venv/bin/python docs/research/scripts/shift_by_reaction.py --seeds 900 901 --json out.json
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from multiprocessing import Pool
from pathlib import Path

import numpy as np

from pernav.study.benchmarks import sweep_schedule
from pernav.study.config import preset
from pernav.study.driver_rounds import SHIFTS
from pernav.study.episodes import EpisodeJob, run_episode_job
from pernav.study.stats import paired_difference
from pernav.trainer.collect import derive_seed
from pernav.world.drivers import resolve

sys.path.insert(0, str(Path(__file__).resolve().parents[3]))  # the repository root: recipes
from recipes.benchmarks.follow import spearman  # noqa: E402

JUDGED_SWEEP_SEEDS = (230, 231, 232, 233)


def _drive(args: tuple) -> tuple[tuple, dict]:
    cfg, town, entry, route, seed, shift = args
    job = EpisodeJob(cfg, town, entry, route, derive_seed(seed, town, entry.label, "eval", route), "shift",
                     params=shift)
    return (town, entry.label, seed, route, shift), run_episode_job(job)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[900, 901])
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--json", default=None)
    args = parser.parse_args()
    if set(args.seeds) & set(JUDGED_SWEEP_SEEDS):
        parser.error(f"--seeds: {sorted(set(args.seeds) & set(JUDGED_SWEEP_SEEDS))} are the sweep look's seeds")
    cfg = preset("personal_sweep")
    online = [e for e in sweep_schedule() if e.phase == "online"]
    jobs = [(dataclasses.replace(cfg, seed=s), town, e, r, s, k) for town in cfg.towns for e in online
            for s in args.seeds for r in range(cfg.routes) for k in SHIFTS]
    with Pool(args.workers) as pool:
        done = dict(pool.imap_unordered(_drive, jobs, chunksize=4))
    report: dict = {"seeds": args.seeds, "shifts": list(SHIFTS), "towns": {}}
    for town in cfg.towns:
        rows, best, reactions, best_leads = {}, [], [], []
        for e in online:
            keys = [(s, r) for s in args.seeds for r in range(cfg.routes)]
            cost = {k: [done[(town, e.label, s, r, k)]["tracking_cost"] for s, r in keys] for k in SHIFTS}
            lead = {k: [done[(town, e.label, s, r, k)].get("turn_lead") for s, r in keys] for k in SHIFTS}
            mean = {k: float(np.mean(v)) for k, v in cost.items()}
            cheapest = min(SHIFTS, key=mean.__getitem__)
            reaction = round(resolve(e.profile(), e.context()).reaction_time, 4)
            rows[str(reaction)] = {
                "cost": {str(k): round(v, 1) for k, v in mean.items()},
                "explore_minus_shift": {str(k): {m: round(x, 1) for m, x in paired_difference(cost[0], cost[k]).items()
                                                 if m != "n"} for k in SHIFTS if k != 0},
                "lead": {str(k): round(float(np.mean([x for x in v if x is not None])), 2) for k, v in lead.items()},
                "best_shift": cheapest, "episodes": len(keys)}
            reactions.append(reaction)
            best.append(cheapest)
            best_leads.append(rows[str(reaction)]["lead"][str(cheapest)])
        report["towns"][town] = {"by_reaction": rows, "spearman_best_shift": spearman(reactions, best),
                                 "spearman_best_lead": spearman(reactions, best_leads)}
        print(town, json.dumps(report["towns"][town]), flush=True)
    if args.json:
        with open(args.json, "w") as f:
            json.dump(report, f, indent=1)


if __name__ == "__main__":
    main()
