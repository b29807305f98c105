"""How far can the paper's premise go in this world? Bounds for the world v2 calibration's targets 1 and 3.

Two parts, both on explore and the oracle only (no learner):

1. **Lateness per context, analytically** (no simulation, a second). For each online round of the paper
   schedule: explore's and the oracle's "turn" lead at a speed, and the share of "turn" prompts that reach
   the driver only after its commit point (a swerve or a miss) or after the stop line (a miss), from the
   driver's per-prompt reaction time (lognormal, :meth:`pernav.world.drivers.Driver.reaction_draw`) and
   the one-second decision step (a prompt is said up to one step before its lead runs out).
2. **What the measured episodes allow** (from a ``calibration.json`` of ``docs/research/scripts/world_calibration.py``):
   the targets recomputed as if every late prompt that made the driver swerve had also ended in a
   collision, and as if it had also cost a missed turn (the paired cost of one missed turn, fitted on
   the same episodes). These are upper bounds for any mechanism that only gives late prompts worse
   consequences: it cannot make more prompts late.

Usage:
    git show 4cd6bc4:docs/figures/world_v2/judged/calibration.json > calibration.json  # the judged calibration
    .venv/bin/python docs/research/scripts/premise_bound.py OUT [--calibration calibration.json] [--speed 10] [--probe]

Without ``--calibration`` it reads the judged calibration where it lay before it was archived (``none``: part 1
only). The targets are those of docs/research/world_v2_preregistration.md.

Writes ``OUT/premise_bound.json`` and ``OUT/premise_bound.md``; refuses an existing ``OUT`` (exit 2).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from pathlib import Path

import numpy as np

from pernav.env.policies import PromptPolicy, explore_policy
from pernav.env.policies import late_share as p_late  # one home: the analytic lateness
from pernav.study.schedule import paper_schedule
from pernav.world.constants import audio_duration
from pernav.world.drivers import resolve

TURN = 1  # "turn left": audio durations of the two turns are equal
CALIBRATION = "docs/figures/world_v2/judged/calibration.json"


def lateness(speed: float = 10.0, extra: dict[str, float] | None = None) -> list[dict]:
    """Per online round: leads and late shares of explore and the oracle at ``speed`` m/s. ``extra``: seconds
    added to a named driver's decision time in every context (a what-if, e.g. ``{"user1": 0.5}``)."""
    ex = explore_policy()
    rows = []
    for e in paper_schedule():
        if e.phase != "online":
            continue
        c = e.context()
        d = resolve(e.profile(), c)
        if extra and e.driver in extra:
            d = dataclasses.replace(d, decision_time=d.decision_time + extra[e.driver])
        orc = PromptPolicy(d)
        commit = max(d.decision_time, 4.0 / speed)  # the driver chooses its branch this long before the line
        row = {"round": e.label, "driver": e.driver, "vehicle": c.vehicle, "camera": c.camera, "visual": c.visual,
               "equipment": c.equipment, "towns": e.towns or "all",
               "mean_need_s": audio_duration(TURN) + d.reaction_time + commit}
        for name, pol in (("explore", ex), ("oracle", orc)):
            lead = pol.turn_lead(speed) / speed
            row[f"{name}_lead_s"] = lead
            row[f"{name}_late_commit"] = p_late(d, lead, commit)
            row[f"{name}_late_line"] = p_late(d, lead, 0.0)
        rows.append(row)
    return rows


def population_lateness(n: int = 200, speed: float = 10.0) -> dict:
    """The same late shares for ``n`` drivers of the population prior (``population_samples``: profile fields
    uniform in their specified ranges, contexts uniform): how many of them explore's timing serves late."""
    from pernav.world.drivers import population_samples

    ex = explore_policy()
    excess = []
    for profile, context in population_samples(n):
        d = resolve(profile, context)
        commit = max(d.decision_time, 4.0 / speed)
        excess.append(p_late(d, ex.turn_lead(speed) / speed, commit)
                      - p_late(d, PromptPolicy(d).turn_lead(speed) / speed, commit))
    x = np.array(excess)
    return {"drivers": n, "late_5pct": float((x >= 0.05).mean()), "late_20pct": float((x >= 0.2).mean()),
            "median_excess": float(np.median(x))}


def late_cells(rows: list[dict], excess: float = 0.05, n_towns: int = 5) -> int:
    """(town, round) cells in which explore's "turn" prompts are late for the commit in at least ``excess``
    more of the prompts than the oracle's: the only cells where personal timing has late prompts to fix."""
    return sum(n_towns if r["towns"] == "all" else len(r["towns"])
               for r in rows if r["explore_late_commit"] - r["oracle_late_commit"] >= excess)


def _paired(episodes: list[dict]) -> dict[tuple, dict]:
    """``{(town, round label, seed, route): {"explore": episode, "oracle": episode}}`` where both drove it."""
    pairs: dict[tuple, dict] = {}
    for x in episodes:
        pairs.setdefault((x["town"], x["label"], x["seed"], x["route"]), {})[x["policy"]] = x
    return {k: v for k, v in pairs.items() if {"explore", "oracle"} <= set(v)}


def split(episodes: list[dict], rows: list[dict], excess: float = 0.05, routes: int = 10) -> dict:
    """Explore vs the oracle (paired) in the cells where explore is late (as :func:`late_cells` counts them) and
    in the others: collisions per route set, their ratio and paired CI, tracking's paired CI, cells 10 % cheaper."""
    from pernav.study.stats import paired_difference

    late = {r["round"] for r in rows if r["explore_late_commit"] - r["oracle_late_commit"] >= excess}
    pairs = _paired(episodes)
    out = {}
    for name, want in (("late", True), ("on time", False)):
        keys = [k for k in pairs if (k[1] in late) == want]
        if not keys:
            continue
        get = {p: {f: np.array([pairs[k][p][f] for k in keys]) for f in ("collisions", "tracking_cost")}
               for p in ("explore", "oracle")}
        cells = sorted({k[:2] for k in keys})
        cheaper = 0
        for cell in cells:
            idx = [i for i, k in enumerate(keys) if k[:2] == cell]
            cheaper += get["oracle"]["tracking_cost"][idx].mean() <= 0.9 * get["explore"]["tracking_cost"][idx].mean()
        ec, oc = get["explore"]["collisions"], get["oracle"]["collisions"]
        per_town = {}
        for town in sorted({k[0] for k in keys}):
            idx = [i for i, k in enumerate(keys) if k[0] == town]
            per_town[town] = {"explore_collisions_per_route_set": float(ec[idx].mean() * routes),
                              "oracle_collisions_per_route_set": float(oc[idx].mean() * routes),
                              "tracking_diff_ci": paired_difference(get["explore"]["tracking_cost"][idx],
                                                                    get["oracle"]["tracking_cost"][idx])}
        out[name] = {"cells": len(cells), "episodes": len(keys), "per_town": per_town,
                     "explore_collisions_per_route_set": float(ec.mean() * routes),
                     "oracle_collisions_per_route_set": float(oc.mean() * routes),
                     "oracle_over_explore": float(oc.sum() / max(ec.sum(), 1e-9)),
                     "collisions_diff_ci": paired_difference(ec, oc),
                     "tracking_diff_ci": paired_difference(get["explore"]["tracking_cost"], get["oracle"]["tracking_cost"]),
                     "cells_oracle_10pct_cheaper": int(cheaper)}
    return out


def bounds(episodes: list[dict], routes: int = 10) -> dict:
    """Targets 1-3 from the episodes as they are, and with every swerve also a collision (and a missed
    turn at the fitted paired cost of one)."""
    pairs = _paired(episodes)
    keys = list(pairs)
    dc = np.array([pairs[k]["explore"]["tracking_cost"] - pairs[k]["oracle"]["tracking_cost"] for k in keys])
    dm = np.array([pairs[k]["explore"]["missed_turns"] - pairs[k]["oracle"]["missed_turns"] for k in keys])
    per_miss = float((dc * dm).sum() / max((dm * dm).sum(), 1e-9))  # least squares through the origin
    towns = sorted({k[0] for k in keys})
    out = {"cost_per_missed_turn": per_miss}
    for mode in ("as measured", "every swerve a collision", "every swerve a collision and a missed turn"):
        col_swerve = mode != "as measured"
        miss_swerve = mode.endswith("missed turn")
        per_town, cells, n_cells, total = {}, 0, 0, {"explore": 0.0, "oracle": 0.0}
        for town in towns:
            rounds = sorted({k[1] for k in keys if k[0] == town})
            col = {"explore": 0.0, "oracle": 0.0}
            for rnd in rounds:
                cell = [pairs[k] for k in keys if k[0] == town and k[1] == rnd]
                cost = {}
                for p in col:
                    sw = np.mean([c[p]["swerves"] for c in cell])
                    total[p] += sum(c[p]["collisions"] + (c[p]["swerves"] if col_swerve else 0.0) for c in cell)
                    col[p] += np.mean([c[p]["collisions"] for c in cell]) + (sw if col_swerve else 0.0)
                    cost[p] = np.mean([c[p]["tracking_cost"] for c in cell]) + (per_miss * sw if miss_swerve else 0.0)
                cells += cost["oracle"] <= 0.9 * cost["explore"]
                n_cells += 1
            per_town[town] = {p: float(v / len(rounds) * routes) for p, v in col.items()}
        ex = np.array([v["explore"] for v in per_town.values()])
        out[mode] = {"per_town": per_town, "explore_mean": float(ex.mean()),
                     "oracle_over_explore": float(total["oracle"] / max(total["explore"], 1e-9)),
                     "cells_oracle_10pct_cheaper": int(cells), "cells": int(n_cells)}
    return out


def swerve_probe(towns: tuple[str, ...] = ("Town1", "Town3"), rounds: tuple[int, ...] = (4, 8), routes: int = 5,
                 seed: int = 1000) -> list[dict]:
    """Where explore's late prompts make the driver swerve: distance to the stop line, speed, the follower's
    gap, and the collisions and kerb strikes in the 6 s after (development seed; the calibration's seeding).
    It watches ``DriverCar.commit`` for late re-commits, a read-only wrapper restored afterwards."""
    from pernav.env.episodes import run_episode
    from pernav.env.navigation import NavigationEnv
    from pernav.world import driver_car

    online = [e for e in paper_schedule() if e.phase == "online"]
    seen: list[dict] = []
    original = driver_car.DriverCar.commit

    def watched(car, node, now, late=False):
        if late:
            f = car.world.follower
            seen.append({"t": now, "speed": float(car.speed),
                         "to_line": float(car.world.town.lane(car.path[0]).length - car.s),
                         "follower_gap": None if f is None else float(np.linalg.norm(f.position - car.position))})
        return original(car, node, now, late)

    out = []
    driver_car.DriverCar.commit = watched
    try:
        for town in towns:
            env = NavigationEnv(town, config={"n_traffic": 8})
            for i in rounds:
                e = online[i]
                if e.towns and town not in e.towns:
                    continue
                for r in range(routes):
                    seen.clear()
                    run_episode(env, "explore", r, 10000 * seed + 100 * i + r,
                                options={"user": e.profile(), "context": e.context()})
                    log = env.world.events.log
                    for sw in seen:
                        after = [k for k, t in log if k in ("collision", "edge") and sw["t"] <= t <= sw["t"] + 6.0]
                        out.append({"town": town, "round": i, "route": r, **sw, "after": after})
    finally:
        driver_car.DriverCar.commit = original
    return out


def report(rows: list[dict], b: dict | None, speed: float, probe: list[dict] | None = None,
           parts: dict | None = None, population: dict | None = None) -> str:
    lines = [f"## Late \"turn\" prompts per online round (speed {speed:g} m/s)", "",
             "| round | driver | vehicle, camera, visual, equipment | need (mean, s) | lead explore / oracle (s) | "
             "explore late for the commit | oracle late for the commit | explore after the line |",
             "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['round']} | {r['driver']} | {r['vehicle']}, {r['camera']}, {r['visual']}, "
                     f"{r['equipment']} | {r['mean_need_s']:.2f} | {r['explore_lead_s']:.2f} / "
                     f"{r['oracle_lead_s']:.2f} | {r['explore_late_commit']:.1%} | {r['oracle_late_commit']:.1%} | "
                     f"{r['explore_late_line']:.1%} |")
    n = sum(5 if r["towns"] == "all" else len(r["towns"]) for r in rows)
    what_if = {x: late_cells(lateness(speed, {"user1": x})) for x in (0.2, 0.4, 0.5, 1.0)}
    lines += ["", f"Cells (town, round) where explore is late for the commit in at least 5 % more prompts than "
              f"the oracle: **{late_cells(rows)} of {n}**. If user1 needed more time before its commit in every "
              "context: " + ", ".join(f"+{x:g} s: {c}" for x, c in what_if.items()) + "."]
    if population is not None:
        lines += ["", f"Of {population['drivers']} drivers of the population prior (profiles uniform in their ranges, "
                  f"contexts uniform), explore is late for the commit in at least 5 % more prompts than the oracle for "
                  f"**{population['late_5pct']:.0%}**, in at least 20 % more for {population['late_20pct']:.0%} "
                  f"(median excess {population['median_excess']:.0%})."]
    if b is not None:
        lines += ["", "## Upper bounds from the measured episodes", "",
                  f"Paired cost of one missed turn (explore − oracle, fitted): {b['cost_per_missed_turn']:.0f}.", "",
                  "| as if | explore collisions / route set, mean (per town) | oracle / explore collisions | "
                  "oracle ≥ 10 % cheaper (cells) |", "|---|---|---|---|"]
        for mode, v in b.items():
            if mode == "cost_per_missed_turn":
                continue
            towns = ", ".join(f"{t} {x['explore']:.2f}" for t, x in v["per_town"].items())
            lines.append(f"| {mode} | {v['explore_mean']:.2f} ({towns}) | {v['oracle_over_explore']:.0%} | "
                         f"{v['cells_oracle_10pct_cheaper']} of {v['cells']} |")
    if parts:
        lines += ["", "## Explore vs the oracle where explore is late and where it is on time (measured episodes)", "",
                  "| cells | episodes | collisions / route set explore / oracle | oracle / explore | explore − oracle "
                  "collisions per episode [95 % CI] | explore − oracle tracking [95 % CI] | oracle ≥ 10 % cheaper |",
                  "|---|---|---|---|---|---|---|"]
        for name, v in parts.items():
            c, t = v["collisions_diff_ci"], v["tracking_diff_ci"]
            lines.append(f"| {name} ({v['cells']}) | {v['episodes']} | {v['explore_collisions_per_route_set']:.2f} / "
                         f"{v['oracle_collisions_per_route_set']:.2f} | {v['oracle_over_explore']:.0%} | "
                         f"{c['mean']:+.3f} [{c['low']:+.3f}, {c['high']:+.3f}] | {t['mean']:+.1f} [{t['low']:+.1f}, "
                         f"{t['high']:+.1f}] | {v['cells_oracle_10pct_cheaper']} of {v['cells']} |")
        for name, v in parts.items():
            towns = []
            for town, x in v["per_town"].items():
                t = x["tracking_diff_ci"]
                towns.append(f"{town} {x['explore_collisions_per_route_set']:.2f} / "
                             f"{x['oracle_collisions_per_route_set']:.2f}, "
                             f"{t['mean']:+.0f} [{t['low']:+.0f}, {t['high']:+.0f}]")
            lines += ["", f"Per town, explore {name} (collisions per route set explore / oracle; explore − oracle "
                      "tracking [95 % CI]): " + "; ".join(towns) + "."]
    if probe:
        d = np.array([p["to_line"] for p in probe])
        v = np.array([p["speed"] for p in probe])
        hit = sum(bool(p["after"]) for p in probe)
        need = np.median(np.maximum(v**2 - 6.5**2, 0.0) / (2 * np.maximum(d, 1.0)))
        lines += ["", "## Where explore's swerves happen (development seed)", "",
                  f"{len(probe)} swerves: {d.min():.0f}-{d.max():.0f} m before the stop line (median {np.median(d):.0f}), "
                  f"at {v.min():.1f}-{v.max():.1f} m/s; braking to 6.5 m/s needs a median {need:.1f} m/s²; "
                  f"a collision or kerb strike within 6 s after {hit} of them."]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out")
    parser.add_argument("--calibration", default=CALIBRATION, help="a calibration.json; 'none' to skip part 2")
    parser.add_argument("--speed", type=float, default=10.0, help="approach speed (m/s) of part 1")
    parser.add_argument("--probe", action="store_true",
                        help="also drive explore in Town1 and Town3, rounds 4 and 8, five routes, seed 1000 (40 s) "
                             "and report where its swerves happen")
    args = parser.parse_args(argv)
    out = Path(args.out)
    if out.exists():
        print(f"error: {out} exists; choose another OUT", file=sys.stderr)
        return 2
    if not args.speed > 0:
        print(f"error: --speed must be > 0 m/s, got {args.speed}", file=sys.stderr)
        return 2
    b = None
    if args.calibration != "none":
        path = Path(args.calibration)
        if not path.is_file():
            print(f"error: --calibration {path} is not a file (a calibration.json of "
                  "recipes/world_calibration.py, or 'none')", file=sys.stderr)
            return 2
        episodes = json.loads(path.read_text())["episodes"]
        b = bounds(episodes)
    rows = lateness(args.speed)
    parts = split(episodes, rows) if b is not None else None
    probe = swerve_probe() if args.probe else None
    population = population_lateness(200, args.speed)
    out.mkdir(parents=True)
    doc = {"speed": args.speed, "calibration": args.calibration, "lateness": rows, "late_cells": late_cells(rows),
           "population": population, "bounds": b, "split": parts, "swerve_probe": probe}
    (out / "premise_bound.json").write_text(json.dumps(doc, indent=1))
    text = report(rows, b, args.speed, probe, parts, population)
    (out / "premise_bound.md").write_text(text)
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
