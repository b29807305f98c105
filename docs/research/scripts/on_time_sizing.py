"""How many seeds does the personal benchmark's on-time target need? (research check; docs/personal.md, "A judging
sized for the on-time target")

Reads the judged studies of the timing learner on seeds 0-17 (explore and the oracle from ``eo_seed0-5`` and
``fresh_seed6-11``, the learner with its second guard from ``v2t_seed0-11`` and ``v2_seed12-17``; a later folder's
method replaces an earlier one's, as in ``recipes/benchmarks/judge.py``). It draws ``n`` seeds with replacement from those
eighteen, pools their episodes, and checks the pre-registered late and on-time targets on the draw
(:mod:`pernav.diagnostics.stats`, 1000 resamples); it prints, per ``n``, the share of draws that meet each target and
the median upper end of the on-time ratio's CI.

Run (about 2 min; the studies are the commands of docs/personal.md):
    .venv/bin/python docs/research/scripts/on_time_sizing.py runs/personal [--draws 150] [--seeds 6 12 16 24]
"""

from __future__ import annotations

import argparse
import json
import random
from pathlib import Path

import numpy as np

from pernav.study.benchmarks import classify, episodes, personal_schedule
from pernav.study.stats import gap_closed, paired_ratio
from recipes.benchmarks.headroom import TARGETS

FOLDERS = ([f"eo_seed{s}" for s in range(6)] + [f"fresh_seed{s}" for s in range(6, 12)]
           + [f"v2t_seed{s}" for s in range(12)] + [f"v2_seed{s}" for s in range(12, 18)])


def passes(rows: dict[bool, np.ndarray]) -> tuple[bool, bool, float]:
    """(late target met, on-time target met, on-time CI upper end) of pooled ``[explore, timing, oracle]`` rows."""
    late, on_time = rows[True], rows[False]
    g = gap_closed(late[:, 0], late[:, 1], late[:, 2], resamples=1000)
    r = paired_ratio(on_time[:, 1], on_time[:, 0], resamples=1000)
    t = TARGETS
    return (g["mean"] >= t["late_gap_closed"]["point"] and g["low"] > t["late_gap_closed"]["ci_low"],
            r["mean"] <= t["on_time_cost_ratio"]["point"] and r["high"] <= t["on_time_cost_ratio"]["ci_high"],
            r["high"])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("runs", help="the folder holding the studies (runs/personal)")
    ap.add_argument("--draws", type=int, default=150)
    ap.add_argument("--seeds", type=int, nargs="+", default=[6, 12, 16, 24])
    args = ap.parse_args()
    pairs = episodes([json.loads((Path(args.runs) / f / "results.json").read_text()) for f in FOLDERS])
    late = {(c["town"], c["round"]): c["late"] for c in classify(personal_schedule(), ["Town1", "Town3"])}
    by_seed: dict[int, dict[bool, list]] = {}
    for (seed, town, label, _), m in pairs.items():
        row = [m[k]["tracking_cost"] for k in ("explore", "timing", "oracle")]
        by_seed.setdefault(seed, {True: [], False: []})[late[(town, label)]].append(row)
    seeds, rng = sorted(by_seed), random.Random(1)
    for n in args.seeds:
        results = []
        for _ in range(args.draws):
            draw = [rng.choice(seeds) for _ in range(n)]
            results.append(passes({k: np.array([r for s in draw for r in by_seed[s][k]]) for k in (True, False)}))
        a = np.array(results, dtype=float)
        print(f"{n} seeds: late target met {a[:, 0].mean():.0%}, on-time target met {a[:, 1].mean():.0%}, "
              f"median on-time CI upper end {np.median(a[:, 2]):.3f}")


if __name__ == "__main__":
    main()
