"""The headroom benchmark's pre-registered classification is what the code computes (nothing re-classified after
the runs), and the analytic lateness behind it agrees with sampled reaction times."""

import json
import math
import random
from pathlib import Path

from pernav.env.policies import explore_policy, late_share, lateness
from pernav.study.benchmarks import SWEEP_SHIFTS, classify, personal_schedule, split_schedule, sweep_schedule
from pernav.study.config import preset
from pernav.world.constants import audio_duration
from pernav.world.drivers import POPULATION_AVERAGE, Context, named_user, resolve
from recipes.benchmarks.headroom import SEEDS, SPLIT_SEEDS, TARGETS, judge, preregistration, split_preregistration
from recipes.benchmarks.judge import main as judge_main

REGISTERED = Path(__file__).parents[2] / "docs" / "figures" / "personal" / "preregistration.json"


def test_the_preregistered_classification_is_reproduced() -> None:
    registered = json.loads(REGISTERED.read_text())
    assert registered == json.loads(json.dumps(preregistration(registered["towns"])))
    cells = registered["cells"]
    assert sum(c["late"] for c in cells) == 20 and len(cells) == 32  # at least half outside the slack
    assert len(SEEDS) >= 6 and TARGETS["late_gap_closed"]["point"] == 0.60


def test_the_split_benchmark_s_preregistered_classification_is_reproduced() -> None:
    registered = json.loads((REGISTERED.parents[1] / "split" / "preregistration.json").read_text())
    assert registered == json.loads(json.dumps(split_preregistration(tuple(registered["towns"]))))
    cells = registered["cells"]
    # half slow (late: outside explore's slack), half quick (inside it), alternating, in both towns
    assert [c["late"] for c in cells] == [True, False] * 10
    assert all(c["round"].startswith("slow" if c["late"] else "quick") for c in cells)
    assert all(c["explore_late"] < 0.05 for c in cells if not c["late"])
    assert len(SPLIT_SEEDS) >= 16 and not set(SPLIT_SEEDS) & set(SEEDS)  # fresh seeds, sized for the targets
    cfg = preset("split")
    cfg.validate()
    assert cfg.schedule == split_schedule() and "belief" in cfg.methods and "timing" in cfg.methods


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


# ----- the timing learner ----------------------------------------------------------------------------------------
import pytest  # noqa: E402
import torch  # noqa: E402
from navigation_helpers import shared_value  # noqa: E402

from pernav.env.policies import belief_policy  # noqa: E402
from pernav.env.torchrl_env import explore_module  # noqa: E402
from pernav.learners.timing import FEATURES, N_FEATURES, TimingModel, timing_features  # noqa: E402
from pernav.trainer.collect import drive, history_env  # noqa: E402
from pernav.world.drivers import Population  # noqa: E402


def _tau(user, context: Context, route: int, seed: int):
    env = history_env("Town1", {"route": route, "user": user, "context": context}, config={"n_traffic": 2},
                      seed=seed, K=2)
    return drive(env, explore_module())


def _fit_timing() -> TimingModel:
    population, X, Y = Population(seed=7), [], []
    for k in range(16):
        profile, context = population.sample()
        X.append(timing_features(_tau(profile, context, k % 10, 100 + k)))
        driver = resolve(profile, context)
        Y.append(torch.tensor([driver.reaction_time, driver.decision_time]))
    return TimingModel().fit(torch.stack(X), torch.stack(Y))


@pytest.fixture(scope="module")
def fitted(tmp_path_factory) -> TimingModel:
    """A timing model fitted as the study fits it, on 16 simulated population drivers' explore drives (built once
    for both pytest workers)."""
    return shared_value(tmp_path_factory, "headroom_timing_model", _fit_timing)


def test_ridge_recovers_a_linear_relation_and_shrinks_to_the_mean_without_evidence() -> None:
    g = torch.Generator().manual_seed(0)
    X = torch.randn(200, N_FEATURES, generator=g)
    Y = torch.stack([(0.3 * X[:, 0]).exp() * 1.5, (0.0 * X[:, 1]).exp() * 2.0], -1)
    model = TimingModel(l2=1e-6).fit(X, Y)
    torch.testing.assert_close(model.predict(X), Y, rtol=1e-4, atol=1e-4)
    at_mean = TimingModel(l2=1e6).fit(X, Y).predict(torch.zeros(N_FEATURES))
    torch.testing.assert_close(at_mean, Y.log().mean(0).exp(), rtol=1e-2, atol=1e-2)
    assert len(FEATURES) == N_FEATURES
    with pytest.raises(RuntimeError, match="fit the TimingModel"):
        TimingModel().predict(X)


def test_features_read_what_the_navigation_saw_not_the_oracle() -> None:
    tau = _tau("user3", Context(), 0, 1)
    before = timing_features(tau)
    tau["oracle_action"] = torch.full_like(tau["oracle_action"], 3)
    tau["next", "oracle_action"] = torch.full_like(tau["next", "oracle_action"], 3)
    assert torch.equal(timing_features(tau), before)
    assert torch.isfinite(before).all()


@pytest.mark.slow
def test_a_late_answering_driver_is_prompted_earlier_and_one_inside_the_slack_as_explore(fitted) -> None:
    slow = fitted.belief(_tau("user3", Context(vehicle="cybertruck", visual="foggy"), 1, 3))
    fast = fitted.belief(_tau("user4", Context(), 1, 3))
    assert slow and belief_policy(slow).turn_lead(10.0) > explore_policy().turn_lead(10.0) + 3.0
    assert fast == {}  # the gate: explore's own timing


@pytest.mark.slow
def test_a_study_runs_the_timing_learner_and_records_its_beliefs(tmp_path_factory) -> None:
    from study_helpers import smoke_study

    assert "timing" in preset("smoke").methods  # the shared smoke study runs every method
    assert "timing" in preset("default").methods  # it joined `make study` after its sized judging (docs/personal.md)
    results = json.loads((smoke_study(tmp_path_factory) / "results.json").read_text())  # Town1: the whole smoke study
    beliefs = results["diagnostics"]["Town1"]["timing"]["beliefs"]
    assert set(beliefs) == {"Online 0", "Online 8"}
    for it in results["iterations"]:
        if it["phase"] == "online":
            assert {"explore", "timing", "oracle"} <= set(it["towns"]["Town1"])


def _synthetic_results(seed: int) -> dict:
    """A results.json of the personal preset with one route per cell: explore 100, oracle 50 and timing 60 on the
    late cells; explore 100, oracle 100 and timing 103 on the on-time cells; one timing collision per seed."""
    iterations = []
    cells = classify(personal_schedule(), ["Town1", "Town3"])
    for label in dict.fromkeys(c["round"] for c in cells):
        towns = {}
        for c in (c for c in cells if c["round"] == label):
            costs = {"explore": 100.0, "oracle": 50.0, "timing": 60.0} if c["late"] else \
                {"explore": 100.0, "oracle": 100.0, "timing": 103.0}
            towns[c["town"]] = {m: {"tracking_cost": v, "episodes": [
                {"route": 0, "tracking_cost": v, "collisions": int(m == "timing" and label == "user3"
                                                                   and c["town"] == "Town1")}]}
                for m, v in costs.items()}
        iterations.append({"label": label, "phase": "online", "towns": towns})
    return {"config": {"seed": seed}, "iterations": iterations}


def test_judge_computes_the_preregistered_figures_on_known_episodes(tmp_path) -> None:
    j = judge([_synthetic_results(0), _synthetic_results(1)])
    assert j["late"]["episodes"] == 40 and j["on_time"]["episodes"] == 24
    assert j["late"]["gap_closed"]["mean"] == pytest.approx(0.8)
    assert j["on_time"]["cost_ratio"]["mean"] == pytest.approx(1.03)
    assert j["late"]["per_town"]["Town3"]["gap_closed"]["mean"] == pytest.approx(0.8)
    assert j["collisions"]["learner"] == 2 and j["collisions"]["explore"] == 0
    files = []
    for seed in (0, 1):
        files.append(tmp_path / f"r{seed}.json")
        files[-1].write_text(json.dumps(_synthetic_results(seed)))
    out = tmp_path / "judged"
    assert judge_main([*map(str, files), "--out", str(out)]) == 0
    assert json.loads((out / "judged.json").read_text())["late"]["gap_closed"]["mean"] == pytest.approx(0.8)
    assert judge_main([*map(str, files), "--out", str(out)]) == 2  # nothing is overwritten
    assert judge_main([str(tmp_path / "missing"), "--out", str(tmp_path / "o2")]) == 2


def test_the_sweep_shifts_only_the_average_drivers_reaction_time() -> None:
    online = [e for e in sweep_schedule() if e.phase == "online"]
    assert [round(e.profile().reaction_time - POPULATION_AVERAGE.reaction_time, 2) for e in online] == \
        list(SWEEP_SHIFTS)
    for e in online:
        others = {k: v for k, v in e.profile().to_dict().items() if k != "reaction_time"}
        assert others == {k: v for k, v in POPULATION_AVERAGE.to_dict().items() if k != "reaction_time"}
        assert e.context() == Context()
    preset("personal_sweep").validate()


def _first_exit_prompt(policy, route, v: float = 8.0) -> float:
    """Progress (m) at which ``policy`` first says the roundabout exit's "turn right", at a steady ``v`` m/s."""
    from pernav.env.policies import EXIT, NavView

    exit_ = next(m for m in route.manoeuvres if m.kind == "exit")
    enter = next(m for m in route.manoeuvres if m.kind == "enter")
    log: list[tuple[int, float]] = []
    last = 0
    for p in [enter.s - 60.0 + 0.5 * k for k in range(int((exit_.s - enter.s + 60.0) / 0.5))]:
        action = policy(NavView(route, p, v, last, log))
        if action == EXIT and exit_.s - p < 120 and p > enter.s:
            return p
        if action:
            log.append((action, p))
        last = action
    raise AssertionError("no exit prompt")


def test_the_guard_keeps_an_early_exit_prompt_after_a_quick_drivers_commit_at_the_exit_to_pass() -> None:
    # a belief of a slow driver says the roundabout's exit prompt early; a quick driver who hears it before
    # committing to pass the exit before would take that one. With ``fastest`` the prompt waits until the quick
    # driver acts on it after its commit point there (and is still earlier than explore's)
    from pernav.world.constants import audio_duration as audio
    from pernav.world.towns import get_town

    route = get_town("Town3").routes[1]
    before = next(m for m in route.manoeuvres if m.kind == "pass")
    slow = {"reaction_time": 2.6, "decision_time": 2.6}
    fastest = {"reaction_time": 0.6, "decision_time": 1.4}
    unguarded = _first_exit_prompt(belief_policy(slow), route)
    guarded = _first_exit_prompt(belief_policy({**slow, "fastest": fastest}), route)
    explore = _first_exit_prompt(explore_policy(), route)
    assert unguarded < guarded <= explore
    assert guarded + 8.0 * (audio(2) + fastest["reaction_time"]) >= before.s - 8.0 * fastest["decision_time"] + 1.0
    assert unguarded + 8.0 * (audio(2) + fastest["reaction_time"]) < before.s - 8.0 * fastest["decision_time"]
    # approaching faster than the ring's speed, the car slows to it before the exit to pass: the guard assumes the
    # ring's speed (8 m/s), at which the quick listener acts sooner and commits closer than at 11 m/s
    fast_approach = _first_exit_prompt(belief_policy({**slow, "fastest": fastest}), route, v=11.0)
    assert fast_approach + 8.0 * (audio(2) + fastest["reaction_time"]) >= before.s - 8.0 * fastest["decision_time"] + 1
    with pytest.raises(ValueError, match="unknown fastest field 'speed'"):
        belief_policy({**slow, "fastest": {"speed": 1.0}})


@pytest.mark.slow
def test_the_guarded_belief_names_a_quick_driver_beside_the_same_slow_belief(fitted) -> None:
    tau = _tau("user3", Context(vehicle="cybertruck", visual="foggy"), 1, 3)
    belief = fitted.belief(tau)
    assert belief["fastest"]["reaction_time"] < explore_policy().driver.reaction_time < belief["reaction_time"]
    assert belief["fastest"]["decision_time"] <= explore_policy().driver.decision_time
    unguarded = TimingModel().load_state_dict({**fitted.state_dict(), "guard": False})
    assert unguarded.belief(tau) == {k: v for k, v in belief.items() if k != "fastest"}


def _dropped(town: str, user: str, belief: dict, routes: range) -> int:
    """Prompts ``user`` dropped on entering a junction box over ``routes``, the env's belief policy driving."""
    from pernav.env.navigation import NavigationEnv

    dropped = 0
    for route in routes:
        env = NavigationEnv(town, config={"n_traffic": 2, "belief": belief})
        _, info = env.reset(seed=route, options={"route": route, "user": user})
        done = False
        while not done:
            _, _, terminated, truncated, info = env.step(info["belief_action"])
            done = terminated or truncated
        dropped += env.world.events.discarded
    return dropped


@pytest.mark.slow
def test_the_guarded_belief_waits_until_the_car_is_in_the_junction_box_before_the_one_meant() -> None:
    # a slow belief says the next junction's prompt as soon as the last one is passed, or before a bend; a driver who
    # hears it before entering that box takes it for that junction and drops it. The guard waits; explore's timing
    # (no ``fastest``) is unchanged
    slow = {"reaction_time": 2.8, "decision_time": 3.0}
    guarded = {**slow, "fastest": {"reaction_time": 0.6, "decision_time": 1.3}}
    unguarded_drops = _dropped("Town1", "user4", slow, range(4))
    assert unguarded_drops > 0
    assert _dropped("Town1", "user4", guarded, range(4)) < unguarded_drops
    assert belief_policy({}).fastest is None
