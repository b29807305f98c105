"""The headroom benchmark's pre-registered classification is what the code computes (nothing re-classified after
the runs), and the analytic lateness behind it agrees with sampled reaction times."""

import json
import math
import random
from pathlib import Path

from pernav.env.policies import explore_policy, late_share, lateness
from pernav.study.config import preset
from pernav.study.headroom import SEEDS, TARGETS, classify, personal_schedule, preregistration
from pernav.world.drivers import Context, named_user, resolve
from pernav.world.layout import audio_duration

REGISTERED = Path(__file__).parents[1] / "docs" / "figures" / "personal" / "preregistration.json"


def test_the_preregistered_classification_is_reproduced() -> None:
    registered = json.loads(REGISTERED.read_text())
    assert registered == json.loads(json.dumps(preregistration(registered["towns"])))
    cells = registered["cells"]
    assert sum(c["late"] for c in cells) == 20 and len(cells) == 32  # at least half outside the slack
    assert len(SEEDS) >= 6 and TARGETS["late_gap_closed"]["point"] == 0.60


def test_the_preset_runs_the_classified_rounds() -> None:
    cfg = preset("personal")
    cfg.validate()
    assert {c["round"] for c in classify(cfg.schedule, cfg.towns)} == {e.label for e in personal_schedule()
                                                                       if e.phase == "online"}
    assert preset("personal_paper").towns == ["Town1", "Town2", "Town3", "Town4", "Town5"]


def test_analytic_lateness_agrees_with_sampled_reaction_times() -> None:
    driver = resolve(named_user("user2"), Context())
    lead = explore_policy().turn_lead(10.0) / 10.0
    commit = max(driver.decision_time, 0.4)
    rng = random.Random(0)
    n, late = 20000, 0
    for _ in range(n):
        said = lead + rng.random()  # the lead ran out somewhere within the decision step
        late += audio_duration(1) + driver.reaction_draw(rng.gauss(0.0, 1.0)) > said - commit
    assert math.isclose(late / n, late_share(driver, lead, commit), abs_tol=0.015)
    assert lateness(driver)["excess"] > 0.3 > lateness(resolve(named_user("user4"), Context()))["excess"]
