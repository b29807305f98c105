"""Behaviour the simulator must show, on one sweep of lead times per profile. The claims that take dozens of whole
episodes (explore completes its routes; the oracle beats it for atypical users) are in recipes/claims/test_world.py
(``make claims``, run by CI after ``make test``)."""

import numpy as np
import pytest
from navigation_helpers import shared_value

from pernav.env.sweep import best_lead, timing_sweep
from pernav.world.drivers import Context, named_user

PROFILES = {
    "fast_keyboard": (named_user("user4"), Context(equipment="keyboard")),
    "user1": (named_user("user1"), Context()),
    "slow_fog_truck": (named_user("user3"), Context(vehicle="cybertruck", visual="foggy")),
    "truck": (named_user("user7"), Context(vehicle="cybertruck")),
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
