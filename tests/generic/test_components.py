"""Components of the method used on their own: planner vs brute force, masks in a
real env, replay windows, the meta-gradient through U(P, tau), save/load, the imagined env, the docs.

Small models (hidden (16, 16) or less) wherever the size does not matter; everything is seeded.
"""

from __future__ import annotations

import itertools
import re
from pathlib import Path

import pytest
import torch
from tensordict import TensorDict
from torchrl.collectors import Collector
from torchrl.envs import check_env_specs

from pernav.env.planning import TURN_REACH
from pernav.model import DynamicsModel, adapt, multistep_loss
from pernav.model.world_model import ImaginedNavigationEnv, make_world_model
from pernav.planner import TreeSearchPlanner
from pernav.trainer import RoundBuffers
from pernav.trainer.collect import history_env

S = 14
DOCS = Path(__file__).resolve().parents[2] / "docs" / "components.md"
TOWN1 = ("Town1", {"route": 0, "user": "user1"})
FAST = {"n_traffic": 2}


def _model(seed: int, n_actions: int = 7, K: int = 5, hidden: tuple[int, ...] = (16, 16)) -> DynamicsModel:
    torch.manual_seed(seed)
    return DynamicsModel(n_actions=n_actions, K=K, hidden=hidden)


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


# ----- 1. planner == brute force ------------------------------------------------------------------------
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


# ----- 2. beam == exhaustive when it keeps every node -----------------------------------------------------
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


# ----- 3. no turn prompts without a junction ahead -----------------------------------------------------
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


# ----- 4. replay windows never cross a trajectory end ---------------------------------------------------
def test_buffer_windows_stay_inside_one_trajectory() -> None:
    L = 5
    buffers = RoundBuffers(L=L, capacity=1000, seed=0)
    lengths = [7, 5, 12, 30, 6, 19]
    for marker, T in enumerate(lengths):
        obs = torch.zeros(T, S)
        obs[:, 0] = torch.arange(T, dtype=torch.float32)
        obs[:, 1] = float(marker)
        traj = TensorDict({"observation": obs, "action": torch.randint(7, (T,)), "history": torch.zeros(T, 5, 21),
                           ("next", "observation"): obs + 1}, [T])
        buffers.add(marker % 2, traj, tau=marker < 2)
    for round_ in (0, 1):
        windows = buffers.sample(round_, 400)
        assert windows.shape == (400, L)
        step, marker = windows["observation"][..., 0], windows["observation"][..., 1]
        assert (marker == marker[:, :1]).all()
        assert (windows["traj"] == windows["traj"][:, :1]).all()
        assert (step.diff(dim=1) == 1).all()
        assert (windows["round"] == round_).all()
        assert set(marker[:, 0].long().tolist()) == {m for m in range(len(lengths)) if m % 2 == round_}
        ends = torch.tensor(lengths)[marker[:, -1].long()]
        assert (step[:, -1] < ends).all()


# ----- 5. the meta-gradient through U(P, tau) -------------------------------------------------------------
def _meta_problem(seed: int = 0, T: int = 9, B: int = 3, L: int = 3):
    model = _model(seed, K=3, hidden=(8,)).double()
    g = torch.Generator().manual_seed(seed)

    def transitions(*shape):
        return TensorDict({"history": torch.randn(*shape, 3, 21, generator=g, dtype=torch.float64),
                           "action": torch.randint(7, shape, generator=g),
                           "observation": torch.randn(*shape, S, generator=g, dtype=torch.float64),
                           ("next", "observation"): torch.randn(*shape, S, generator=g, dtype=torch.float64)},
                          list(shape))

    params = TensorDict.from_module(model).detach().clone()
    for key in params.keys(True, True):
        if key[0] == "net":  # the MLP's weights and biases; the normalization buffers stay constant
            params.get(key).requires_grad_()
    return model, params, transitions(T), transitions(B, L)


def _outer(model, params, tau, batch, key, first_order: bool = False):
    def f(tensor):
        p = params.copy()
        p.set(key, tensor)
        adapted = adapt(model, tau, alpha=0.05, L=3, first_order=first_order, params=p)
        return multistep_loss(model, batch, params=adapted)
    return f


def test_meta_gradient_matches_finite_differences() -> None:
    model, params, tau, batch = _meta_problem()
    for key in (("net", "0", "bias"), ("net", "2", "weight")):
        theta = params.get(key).detach().clone().requires_grad_()
        assert torch.autograd.gradcheck(_outer(model, params, tau, batch, key), (theta,), eps=1e-6, atol=1e-6)


def test_first_order_drops_the_second_order_term() -> None:
    model, params, tau, batch = _meta_problem(seed=1)
    key = ("net", "0", "weight")
    theta = params.get(key).detach().clone().requires_grad_()
    second, = torch.autograd.grad(_outer(model, params, tau, batch, key)(theta), theta)
    first, = torch.autograd.grad(_outer(model, params, tau, batch, key, first_order=True)(theta), theta)
    # first order by hand: the adaptation gradient detached
    p = params.copy()
    p.set(key, theta)
    keys = [k for k in p.keys(True, True) if p.get(k).requires_grad]
    grads = torch.autograd.grad(multistep_loss(model, _windows(tau, 3), params=p), [p.get(k) for k in keys])
    adapted = p.copy()
    for k, gk in zip(keys, grads, strict=True):
        adapted.set(k, p.get(k) - 0.05 * gk.detach())
    manual, = torch.autograd.grad(multistep_loss(model, batch, params=adapted), theta)
    assert torch.allclose(first, manual, rtol=1e-10, atol=1e-12)
    assert not torch.allclose(first, second, rtol=1e-3, atol=1e-6)


def _windows(tau, L):
    """The L-slices that tile tau (adapt's default, stride L)."""
    index = torch.arange(0, tau.shape[0] - L + 1, L)[:, None] + torch.arange(L)[None]
    return tau[index]


# ----- 6. save / load ---------------------------------------------------------------------------------
def test_round_buffers_save_load(tmp_path) -> None:
    buffers = RoundBuffers(L=4, capacity=200, seed=3)
    g = torch.Generator().manual_seed(0)
    for i, T in enumerate([10, 8, 15]):
        buffers.add(i // 2, TensorDict({"observation": torch.randn(T, S, generator=g),
                                        "action": torch.randint(7, (T,), generator=g),
                                        "history": torch.randn(T, 5, 21, generator=g),
                                        ("next", "observation"): torch.randn(T, S, generator=g)}, [T]),
                    tau=i != 1)
    buffers.sample(0, 3)  # the generator has moved: the saved state must be the current one
    buffers.save(tmp_path / "rb")
    loaded = RoundBuffers.load(tmp_path / "rb")
    assert loaded.rounds == buffers.rounds and loaded.n_traj == buffers.n_traj and loaded.L == buffers.L
    for r in buffers.rounds:
        assert (loaded.data(r) == buffers.data(r)).all()
        assert (loaded.tau(r) == buffers.tau(r)).all()
    for r in (0, 1, 0):
        assert (loaded.sample(r, 6) == buffers.sample(r, 6)).all()


def test_dynamics_state_dict_round_trip(tmp_path) -> None:
    env = history_env(*TOWN1, config=FAST, seed=0)
    from pernav.env.torchrl_env import explore_module

    data = env.rollout(30, policy=explore_module())
    model = _model(5)
    model.fit_normalization(data["history"], data["action"], data["next", "observation"])
    assert not torch.equal(model.in_std, torch.ones_like(model.in_std))
    torch.save({"config": model.config(), "state": model.state_dict()}, tmp_path / "model.pt")
    ckpt = torch.load(tmp_path / "model.pt")
    twin = DynamicsModel(**ckpt["config"])
    twin.load_state_dict(ckpt["state"])
    for name in ("in_mean", "in_std", "out_mean", "out_std"):
        assert torch.equal(getattr(twin, name), getattr(model, name))
    with torch.no_grad():
        assert torch.equal(twin(data["history"], data["action"]), model(data["history"], data["action"]))


# ----- 7. the imagined env ------------------------------------------------------------------------------
def test_imagined_rollout_equals_stepping_by_hand() -> None:
    model = _model(6)
    env = ImaginedNavigationEnv(make_world_model(model))
    g = torch.Generator().manual_seed(0)
    B, T = 3, 4
    history = torch.randn(B, 5, 21, generator=g)
    start = TensorDict({"observation": history[:, -1, :S].clone(), "history": history}, [B])
    actions = torch.randint(7, (T, B), generator=g)
    with torch.no_grad():
        td = env.rollout(T, auto_reset=False, tensordict=start.clone(), break_when_any_done=False,
                         actions=list(actions))
        h = history
        for t in range(T):
            state = model(h, actions[t])
            prev_goal = h[:, -1, 9:11]
            h = model.next_window(h, actions[t], state)
            assert torch.equal(td["action"][:, t], actions[t])
            assert torch.allclose(td["next", "observation"][:, t], state)
            assert torch.allclose(td["next", "history"][:, t], h)
            reward = -((state[:, :2] - prev_goal) ** 2).sum(-1, keepdim=True)
            assert torch.allclose(td["next", "reward"][:, t], reward)


def test_real_env_specs_with_history() -> None:
    check_env_specs(history_env(*TOWN1, config=FAST, seed=0))
    check_env_specs(history_env("Town1", {"route": 1}, config={**FAST, "adaptive_speed": True}, seed=0, K=3))


# ----- docs -------------------------------------------------------------------------------------------
def _doc_blocks() -> list[str]:
    return re.findall(r"```python\n(.*?)```", DOCS.read_text(), flags=re.S)


@pytest.mark.parametrize("index", range(7))
def test_docs_example_runs_on_its_own(index: int, tmp_path, monkeypatch, capfd) -> None:
    """Every example of docs/components.md, alone in a fresh namespace and folder (as a reader would paste it):
    it writes nothing into the current folder and prints only what it prints itself (no library chatter)."""
    blocks = _doc_blocks()
    assert len(blocks) == 7  # a new example: add it to the range above
    monkeypatch.chdir(tmp_path)
    exec(compile(blocks[index], f"{DOCS.name}[block {index}]", "exec"), {"__name__": "__docs__"})  # noqa: S102
    assert sorted(p.name for p in tmp_path.iterdir()) == []
    printed = capfd.readouterr().out.splitlines()
    assert len(printed) == blocks[index].count("print("), printed
