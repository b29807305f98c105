"""Behaviour the simulator must show (issue #2 acceptance); slower, still run in CI."""

import numpy as np
import pytest

from pernav.env.episodes import drive_routes
from pernav.env.sweep import best_lead, timing_sweep
from pernav.world.drivers import Context, named_user
from pernav.world.towns import TOWN_NAMES

PROFILES = {
    "fast_keyboard": (named_user("user4"), Context(equipment="keyboard")),
    "user1": (named_user("user1"), Context()),
    "slow_fog_truck": (named_user("user3"), Context(vehicle="cybertruck", visual="foggy")),
}


@pytest.fixture(scope="module")
def sweeps():
    return {k: timing_sweep(p, c, leads=np.arange(0.0, 16.5, 1.0)) for k, (p, c) in PROFILES.items()}


@pytest.mark.slow
def test_best_lead_time_is_personal(sweeps):
    best = {k: best_lead(rows) for k, rows in sweeps.items()}
    assert best["slow_fog_truck"] - best["fast_keyboard"] >= 2.0, best
    assert best["fast_keyboard"] <= best["user1"] <= best["slow_fog_truck"], best


@pytest.mark.slow
def test_too_late_misses_and_too_early_goes_wrong(sweeps):
    for rows in sweeps.values():
        assert rows[0]["outcome"] in ("missed", "forgot")  # spoken at the junction: too late
        outcomes = [r["outcome"] for r in rows]
        assert "missed" in outcomes
    # too early: the fast and the average driver turn at the junction before, or lose the prompt
    for k in ("fast_keyboard", "user1"):
        assert {"wrong", "forgot"} & {r["outcome"] for r in sweeps[k][-4:]}


@pytest.mark.slow
def test_explore_completes_routes_with_the_average_driver():
    done, collisions = 0, 0
    for town in TOWN_NAMES:
        out = drive_routes(town, "explore", "user7")
        done += sum(e["completed"] for e in out["episodes"])
        collisions += out["summary"]["collisions"]
    print(f"explore, average driver: {done}/50 routes completed, {collisions} collisions")
    # Regression guard at the measured level (43/50 on 2026-11-22). The issue target is 48/50 (95 %)
    # and is NOT met yet: see docs/simulator.md, "Known gaps".
    assert done >= 42
