"""Behaviour the simulator must show; slower, still run in CI."""

import numpy as np
import pytest
from navigation_helpers import shared_value

from pernav.env.episodes import drive_routes
from pernav.env.sweep import best_lead, timing_sweep
from pernav.world.constants import TOWN_NAMES
from pernav.world.drivers import Context, named_user

PROFILES = {
    "fast_keyboard": (named_user("user4"), Context(equipment="keyboard")),
    "user1": (named_user("user1"), Context()),
    "slow_fog_truck": (named_user("user3"), Context(vehicle="cybertruck", visual="foggy")),
    "truck": (named_user("user7"), Context(vehicle="cybertruck")),
}
# docs/simulator.md users whose timing differs from the population average, and for whom the oracle beats
# explore on paired episodes (the criterion was fixed before the runs; docs/research/scripts/oracle_vs_explore.py,
# figures in docs/simulator.md). The fast keyboard driver (user4) and the distracted one (user6) do
# not meet it: explore's timing already suits them (docs/simulator.md, "Known gaps"). user5 in fog in the
# truck ties (oracle cheaper on 10, dearer on 10 of these 20 episodes): it is not among the users this test
# claims.
ATYPICAL = {
    "slow_fog_truck": ("user3", {"vehicle": "cybertruck", "visual": "foggy"}),
    "elderly_like": ("user3", {}),
}


@pytest.fixture(scope="module")
def sweeps(tmp_path_factory):
    """Each profile's lead-time sweep, built once for both pytest workers."""
    return shared_value(tmp_path_factory, "acceptance_sweeps", lambda: {
        k: timing_sweep(p, c, leads=np.arange(0.0, 16.5, 1.0)) for k, (p, c) in PROFILES.items()})


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
def test_too_late_swerves_strike_for_truck_and_fast_keyboard(sweeps):
    # between "missed" and "clean" a late prompt makes the driver swerve; at speed the swerve asks
    # the tyres for more than their grip and the car runs wide over the kerb
    for k in ("fast_keyboard", "truck"):
        rows = sweeps[k]
        first_clean = next(i for i, r in enumerate(rows) if r["outcome"] == "clean")
        late = rows[:first_clean]
        assert any(r["edge_strikes"] + r["vehicle_collisions"] > 0 for r in late), (k, late)
        assert any(r["outcome"] == "strike" for r in late), (k, [r["outcome"] for r in late])


@pytest.mark.slow
def test_explore_completes_routes_with_the_average_driver():
    done, collisions = 0, 0
    for town in TOWN_NAMES:
        out = drive_routes(town, "explore", "user7")
        done += sum(e["completed"] for e in out["episodes"])
        collisions += out["summary"]["collisions"]
    print(f"explore, average driver: {done}/50 routes completed, {collisions} collisions")
    assert done >= 48  # explore is a strong baseline (>= 95 % with the average driver)
    assert collisions <= 8


@pytest.mark.slow
@pytest.mark.parametrize("user", list(ATYPICAL))
def test_oracle_beats_explore_for_atypical_users(user):
    # the default study's towns (Town3 has a roundabout), the same 20 episodes for both policies
    name, context = ATYPICAL[user]
    runs = {p: [drive_routes(t, p, name, context=context) for t in ("Town1", "Town3")] for p in ("explore", "oracle")}
    cost = {p: np.array([e["tracking_cost"] for r in rs for e in r["episodes"]]) for p, rs in runs.items()}
    hits = {p: sum(r["summary"]["collisions"] for r in rs) for p, rs in runs.items()}
    cheaper, dearer = int((cost["oracle"] < cost["explore"]).sum()), int((cost["oracle"] > cost["explore"]).sum())
    print(user, {p: round(float(c.mean())) for p, c in cost.items()}, hits, cheaper, dearer)
    assert hits["oracle"] <= hits["explore"], (user, hits)
    assert cost["oracle"].mean() < cost["explore"].mean(), user
    assert cheaper > dearer, (user, cheaper, dearer)  # not one lucky episode: most episodes
