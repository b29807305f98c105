"""Is a "turn" that takes effect too late to slow for swerved into, or given up? Data for ``adapt_driver``'s model.

The sixteenth session's hybrid model swerved into a late "turn" (one in effect after the driver committed to going
on, before the junction) only where the car could still slow to its turn speed by the junction braking hard
(``HARD_BRAKE`` x its braking); otherwise its car went on (a missed turn). Here the true simulator drives explore's
prompts each said ``delay`` steps later (so that turns come late) for population drivers the diagnostic's panel does
not hold, and every swerve and missed turn is counted. Swerves and misses after a "turn" in effect before the junction
(for a miss, the moment the car reached it estimated from the step before: distance over speed) are split by whether
the driver had committed (its decision time at its speed before the junction) and the car had that room when the
"turn" took effect (the simulator's record of when a heard prompt acts; the car's
speed and distance then, extrapolated from its step's start; the driver's own turn speed and comfortable braking from
the profile: labels of this offline check, never the model's input). The old rule said "swerve" with the room and
"miss" without; the seventeenth session's says "swerve" for every one of them.

    .venv/bin/python docs/research/scripts/late_turns.py --towns Town4 Town1 --delays 1 2 3 --drivers 8
"""

from __future__ import annotations

import argparse
import json
from collections import deque

from pernav.env.navigation import NavigationEnv
from pernav.learners.answers import record_hearing
from pernav.world.constants import TURNS
from pernav.world.drivers import population_samples, resolve

HARD_BRAKE = 2.5  # the sixteenth session's model's multiple of the comfortable braking for a late turn


def drive_counts(town: str, profile, context, route: int, seed: int, delay: int) -> dict:
    """One drive of explore's prompts ``delay`` steps late: its swerves and missed turns, each after a "turn" in effect
    before the junction split by whether the car had the room to slow to its turn speed braking hard at that moment."""
    env = NavigationEnv(town, config={"n_traffic": 2})
    _, info = env.reset(seed=seed, options={"route": route, "user": profile, "context": context})
    d = resolve(profile, context)
    said = deque([0] * delay)
    counts = {k: 0 for k in ("swerves", "missed", "missed_without_turn_in_effect", "swerved_in_time", "swerved_with_room",
                             "swerved_without_room", "missed_in_time", "missed_with_room", "missed_without_room")}
    ego, steps = env.world.ego, []
    hearing = record_hearing(ego)

    def room_at(moment: float) -> str:
        """``in_time`` where the driver had not committed at ``moment`` (its decision time at its speed, at least 4 m,
        before the junction), else ``with_room`` or ``without_room``: whether the car could slow to its turn speed
        braking hard by the junction from then."""
        t0, dist, v = next(((t, x, u) for t, x, u in reversed(steps) if t <= moment), steps[0])
        left = dist - v * (moment - t0)
        if left > max(d.decision_time * v, 4.0):
            return "in_time"
        return "with_room" if (v**2 - d.turn_speed**2) / (2 * HARD_BRAKE * d.comfort_decel) <= left else "without_room"

    swerves, missed, done = 0, 0, False
    while not done:
        said.append(int(info["explore_action"]))
        v, dist, now = float(ego.speed), float(info["distance_to_junction"]), float(info["time"])
        steps.append((now, dist, v))
        _, _, terminated, truncated, info = env.step(said.popleft())
        done = terminated or truncated
        for kind, happened in (("swerved", env.world.events.swerves > swerves),
                               ("missed", int(info["missed_turns"]) > missed)):
            if not happened:
                continue
            counts["swerves" if kind == "swerved" else "missed"] += 1
            reach = now + 1.0 if kind == "swerved" else now + dist / max(v, 0.1)  # when the car reached it
            heard = [h.active_at for _, new in hearing for h in new if h.instruction in TURNS and h.heard_at < reach]
            if heard and heard[-1] < reach:
                counts[f"{kind}_{room_at(heard[-1])}"] += 1
            elif kind == "missed":
                counts["missed_without_turn_in_effect"] += 1
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
            total: dict[str, int] = {}
            for i, (profile, context) in enumerate(drivers):
                for route in range(args.routes):
                    for k, n in drive_counts(town, profile, context, route, 600 + 10 * i + route, delay).items():
                        total[k] = total.get(k, 0) + n
            out[f"{town} delay {delay}"] = total
            print(town, delay, json.dumps(total), flush=True)
    if args.json:
        with open(args.json, "w") as f:
            json.dump({"drivers": args.drivers, "routes": args.routes, "rows": out}, f, indent=1)


if __name__ == "__main__":
    main()
