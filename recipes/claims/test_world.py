"""The frozen world's claims that take dozens of whole episodes to check (about 3 CPU-minutes): explore is a strong
baseline, and the oracle beats it for the atypical users of docs/simulator.md.

Run by ``make claims`` and by CI after ``make test`` (``.ci/run``); ``make test`` keeps the world's quick checks
(tests/world). They are claims about the world's behaviour on fixed episodes, not checks of the code's logic: a change
to ``pernav/world`` that alters them alters the documented figures too. Run them before committing any change there.
"""

import numpy as np
import pytest

from pernav.env.episodes import drive_routes
from pernav.world.constants import TOWN_NAMES

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


def test_explore_completes_routes_with_the_average_driver():
    done, collisions = 0, 0
    for town in TOWN_NAMES:
        out = drive_routes(town, "explore", "user7")
        done += sum(e["completed"] for e in out["episodes"])
        collisions += out["summary"]["collisions"]
    print(f"explore, average driver: {done}/50 routes completed, {collisions} collisions")
    assert done >= 48  # explore is a strong baseline (>= 95 % with the average driver)
    assert collisions <= 8


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
