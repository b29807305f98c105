"""The looks of recipes/benchmarks/follow.py: the pre-registration is reproduced, and each judge reads known figures back
from synthetic study results (no simulation)."""

from __future__ import annotations

import itertools
import json
import random
from pathlib import Path

import pytest

from pernav.study.benchmarks import (
    REPEAT_DRIVERS,
    REPEAT_DRIVES,
    classify,
    personal_schedule,
    repeat_schedule,
    sweep_schedule,
)
from recipes.benchmarks import follow
from recipes.benchmarks.headroom import SEEDS, SPLIT_SEEDS

REGISTERED = Path(__file__).parents[2] / "docs" / "figures" / "follow" / "preregistration.json"


def _results(cost, seeds=(0, 1), towns=("Town1", "Town3"), labels=(), routes=2, beliefs=None) -> list[dict]:
    """Study results whose episode (seed, town, label, route, method) has ``cost(...)``'s tracking cost and turn
    lead."""
    out = []
    for seed in seeds:
        iterations = []
        for label in labels:
            towns_ = {}
            for town in towns:
                towns_[town] = {}
                for method in ("explore", "timing", "belief", "oracle"):
                    eps = []
                    for route in range(routes):
                        c, lead = cost(seed, town, label, route, method)
                        eps.append({"route": route, "tracking_cost": c, "turn_lead": lead, "collisions": 0})
                    towns_[town][method] = {"episodes": eps}
            iterations.append({"phase": "online", "label": label, "towns": towns_})
        diagnostics = {t: {"belief": {"beliefs": beliefs(seed)}} for t in towns} if beliefs else {}
        out.append({"config": {"seed": seed}, "iterations": iterations, "diagnostics": diagnostics})
    return out


def test_the_pre_registration_is_reproduced():
    registered = json.loads(REGISTERED.read_text())
    assert registered == json.loads(json.dumps(follow.preregistration()))
    assert registered["repeat"]["seeds"] == list(follow.REPEAT_SEEDS) and registered["one_look"]
    # fresh seeds: none of the three looks shares a seed with another, nor with the split benchmark's
    looks = [follow.SWEEP_SEEDS, follow.REPEAT_SEEDS, follow.HEADROOM_FRESH_SEEDS, SPLIT_SEEDS, SEEDS,
             follow.SECOND_LOOK_SWEEP_SEEDS, follow.SECOND_LOOK_SPLIT_SEEDS, follow.THIRD_LOOK_SPLIT_SEEDS,
             follow.REPEAT_SECOND_LOOK_SEEDS, follow.THIRD_VERSION_SWEEP_SEEDS, follow.THIRD_VERSION_HEADROOM_SEEDS]
    assert all(not set(a) & set(b) for a, b in itertools.combinations(looks, 2))


def test_the_second_look_is_reproduced_and_judges_the_learner_as_committed():
    registered = json.loads((REGISTERED.parent / "second_look.json").read_text())
    assert registered == json.loads(json.dumps(follow.second_look()))
    from pernav.study.config import BELIEF_DEFAULTS

    assert all(BELIEF_DEFAULTS[k] == v for k, v in registered["changed"].items()) and registered["one_look"]


def test_the_third_look_is_reproduced_and_judges_the_learner_as_committed():
    registered = json.loads((REGISTERED.parent / "third_look.json").read_text())
    assert registered == json.loads(json.dumps(follow.third_look()))
    from pernav.study.config import BELIEF_DEFAULTS

    assert registered["options"] == BELIEF_DEFAULTS and registered["one_look"] and registered["look"] == 3
    assert registered["changed"] == {"slower": 0.5}


def test_the_third_versions_sweep_and_headroom_looks_are_reproduced_with_their_earlier_targets():
    registered = json.loads((REGISTERED.parent / "third_version_looks.json").read_text())
    assert registered == json.loads(json.dumps(follow.third_version_looks()))
    first = json.loads(REGISTERED.read_text())
    assert registered["sweep"]["targets"] == first["sweep"]["targets"]
    assert registered["headroom"]["targets"] == first["headroom"]["targets"]
    from pernav.study.config import BELIEF_DEFAULTS

    assert registered["options"] == BELIEF_DEFAULTS and registered["one_look"]


def test_the_repeated_drives_second_look_is_reproduced_with_the_first_looks_drivers_and_targets():
    registered = json.loads((REGISTERED.parent / "repeat_second_look.json").read_text())
    assert registered == json.loads(json.dumps(follow.repeat_second_look()))
    first = json.loads(REGISTERED.read_text())["repeat"]
    assert registered["repeat"]["targets"] == first["targets"]
    assert registered["repeat"]["population_seed"] == first["population_seed"]
    from pernav.study.config import BELIEF_DEFAULTS

    assert registered["options"] == BELIEF_DEFAULTS and registered["one_look"]


def test_the_repeat_schedule_drives_each_driver_five_times_in_its_class():
    online = [e for e in repeat_schedule() if e.phase == "online"]
    assert len(online) == 2 * REPEAT_DRIVERS * REPEAT_DRIVES
    cells = classify(repeat_schedule(), ["Town1"])
    by_driver: dict[str, set] = {}
    for e, c in zip(online, cells, strict=True):
        driver = e.label.rsplit(" drive", 1)[0]
        by_driver.setdefault(driver, set()).add((json.dumps(e.profile().to_dict(), sort_keys=True), c["late"]))
        assert c["late"] == driver.startswith("slow")
    assert all(len(v) == 1 for v in by_driver.values())  # one profile and one class per driver


def test_spearman_matches_the_textbook_formula_without_ties():
    rng = random.Random(0)
    for n in (4, 5, 9):
        x, y = rng.sample(range(100), n), rng.sample(range(100), n)
        rx = {v: i for i, v in enumerate(sorted(x))}
        ry = {v: i for i, v in enumerate(sorted(y))}
        d2 = sum((rx[a] - ry[b]) ** 2 for a, b in zip(x, y, strict=True))
        assert follow.spearman(x, y) == pytest.approx(1 - 6 * d2 / (n * (n * n - 1)), abs=1e-6)
    assert follow.spearman([1, 2, 3], [5, 5, 5]) != follow.spearman([1, 2, 3], [5, 5, 5])  # NaN: constant


def test_judge_sweep_reads_leads_that_follow_the_driver_and_the_end_points():
    online = [e for e in sweep_schedule() if e.phase == "online"]
    index = {e.label: i for i, e in enumerate(online)}

    def cost(seed, town, label, route, method):
        i = index[label]
        explore, oracle = 100.0 + 20 * i, 100.0
        c = {"explore": explore, "oracle": oracle, "timing": explore,
             "belief": explore if i == 0 else explore - 0.75 * (explore - oracle)}[method]
        lead = {"explore": 2.0, "oracle": 2.0 + 0.5 * i, "timing": 2.0 + 0.1 * (i % 2), "belief": 2.0 + 0.4 * i}[method]
        return c, lead + 0.01 * route

    j = follow.judge_sweep(_results(cost, labels=list(index)))
    assert j["spearman"]["belief"] == {t: {"0": 1.0, "1": 1.0} for t in ("Town1", "Town3")} and j["spearman_min"] == 1.0
    assert "explore" not in j["spearman"] or all(v != v for t in j["spearman"]["explore"].values() for v in t.values())
    assert j["pooled"]["quick_end_cost_ratio"]["mean"] == pytest.approx(1.0)
    assert j["pooled"]["slow_end_gap_closed"]["mean"] == pytest.approx(0.75)


def test_judge_repeat_reads_the_curve_per_drive(tmp_path):
    labels = [e.label for e in repeat_schedule() if e.phase == "online"]

    def cost(seed, town, label, route, method):
        k = int(label.rsplit(" ", 1)[1])
        if label.startswith("slow"):
            return {"explore": 300.0, "oracle": 200.0, "timing": 250.0, "belief": 300.0 - 20 * k}[method], 3.0
        return {"explore": 100.0, "oracle": 100.0, "timing": 104.0, "belief": 101.0}[method], 2.0

    truth = {e.label: e for e in repeat_schedule() if e.phase == "online"}

    def beliefs(seed):
        from pernav.world.drivers import resolve

        return {label: {"reaction_time": resolve(e.profile(), e.context()).reaction_time, "interval": [1.0, 1.0 + 1 / k]}
                for label, e in truth.items() for k in [int(label.rsplit(" ", 1)[1])]}

    j = follow.judge_repeat(_results(cost, labels=labels, beliefs=beliefs))
    for k in range(1, 6):
        row = j["drives"][str(k)]
        assert row["slow_gap_closed"]["mean"] == pytest.approx(0.2 * k)
        assert row["quick_cost_ratio"]["mean"] == pytest.approx(1.01)
        assert row["interval_width"] == pytest.approx(1 / k, abs=1e-4) and row["abs_log_error"] == 0
        assert row["slow_saved"]["belief"]["mean"] == pytest.approx(20 * k) and row["slow_saved"]["oracle"]["mean"] == 100
    follow.plot_personalization(j, str(tmp_path / "curve.png"))
    assert (tmp_path / "curve.png").stat().st_size > 10_000


def test_judge_headroom_fresh_measures_the_learner_against_timing_in_shares_of_the_gap():
    late = {c["round"]: c["late"] for c in classify(personal_schedule(), ["Town1"])}

    def cost(seed, town, label, route, method):
        if late[label]:
            return {"explore": 400.0, "oracle": 300.0, "timing": 320.0, "belief": 330.0}[method], 3.0
        return {"explore": 100.0, "oracle": 99.0, "timing": 103.0, "belief": 101.0}[method], 2.0

    j = follow.judge_headroom_fresh(_results(cost, labels=list(late)))
    assert j["late_minus_baseline"]["mean"] == pytest.approx(0.10)
    assert j["learner"]["on_time"]["cost_ratio"]["mean"] == pytest.approx(1.01)
    assert j["baseline"]["late"]["gap_closed"]["mean"] == pytest.approx(0.80)
