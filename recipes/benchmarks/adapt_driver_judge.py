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
judge, default ``first_look``; ``--name``: the file, default ``look_paper``). The split and the headroom looks (the
``split`` and ``personal`` presets; slow drivers are the late cells, quick ones the on-time cells):

    for s in $(seq 148 163); do pernav study --preset split --seed $s \
        --methods explore timing belief adapt_driver best_shift oracle --out runs/look_split/seed$s --workers 2; done
    .venv/bin/python -m recipes.benchmarks.adapt_driver_judge split runs/look_split/seed*
    for s in $(seq 320 325); do pernav study --preset personal --seed $s \
        --methods explore timing belief adapt_driver best_shift oracle --out runs/look_headroom/seed$s --workers 2; done
    .venv/bin/python -m recipes.benchmarks.adapt_driver_judge headroom runs/look_headroom/seed*

write ``look_split.json`` and ``look_headroom.json`` beside the paper looks' (``--name``: another file).
"""

from __future__ import annotations

import functools
import json
import sys
from pathlib import Path
from typing import Any

from pernav.study.benchmarks import classify, episodes, personal_schedule, split_schedule
from pernav.study.stats import gap_closed, paired_difference, paired_ratio
from recipes.benchmarks import follow
from recipes.benchmarks.registered import registration

OUT = Path("docs/figures/adapt_driver")
SWEEP_METHODS = ("explore", "timing", "belief", "adapt_driver", "oracle")
#: the split and headroom looks: the preset each runs and the schedule its cells (and their classes) come from
PERSONAL_LOOKS = {"split": ("split", split_schedule), "headroom": ("personal", personal_schedule)}
#: the methods every episode of a split or headroom look must have driven
PERSONAL_METHODS = ("explore", "timing", "belief", "adapt_driver", "best_shift")


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
    pooled: dict[str, list[tuple[dict, dict]]] = {}  # town -> pairs over the runs (seeds), where the look pools them
    given: set[tuple[str, Any]] = set()
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
            # a look with ``pool`` judges a town's episodes over its seeds together; otherwise one run per town
            if (town, cfg.get("seed")) in given or (town in pooled and not look.get("pool")):
                raise ValueError(f"{town} is given twice" + ("" if look.get("pool") else " (this look pools no seeds)"))
            given.add((town, cfg.get("seed")))
            pooled.setdefault(town, []).extend(pairs)
    for town, pairs in pooled.items():
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
        # how much adapt_driver leaves explore (its share of steps), and what the episodes where it did cost: the
        # others are explore's own drive, paired exactly
        departed = [e["tracking_cost"] - a["tracking_cost"] for e, a in pairs if a.get("left_explore", 0) > 0]
        departures = {"left_explore_mean": sum(a.get("left_explore", 0) for _, a in pairs) / len(pairs),
                      "episodes": len(departed),
                      "explore_minus_adapt_driver_mean": sum(departed) / len(departed) if departed else None}
        towns[town] = {"episodes": len(pairs), "explore_mean_cost": mean_e, "explore_minus_adapt_driver": d,
                       "departures": departures,
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


def personal(runs: list[dict[str, Any]], bench: str, look: dict[str, Any], targets: dict[str, Any],
             out: Path = OUT, name: str | None = None) -> list[str]:
    """The split or headroom look (``bench``) of ``adapt_driver`` against ``targets``, on the paired episodes that
    every method of :data:`PERSONAL_METHODS` drove on ``look``'s seeds: over all drivers, its cost over the cheaper
    of belief and timing (the one whose mean over these episodes is lower, chosen once for the whole look); on the
    quick drivers' (on-time) cells its cost over explore's; on the slow drivers' (late) cells the share of explore's
    cost above ``best_shift``'s that it removes; collisions over explore's (paired 95 % bootstrap CIs). Writes
    ``<out>/look_<bench>.json`` (or ``<name>.json``)."""
    preset = PERSONAL_LOOKS[bench][0]
    seeds, towns = set(), set()
    for res in runs:
        cfg = res["config"]
        if cfg.get("preset") != preset or cfg.get("seed") not in look["seeds"]:
            raise ValueError(f"the {bench} look is registered on the {preset} preset, seeds {look['seeds']}; this run "
                             f"is {cfg.get('preset')!r} seed {cfg.get('seed')}")
        seeds.add(cfg["seed"])
        towns.update(cfg["towns"])
    if sorted(seeds) != sorted(look["seeds"]):
        raise ValueError(f"the {bench} look is registered on seeds {look['seeds']}; these runs are {sorted(seeds)}")
    late = _classes(bench, tuple(sorted(towns)))
    pairs = {k: v for k, v in episodes(runs).items() if (k[1], k[2]) in late and set(PERSONAL_METHODS) <= set(v)}

    def keys(want: bool | None) -> list[tuple]:
        return sorted(k for k in pairs if want is None or late[(k[1], k[2])] == want)

    def values(ks: list[tuple], method: str, field: str = "tracking_cost") -> list[float]:
        return [float(pairs[k][method][field]) for k in ks]

    every, quick, slow = keys(None), keys(False), keys(True)
    if not (quick and slow):
        raise ValueError(f"the {bench} look needs episodes of every method {PERSONAL_METHODS} in both classes of cell")
    means = {m: sum(values(every, m)) / len(every) for m in ("belief", "timing")}
    best = min(means, key=means.__getitem__)
    figures: dict[str, Any] = {
        "look": name or f"look_{bench}", "seeds": sorted(seeds), "towns": sorted(towns),
        "episodes": {"all": len(every), "quick": len(quick), "slow": len(slow)},
        # the oracle is a further reference where the runs drove it (the targets do not use it)
        "mean_cost": {c: {m: sum(values(ks, m)) / len(ks) for m in (*PERSONAL_METHODS, "oracle")
                          if all(m in pairs[k] for k in ks)}
                      for c, ks in (("all", every), ("quick", quick), ("slow", slow))},
        "cheaper_learner": best,
        "all_over_learner": {m: paired_ratio(values(every, "adapt_driver"), values(every, m)) for m in means},
        "quick_over_explore": paired_ratio(values(quick, "adapt_driver"), values(quick, "explore")),
        "slow_best_shift_gain": paired_difference(values(slow, "explore"), values(slow, "best_shift")),
        "slow_gap_closed": gap_closed(values(slow, "explore"), values(slow, "adapt_driver"),
                                      values(slow, "best_shift")),
        "collisions": {"adapt_driver": sum(values(every, "adapt_driver", "collisions")),
                       "explore": sum(values(every, "explore", "collisions")),
                       "adapt_driver_minus_explore": paired_difference(values(every, "adapt_driver", "collisions"),
                                                                       values(every, "explore", "collisions"))},
        "per_town": {t: {"slow_gap_closed": gap_closed(*(values([k for k in slow if k[1] == t], m)
                                                         for m in ("explore", "adapt_driver", "best_shift"))),
                         "quick_over_explore": paired_ratio(*(values([k for k in quick if k[1] == t], m)
                                                              for m in ("adapt_driver", "explore")))}
                     for t in sorted(towns)}}
    a, q, g = figures["all_over_learner"][best], figures["quick_over_explore"], figures["slow_gap_closed"]
    hit = figures["collisions"]["adapt_driver_minus_explore"]
    t = targets
    figures["verdict"] = {
        "all_against_best_learner": {"target": t["all_against_best_learner"]["point"],
                                     "target_ci_high": t["all_against_best_learner"]["ci_high"],
                                     "met": a["mean"] <= t["all_against_best_learner"]["point"]
                                     and a["high"] <= t["all_against_best_learner"]["ci_high"]},
        "quick_cost_ratio": {"target": t["quick_cost_ratio"]["point"],
                             "met": q["mean"] <= t["quick_cost_ratio"]["point"]},
        "slow_gap_to_best_shift": {"target": t["slow_gap_to_best_shift"]["point"],
                                   "target_ci_low": t["slow_gap_to_best_shift"]["ci_low"],
                                   # NaN (best_shift no cheaper than explore on the slow cells) meets nothing
                                   "met": bool(g["mean"] >= t["slow_gap_to_best_shift"]["point"]
                                               and g["low"] > t["slow_gap_to_best_shift"]["ci_low"])},
        "collisions": {"met": hit["low"] <= 0.0}}
    out.mkdir(parents=True, exist_ok=True)
    (out / f"{figures['look']}.json").write_text(json.dumps(figures, indent=1) + "\n")

    def ci(x: dict[str, float], scale: float = 1.0, fmt: str = "{:.3f}") -> str:
        m, lo, hi = (fmt.format(x[k] * scale) for k in ("mean", "low", "high"))
        return f"{m} [{lo}, {hi}]"

    other = "timing" if best == "belief" else "belief"
    lines = [f"{bench}: seeds {min(seeds)}-{max(seeds)} ({len(seeds)}), {len(every)} paired episodes "
             f"({len(quick)} quick, {len(slow)} slow)",
             f"all drivers: adapt_driver / {best} (the cheaper) {ci(a)}; adapt_driver / {other} "
             f"{ci(figures['all_over_learner'][other])}",
             f"quick drivers: adapt_driver / explore {ci(q)}",
             f"slow drivers: explore - best_shift {ci(figures['slow_best_shift_gain'], 1, '{:+.1f}')} per episode; "
             f"gap closed by adapt_driver {ci(g, 100, '{:.0f}')} %",
             f"collisions: adapt_driver {figures['collisions']['adapt_driver']:.0f}, explore "
             f"{figures['collisions']['explore']:.0f}; per episode {ci(hit, 1, '{:+.3f}')}"]
    for town, f in figures["per_town"].items():
        lines.append(f"  {town}: slow gap closed {ci(f['slow_gap_closed'], 100, '{:.0f}')} %, quick adapt_driver / "
                     f"explore {ci(f['quick_over_explore'])}")
    lines += [f"{k}: {'met' if v['met'] else 'not met'}" for k, v in figures["verdict"].items()]
    return lines


@functools.lru_cache(maxsize=4)
def _classes(bench: str, towns: tuple[str, ...]) -> dict[tuple[str, str], bool]:
    """``{(town, round): late}`` of a split or headroom look's cells (simulates each driver's lateness: seconds)."""
    return {(c["town"], c["round"]): c["late"] for c in classify(PERSONAL_LOOKS[bench][1](), list(towns))}


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
    if not args:
        _fail("name a look (sweep, paper, split, headroom) and its runs")
    look, paths = args[0], args[1:]
    if look not in ("sweep", "paper", *PERSONAL_LOOKS):
        _fail(f"unknown look {look!r}; judged here: sweep, paper, split, headroom")
    runs = [json.loads((Path(p) / "results.json").read_text()) for p in paths]
    if look == "sweep":
        print("\n".join(sweep(runs, out)))
        return
    looks = registration("adapt_driver")
    if look in PERSONAL_LOOKS:
        if look not in looks[entry]:
            _fail(f"the registration's entry {entry!r} has no {look} look")
        try:
            print("\n".join(personal(runs, look, looks[entry][look], looks[entry]["targets"], out,
                                     None if options["--name"] == "look_paper" else name)))
        except ValueError as e:  # runs that are not the registered look: say which, no traceback
            _fail(str(e))
        return
    if entry not in looks or "paper" not in looks[entry]:
        _fail(f"the registration has no paper look {entry!r}; it has: "
              + ", ".join(k for k, v in looks.items() if "paper" in v))
    print("\n".join(paper(runs, looks[entry]["paper"], out, name)))


if __name__ == "__main__":
    main()
