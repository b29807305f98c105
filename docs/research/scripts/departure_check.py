"""Was a planner's departure from explore bad in expectation (model error) or bad luck (one unlucky draw)?

Drives one study round's episode with explore, and with explore except for one step where the planner
departed (its action replaced), over the episode's own seed and ``--seeds`` others (traffic, mishearing and
compliance draws change with the seed; driver, town and route do not), and reports the paired difference
(explore - departure, > 0: the departure pays) with a 95 % bootstrap CI and the missed turns of each.

The example below is the one catastrophe of `docs/research/configs/headroom_prior12.yaml` (seed 2, Town3,
population sample 1, route 1: adapt 4764 vs explore 317). The planner delayed explore's "prepare to turn left"
by one step at step 3 (its three ensemble members all predicted a gain of 34-160); found by logging the
planner's departures while resuming a kept checkpoint (docs/research/findings.md, "One delayed prompt").

Run: .venv/bin/python docs/research/scripts/departure_check.py --schedule docs/research/configs/headroom_prior12.yaml \
    --seed 2 --town Town3 --label "population sample 1" --route 1 --step 3 --action 0 --seeds 20 [--json FILE]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

import torch
from tensordict import TensorDictBase
from tqdm import tqdm

from pernav.env.torchrl_env import explore_module
from pernav.study.config import preset
from pernav.study.episodes import episode
from pernav.study.schedule import load_schedule
from pernav.study.stats import paired_difference
from pernav.trainer.collect import derive_seed, episode_metrics


class OneStepChanged:
    """Explore, except that at step ``at`` it plays ``action`` (``at < 0``: explore throughout)."""

    def __init__(self, at: int, action: int) -> None:
        self.at, self.action, self.t, self.explore = at, action, 0, explore_module()

    def __call__(self, td: TensorDictBase) -> TensorDictBase:
        td = self.explore(td)
        action = td["explore_action"]
        td["action"] = torch.full_like(action, self.action) if self.t == self.at else action
        self.t += 1
        return td


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--schedule", required=True, help="the study's schedule file")
    ap.add_argument("--seed", type=int, default=0, help="the study's seed (the episode's seed derives from it)")
    ap.add_argument("--town", required=True)
    ap.add_argument("--label", required=True, help="the round's label, e.g. 'population sample 1'")
    ap.add_argument("--route", type=int, required=True)
    ap.add_argument("--step", type=int, required=True, help="the step (from 0) whose action is replaced")
    ap.add_argument("--action", type=int, required=True, help="the planner's action at that step (0-6)")
    ap.add_argument("--seeds", type=int, default=20, help="episode seeds besides the round's own")
    ap.add_argument("--json", help="write the per-seed figures and the summary here")
    args = ap.parse_args()
    cfg = preset("default")
    cfg.schedule, cfg.seed = load_schedule(args.schedule), args.seed
    entries = {e.label: e for e in cfg.entries_for(args.town)}
    if args.label not in entries:
        print(f"error: no round {args.label!r} in {args.town}; rounds: {', '.join(entries)}", file=sys.stderr)
        sys.exit(2)
    if not 0 <= args.action < 7:
        print(f"error: --action must be in 0-6, got {args.action}", file=sys.stderr)
        sys.exit(2)
    entry = entries[args.label]
    own = derive_seed(cfg.seed, args.town, entry.label, "eval", args.route)  # the study's evaluation seed
    rows: list[dict[str, Any]] = []
    for seed in tqdm([own, *range(1000, 1000 + args.seeds)], desc="episode seeds"):
        base = episode_metrics(episode(cfg, args.town, entry, args.route, seed, OneStepChanged(-1, 0)))
        moved = episode_metrics(episode(cfg, args.town, entry, args.route, seed, OneStepChanged(args.step, args.action)))
        rows.append({"seed": seed, "explore": base["tracking_cost"], "departure": moved["tracking_cost"],
                     "explore_missed": base["missed_turns"], "departure_missed": moved["missed_turns"]})
    others = rows[1:] or rows
    summary = {"study_episode": rows[0],
               # explore - departure per paired episode (> 0: the departure is cheaper)
               "explore_minus_departure": paired_difference([r["explore"] for r in others],
                                                            [r["departure"] for r in others]),
               "explore_mean": sum(r["explore"] for r in others) / len(others),
               "departure_mean": sum(r["departure"] for r in others) / len(others),
               "missed_turns": {"explore": sum(r["explore_missed"] for r in others),
                                "departure": sum(r["departure_missed"] for r in others)}}
    print(json.dumps(summary, indent=1))
    if args.json:
        Path(args.json).write_text(json.dumps({"args": vars(args), "rows": rows, "summary": summary}, indent=1))


if __name__ == "__main__":
    main()
