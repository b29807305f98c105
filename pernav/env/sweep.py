"""Timing sweep: how the lead time of a single "turn" instruction changes the outcome per driver.

The scenario (Town1): the car starts on the west edge, drives straight through a 4-way junction
(J11), and must turn right at the next one (J12). A single "turn right" is spoken when the car is
``lead`` seconds from J12's stop line; no other instruction, no traffic. Too late: the driver has
committed (missed turn) or swerves (harsh braking, running wide: curb strikes). Too early: the turn
is taken at J11 (wrong turn) or forgotten.

Example:
    >>> from pernav.world.drivers import named_user, Context
    >>> rows = timing_sweep(named_user("user1"), Context(), leads=[6.0])
    >>> rows[0]["outcome"]
    'clean'
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Iterable
from typing import Any

import numpy as np

from pernav.env.navigation import NavigationEnv
from pernav.world.drivers import Context, DriverProfile
from pernav.world.routing import Route, plan_route
from pernav.world.towns import get_town

START = ("J10:oE", "J11:iW", 0)
GOAL = ("J12:oS", "J22:iN", 0)
TARGET_NODE, EARLY_NODE = "J12:iW", "J11:iW"


def sweep_route() -> Route:
    """Straight through J11, right at J12 (Town1)."""
    return plan_route(get_town("Town1"), START, 5.0, [(GOAL, 60.0)], name="sweep")


def run_lead(profile: DriverProfile, context: Context, lead: float, seed: int = 0) -> dict[str, Any]:
    """One drive with the "turn right" spoken ``lead`` seconds before J12 (by distance / speed)."""
    env = NavigationEnv("Town1", config={"n_traffic": 0})
    route = sweep_route()
    target = next(m for m in route.manoeuvres if m.node == TARGET_NODE)
    env.reset(seed=seed, options={"route": route, "user": profile, "context": context})
    early = next(m for m in route.manoeuvres if m.node == EARLY_NODE)
    spoken, done, cost, spoken_at = False, False, 0.0, 0.0
    while not done and env.time < 90:
        ego = env.world.ego
        remaining = target.s - env.progress
        action = 0
        if not spoken and env.route is route and remaining <= lead * max(ego.speed, 1.0) + 1e-6:
            action, spoken, spoken_at = 2, True, env.progress
        _, reward, terminated, truncated, info = env.step(action)
        cost -= reward
        done = terminated or truncated
    choice = env.world.ego.last_choice
    ev = env.world.events
    if choice.get(EARLY_NODE) == "right":
        outcome = "wrong"
    elif choice.get(TARGET_NODE) != "right":
        # spoken before the earlier junction and lost there, or faded: forgotten; else too late
        outcome = "forgot" if ev.forgotten or spoken_at < early.s else "missed"
    elif info["collisions"]:
        outcome = "strike"
    elif ev.swerves or ev.harsh_brakes:
        outcome = "harsh"
    else:
        outcome = "clean"
    return {"lead": lead, "outcome": outcome, "tracking_cost": cost, "edge_strikes": info["edge_strikes"],
            "vehicle_collisions": info["vehicle_collisions"], "harsh_brakes": ev.harsh_brakes,
            "swerves": ev.swerves, "time": info["time"]}


def timing_sweep(profile: DriverProfile, context: Context, leads=None, seed: int = 0) -> list[dict[str, Any]]:
    """Outcome and tracking cost for each lead time (seconds) of the single "turn" prompt."""
    leads = np.arange(0.0, 16.5, 1.0) if leads is None else leads
    return [run_lead(profile, context, float(lead), seed) for lead in leads]


def best_lead(rows: list[dict[str, Any]]) -> float:
    """Lead time with the lowest tracking cost among clean turns (NaN if none)."""
    clean = [r for r in rows if r["outcome"] == "clean"]
    return min(clean, key=lambda r: r["tracking_cost"])["lead"] if clean else float("nan")


def seeded_sweep(profile: DriverProfile, context: Context, leads=None, seeds: Iterable[int] = range(10)
                 ) -> list[dict[str, Any]]:
    """Per lead time: the share of each outcome over ``seeds`` and the mean tracking cost and collisions.

    The world draws each prompt's reaction time, so one lead gives a spread of outcomes; the same seeds are
    used at every lead (paired).

    >>> from pernav.world.drivers import named_user, Context
    >>> row = seeded_sweep(named_user("user1"), Context(), leads=[6.0], seeds=[0, 1])[0]
    >>> row["lead"], sum(row["shares"].values())
    (6.0, 1.0)
    """
    leads = np.arange(0.0, 16.5, 1.0) if leads is None else leads
    seeds = list(seeds)
    out = []
    for lead in leads:
        runs = [run_lead(profile, context, float(lead), s) for s in seeds]
        counts = Counter(r["outcome"] for r in runs)
        out.append({"lead": float(lead), "shares": {k: v / len(runs) for k, v in sorted(counts.items())},
                    "tracking_cost": float(np.mean([r["tracking_cost"] for r in runs])),
                    "collisions": int(sum(r["edge_strikes"] + r["vehicle_collisions"] for r in runs)),
                    "runs": len(runs)})
    return out


def best_seeded_lead(rows: list[dict[str, Any]], clean_share: float = 0.8, tolerance: float = 0.01) -> float:
    """The shortest lead (the latest prompt) among those clean in at least ``clean_share`` of the seeds whose
    mean tracking cost is within ``tolerance`` of the cheapest of them; NaN if no lead is that reliable."""
    ok = [r for r in rows if r["shares"].get("clean", 0.0) >= clean_share]
    if not ok:
        return float("nan")
    cheapest = min(r["tracking_cost"] for r in ok)
    return min(r["lead"] for r in ok if r["tracking_cost"] <= cheapest * (1 + tolerance))
