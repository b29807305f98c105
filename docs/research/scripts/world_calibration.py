"""World calibration (world v2): explore vs the oracle over the paper schedule's online rounds.

Every (town, online round, route, seed) is driven twice on the same episode seed, once with explore and
once with the oracle (paired). Only these two rule policies are driven: no learner result enters a world
parameter. Writes ``OUT/calibration.json`` (every episode) and ``OUT/calibration.md`` (the table and the
targets of docs/research/world_v2_preregistration.md, each marked met or not).

Usage:
    .venv/bin/python docs/research/scripts/world_calibration.py OUT [--seeds 0 1 2] [--routes 10] [--towns ...]
        [--n-traffic N] [--workers 2] [--population | --average]

Episode seed of route r in round i with seed s: ``10000 * s + 100 * i + r``.

Example (seconds, one town, one route, two rounds):
    .venv/bin/python docs/research/scripts/world_calibration.py /tmp/cal --towns Town1 --routes 1 --rounds 2 --seeds 0
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from multiprocessing import get_context
from pathlib import Path

import numpy as np
from tqdm import tqdm

from pernav.env.episodes import run_episode
from pernav.env.navigation import NavigationEnv
from pernav.study.config import preset
from pernav.study.schedule import paper_schedule
from pernav.study.stats import paired_difference as paired_bootstrap_ci
from pernav.world.constants import TOWN_NAMES
from pernav.world.drivers import AVERAGE_CONTEXT, POPULATION_AVERAGE, population_samples

POLICIES = ("explore", "oracle")
EVENTS = ("swerves", "harsh_brakes", "forgotten", "discarded", "misunderstood", "ignored", "traffic_collisions")
_ENVS: dict = {}


def _drive(task: tuple) -> list[dict]:
    """Both policies on one episode (town, round, route, seed)."""
    town, i, label, profile, context, route, seed, n_traffic = task
    env = _ENVS.get((town, n_traffic))
    if env is None:
        env = _ENVS[(town, n_traffic)] = NavigationEnv(town, config={"n_traffic": n_traffic})
    options = {"user": profile, "context": context}
    ep_seed = 10000 * seed + 100 * i + route
    out = []
    for policy in POLICIES:
        m = run_episode(env, policy, route, ep_seed, options=options)
        ev = env.world.events
        out.append({"town": town, "round": i, "label": label, "seed": seed, "episode_seed": ep_seed,
                    "policy": policy, **{k: (bool(v) if k == "completed" else float(v)) for k, v in m.items()},
                    **{k: getattr(ev, k) for k in EVENTS}})
    return out


def tasks(towns: list[str], routes: int, seeds: list[int], n_traffic: int, rounds: int | None,
          average: bool, population: bool = False) -> list[tuple]:
    """The episodes of the calibration: online rounds of the paper schedule (or the average driver). With
    ``population`` the k-th online round's driver and context are the k-th draw of the population prior
    (``population_samples``, its fixed seed) instead of the schedule's, in the same towns."""
    if average:
        entries = [("average", POPULATION_AVERAGE.to_dict(), AVERAGE_CONTEXT.to_dict())]
    else:
        online = [e for e in paper_schedule() if e.phase == "online"]
        if population:
            draws = population_samples(len(online))
            entries = [(f"Population {k}", p.to_dict(), c.to_dict(), e.towns)
                       for k, (e, (p, c)) in enumerate(zip(online, draws, strict=True))]
        else:
            entries = [(e.label, e.profile().to_dict(), e.context().to_dict(), e.towns) for e in online]
    out = []
    for town in towns:
        i = 0
        for entry in entries:
            label, prof, ctx = entry[:3]
            if len(entry) > 3 and entry[3] is not None and town not in entry[3]:
                continue
            if rounds is not None and i >= rounds:
                break
            for s in seeds:
                for r in range(routes):
                    out.append((town, i, label, prof, ctx, r, s, n_traffic))
            i += 1
    return out


def summarize(episodes: list[dict], routes: int) -> dict:
    """Per-town and overall figures, and the pre-registered targets (met or not)."""
    def pairs(sel):
        e = {(x["town"], x["round"], x["seed"], x["route"]): x for x in sel if x["policy"] == "explore"}
        o = {(x["town"], x["round"], x["seed"], x["route"]): x for x in sel if x["policy"] == "oracle"}
        keys = sorted(e)
        return [e[k] for k in keys], [o[k] for k in keys]

    towns = sorted({x["town"] for x in episodes}, key=lambda t: TOWN_NAMES.index(t))
    per_town = {}
    cells_ok = cells = 0
    for town in towns:
        ex, orc = pairs([x for x in episodes if x["town"] == town])
        ec = np.array([x["collisions"] for x in ex])
        oc = np.array([x["collisions"] for x in orc])
        et = np.array([x["tracking_cost"] for x in ex])
        ot = np.array([x["tracking_cost"] for x in orc])
        rounds = sorted({x["round"] for x in ex})
        ok = 0
        for rnd in rounds:
            idx = [k for k, x in enumerate(ex) if x["round"] == rnd]
            if ot[idx].mean() <= 0.9 * et[idx].mean():
                ok += 1
        cells_ok += ok
        cells += len(rounds)
        per_town[town] = {
            "rounds": len(rounds), "episodes": len(ex),
            "explore_collisions_per_route_set": float(ec.mean() * routes),
            "oracle_collisions_per_route_set": float(oc.mean() * routes),
            "explore_vehicle_collisions": float(sum(x["vehicle_collisions"] for x in ex)),
            "explore_edge_strikes": float(sum(x["edge_strikes"] for x in ex)),
            "oracle_vehicle_collisions": float(sum(x["vehicle_collisions"] for x in orc)),
            "oracle_edge_strikes": float(sum(x["edge_strikes"] for x in orc)),
            "collisions_diff_ci": paired_bootstrap_ci(ec, oc),
            "explore_tracking": float(et.mean()), "oracle_tracking": float(ot.mean()),
            "tracking_diff_ci": paired_bootstrap_ci(et, ot),
            "cells_oracle_10pct_cheaper": ok,
            "explore_completion": float(np.mean([x["completed"] for x in ex])),
            "oracle_completion": float(np.mean([x["completed"] for x in orc])),
            "explore_missed_turns": float(sum(x["missed_turns"] for x in ex)),
            "oracle_missed_turns": float(sum(x["missed_turns"] for x in orc)),
        }
    ex, orc = pairs(episodes)
    ec = np.array([x["collisions"] for x in ex])
    oc = np.array([x["collisions"] for x in orc])
    mean_rs = float(np.mean([v["explore_collisions_per_route_set"] for v in per_town.values()]))
    ci = paired_bootstrap_ci(ec, oc)
    targets = {k: bool(v) for k, v in {
        "1_explore_collisions_mean_in_[1.5,4.5]": 1.5 <= mean_rs <= 4.5,
        "1_explore_collisions_every_town_>=0.5": all(v["explore_collisions_per_route_set"] >= 0.5
                                                      for v in per_town.values()),
        "2_oracle_at_most_half": oc.sum() <= 0.5 * ec.sum(),
        "2_collision_ci_clear_of_zero": ci["low"] > 0,
        "3_cells_>=60%": cells_ok >= 0.6 * max(cells, 1),
        "3_tracking_ci_clear_every_town": all(v["tracking_diff_ci"]["low"] > 0 for v in per_town.values()),
        "4_explore_completion_>=85%": float(np.mean([x["completed"] for x in ex])) >= 0.85,
    }.items()}
    return {"per_town": per_town, "explore_collisions_per_route_set_mean": mean_rs,
            "oracle_collisions_per_route_set_mean": float(np.mean(
                [v["oracle_collisions_per_route_set"] for v in per_town.values()])),
            "collisions_total": {"explore": float(ec.sum()), "oracle": float(oc.sum())},
            "collisions_diff_ci": ci, "cells_oracle_10pct_cheaper": cells_ok, "cells": cells,
            "explore_completion": float(np.mean([x["completed"] for x in ex])), "targets": targets}


def table(summary: dict) -> str:
    """The per-town table in Markdown."""
    paper = {"Town1": 3.08, "Town2": 1.00, "Town3": 1.38, "Town4": 4.00, "Town5": 2.89}
    lines = ["| town | rounds | explore collisions / route set (paper) | oracle | explore − oracle collisions "
             "[95 % CI] | tracking explore / oracle | explore − oracle [95 % CI] | oracle ≥ 10 % cheaper | "
             "completion explore / oracle | missed turns explore / oracle |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for town, v in summary["per_town"].items():
        c, t = v["collisions_diff_ci"], v["tracking_diff_ci"]
        lines.append(
            f"| {town} | {v['rounds']} | {v['explore_collisions_per_route_set']:.2f} ({paper[town]:.2f}) | "
            f"{v['oracle_collisions_per_route_set']:.2f} | {c['mean']:+.3f} [{c['low']:+.3f}, {c['high']:+.3f}] | "
            f"{v['explore_tracking']:.0f} / {v['oracle_tracking']:.0f} | {t['mean']:+.0f} [{t['low']:+.0f}, "
            f"{t['high']:+.0f}] | {v['cells_oracle_10pct_cheaper']} of {v['rounds']} | "
            f"{v['explore_completion']:.0%} / {v['oracle_completion']:.0%} | "
            f"{v['explore_missed_turns']:.0f} / {v['oracle_missed_turns']:.0f} |")
    s = summary
    lines += ["", f"Explore collisions per route set, mean over towns: **{s['explore_collisions_per_route_set_mean']:.2f}** "
              f"(paper 2.47); oracle {s['oracle_collisions_per_route_set_mean']:.2f}; totals "
              f"{s['collisions_total']['explore']:.0f} vs {s['collisions_total']['oracle']:.0f}, per episode "
              f"explore − oracle {s['collisions_diff_ci']['mean']:+.3f} [{s['collisions_diff_ci']['low']:+.3f}, "
              f"{s['collisions_diff_ci']['high']:+.3f}]; oracle ≥ 10 % cheaper in {s['cells_oracle_10pct_cheaper']} "
              f"of {s['cells']} cells; explore completion {s['explore_completion']:.1%}.", "",
              "| target | met |", "|---|---|"]
    lines += [f"| {k} | {'yes' if v else '**no**'} |" for k, v in s["targets"].items()]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--routes", type=int, default=10)
    parser.add_argument("--rounds", type=int, default=None, help="only the first N online rounds per town")
    parser.add_argument("--towns", nargs="+", default=list(TOWN_NAMES), choices=TOWN_NAMES)
    parser.add_argument("--n-traffic", type=int, default=preset("paper").n_traffic)
    parser.add_argument("--average", action="store_true",
                        help="the population-average driver in the average context instead of the schedule")
    parser.add_argument("--population", action="store_true",
                        help="each online round's driver and context drawn from the population prior instead of the "
                             "schedule's (exploration of another schedule; not the pre-registered judging set-up)")
    parser.add_argument("--workers", type=int, default=2)
    args = parser.parse_args(argv)
    if args.population and args.average:
        print("error: --population and --average exclude each other", file=sys.stderr)
        return 2
    out = Path(args.out)
    if (out / "calibration.json").exists():
        print(f"error: {out / 'calibration.json'} exists; choose another OUT", file=sys.stderr)
        return 2
    out.mkdir(parents=True, exist_ok=True)
    work = tasks(args.towns, args.routes, args.seeds, args.n_traffic, args.rounds, args.average, args.population)
    t0 = time.time()
    episodes: list[dict] = []
    if args.workers > 1:
        with get_context("fork").Pool(args.workers) as pool:
            for res in tqdm(pool.imap_unordered(_drive, work, chunksize=2), total=len(work), desc="episodes"):
                episodes.extend(res)
    else:
        for t in tqdm(work, desc="episodes"):
            episodes.extend(_drive(t))
    summary = summarize(episodes, args.routes)
    doc = {"args": vars(args), "seconds": time.time() - t0, "commit": os.popen("git rev-parse HEAD").read().strip(),
           "summary": summary, "episodes": episodes}
    tmp = out / "calibration.json.tmp"
    tmp.write_text(json.dumps(doc, indent=1))
    tmp.replace(out / "calibration.json")
    (out / "calibration.md").write_text(table(summary))
    print(table(summary))
    print(f"{len(work)} paired episodes in {time.time() - t0:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
