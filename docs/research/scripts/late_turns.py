"""Is a "turn" that takes effect too late to slow for swerved into, or given up? Data for ``adapt_driver``'s model.

The sixteenth session's hybrid model swerved into a late "turn" (one in effect after the driver committed to going
on, before the junction) only where the car could still slow to its turn speed by the junction braking hard
(``HARD_BRAKE`` x its braking); otherwise its car went on (a missed turn). Here the true simulator drives explore's
prompts each said ``delay`` steps later (so that turns come late) for population drivers the diagnostic's panel does
not hold, and every swerve and missed turn is counted; for each swerve, whether the car had that room at the start of
its step (its speed and distance to the junction then; the driver's own turn speed and comfortable braking, read
from the profile: a label of this offline check, never the model's input). Swerves without the room are late turns
the old rule called misses.

    .venv/bin/python docs/research/scripts/late_turns.py --towns Town4 Town1 --delays 1 2 3 --drivers 8
"""

from __future__ import annotations

import argparse
import json
from collections import deque

from pernav.env.navigation import NavigationEnv
from pernav.world.drivers import population_samples, resolve

HARD_BRAKE = 2.5  # the sixteenth session's model's multiple of the comfortable braking for a late turn


def drive_counts(town: str, profile, context, route: int, seed: int, delay: int) -> dict:
    """One drive of explore's prompts ``delay`` steps late: its swerves (with and without the room to slow) and
    missed turns."""
    env = NavigationEnv(town, config={"n_traffic": 2})
    _, info = env.reset(seed=seed, options={"route": route, "user": profile, "context": context})
    d = resolve(profile, context)
    said = deque([0] * delay)
    counts = {"swerves": 0, "swerves_without_room": 0, "missed": 0, "swerve_speeds": []}
    swerves, missed, done = 0, 0, False
    while not done:
        said.append(int(info["explore_action"]))
        v, dist = float(env.world.ego.speed), float(info["distance_to_junction"])
        _, _, terminated, truncated, info = env.step(said.popleft())
        done = terminated or truncated
        if env.world.events.swerves > swerves:
            room = (v**2 - d.turn_speed**2) / (2 * HARD_BRAKE * d.comfort_decel) <= dist
            counts["swerves"] += 1
            counts["swerves_without_room"] += int(not room)
            counts["swerve_speeds"].append(round(v, 1))
        counts["missed"] += int(info["missed_turns"]) - missed
        swerves, missed = env.world.events.swerves, int(info["missed_turns"])
    return counts


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--towns", nargs="+", default=["Town4", "Town1"])
    ap.add_argument("--delays", nargs="+", type=int, default=[1, 2, 3])
    ap.add_argument("--drivers", type=int, default=8, help="population drivers (a seed the panel does not use)")
    ap.add_argument("--routes", type=int, default=2)
    ap.add_argument("--json", default=None)
    args = ap.parse_args()
    drivers = population_samples(args.drivers, seed=4242)
    out = {}
    for town in args.towns:
        for delay in args.delays:
            total = {"swerves": 0, "swerves_without_room": 0, "missed": 0, "swerve_speeds": []}
            for i, (profile, context) in enumerate(drivers):
                for route in range(args.routes):
                    c = drive_counts(town, profile, context, route, 600 + 10 * i + route, delay)
                    for k in total:
                        total[k] += c[k]
            late = total["swerves"] + total["missed"]
            total["late_turns"] = late
            total["share_swerved_without_room"] = round(total["swerves_without_room"] / late, 3) if late else None
            out[f"{town} delay {delay}"] = total
            print(town, delay, json.dumps({k: v for k, v in total.items() if k != "swerve_speeds"}), flush=True)
    if args.json:
        with open(args.json, "w") as f:
            json.dump({"drivers": args.drivers, "routes": args.routes, "rows": out}, f, indent=1)


if __name__ == "__main__":
    main()
