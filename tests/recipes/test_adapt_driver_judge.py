"""The paper look of recipes/benchmarks/adapt_driver_judge.py: its figures read known episodes back, and it refuses a
run that is not the registered one."""

import json
from collections.abc import Callable

import pytest

from recipes.benchmarks.adapt_driver_judge import paper, personal

LOOK = {"seeds": [1], "targets": {"cost": {"ci_low": -0.01}, "missed_turns": {"point": 1.10},
                                  "collisions": {"point": 1.0}}}


def _results(explore: list[float], driver: list[float], missed: tuple[int, int], seed: int = 1) -> dict:
    def episodes(costs: list[float], miss: int) -> list[dict]:
        return [{"tracking_cost": c, "missed_turns": int(i < miss), "collisions": 0, "wrong_turns": 0,
                 "completed": True} for i, c in enumerate(costs)]

    rounds = [{"label": "Online 0", "phase": "online", "towns": {"Town4": {
        "explore": {"episodes": episodes(explore, missed[0])},
        "adapt_driver": {"episodes": episodes(driver, missed[1])}}}},
        {"label": "Offline 0", "phase": "offline", "towns": {"Town4": {}}}]
    return {"config": {"preset": "paper", "seed": seed}, "iterations": rounds}


def test_the_paper_look_reads_cost_missed_turns_and_collisions_against_the_targets(tmp_path):
    explore = [100.0, 120.0, 80.0, 100.0]
    lines = paper([_results(explore, [c - 10 for c in explore], (2, 2))], LOOK, tmp_path, "look")
    town = json.loads((tmp_path / "look.json").read_text())["towns"]["Town4"]
    assert town["explore_minus_adapt_driver"]["mean"] == pytest.approx(10.0)
    assert town["as_share_of_explore"]["low"] == pytest.approx(0.1)
    assert all(v["met"] for v in town["verdict"].values()) and "Town4" in lines[0]
    # dearer by 10 % and missing twice as often: neither target met
    paper([_results(explore, [c * 1.1 for c in explore], (1, 2))], LOOK, tmp_path, "look")
    town = json.loads((tmp_path / "look.json").read_text())["towns"]["Town4"]
    assert not town["verdict"]["cost"]["met"] and not town["verdict"]["missed_turns"]["met"]


def test_the_paper_look_refuses_a_seed_it_is_not_registered_on(tmp_path):
    with pytest.raises(ValueError, match="seeds \\[1\\]"):
        paper([_results([1.0], [1.0], (0, 0), seed=0)], LOOK, tmp_path, "look")


def test_a_pooled_look_judges_a_towns_episodes_over_its_seeds_and_a_look_that_pools_none_refuses_two(tmp_path):
    one = _results([100.0, 100.0], [90.0, 90.0], (1, 1), seed=1)
    two = _results([100.0, 100.0], [130.0, 130.0], (0, 2), seed=2)
    pooled = {**LOOK, "seeds": [1, 2], "pool": True}
    paper([one, two], pooled, tmp_path, "look")
    town = json.loads((tmp_path / "look.json").read_text())["towns"]["Town4"]
    assert town["episodes"] == 4 and town["explore_minus_adapt_driver"]["mean"] == pytest.approx(-10.0)
    assert town["adapt_driver_vs_explore"]["missed_turns"] == [3, 1]
    assert town["departures"]["episodes"] == 0 and town["departures"]["explore_minus_adapt_driver_mean"] is None
    for i, e in enumerate(two["iterations"][0]["towns"]["Town4"]["adapt_driver"]["episodes"]):
        e["left_explore"] = 0.1 * i  # the second of seed 2's episodes left explore, at a tenth of its steps
    paper([one, two], pooled, tmp_path, "look")
    departures = json.loads((tmp_path / "look.json").read_text())["towns"]["Town4"]["departures"]
    assert departures["episodes"] == 1 and departures["explore_minus_adapt_driver_mean"] == pytest.approx(-30.0)
    assert departures["left_explore_mean"] == pytest.approx(0.1 / 4)
    with pytest.raises(ValueError, match="given twice"):  # the same seed twice, even where seeds pool
        paper([one, one], pooled, tmp_path, "look")
    with pytest.raises(ValueError, match="pools no seeds"):
        paper([one, two], {**LOOK, "seeds": [1, 2]}, tmp_path, "look")


TARGETS = {"all_against_best_learner": {"point": 1.01, "ci_high": 1.02}, "quick_cost_ratio": {"point": 1.01},
           "slow_gap_to_best_shift": {"point": 0.6, "ci_low": 0.3}, "collisions": {}}


def _split(seed: int, cost: dict[str, Callable[[bool, int], float]],
           rounds: tuple[str, ...] = ("slow 0", "quick 0")) -> dict:
    """A split study of one seed: four routes of each round in Town1, each method's cost a function of
    (slow, route); explore collides on route 0, adapt_driver on none."""
    def episodes(method: str, slow: bool) -> list[dict]:
        return [{"route": r, "tracking_cost": cost[method](slow, r),
                 "collisions": int(method == "explore" and r == 0)} for r in range(4)]

    its = [{"label": label, "phase": "online", "towns": {"Town1": {
        m: {"episodes": episodes(m, label.startswith("slow"))} for m in cost}}} for label in rounds]
    return {"config": {"preset": "split", "seed": seed, "towns": ["Town1"]}, "iterations": its}


def _costs(driver_slow: float, driver_quick: float) -> dict:
    """explore 100 (slow drivers 140), best_shift 100 on all, belief and timing 110 and 120 on all: adapt_driver's
    slow and quick costs as given, with a little route-to-route spread."""
    return {"explore": lambda slow, r: (140.0 if slow else 100.0) + r,
            "best_shift": lambda slow, r: 100.0 + r, "belief": lambda slow, r: 110.0 + r,
            "timing": lambda slow, r: 120.0 + r, "oracle": lambda slow, r: 100.0 + r,
            "adapt_driver": lambda slow, r: (driver_slow if slow else driver_quick) + r}


def test_the_split_look_reads_the_gap_to_best_shift_the_quick_ratio_and_the_cheaper_learner(tmp_path):
    look = {"seeds": [148, 149]}
    runs = [_split(s, _costs(104.0, 100.0)) for s in look["seeds"]]
    lines = personal(runs, "split", look, TARGETS, tmp_path)
    f = json.loads((tmp_path / "look_split.json").read_text())
    assert f["episodes"] == {"all": 16, "quick": 8, "slow": 8}
    assert f["cheaper_learner"] == "belief"  # 110 against timing's 120 on every episode
    # explore 140 -> best_shift 100 on the slow cells; adapt_driver at 104 removes 36 of the 40
    assert f["slow_gap_closed"]["mean"] == pytest.approx(0.9)
    assert f["quick_over_explore"]["mean"] == pytest.approx(1.0)
    assert f["collisions"]["adapt_driver_minus_explore"]["mean"] == pytest.approx(-0.25)
    # all drivers: (102 + 1.5) / (110 + 1.5) of the belief's cost: every target met
    assert f["all_over_learner"]["belief"]["mean"] == pytest.approx(103.5 / 111.5)
    assert all(v["met"] for v in f["verdict"].values()) and "split" in lines[0]
    # quick drivers 5 % dearer and the slow ones no better than explore: those two targets missed
    personal([_split(s, _costs(140.0, 105.0)) for s in look["seeds"]], "split", look, TARGETS, tmp_path)
    v = json.loads((tmp_path / "look_split.json").read_text())["verdict"]
    assert not v["quick_cost_ratio"]["met"] and not v["slow_gap_to_best_shift"]["met"]


def test_the_split_look_refuses_a_partial_or_unregistered_set_of_seeds(tmp_path):
    with pytest.raises(ValueError, match="registered on seeds"):
        personal([_split(148, _costs(100.0, 100.0))], "split", {"seeds": [148, 149]}, TARGETS, tmp_path)
    with pytest.raises(ValueError, match="seed 7"):
        personal([_split(7, _costs(100.0, 100.0))], "split", {"seeds": [148]}, TARGETS, tmp_path)
    with pytest.raises(ValueError, match="both classes"):
        personal([_split(148, _costs(100.0, 100.0), rounds=("slow 0",))], "split", {"seeds": [148]}, TARGETS,
                 tmp_path)
