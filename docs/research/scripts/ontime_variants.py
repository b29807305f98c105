"""Does re-timing only the "turn" prompts cost on-time drivers less than the learner's second guard? (research
check, world v2; docs/personal.md, "A judging sized for the on-time target")

Development drivers of the population prior (never the benchmark's) are drawn until ``drivers`` of them are on time
for explore (:func:`pernav.env.policies.lateness`, from the profile; late drivers are skipped before they drive).
Each drives one explore tau, from which the study's timing model (study seed 900) reads a belief; then two evaluation
routes (same seed for every variant: paired episodes) with explore, ``belief`` (the learner as the package runs it)
and ``turn_only`` (its "prepare" no earlier than explore's), driven by :func:`dropped_prompts.drive`. It prints each
variant's cost ratio to explore with a 95 % paired bootstrap CI, the share of episodes whose cost differs from
explore's, and the collisions.

Run (one town per process; about 5 min for 80 drivers on one core; docs/personal.md used population seeds 7171 for
Town1 and 7272 for Town3):
    .venv/bin/python docs/research/scripts/ontime_variants.py Town1 80 7171 [--out rows.json]
"""

from __future__ import annotations

import json
import random
import sys
from pathlib import Path

import numpy as np

from pernav.env.policies import lateness
from pernav.env.torchrl_env import explore_module
from pernav.study import episodes
from pernav.study.schedule import Entry
from pernav.study.stats import paired_ratio
from pernav.world.drivers import Population, resolve

sys.path.insert(0, str(Path(__file__).resolve().parent))
from dropped_prompts import development_setup, drive  # noqa: E402  (shared setup; one episode of a variant)

VARIANTS = ("explore", "belief", "turn_only")


def main() -> None:
    args, cfg, model = development_setup(__doc__.splitlines()[0])
    population, rng = Population(seed=args.population_seed), random.Random(args.population_seed)
    rows, k = [], 0
    while len(rows) < 2 * args.drivers:
        profile, context = population.sample()
        k += 1
        if lateness(resolve(profile, context))["excess"] >= 0.05:  # late for explore: not this check's driver
            continue
        entry = Entry(f"p{k}", "online", profile.to_dict(), **context.to_dict())
        belief = model.belief(episodes.episode(cfg, args.town, entry, rng.randrange(10), 1000 + k, explore_module()))
        for r in range(2):
            route, seed = rng.randrange(10), 2000 + 10 * k + r
            rows.append({"driver": k, "route": route, **{v: drive(args.town, entry, route, seed, belief, v)
                                                         for v in VARIANTS}})
    if args.out:
        with open(args.out, "w") as f:
            json.dump(rows, f)
    explore = np.array([r["explore"]["cost"] for r in rows])
    for v in VARIANTS[1:]:
        cost = np.array([r[v]["cost"] for r in rows])
        est = paired_ratio(cost, explore)
        print(f"{args.town} {v}: / explore {est['mean']:.3f} [{est['low']:.3f}, {est['high']:.3f}] over {len(rows)} "
              f"episodes; differs from explore in {np.mean(cost != explore):.0%}; collisions "
              f"{sum(r[v]['collisions'] for r in rows)} (explore {sum(r['explore']['collisions'] for r in rows)})")


if __name__ == "__main__":
    main()
