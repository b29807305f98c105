"""What each constant shift of explore's rule does in the episodes on the sweep approach: misses, swerves, drops.

``shift_truth.py`` finds that the hybrid model misses user3's (truck in fog) clear +3: on the model a "turn" one step
late costs nothing, on the truth thousands. This counts, per episode, what the simulator's events say happened under
each shift (``ShiftedExplore``, on the episodes ``planner_vs_best_shift.py`` drives): the tracking cost, missed and
wrong turns, swerves (a "turn" that took effect after the driver committed), misheard, ignored, forgotten and dropped
prompts, and collisions. Reading the world's event counters is allowed here: this is a check of the model, not a learner.

    .venv/bin/python docs/research/scripts/shift_events.py --driver user3_truck_fog --seeds 10 --json out.json
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from planner_vs_best_shift import CONFIG, DRIVERS  # noqa: E402

from pernav.env.sweep import sweep_route  # noqa: E402
from pernav.env.torchrl_env import explore_module, navigation_of  # noqa: E402
from pernav.planner.retiming import ShiftedExplore  # noqa: E402
from pernav.trainer.collect import drive, episode_metrics, history_env  # noqa: E402

EVENTS = ("swerves", "misunderstood", "ignored", "forgotten", "discarded")


def shifted(name: str, k: int, seed: int) -> tuple:
    """The env of ``name``'s driver on the sweep approach at ``seed`` and the policy of shift ``k`` (explore at 0): the
    episodes ``planner_vs_best_shift.py`` drives."""
    profile, context = DRIVERS[name]
    env = history_env("Town1", {"route": sweep_route(), "user": profile, "context": context}, config=CONFIG, seed=seed)
    return env, ShiftedExplore(k, plan_shift=CONFIG["plan_shift"]) if k else explore_module()


def episode(name: str, k: int, seed: int) -> dict:
    """One episode of ``name``'s driver under shift ``k`` (the episodes ``planner_vs_best_shift.py`` drives): its cost
    and what happened."""
    env, policy = shifted(name, k, seed)
    m = episode_metrics(drive(env, policy))
    nav = navigation_of(env)
    return {"tracking_cost": round(m["tracking_cost"], 1), "missed_turns": m["missed_turns"],
            "wrong_turns": m["wrong_turns"], "collisions": m["collisions"],
            **{e: int(getattr(nav.world.events, e)) for e in EVENTS}}


def by_shift(doc: str, episode, summary, shifts: tuple[int, ...]) -> None:
    """The command line of this and ``swerve_cost.py``: ``episode(driver, k, seed)`` for each shift ``k`` and seed,
    ``summary(rows)`` of each shift's episodes printed and written (with the episodes) to ``--json``."""
    parser = argparse.ArgumentParser(description=doc.splitlines()[0])
    parser.add_argument("--driver", default="user3_truck_fog", choices=list(DRIVERS))
    parser.add_argument("--shifts", type=int, nargs="+", default=list(shifts))
    parser.add_argument("--seeds", type=int, default=10)
    parser.add_argument("--json", default=None)
    args = parser.parse_args()
    report = {}
    for k in args.shifts:
        rows = [episode(args.driver, k, s) for s in range(args.seeds)]
        report[str(k)] = {**summary(rows), "episodes": rows}
        print(k, json.dumps({key: v for key, v in report[str(k)].items() if key != "episodes"}), flush=True)
    if args.json:
        with open(args.json, "w") as f:
            json.dump({"driver": args.driver, "seeds": args.seeds, "shifts": report}, f, indent=1)


def summary(rows: list[dict]) -> dict:
    """A shift's mean cost and the episodes with each event."""
    return {"mean_cost": round(statistics.mean(r["tracking_cost"] for r in rows), 1),
            "episodes_with": {key: sum(r[key] > 0 for r in rows) for key in rows[0] if key != "tracking_cost"}}


def main() -> None:
    by_shift(__doc__, episode, summary, (-1, 0, 3))


if __name__ == "__main__":
    main()
