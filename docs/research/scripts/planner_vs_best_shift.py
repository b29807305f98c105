"""Does the planner on the hybrid model, given a driver's *true* parameters, time the turn as best_shift does?

adapt_driver's acceptance asks that the re-timing planner on the true driver parameters choose what ``best_shift``
chooses on a constructed approach. The approach is the timing sweep's (Town1: straight through J11, right at J12,
no traffic; ``pernav.env.sweep``), driven by a slow and a quick profile, user3 in the truck in fog and user4 on the
keyboard (and the two extremes below) with every shift of explore's rule (``SHIFTS``), explore itself, and the planner
(``DRIVER_PLANNER``) on ``DriverParams`` read from the simulated driver (reaction and decision time, turn speed,
braking and acceleration; its cruise read from an explore drive of its own on another seed, as the learner reads it:
before the fifteenth session it was the model's default, 10 m/s, whatever the driver's), on the same seeds. Two
constructed extremes are added: a very slow driver (the slowest reaction and decision time, the fastest cruise, the
gentlest braking, in fog) and a very quick one (the quickest reaction and decision, the slowest cruise, the hardest
braking). Reading the profile is allowed here: this is a check of the model's structure, not a learner at round time.

Reports per driver the planner's mean "turn" lead minus explore's (s; a shift of k steps moves it by about k s), and,
for the tracking cost and for it without the step that arrives (``before_arrival_``: that step is charged the distance
the car overshoots the route's end by, 0-35 here): each shift's mean and its 95 % bootstrap CI, the best shift, the
planner's cost; and, paired by seed, explore minus the best shift (where its CI includes 0 the approach cannot tell
the best shift from explore's rule) and explore minus the planner.

    .venv/bin/python docs/research/scripts/planner_vs_best_shift.py --seeds 10 [--step-cap 10] --json out.json
"""

from __future__ import annotations

import argparse
import json
import statistics

from pernav.env.sweep import sweep_route
from pernav.env.torchrl_env import explore_module
from pernav.learners.driver import read_response
from pernav.model.driver import DriverImaginedEnv, DriverParams
from pernav.planner.factory import env_planning_config
from pernav.planner.retiming import Departure, RetimingPlanner, ShiftedExplore
from pernav.study.driver_rounds import DRIVER_PLANNER, SHIFTS
from pernav.study.stats import bootstrap_ci, paired_difference
from pernav.trainer.collect import drive, episode_metrics, history_env
from pernav.world.drivers import Context, DriverProfile, named_user, resolve

OPTIONS = {k: v for k, v in DRIVER_PLANNER.items() if k != "departure"}
CONFIG = {"n_traffic": 0, **env_planning_config({"kind": "retime", **OPTIONS})}
DRIVERS = {"slow": (DriverProfile(reaction_time=2.4, decision_time=2.0), Context(visual="foggy")),
           "quick": (DriverProfile(reaction_time=0.6, decision_time=1.5), Context()),
           "user3_truck_fog": (named_user("user3"), Context(vehicle="cybertruck", visual="foggy")),
           "user4_keyboard": (named_user("user4"), Context(equipment="keyboard")),
           "very_slow": (DriverProfile(reaction_time=2.5, speed_factor=1.15, decision_time=3.0, memory=30.0,
                                       comfort_decel=1.5), Context(visual="foggy")),
           "very_quick": (DriverProfile(reaction_time=0.5, speed_factor=0.8, decision_time=1.0, memory=8.0,
                                        comfort_decel=5.0), Context())}
CRUISE_SEED = 10_000  # the drive the cruise is read from: none of the evaluation's seeds


def true_params(profile: DriverProfile, context: Context) -> DriverParams:
    """The hybrid model's parameters as the simulated driver has them; its cruise read from a drive of its own."""
    d = resolve(profile, context)
    env = history_env("Town1", {"route": sweep_route(), "user": profile, "context": context}, config=CONFIG,
                      seed=CRUISE_SEED)
    return DriverParams(reaction_time=d.reaction_time, decision_time=d.decision_time, turn_speed=d.turn_speed,
                        brake=d.comfort_decel, accel=d.comfort_accel,
                        cruise=read_response(drive(env, explore_module())).cruise)


def _paired(baseline: list[float], method: list[float]) -> dict[str, float]:
    d = paired_difference(baseline, method)
    return {"mean": round(d["mean"], 1), "ci": [round(d["low"], 1), round(d["high"], 1)]}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=10)
    parser.add_argument("--first-seed", type=int, default=0, help="the seeds are first-seed .. first-seed + seeds - 1")
    parser.add_argument("--drivers", nargs="+", default=list(DRIVERS), choices=list(DRIVERS))
    parser.add_argument("--step-cap", type=float, default=None,
                        help="the planner's RetimingPlanner.step_cap (each imagined step's charge capped)")
    parser.add_argument("--margin", type=float, default=None,
                        help="the planner's absolute departure margin (default: DRIVER_PLANNER's)")
    parser.add_argument("--json", default=None)
    args = parser.parse_args()
    departure = {**DRIVER_PLANNER["departure"], **({} if args.margin is None else {"margin": args.margin})}
    route, seeds, report = sweep_route(), range(args.first_seed, args.first_seed + args.seeds), {}
    for name in args.drivers:
        profile, context = DRIVERS[name]
        def run(policy, seed: int, profile=profile, context=context) -> dict:
            env = history_env("Town1", {"route": route, "user": profile, "context": context}, config=CONFIG,
                              seed=seed)
            trajectory = drive(env, policy)
            # the step that arrives is charged the distance the car overshoots the route's end by (the goal is
            # clamped there): on this short approach it decides many comparisons, so both figures are reported
            return {**episode_metrics(trajectory),
                    "before_arrival": float(-trajectory["next", "reward"].reshape(-1)[:-1].sum())}

        shifted = {k: [run(ShiftedExplore(k), s) for s in seeds] for k in SHIFTS}
        explore = [run(explore_module(), s) for s in seeds]
        planner = RetimingPlanner(DriverImaginedEnv([true_params(profile, context)]),
                                  departure=Departure(**departure), **OPTIONS)
        planner.step_cap = args.step_cap
        planned = [run(planner, s) for s in seeds]
        leads = [p["turn_lead"] - e["turn_lead"] for p, e in zip(planned, explore, strict=True)
                 if p["turn_lead"] is not None and e["turn_lead"] is not None]
        report[name] = {"planner_lead_minus_explore_s": round(statistics.mean(leads), 2) if leads else None}
        for key, label in (("tracking_cost", ""), ("before_arrival", "before_arrival_")):
            shifts = {k: [m[key] for m in runs] for k, runs in shifted.items()}
            best = min(SHIFTS, key=lambda k, shifts=shifts: (statistics.mean(shifts[k]), abs(k)))
            report[name].update({
                f"{label}shift_costs": {str(k): {"mean": round(statistics.mean(c), 1),
                                                 "ci": [round(x, 1) for x in bootstrap_ci(c)[1:]]}
                                        for k, c in shifts.items()},
                f"{label}best_shift": best,
                f"{label}planner_cost": round(statistics.mean(p[key] for p in planned), 1),
                f"{label}explore_cost": round(statistics.mean(e[key] for e in explore), 1),
                # paired by seed: > 0 where the best shift (the planner) is cheaper than explore's rule
                f"{label}explore_minus_best_shift": _paired([e[key] for e in explore], shifts[best]),
                f"{label}explore_minus_planner": _paired([e[key] for e in explore], [p[key] for p in planned])})
        print(name, json.dumps(report[name]))
    if args.json:
        with open(args.json, "w") as f:
            json.dump({"seeds": args.seeds, "first_seed": args.first_seed, "step_cap": args.step_cap,
                       "margin": departure["margin"], "drivers": report}, f, indent=1)


if __name__ == "__main__":
    main()
