"""The long-horizon planner, the true-dynamics world model, branching, and the paired statistics."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from tensordict import TensorDict

from pernav.diagnostics import TrueDynamicsEnv
from pernav.diagnostics.panel import PanelJob, comparison_table, drive_panel_episode
from pernav.env.navigation import NavigationEnv
from pernav.model import DynamicsModel
from pernav.model.driver import DriverImaginedEnv
from pernav.model.navigation import ImaginedNavigationEnv, make_world_model
from pernav.planner import Departure, RetimingPlanner, TreeSearchPlanner, build_planner, candidate_plans
from pernav.study.compare import compare
from pernav.study.stats import bootstrap_ci, gap_closed, paired_difference
from pernav.world.cost import tracking_cost


def _live(steps: int = 25, town: str = "Town1", route: int = 0, seed: int = 3) -> tuple[NavigationEnv, dict]:
    env = NavigationEnv(town, config={"n_traffic": 3})
    _, info = env.reset(seed=seed, options={"route": route, "user": "user3"})
    for _ in range(steps):
        *_, info = env.step(info["explore_action"])
    return env, info


def test_branch_replays_the_original_exactly_and_a_seeded_branch_does_not_share_its_draws():
    env, info = _live()
    twin, other = env.branch(), env.branch(seed=7)
    for _ in range(40):
        a = info["explore_action"]
        _, r, *_, info = env.step(a)
        assert twin.step(a)[1] == r
        other.step(a)
    assert np.array_equal(env.world.ego.position, twin.world.ego.position)
    assert env.world.driver_rng.random() != other.world.driver_rng.random()


def test_true_model_prefix_sharing_equals_independent_rollouts():
    env, _ = _live()
    seqs = torch.tensor([[0, 0, 4, 4, 2, 2], [0, 4, 4, 2, 2, 2], [0, 0, 4, 4, 4, 4], [2, 2, 2, 2, 2, 2]])
    pos, goal = TrueDynamicsEnv(env, samples=1, seed=11).imagine(None, seqs)
    seed = int(np.random.default_rng(11).integers(2**31 - 1))  # the first copy's seed
    for n, seq in enumerate(seqs.tolist()):
        copy = env.branch(seed)
        for h, a in enumerate(seq):
            copy.advance(a)
            assert np.allclose(pos[0, n, h].numpy(), copy.world.ego.position, atol=1e-4)
            assert np.allclose(goal[0, n, h].numpy(), copy.goal, atol=1e-4)


def test_true_model_is_a_torchrl_env_of_any_batch_size():
    env, _ = _live(steps=5)
    true = TrueDynamicsEnv(env, samples=1)
    td = true.rollout(3, auto_reset=False, tensordict=true.reset(TensorDict({}, [4])), break_when_any_done=False)
    assert td.shape == (4, 3) and td["next", "observation"].shape == (4, 3, 14)
    with pytest.raises(ValueError, match="samples"):
        TrueDynamicsEnv(env, samples=0)


def test_candidate_plans_are_explore_re_timed_unique_and_explore_is_one_of_them():
    future = torch.tensor([0, 0, 4, 4, 2, 2, 0, 0, 0, 0])
    seqs, e = candidate_plans(future, last=0, allowed=torch.tensor([0, 2, 4]), horizon=5, advance=3, delay=2)
    rows = seqs.tolist()
    assert rows[e] == [0, 0, 4, 4, 2]
    assert len({tuple(r) for r in rows}) == len(rows)
    for k in range(1, 4):
        assert future[k:k + 5].tolist() in rows  # advanced by k
    assert [0, 0, 0, 4, 4] in rows and [0, 0, 0, 0, 4] in rows  # delayed by 1, 2
    assert [2] * 5 in rows and [4] * 5 in rows  # the fine choices now (a prompt is within reach)
    far, _ = candidate_plans(torch.zeros(10, dtype=torch.long).index_fill(0, torch.tensor([9]), 2), 0,
                             torch.tensor([0, 2]), 5, 3, 2)
    assert not (far[:, 0] != 0).any()  # nothing due within reach: no prompt now
    due, _ = candidate_plans(torch.tensor([1, 1, 0, 4, 4, 0, 0, 0]), 0, torch.tensor([0, 1]), 4, 3, 0)
    assert [0, 4, 4, 0] not in due.tolist() and [4, 4, 0, 0] not in due.tolist()  # "turn left" is never dropped
    held, _ = candidate_plans(torch.tensor([3, 3, 0, 1, 1, 0, 0, 0]), 3, torch.tensor([0, 1, 3]), 4, 3, 0)
    assert [1, 1, 0, 0] in held.tolist()  # the "prepare" already playing may give way to the "turn" early


def test_in_order_fine_choices_never_say_an_instruction_before_one_explore_would_say_first():
    g = torch.Generator().manual_seed(3)
    allowed = torch.arange(7)
    checked = 0
    for _ in range(300):  # brute force over random plans: each kept fine choice skips nothing explore says before it
        future = torch.randint(0, 7, (12,), generator=g) * (torch.rand(12, generator=g) < 0.4)
        last = int(torch.randint(0, 7, (), generator=g))
        loose, _ = candidate_plans(future, last, allowed, 4, 3, 1)
        strict, e = candidate_plans(future, last, allowed, 4, 3, 1, in_order=True)
        assert strict.tolist()[e] == future[:4].tolist()
        assert {tuple(r) for r in strict.tolist()} <= {tuple(r) for r in loose.tolist()}  # a subset, never new plans
        reach = future[:4].tolist()
        for row in loose.tolist():
            a = row[0]
            if a == 0 or row != [a] * 4 or row in [future[k:k + 4].tolist() for k in range(4)]:
                continue  # not a fine choice (or also a re-timing of explore's plan)
            before = reach[: reach.index(a)] if a in reach else reach
            assert (row in strict.tolist()) == (not set(before) - {0, last, a}), (future, last, row)
            checked += 1
    assert checked > 100
    # explore's "prepare right" is still to come: "turn right" now is a loose candidate, not an in-order one
    future = torch.tensor([0, 4, 4, 2, 2, 0, 0, 0])
    assert [2] * 4 in candidate_plans(future, 0, allowed, 4, 3, 0)[0].tolist()
    assert [2] * 4 not in candidate_plans(future, 0, allowed, 4, 3, 0, in_order=True)[0].tolist()
    assert [2] * 4 in candidate_plans(future, 4, allowed, 4, 3, 0, in_order=True)[0].tolist()  # "prepare" said

def _root(n_actions: int = 7) -> TensorDict:
    g = torch.Generator().manual_seed(0)
    hist = torch.randn(5, 14 + n_actions, generator=g)
    return TensorDict({"history": hist, "explore_future": torch.tensor([0, 4, 4, 2, 2, 0, 0, 0, 0, 0]),
                       "route_ahead": torch.randn(20, 2, generator=g) * 10,
                       "action_mask": torch.ones(5, n_actions, dtype=torch.bool)}, [])


@torch.no_grad()
def test_retiming_cost_equals_a_brute_force_rollout_of_each_sequence():
    torch.manual_seed(0)
    model = DynamicsModel(hidden=(16,))
    planner = RetimingPlanner(ImaginedNavigationEnv(make_world_model(model)), horizon=4, advance=2, delay=1)
    root = _root()
    seqs, _ = candidate_plans(root["explore_future"], 0, torch.arange(7), 4, 2, 1)
    cost = planner.costs(root, seqs)[0][0]
    route = root["route_ahead"]
    for n, seq in enumerate(seqs.tolist()):
        hist, goal, total = root["history"].unsqueeze(0), root["history"][-1, 9:11], 0.0
        for a in seq:
            state = model(hist, torch.tensor([a]))
            hist = model.next_window(hist, torch.tensor([a]), state)
            d = (route - state[0, :2]).norm(dim=-1)
            total += float(tracking_cost(state[0, :2], goal)) + float(d.min()) ** 2
            goal = state[0, 9:11]
        total -= 3.0 * int(d.argmin())
        assert cost[n].item() == pytest.approx(total, rel=1e-4, abs=1e-3)


EAGER = Departure(margin=-1e12, rel_margin=0.0, agree=1e-9)  # leaves explore for any cheaper candidate


def test_retiming_planner_keeps_explore_unless_the_gain_is_clear():
    torch.manual_seed(0)
    env = ImaginedNavigationEnv(make_world_model(DynamicsModel(hidden=(16,))))
    root = _root()
    stubborn = RetimingPlanner(env, horizon=4, advance=2, delay=1, departure=Departure(margin=1e12))
    action, result = stubborn.decide(root)
    assert action == int(root["explore_future"][0]) and result.chosen == result.explore
    eager = RetimingPlanner(env, horizon=4, advance=2, delay=1, departure=EAGER)
    action, result = eager.decide(root)
    assert result.chosen == int(result.costs.argmin())  # no margin: the cheapest candidate
    assert eager(root.unsqueeze(0).expand(3))["action"].shape == (3,)


def test_retiming_planner_stays_with_explore_where_the_ensemble_disagrees():
    from pernav.model.adapt import meta_parameters

    torch.manual_seed(0)
    members = [DynamicsModel(hidden=(16,)) for _ in range(2)]
    env = ImaginedNavigationEnv(make_world_model(members[0]))
    root = _root()
    eager = {"margin": -1e12, "rel_margin": 0.0, "agree": 1e-9}  # as EAGER, with a spread test of its own
    confident = RetimingPlanner(env, 4, 2, 1, departure=Departure(max_spread=None, **eager))
    cautious = RetimingPlanner(env, 4, 2, 1, departure=Departure(max_spread=1e-6, rel_spread=0.0, **eager))
    for planner in (confident, cautious):
        planner.params = [meta_parameters(m).detach() for m in members]
    _, free = confident.decide(root)
    _, held = cautious.decide(root)
    assert free.chosen != free.explore  # with no spread test the cheapest candidate wins
    assert held.chosen == held.explore  # two random members disagree by far more than a micrometre
    _, one = RetimingPlanner(env, 4, 2, 1, departure=cautious.departure).decide(root)  # one row: no test
    assert one.chosen == int(one.costs.argmin())


def test_retiming_gate_needs_every_member_to_clear_the_margin_and_scales_the_spread_with_the_effect():
    env = ImaginedNavigationEnv(make_world_model(DynamicsModel(hidden=(8,))))
    root = _root()
    probe = RetimingPlanner(env, horizon=4, advance=2, delay=1, departure=EAGER)
    _, res = probe.decide(root)
    N, e = res.candidates.shape[0], res.explore
    j = next(i for i in range(N) if int(res.candidates[i, 0]) != int(res.candidates[e, 0]))

    def crafted(gains: tuple[float, float], effects: tuple[float, float]):
        cost = torch.full((2, N), 100.0)
        cost[:, j] = 100.0 - torch.tensor(gains)
        pos = torch.zeros(2, N, 4, 2)
        pos[:, j, :, 0] = torch.tensor(effects)[:, None]  # each row moves the car this far off explore's plan
        return lambda *_: (cost, pos)

    def leaves(gains, effects, **kw) -> bool:
        kw = {"rel_spread": 0.5, **kw}
        departure = Departure(margin=20.0, rel_margin=0.0, **kw)
        planner = RetimingPlanner(env, horizon=4, advance=2, delay=1, departure=departure)
        planner.costs = crafted(gains, effects)
        return planner.decide(root)[1].chosen == j

    assert leaves((60.0, 50.0), (30.0, 20.0))  # both clear 20; spread 5 m <= 2 + 0.5 * 25 m
    assert not leaves((95.0, 10.0), (30.0, 20.0))  # mean 52.5 clears it, the worst member does not
    assert leaves((95.0, 10.0), (30.0, 20.0), agree=0.5)
    assert not leaves((60.0, 50.0), (30.0, 20.0), rel_spread=0.0)  # a fixed 2 m bound holds it back
    assert not leaves((60.0, 50.0), (40.0, 0.0))  # spread 20 m > 2 + 0.5 * 20 m: they disagree on the effect


def test_with_wait_a_departure_must_beat_waiting_a_step_not_only_explores_plan():
    env = ImaginedNavigationEnv(make_world_model(DynamicsModel(hidden=(8,))))
    root = _root()
    _, res = RetimingPlanner(env, horizon=4, advance=2, delay=1, departure=EAGER).decide(root)
    N, e, first = res.candidates.shape[0], res.explore, res.candidates[:, 0]
    j = next(i for i in range(N) if int(first[i]) != int(first[e]))  # plays another action now
    w = next(i for i in range(N) if i != e and int(first[i]) == int(first[e]))  # explore's action now, re-timed later

    def chosen(cost_j: float, wait: bool) -> int:
        cost = torch.full((2, N), 400.0)
        cost[:, e], cost[:, w], cost[:, j] = 300.0, 100.0, cost_j  # explore's own plan is the dear one
        planner = RetimingPlanner(env, horizon=4, advance=2, delay=1,
                                  departure=Departure(margin=20.0, rel_margin=0.0, max_spread=None, wait=wait))
        planner.costs = lambda *_: (cost, torch.zeros(2, N, 4, 2))
        return planner.decide(root)[0]

    assert chosen(90.0, wait=False) == int(first[j])  # 210 cheaper than explore's plan
    assert chosen(90.0, wait=True) == int(first[e])  # but only 10 cheaper than waiting a step: wait
    assert chosen(50.0, wait=True) == int(first[j])  # 50 cheaper than waiting: leave now


def test_retiming_planner_with_21_actions_plans_every_playback():
    env = ImaginedNavigationEnv(make_world_model(DynamicsModel(n_actions=21, hidden=(8,))))
    planner = RetimingPlanner(env, horizon=3, advance=2, delay=1, departure=EAGER)
    action, result = planner.decide(_root(21))
    assert 0 <= action < 21 and {int(a) % 3 for a in result.candidates[:, 0] if a >= 3} == {0, 1, 2}


def test_paper_planner_on_the_true_model_matches_its_tree_on_a_deterministic_copy():
    env, info = _live()
    true = TrueDynamicsEnv(env, samples=1)
    planner = TreeSearchPlanner(true, horizon=3, shift=2)
    root = TensorDict({"observation": torch.as_tensor(env._observation()),
                       "history": torch.as_tensor(env._observation()).expand(5, 14).clone(),
                       "plan_goals": torch.as_tensor(info["plan_goals"]),
                       "explore_plan": torch.as_tensor(info["explore_plan"]),
                       "action_mask": torch.as_tensor(info["action_mask"])}, [])
    root["history"] = torch.cat([root["history"], torch.zeros(5, 7)], -1)
    assert 0 <= int(planner(root)["action"]) < 7 and planner.last.evaluations >= 3


def test_build_planner_rejects_unknown_kinds_and_options():
    env = ImaginedNavigationEnv(make_world_model(DynamicsModel(hidden=(8,))))
    assert isinstance(build_planner(env, {}), RetimingPlanner)
    with pytest.raises(ValueError, match="unknown planner kind 'cem'"):
        build_planner(env, {"kind": "cem"})
    with pytest.raises(ValueError, match="unknown retime planner option 'bonus'"):
        build_planner(env, {"kind": "retime", "bonus": 1.0})


def test_bootstrap_intervals_cover_the_mean_and_pairs_must_match():
    rng = np.random.default_rng(0)
    x = rng.normal(5.0, 1.0, 200)
    mean, lo, hi = bootstrap_ci(x)
    assert lo < 5.0 < hi and hi - lo < 0.5
    d = paired_difference(x + 1.0, x)
    assert d["mean"] == pytest.approx(1.0) and d["low"] == pytest.approx(1.0)
    with pytest.raises(ValueError, match="paired"):
        paired_difference([1.0, 2.0], [1.0])
    g = gap_closed([10.0, 12.0, 11.0], [6.0, 7.0, 6.5], [2.0, 2.0, 2.0])
    assert g["low"] <= g["mean"] <= g["high"] and g["mean"] == pytest.approx(0.5)
    assert np.isnan(gap_closed([1.0], [1.0], [2.0])["mean"])  # no gap: nothing to close


def test_compare_pools_rounds_and_separates_rounds_without_headroom():
    def rnd(explore: float, method: float, oracle: float) -> dict:
        ep = lambda c: {"tracking_cost": c, "collisions": 0, "missed_turns": 0, "extra_distance": 0.0}  # noqa: E731
        return {"phase": "online", "towns": {"T": {m: {"episodes": [ep(c), ep(c + 2)]} for m, c in
                                                  (("explore", explore), ("adapt", method), ("oracle", oracle))}}}

    out = compare([[rnd(100.0, 60.0, 20.0)], [rnd(100.0, 104.0, 98.0)]])["T"]["adapt"]
    assert out["rounds"] == 2 and out["headroom_rounds"] == 1
    assert out["gap_closed_headroom"]["mean"] == pytest.approx(0.5)
    assert out["relative_cost_no_headroom"] == pytest.approx(105.0 / 101.0)


def test_comparison_table_pairs_episodes_by_driver_town_route_and_seed():
    def ep(method: str, route: int, cost: float, seed: int = 0) -> dict:
        return {"driver": "d", "town": "T", "route": route, "seed": seed, "method": method, "tracking_cost": cost,
                "collisions": 0, "missed_turns": route, "extra_distance": 0.0}

    episodes = [ep(m, r, c + r) for r in range(4) for m, c in (("explore", 10.0), ("oracle", 4.0), ("x", 7.0))]
    episodes.append(ep("x", 0, 1000.0, seed=9))  # no explore/oracle episode with this seed: left out
    rows = {line.split("|")[1].strip(): line.split("|")[2:-1] for line in comparison_table(episodes).splitlines()[2:]}
    assert rows["x"][0].strip() == "4" and rows["x"][1].strip() == "8"  # mean of 7, 8, 9, 10 on the paired four
    assert rows["x"][2].startswith(" +3 [+3, +3]") and rows["x"][3].startswith(" 50% [50%, 50%]")
    assert rows["x"][5].strip() == "6 (6)"  # missed turns summed over the same episodes as explore's


@pytest.mark.slow
def test_panel_job_on_a_learned_model_reads_the_history_the_model_was_trained_with():
    model = DynamicsModel(n_actions=7, K=10, hidden=(8,))
    spec = {"config": model.config(), "state": model.state_dict()}
    m = drive_panel_episode(PanelJob("user4, keyboard (fast)", "Town1", 0, 0, "retime@learned", n_traffic=0,
                                     model=spec))
    assert m["method"] == "retime@learned" and m["steps"] > 0 and 0.0 <= m["left_explore"] <= 1.0


def test_extra_distance_is_zero_on_a_clean_drive_and_never_negative():
    env = NavigationEnv("Town1", config={"n_traffic": 0})
    _, info = env.reset(seed=0, options={"route": 0, "user": "user7"})
    done = False
    while not done:
        _, _, te, tr, info = env.step(info["explore_action"])
        done = te or tr
        assert info["extra_distance"] >= 0.0
    assert info["completed"] and info["missed_turns"] == 0 and info["extra_distance"] < 10.0


def _collect(policy, seed: int = 5):
    from pernav.planner.factory import env_planning_config
    from pernav.trainer.collect import drive, history_env

    config = {"n_traffic": 2, **env_planning_config({"kind": "retime"})}
    env = history_env("Town1", {"route": 1, "user": "user3"}, config=config, seed=seed, K=5)
    return drive(env, policy, max_steps=80)


@pytest.mark.slow
def test_retimed_explore_is_explore_at_p0_and_retimes_explore_prompts_otherwise():
    from pernav.env.torchrl_env import explore_module
    from pernav.planner import RetimedExplore

    explore = _collect(explore_module())
    assert torch.equal(_collect(RetimedExplore(p=0.0, seed=1))["action"], explore["action"])
    a, b = _collect(RetimedExplore(p=1.0, seed=1)), _collect(RetimedExplore(p=1.0, seed=1))
    assert torch.equal(a["action"], b["action"])  # seeded
    assert (a["action"][: explore.shape[0]] != explore["action"][: a.shape[0]]).any()
    from pernav.trainer.collect import episode_metrics

    assert episode_metrics(explore)["left_explore"] == 0.0 and 0.0 < episode_metrics(a)["left_explore"] < 1.0
    # it only re-times: every instruction it plays is one explore plays on this route or one the mask allows
    masks = a["action_mask"][:, 0]
    said = set(explore["action"].tolist()) | {0}
    assert all(int(x) in said or bool(m[int(x)]) for x, m in zip(a["action"], masks, strict=True))
    with pytest.raises(ValueError, match="hold"):
        RetimedExplore(hold=0)


def test_planner_options_parse_json_values_and_name_the_allowed_keys():
    from pernav.planner.factory import build_planner, parse_planner_options

    opts = parse_planner_options("retime", ["max_spread=null", "agree=0.67", "horizon=10"])
    assert opts == {"max_spread": None, "agree": 0.67, "horizon": 10}
    planner = build_planner(ImaginedNavigationEnv(make_world_model(DynamicsModel(hidden=(8,)))), {"kind": "retime", **opts})
    assert planner.max_spread is None and planner.agree == 0.67 and planner.horizon == 10
    # rescue, rescue_evidence and route_goals were options once (measured, not used): refused like any unknown key
    for bad, match in (("max_spread", "KEY=VALUE"), ("beam=3", "options: horizon"), ("margin=big", "a number"),
                       ("rescue=8", "options: horizon"), ("route_goals=true", "options: horizon")):
        with pytest.raises(ValueError, match=match):
            parse_planner_options("retime", [bad])


def test_by_distance_a_candidate_says_its_prompts_where_the_plan_does_in_metres_not_in_steps():
    # a car imagined at twice (half) the plan's speed reaches the plan's step j at step j / 2 (2 j): by distance,
    # explore's "prepare" due at the plan's step 4 is said at step 2 (8), and the first action is never moved
    from pernav.model.driver import DriverImaginedEnv
    from pernav.model.egocentric import VX, X

    class Straight(DriverImaginedEnv):  # the imagined car drives along x at ``v`` m/s from x = 0, whatever it is told
        def __init__(self, v: float) -> None:
            super().__init__()
            self.v = v

        def imagine(self, root, seqs, **_):
            H = seqs.shape[1]
            x = self.v * torch.arange(1, H + 1, dtype=torch.float32)
            pos = torch.stack([x, torch.zeros(H)], -1).expand(2, seqs.shape[0], H, 2)
            return pos, pos

    root = _root()
    root["history"][-1, X], root["history"][-1, X + 1], root["history"][-1, VX], root["history"][-1, VX + 1] = 0, 0, 5, 0
    plan = torch.tensor([[0, 0, 0, 0, 4, 4, 4, 4, 2, 2, 2, 2]])
    fast = RetimingPlanner(Straight(10.0), horizon=12).distance_steps(root, plan, 0)
    slow = RetimingPlanner(Straight(2.5), horizon=12).distance_steps(root, plan, 0)
    assert fast.tolist() == [[0, 0, 4, 4, 2, 2, 2, 2, 2, 2, 2, 2]]  # the plan's steps 0, 2, 4, ... (the last held)
    assert slow.tolist() == [[0, 0, 0, 0, 0, 0, 0, 0, 4, 4, 4, 4]]  # steps 0, 0, 1, 1, 2, 2, ...
    assert RetimingPlanner(Straight(5.0), horizon=12).distance_steps(root, plan, 0).tolist() == plan.tolist()
    root["history"][-1, VX] = 0.0  # stopped: explore's plan does not move on, nor does the reading
    assert RetimingPlanner(Straight(10.0), horizon=12).distance_steps(root, plan, 0).tolist() == plan.tolist()


def _table(prepare: tuple[float, float], turn: tuple[float, float]) -> torch.Tensor:
    """An explore table that says "prepare right" (4) ``prepare[0] <= x < prepare[1]`` m ahead and "turn right" (2)
    ``turn[0] <= x < turn[1]`` m ahead, at every speed."""
    from pernav.env.layout import EXPLORE_POINTS, EXPLORE_SPEEDS, ROUTE_SPACING

    x = torch.arange(EXPLORE_POINTS) * ROUTE_SPACING
    row = torch.where((x >= prepare[0]) & (x < prepare[1]), 4, 0)
    row = torch.where((x >= turn[0]) & (x < turn[1]), 2, row)
    return row.expand(len(EXPLORE_SPEEDS), -1).clone()


def test_closed_loop_says_explores_prompts_where_its_rule_would_on_the_imagined_car():
    # explore's rule (the table) says "prepare" 30-60 m on and "turn" 60-97 m on. Played closed loop on a car
    # imagined at 10 m/s it says them at steps 3-5 and 6-9; on one at 5 m/s at steps 6-11 and 12-15; shifted 2 steps
    # early (a candidate "explore 2 steps early") 20 m sooner; the first action is always the candidate's own
    from pernav.model.egocentric import VX, X

    def car(speeds: list[float]) -> torch.Tensor:  # [1, 1, H, 2]: positions along x after each step
        x = torch.tensor(speeds).cumsum(0)
        return torch.stack([x, torch.zeros_like(x)], -1)[None, None]

    root = _root()
    root["history"][-1, X], root["history"][-1, X + 1], root["history"][-1, VX], root["history"][-1, VX + 1] = 0, 0, 10, 0
    root["explore_table"] = _table((30.0, 60.0), (60.0, 97.0))
    planner = RetimingPlanner(DriverImaginedEnv(), horizon=16, advance=8)
    seqs = torch.zeros(1, 16, dtype=torch.long)
    k0, k2 = torch.tensor([0]), torch.tensor([2])
    fast = planner.closed_sequences(root, seqs, car([10.0] * 16), k0)[0, 0].tolist()
    assert fast == [0, 0, 0, 4, 4, 4, 2, 2, 2, 2, 0, 0, 0, 0, 0, 0]
    early = planner.closed_sequences(root, seqs, car([10.0] * 16), k2)[0, 0].tolist()
    assert early == [0, 4, 4, 4, 2, 2, 2, 2, 0, 0, 0, 0, 0, 0, 0, 0]
    root["history"][-1, VX] = 5.0
    slow = planner.closed_sequences(root, seqs, car([5.0] * 16), k0)[0, 0].tolist()
    assert slow == [0] * 6 + [4] * 6 + [2] * 4
    # "prepare" said now, 4 steps early; a car that slows hard after the "turn" was said brings the "prepare" back into
    # reach 4 steps ahead (at step 5): as explore's rule, the closed loop says neither again once another was said
    root["history"][-1, VX] = 12.0
    prepare_now = torch.tensor([[4] + [0] * 15])
    braking = planner.closed_sequences(root, prepare_now, car([12.0] * 4 + [2.0] * 12), torch.tensor([4]))
    assert braking[0, 0].tolist() == [4, 2, 2, 2, 2] + [0] * 11
    # a candidate that is no shift of explore's plan (-1: a fine choice held) is imagined as it is
    held = torch.full((1, 16), 2)
    assert planner.closed_sequences(root, held, car([10.0] * 16), torch.tensor([-1]))[0, 0].tolist() == [2] * 16


def _right_turn_root() -> TensorDict:
    """A car at 10 m/s with no prompt yet, a right turn 57 m ahead (the hybrid driver model's example)."""
    route = torch.stack([torch.arange(96.0) * 3 - 15, torch.zeros(96)], -1)
    route[25:, 1] = (torch.arange(71.0) + 1) * 3
    route[25:, 0] = route[24, 0]
    history = torch.zeros(5, 21)
    history[:, 3] = 10.0
    return TensorDict({"history": history, "route_ahead": route, "distance_to_junction": torch.tensor(57.0)}, [])


def test_closed_loop_needs_the_env_table_and_keeps_the_candidates_first_actions():
    from pernav.model.driver import DriverParams

    root = _right_turn_root()
    root["explore_future"] = torch.tensor([0, 0, 4, 4, 4, 2, 2, 2, 2, 2, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0])
    root["action_mask"] = torch.ones(5, 7, dtype=torch.bool)
    planner = RetimingPlanner(DriverImaginedEnv([DriverParams(reaction_time=2.5)]), horizon=16, advance=8,
                              departure=Departure(margin=-1e9, rel_margin=0.0, agree=1e-9, max_spread=None))
    planner.closed_loop = True
    with pytest.raises(KeyError, match="explore_table"):
        planner.decide(root)
    root["explore_table"] = _table((15.0, 45.0), (45.0, 57.0))
    action, result = planner.decide(root)
    assert result is not None and action == int(result.candidates[result.chosen, 0])
    assert torch.isfinite(result.costs).all()


def test_a_capped_step_charge_is_each_steps_charge_clamped_and_makes_a_missed_turn_cost_at_most_the_cap_a_step():
    # RetimingPlanner.step_cap (off by default): the "turn" said now is taken, said 14 steps late it is missed. Capped,
    # the score is the brute-force sum of each step's (tracking + squared route distance) clamped at the cap, less the
    # same progress: a miss then costs at most the cap a step instead of its squared metres
    from pernav.env.layout import ROUTE_SPACING
    from pernav.model.driver import DriverParams
    from pernav.model.egocentric import GX, GY

    root = _right_turn_root()
    route, history = root["route_ahead"], root["history"]
    planner = RetimingPlanner(DriverImaginedEnv([DriverParams(reaction_time=1.0)]), horizon=16)
    seqs = torch.stack([torch.full((16,), 2), torch.cat([torch.zeros(14, dtype=torch.long), torch.full((2,), 2)])])
    pos, goal = planner._imagine(root, seqs)
    plain = planner.score(root, pos, goal)
    planner.step_cap = 10.0
    capped = planner.score(root, pos, goal)
    prev = torch.cat([history[-1, [GX, GY]].expand(*goal.shape[:2], 1, 2), goal[:, :, :-1]], dim=2)
    dist, nearest = torch.cdist(pos.reshape(-1, 2), route).reshape(*pos.shape[:-1], -1).min(-1)
    step = tracking_cost(pos, prev) + dist ** 2
    progress = ROUTE_SPACING * nearest[..., -1].float()
    assert torch.allclose(plain, step.sum(-1) - progress, rtol=1e-5)
    assert torch.allclose(capped, step.clamp(max=10.0).sum(-1) - progress, rtol=1e-5)
    assert float(plain[0, 1] - plain[0, 0]) > 1000.0  # the miss, uncapped: thousands of squared metres
    assert 0.0 < float(capped[0, 1] + progress[0, 1]) <= 16 * 10.0 + 1e-4
