"""Explore and the oracle on the headroom benchmark (seeds 0-5) before and after re-routing at the wrong branch.

"Before" is docs/figures/personal/explore_oracle.json (the navigation re-planned once the car was 8 m off its route,
or 24 m on a road the route uses); "after" the same six studies re-run with the navigation re-planning in the step
the car enters a lane its route does not continue on (NavigationEnv's default since):

    for s in 0 1 2 3 4 5; do pernav study --preset personal --methods explore oracle --seed $s \
        --out runs/personal/eo_branch_seed$s --workers 2; done
    .venv/bin/python docs/research/scripts/reroute_remeasure.py      # -> docs/figures/reroute/headroom_explore_oracle.json
"""

import json
from pathlib import Path

from recipes.benchmarks.headroom import judge


def main() -> None:
    runs = [json.loads(Path(f"runs/personal/eo_branch_seed{s}/results.json").read_text()) for s in range(6)]
    after = judge(runs, learner="oracle")
    before = json.loads(Path("docs/figures/personal/explore_oracle.json").read_text())
    out = {"before": {k: before[k] for k in ("late", "on_time")},
           "after": {k: {f: after[k][f] for f in ("episodes", "explore", "oracle", "oracle_gain")}
                     for k in ("late", "on_time")}}
    for cells in ("late", "on_time"):
        for when in ("before", "after"):
            row = out[when][cells]
            gain = row["oracle_gain"]
            width = gain["high"] - gain["low"]
            print(f"{cells:8} {when:6} explore {row['explore']:.0f} oracle {row['oracle']:.0f} explore - oracle "
                  f"{gain['mean']:+.1f} [{gain['low']:+.1f}, {gain['high']:+.1f}] (CI width {width:.1f})")
    Path("docs/figures/reroute/headroom_explore_oracle.json").write_text(json.dumps(out, indent=1) + "\n")


if __name__ == "__main__":
    main()
