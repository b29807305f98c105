"""Does a drive's own missed turn tell the timing learner what one explore tau does not? (research check, world
v2; docs/personal.md)

Development drivers of the population prior (never the benchmark's) each drive one explore tau and ``routes``
evaluation routes. On each evaluation route (same seed for every policy, so the episodes are paired) this drives:

- explore and the oracle;
- ``timing``: the learner as the study runs it (the belief read from tau, :class:`pernav.learners.timing.TimingModel`,
  with the options given by ``--timing-option``);
- ``guarded``: the same belief with the quickest driver the evidence allows (:meth:`TimingModel.fastest`);
- ``watch``: explore until this drive shows a missed or wrong turn, then explore's rule re-timed for the learner's
  late belief (the model's prediction ``quantile`` SDs above its mean, whatever the mean says);
- ``tau+watch``: the late belief from the start when tau showed a missed or wrong turn, else ``watch``.

It prints the mean tracking cost per class (late / on time, from the profile: :func:`pernav.study.benchmarks.classify`'s
rule) and the share of the explore -> oracle gap each policy closes, with 95 % bootstrap CIs over drivers.

Run (one town per process; about 6 min for 30 drivers x 2 routes on one core; docs/personal.md used population
seeds 5151 for Town3 and 5252 for Town1, the study seed 900 and, for the first table, ``--timing-option guard=0``):
    .venv/bin/python docs/research/scripts/within_drive.py Town3 30 5151 [--methods explore oracle timing guarded]
"""

from __future__ import annotations

import argparse
import json
import random

import numpy as np
import torch
from tensordict.nn import TensorDictModule

from pernav.env.policies import lateness
from pernav.env.torchrl_env import explore_module, info_action_module, oracle_module
from pernav.learners.timing import timing_features
from pernav.study import episodes, runner
from pernav.study.config import preset
from pernav.study.schedule import Entry
from pernav.study.stats import gap_closed, paired_ratio
from pernav.world.drivers import Population, resolve


class _Watch(torch.nn.Module):
    def __init__(self, start_late: bool) -> None:
        super().__init__()
        self.start_late = start_late

    def forward(self, explore, belief, missed, wrong):
        late = (missed + wrong > 0) | self.start_late
        return torch.where(late, belief, explore)


def watch_module(start_late: bool) -> TensorDictModule:
    return TensorDictModule(_Watch(start_late), in_keys=["explore_action", "belief_action", "missed_turns",
                                                         "wrong_turns"], out_keys=["action"])


def development_drivers(cfg, town: str, drivers: int, population_seed: int):
    """Yield ``(k, profile, context, entry, tau, rng)`` for ``drivers`` population drivers, each with its explore tau;
    ``rng`` then draws the driver's evaluation routes (the research scripts on development drivers share this)."""
    population, rng = Population(seed=population_seed), random.Random(population_seed)
    for k in range(drivers):
        profile, context = population.sample()
        entry = Entry(f"p{k}", "online", profile.to_dict(), **context.to_dict())
        yield k, profile, context, entry, episodes.episode(cfg, town, entry, rng.randrange(10), 1000 + k,
                                                         explore_module()), rng


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("town")
    ap.add_argument("drivers", type=int)
    ap.add_argument("population_seed", type=int)
    ap.add_argument("--routes", type=int, default=2)
    ap.add_argument("--study-seed", type=int, default=900)
    ap.add_argument("--out")
    ap.add_argument("--timing-option", action="append", default=[], metavar="KEY=VALUE",
                    help="the timing learner's options (pernav.study.config.TIMING_DEFAULTS)")
    ap.add_argument("--methods", nargs="+", default=["explore", "oracle", "timing", "guarded", "watch", "tau+watch"])
    ap.add_argument("--quantiles", nargs="*", type=float, default=[],
                    help="also drive the guarded learner with its belief at each of these quantiles (variants q<Q>)")
    args = ap.parse_args()
    torch.set_num_threads(1)
    cfg = preset("personal")
    cfg.seed = args.study_seed
    cfg.timing.update({k: float(v) for k, v in (o.split("=", 1) for o in args.timing_option)})
    model = runner._fit_timing(cfg, args.town)
    rows = []
    for k, profile, context, entry, tau, rng in development_drivers(cfg, args.town, args.drivers,
                                                                     args.population_seed):
        last = tau[-1]["next"]
        tau_missed = int(last["missed_turns"]) + int(last["wrong_turns"]) > 0
        features = timing_features(tau)
        late_belief = dict(zip(("reaction_time", "decision_time"), model.predict(features, model.quantile).tolist(),
                               strict=True))
        timing_belief = model.belief(tau)
        guarded_belief = {**timing_belief, "fastest": model.fastest(features)} if timing_belief else {}
        excess = lateness(resolve(profile, context))["excess"]
        for r in range(args.routes):
            route, seed = rng.randrange(10), 2000 + 10 * k + r
            row = {"driver": k, "route": route, "excess": excess, "late": excess >= 0.05, "tau_missed": tau_missed,
                   "timing_left": bool(timing_belief)}
            variants = (("explore", explore_module(), None), ("oracle", oracle_module(), None),
                        ("timing", info_action_module("belief_action"), timing_belief),
                        ("guarded", info_action_module("belief_action"), guarded_belief),
                        ("watch", watch_module(False), late_belief),
                        ("tau+watch", watch_module(tau_missed), late_belief))
            variants += tuple((f"q{q:g}", info_action_module("belief_action"), _at_quantile(model, q, tau))
                              for q in args.quantiles)
            for name, policy, belief in (v for v in variants if v[0] in args.methods or v[0].startswith("q")):
                t = episodes.episode(cfg, args.town, entry, route, seed, policy, belief=belief)
                row[name] = float(t[-1]["next", "tracking_cost"])
                row[name + "_collisions"] = int(t[-1]["next", "collisions"])
            rows.append(row)
            print(json.dumps(row), flush=True)
    if args.out:
        with open(args.out, "w") as f:
            json.dump(rows, f)
    report(rows)


def _at_quantile(model, quantile: float, tau) -> dict:
    """The guarded learner's belief read from ``tau`` with its ``quantile`` set to ``quantile``."""
    saved = model.quantile
    model.quantile = quantile
    try:
        return model.belief(tau)
    finally:
        model.quantile = saved


def report(rows: list[dict]) -> None:
    """Mean cost per class; the gap closed (late) and the cost ratio to explore (on time), with the project's
    paired bootstrap CIs (:mod:`pernav.diagnostics.stats`)."""
    methods = [m for m in ("explore", "oracle", "timing", "guarded", "watch", "tau+watch") if m in rows[0]]
    methods += [m for m in rows[0] if m.startswith("q") and not m.endswith("_collisions")]
    for label, keep in (("late", True), ("on time", False)):
        sel = [r for r in rows if r["late"] == keep]
        if not sel:
            continue
        cost = {m: np.array([r[m] for r in sel]) for m in methods}
        print(f"{label} ({len(sel)} episodes): " + ", ".join(f"{m} {c.mean():.0f}" for m, c in cost.items()))
        for m in methods[2:]:
            if keep:
                est = gap_closed(cost["explore"], cost[m], cost["oracle"])
                print(f"   {m}: gap closed {est['mean']:.0%} [{est['low']:.0%}, {est['high']:.0%}]")
            else:
                est = paired_ratio(cost[m], cost["explore"])
                print(f"   {m}: / explore {est['mean']:.3f} [{est['low']:.3f}, {est['high']:.3f}]")


if __name__ == "__main__":
    main()
