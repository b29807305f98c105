"""``adapt_driver``'s pre-registered looks (``preregistered/adapt_driver.yaml``), judged against the targets written
there before any of them ran. Each look is run once on its seeds; a further look is a new entry in the file with its
reason. The sweep (the ``personal_sweep`` preset, the average driver with its reaction time shifted):

    for s in 230 231 232 233; do pernav study --preset personal_sweep --seed $s \
        --methods explore timing belief adapt_driver oracle --out runs/look_sweep_s$s --workers 2; done
    .venv/bin/python -m recipes.benchmarks.adapt_driver_judge sweep runs/look_sweep_s23*

writes ``docs/figures/adapt_driver/look_sweep.json`` and ``look_sweep_leads.png`` (``--out DIR``: elsewhere) and
prints the figures and whether each target is met. A paper look (the ``paper`` preset, one study per town; the
registration's latest, ``third_look``, seed 2):

    for t in Town1 Town2 Town3 Town4 Town5; do pernav study --preset paper --towns $t --seed 2 \
        --methods explore adapt_driver --out runs/look3_paper/$t --workers 2; done
    .venv/bin/python -m recipes.benchmarks.adapt_driver_judge paper --entry third_look --name look_paper_third \
        runs/look3_paper/Town*

writes ``docs/figures/adapt_driver/<name>.json`` (``--entry``: the registration's entry whose seeds and targets
judge, default ``first_look``; ``--name``: the file, default ``look_paper``).
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

from pernav.study.stats import paired_difference
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


def paper(runs: list[dict[str, Any]], look: dict[str, Any], out: Path = OUT, name: str = "look_paper"
          ) -> list[str]:
    """The paper look: in each town, explore minus ``adapt_driver`` per paired episode of the online rounds (95 %
    bootstrap CI, and as a share of explore's mean cost), missed turns and collisions over explore's, against
    ``look``'s targets (an entry of the registration)."""
    targets = look["targets"]
    towns: dict[str, Any] = {}
    for res in runs:
        cfg = res["config"]
        if cfg.get("preset") != "paper" or cfg.get("seed") not in look["seeds"]:
            raise ValueError(f"the paper look is registered on the paper preset, seeds {look['seeds']}; this run is "
                             f"{cfg.get('preset')!r} seed {cfg.get('seed')}")
        rows: dict[str, list[tuple[dict, dict]]] = {}
        for it in res["iterations"]:
            if it["phase"] != "online":
                continue
            for town, methods in it["towns"].items():
                if "adapt_driver" in methods and "explore" in methods:
                    rows.setdefault(town, []).extend(zip(methods["explore"]["episodes"],
                                                         methods["adapt_driver"]["episodes"], strict=True))
        for town, pairs in rows.items():
            if town in towns:
                raise ValueError(f"{town} is given twice")
            e_cost = [e["tracking_cost"] for e, _ in pairs]
            d = paired_difference(e_cost, [a["tracking_cost"] for _, a in pairs])
            mean_e = sum(e_cost) / len(e_cost)
            count = {k: (sum(int(a.get(k, 0)) for _, a in pairs), sum(int(e.get(k, 0)) for e, _ in pairs))
                     for k in ("missed_turns", "collisions", "wrong_turns", "edge_strikes")}
            incomplete = (sum(not a["completed"] for _, a in pairs), sum(not e["completed"] for e, _ in pairs))
            share = {k: d[k] / mean_e for k in ("mean", "low", "high")}
            collisions = paired_difference([a["collisions"] for _, a in pairs], [e["collisions"] for e, _ in pairs])
            # the mean "turn" lead where both drives said one (s before the junction): how early each prompts
            leads = [(a["turn_lead"], e["turn_lead"]) for e, a in pairs
                     if a.get("turn_lead") is not None and e.get("turn_lead") is not None]
            lead = [sum(x[i] for x in leads) / len(leads) if leads else None for i in (0, 1)]
            towns[town] = {"episodes": len(pairs), "explore_mean_cost": mean_e, "explore_minus_adapt_driver": d,
                           "as_share_of_explore": share, "adapt_driver_minus_explore_collisions": collisions,
                           "adapt_driver_vs_explore": {**count, "incomplete": incomplete, "turn_lead_mean": lead},
                           "verdict": {
                               "cost": {"target_ci_low": targets["cost"]["ci_low"], "ci_low": share["low"],
                                        "met": share["low"] > targets["cost"]["ci_low"]},
                               "missed_turns": {"target": targets["missed_turns"]["point"], "met": count["missed_turns"][0]
                                                <= targets["missed_turns"]["point"] * count["missed_turns"][1]},
                               "collisions": {"target": targets["collisions"]["point"], "met": count["collisions"][0]
                                              <= targets["collisions"]["point"] * count["collisions"][1]}}}
    out.mkdir(parents=True, exist_ok=True)
    (out / f"{name}.json").write_text(json.dumps({"look": name, "towns": towns}, indent=1) + "\n")
    lines = []
    for town, t in towns.items():
        d, s, c = t["explore_minus_adapt_driver"], t["as_share_of_explore"], t["adapt_driver_vs_explore"]
        hit = t["adapt_driver_minus_explore_collisions"]
        lines.append(f"{town} ({t['episodes']} paired episodes): explore - adapt_driver {d['mean']:+.1f} [{d['low']:+.1f}, "
                     f"{d['high']:+.1f}] per episode ({100 * s['mean']:+.1f} % [{100 * s['low']:+.1f} %, "
                     f"{100 * s['high']:+.1f} %] of explore's {t['explore_mean_cost']:.0f}); adapt_driver (explore): "
                     + ", ".join(f"{k} {a} ({b})" for k, (a, b) in c.items() if k != "turn_lead_mean")
                     + f"; collisions per episode {hit['mean']:+.3f} [{hit['low']:+.3f}, {hit['high']:+.3f}]; met: "
                     + ", ".join(f"{k} {'yes' if v['met'] else 'no'}" for k, v in t["verdict"].items()))
    return lines


def _fail(message: str) -> None:
    print(f"error: {message}", file=sys.stderr)
    raise SystemExit(2)


def main() -> None:
    args = sys.argv[1:]
    out = OUT
    if "--out" in args:  # never over an earlier look's figures
        i = args.index("--out")
        out = Path(args[i + 1])
        del args[i: i + 2]
    options = {"--name": "look_paper", "--entry": "first_look"}
    for flag in options:
        if flag in args:
            i = args.index(flag)
            options[flag] = args[i + 1]
            del args[i: i + 2]
    name, entry = options["--name"], options["--entry"]
    look, paths = args[0], args[1:]
    if look not in ("sweep", "paper"):
        _fail(f"unknown look {look!r}; judged here: sweep, paper")
    runs = [json.loads((Path(p) / "results.json").read_text()) for p in paths]
    if look == "sweep":
        print("\n".join(sweep(runs, out)))
        return
    looks = registration("adapt_driver")
    if entry not in looks or "paper" not in looks[entry]:
        _fail(f"the registration has no paper look {entry!r}; it has: "
              + ", ".join(k for k, v in looks.items() if "paper" in v))
    print("\n".join(paper(runs, looks[entry]["paper"], out, name)))


if __name__ == "__main__":
    main()
