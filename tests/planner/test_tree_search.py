"""The paper's TreeSearchPlanner on small random models: its search equals a brute-force enumeration of every
allowed sequence (route or state goals, with or without the mask, bonus and penalty), a beam that keeps every node
equals the exhaustive search, the mask keeps it silent where no junction is ahead (on made-up goals and in the real
Town1 and Town2), and it runs as a TorchRL collector's policy.
"""

from __future__ import annotations

import itertools

import pytest
import torch
from navigation_helpers import FAST, TOWN1, S
from navigation_helpers import seeded_model as _model
from tensordict import TensorDict
from torchrl.collectors import Collector

from pernav.env.planning import TURN_REACH
from pernav.model import DynamicsModel
from pernav.model.navigation import ImaginedNavigationEnv, make_world_model
from pernav.planner import TreeSearchPlanner
from pernav.trainer.collect import history_env


def _planner(model: DynamicsModel, **kwargs) -> TreeSearchPlanner:
    kwargs.setdefault("goal_source", "route")  # the goals these tests control (``plan_goals``)
    kwargs.setdefault("shift_decay", 0.0)  # the brute force below gives every shift the same bonus
    return TreeSearchPlanner(ImaginedNavigationEnv(make_world_model(model)), **kwargs)


def _search(planner: TreeSearchPlanner, obs, hist, goals, plan, mask) -> tuple[torch.Tensor, float, int]:
    """One root's (best sequence [H], its cost, env steps) from the planner's search."""
    root = TensorDict({"observation": obs, "history": hist, "plan_goals": goals, "explore_plan": plan,
                       "action_mask": mask}, []).unsqueeze(0)
    result = planner.search(root)
    return result.actions[0], -float(result.returns[0]), result.evaluations


def _root(n_actions: int, H: int, shift: int, seed: int, K: int = 5):
    """A random planning problem: (observation, history, goals [H, 2], explore plan [H + 2S], mask [H, A])."""
    g = torch.Generator().manual_seed(seed)
    history = torch.randn(K, S + n_actions, generator=g)
    history[:, S:] = torch.nn.functional.one_hot(torch.randint(n_actions, (K,), generator=g), n_actions).float()
    history[-1, S:] = 0.0
    goals = torch.randn(H, 2, generator=g)
    plan = torch.randint(7, (H + 2 * shift,), generator=g)
    mask = torch.rand(H, n_actions, generator=g) < 0.6
    mask[:, 0] = True  # silence is always allowed (as in the env)
    return history[-1, :S].clone(), history, goals, plan, mask


def _brute_force(model: DynamicsModel, history, goals, plan, mask, *, bonus: float, penalty: float,
                 use_mask: bool, playbacks: int, goal_source: str = "route",
                 shift_decay: float = 0.0) -> tuple[torch.Tensor, float]:
    """Every sequence of allowed actions rolled out with ``model`` and ``model.next_window``; best (seq, cost)."""
    H, A = goals.shape[0], model.n_actions
    sets = [[a for a in range(A) if bool(mask[h, a]) or not use_mask] for h in range(H)]
    seqs = torch.tensor(list(itertools.product(*sets)), dtype=torch.long)
    hist = history.expand(seqs.shape[0], *history.shape)
    cost = torch.zeros(seqs.shape[0], dtype=torch.float64)
    previous = hist[:, -1, :14]
    with torch.no_grad():
        for h in range(H):
            a = seqs[:, h]
            state = model(hist, a)
            goal = previous[:, 9:11] if goal_source == "state" else goals[h]  # state: g_t of the previous state
            cost += ((state[:, 0:2] - goal) ** 2).sum(-1).double()
            previous = state
            if not use_mask:
                cost += penalty * ((a // playbacks >= 1) & ~mask[h, a]).double()
            hist = model.next_window(hist, a, state)
    windows = torch.stack([plan[k:k + H] for k in range(plan.shape[0] - H + 1)])
    matches = ((seqs // playbacks)[:, None, :] == windows[None]).all(-1).double()  # [N, 2S + 1]
    S = (windows.shape[0] - 1) // 2
    weights = torch.tensor([1.0 - shift_decay * abs(k - S) for k in range(windows.shape[0])], dtype=torch.float64)
    cost -= bonus * (matches * weights).max(-1).values
    best = int(torch.argmin(cost))
    return seqs[best], float(cost[best])


# ----- planner == brute force ------------------------------------------------------------------------
@pytest.mark.parametrize("goal_source,shift_decay", [("route", 0.0), ("state", 0.0), ("state", 0.25)])
@pytest.mark.parametrize("n_actions,H,use_mask", [(7, 4, True), (7, 4, False), (7, 5, True),
                                                  (21, 3, True), (21, 3, False)])
def test_planner_equals_brute_force(n_actions: int, H: int, use_mask: bool, goal_source: str,
                                    shift_decay: float) -> None:
    playbacks = 3 if n_actions == 21 else 1
    shift, bonus, penalty = 2, 0.5, 2.0  # small bonus/penalty so that both change the optimum sometimes
    for seed in range(3):
        model = _model(seed, n_actions=n_actions)
        planner = _planner(model, horizon=H, shift=shift, bonus=bonus, penalty=penalty, mask=use_mask,
                           goal_source=goal_source, shift_decay=shift_decay)
        assert planner.playbacks == playbacks
        for problem in range(2):
            obs, hist, goals, plan, mask = _root(n_actions, H, shift, seed=100 * seed + problem)
            actions, found, evaluations = _search(planner, obs, hist, goals, plan, mask)
            seq, cost = _brute_force(model, hist, goals, plan, mask, bonus=bonus, penalty=penalty,
                                     use_mask=use_mask, playbacks=playbacks, goal_source=goal_source,
                                     shift_decay=shift_decay)
            assert int(actions[0]) == int(seq[0])
            assert torch.equal(actions, seq)
            assert found == pytest.approx(cost, rel=1e-5, abs=1e-4)
            leaves = int(torch.tensor([int(mask[h].sum()) if use_mask else n_actions for h in range(H)]).prod())
            assert evaluations < H * leaves  # shared prefixes: fewer model steps than a flat enumeration


def test_planner_bonus_and_penalty_matter() -> None:
    """The brute-force comparison is not vacuous: the bonus and the penalty change the chosen sequence."""
    model = _model(0)
    obs, hist, goals, plan, mask = _root(7, 3, 1, seed=5)
    free = _search(_planner(model, horizon=3, shift=1, bonus=0.0, mask=False, penalty=0.0),
                   obs, hist, goals, plan, torch.ones_like(mask))[0]
    plan = torch.cat([torch.zeros(1, dtype=torch.long), (free + 1) % 7, torch.zeros(1, dtype=torch.long)])
    lured = _search(_planner(model, horizon=3, shift=1, bonus=1e6), obs, hist, goals, plan, torch.ones_like(mask))[0]
    windows = plan.unfold(0, 3, 1)  # the plan shifted by -1, 0, 1
    assert (lured == windows).all(-1).any() and not torch.equal(lured, free)
    forbidden = torch.ones_like(mask)
    forbidden[:, 1:] = False
    fined = _search(_planner(model, horizon=3, shift=1, bonus=0.0, penalty=1e6, mask=False),
                    obs, hist, goals, plan, forbidden)[0]
    assert not fined.any()


# ----- beam == exhaustive when it keeps every node -----------------------------------------------------
@pytest.mark.parametrize("n_actions,H", [(7, 4), (21, 3)])
def test_wide_beam_equals_exhaustive(n_actions: int, H: int) -> None:
    model = _model(1, n_actions=n_actions)
    exhaustive = _planner(model, horizon=H, shift=2)
    for seed in range(3):
        obs, hist, goals, plan, mask = _root(n_actions, H, 2, seed=seed)
        leaves = n_actions ** H
        full = _search(exhaustive, obs, hist, goals, plan, mask)
        beam = _search(_planner(model, horizon=H, shift=2, beam=leaves), obs, hist, goals, plan, mask)
        assert torch.equal(beam[0], full[0]) and beam[1] == full[1]
        narrow = _search(_planner(model, horizon=H, shift=2, beam=4), obs, hist, goals, plan, mask)
        assert narrow[1] >= full[1] - 1e-4 and narrow[2] < full[2]


# ----- no turn prompts without a junction ahead -----------------------------------------------------
def test_masked_planner_stays_silent_without_junction() -> None:
    """Goals placed where repeating "turn left" (1) would take the car: the unmasked search prompts, the
    masked one (or a penalized one) stays silent when the mask allows only silence."""
    model = _model(2)
    H = 4
    obs, hist, _, _, _ = _root(7, H, 2, seed=3)
    goals, h = [], hist.unsqueeze(0)
    with torch.no_grad():
        for _ in range(H):
            state = model(h, torch.tensor([1]))
            goals.append(state[0, :2])
            h = model.next_window(h, torch.tensor([1]), state)
    goals = torch.stack(goals)
    plan = torch.zeros(H + 4, dtype=torch.long)
    td = TensorDict({"observation": obs, "history": hist, "plan_goals": goals, "explore_plan": plan,
                     "action_mask": torch.ones(H, 7, dtype=torch.bool)}, [])
    assert int(_planner(model, horizon=H, bonus=0.0)(td.clone())["action"]) == 1
    td["action_mask"][:, 1:] = False
    assert int(_planner(model, horizon=H, bonus=0.0)(td.clone())["action"]) == 0
    assert int(_planner(model, horizon=H, bonus=0.0, mask=False, penalty=1e3)(td.clone())["action"]) == 0


@pytest.mark.parametrize("town,route", [("Town1", 0), ("Town2", 0)])
def test_planner_in_real_env_respects_mask(town: str, route: int) -> None:
    """Town1 route 0 has a junction within reach at every step; Town2 route 0 has long straights."""
    env = history_env(town, {"route": route, "user": "user1"}, config=FAST, seed=0)
    planner = _planner(_model(3))
    td = env.rollout(40, policy=planner, break_when_any_done=True)
    assert td.shape[0] >= 20
    actions = td["action"]
    assert td["action_mask"][torch.arange(td.shape[0]), 0, actions].all()
    assert actions.any()  # the random model does prompt; the mask decides which prompts
    turns = (actions >= 1) & (actions <= 4)
    far = td["distance_to_junction"] > TURN_REACH
    # Beyond TURN_REACH a turn prompt is only ever the explore policy's own (always in the tree, see
    # pernav.env.planning.action_mask): the explore policy says "prepare" up to ~175 m ahead at speed.
    explore_now = td["explore_plan"][:, 2]
    assert (actions[turns & far] == explore_now[turns & far]).all()
    if town == "Town2":
        assert far.sum() >= 10
        assert not turns[far & (explore_now == 0)].any()
    assert (td["next", "observation"][:-1] == td["observation"][1:]).all()


def test_planner_as_collector_policy() -> None:
    planner = _planner(_model(4))
    collector = Collector(lambda: history_env(*TOWN1, config=FAST, seed=0), policy=planner,
                          frames_per_batch=4, total_frames=8, auto_register_policy_transforms=False)
    batches = list(collector)
    collector.shutdown()
    assert len(batches) == 2
    for batch in batches:
        assert batch.numel() == 4
        allowed = batch["action_mask"].reshape(-1, 5, 7)[torch.arange(4), 0, batch["action"].reshape(-1)]
        assert allowed.all()
