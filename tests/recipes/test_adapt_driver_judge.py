"""The paper look of recipes/benchmarks/adapt_driver_judge.py: its figures read known episodes back, and it refuses a
run that is not the registered one."""

import json

import pytest

from recipes.benchmarks.adapt_driver_judge import paper

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
