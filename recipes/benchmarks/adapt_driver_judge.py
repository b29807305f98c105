"""``adapt_driver``'s pre-registered looks (``preregistered/adapt_driver.yaml``), judged against the targets written
there before any of them ran. Each look is run once on its seeds; a further look is a new entry in the file with its
reason. The sweep (the ``personal_sweep`` preset, the average driver with its reaction time shifted):

    for s in 230 231 232 233; do pernav study --preset personal_sweep --seed $s \
        --methods explore timing belief adapt_driver oracle --out runs/look_sweep_s$s --workers 2; done
    .venv/bin/python -m recipes.benchmarks.adapt_driver_judge sweep runs/look_sweep_s23*

writes ``docs/figures/adapt_driver/look_sweep.json`` and ``look_sweep_leads.png`` (``--out DIR``: elsewhere) and
prints the figures and whether each target is met.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

from recipes.benchmarks import follow
from recipes.benchmarks.registered import registration

OUT = Path("docs/figures/adapt_driver")
SWEEP_METHODS = ("explore", "timing", "belief", "adapt_driver", "oracle")


def sweep(runs: list[dict[str, Any]], out: Path = OUT) -> list[str]:
    """The sweep look: ``adapt_driver``'s Spearman of the "turn" lead with the reaction time in each town and seed, and
    its cost at the quickest point over explore's (pooled, paired), against the registration's targets."""
    look = registration("adapt_driver")["first_look"]["sweep"]
    j = follow.judge_sweep(runs, learner="adapt_driver", methods=SWEEP_METHODS)
    if sorted(j["seeds"]) != sorted(look["seeds"]):
        raise ValueError(f"the sweep look is registered on seeds {look['seeds']}; these runs are seeds {j['seeds']}")
    targets = look["targets"]
    quick = j["pooled"]["quick_end_cost_ratio"]
    j["verdict"] = {
        "lead_spearman": {"target": targets["lead_spearman"]["point"], "min": j["spearman_min"],
                          "met": j["spearman_min"] is not None
                          and j["spearman_min"] >= targets["lead_spearman"]["point"]},
        "quickest_cost_ratio": {"target": targets["quickest_cost_ratio"]["point"], "point": quick["mean"],
                                "met": quick["mean"] <= targets["quickest_cost_ratio"]["point"]},
    }
    out.mkdir(parents=True, exist_ok=True)
    j["plot"] = follow.plot_sweep_leads(runs, str(out / "look_sweep_leads.png"), methods=SWEEP_METHODS)
    (out / "look_sweep.json").write_text(json.dumps(j, indent=1) + "\n")
    lines = follow.sweep_lines(j)
    for name in ("pooled", "Town1", "Town3"):
        r = j.get(name, {})
        if "quick_end_cost_ratio" in r:
            q, g = r["quick_end_cost_ratio"], r["slow_end_gap_closed"]
            lines.append(f"{name}: quickest adapt_driver / explore {q['mean']:.3f} [{q['low']:.3f}, {q['high']:.3f}];"
                         f" slowest gap to the oracle closed {100 * g['mean']:.0f} % [{100 * g['low']:.0f} %, "
                         f"{100 * g['high']:.0f} %] ({r['slow_end']})")
    lines += [f"{name}: {v}" for name, v in j["verdict"].items()]
    return lines


def main() -> None:
    args = sys.argv[1:]
    out = OUT
    if "--out" in args:  # never over an earlier look's figures
        i = args.index("--out")
        out = Path(args[i + 1])
        del args[i: i + 2]
    look, paths = args[0], args[1:]
    if look != "sweep":
        raise SystemExit(f"unknown look {look!r}; judged here: sweep")
    runs = [json.loads((Path(p) / "results.json").read_text()) for p in paths]
    print("\n".join(sweep(runs, out)))


if __name__ == "__main__":
    main()
