"""CartPole through ``GymEnv`` with its default one-hot actions, end to end: collect, ``RoundBuffers``, FTML updates,
``adapt`` and the tree search on the adapted model give exactly what the same data with categorical actions gives.
"""

from __future__ import annotations

import pytest
import torch
from torchrl.data import OneHot
from torchrl.envs import GymEnv, TransformedEnv

from pernav.model import DynamicsModel, ImaginedEnv, adapt
from pernav.planner import DiscreteTreeSearchPlanner
from pernav.trainer import FTMLTrainer, RoundBuffers, TrainConfig
from pernav.transforms import HistoryWindow


def upright(state, action, next_state):
    return 1.0 - (next_state[..., 2] / 0.21) ** 2


def fallen(next_state):
    return next_state[..., 2].abs() > 0.21


def _learn(trajectories: list, rounds: int) -> tuple[list[float], dict, dict, torch.Tensor]:
    buffers = RoundBuffers(L=3, seed=0)
    for k, t in enumerate(trajectories):
        buffers.add(k % rounds, t, tau=k < rounds)
    torch.manual_seed(0)
    model = DynamicsModel(state_dim=4, n_actions=2, K=1, hidden=(16,))
    trainer = FTMLTrainer(model, buffers, TrainConfig(batch=8, L=3, K=1, hidden=[16], alpha=0.05), seed=0)
    trainer.fit_normalization()
    losses = trainer.train(3, meta=False) + trainer.train(3, meta=True)
    adapted = adapt(model, buffers.tau(1), alpha=0.05, L=3, first_order=True).detach()
    planner = DiscreteTreeSearchPlanner(ImaginedEnv(model, upright, fallen), planning_horizon=3)
    # the real env's own OneHot spec: the planner writes one-hot actions, decided on the same imagined steps
    one_hot = DiscreteTreeSearchPlanner(ImaginedEnv(model, upright, fallen, action_spec=OneHot(2, dtype=torch.long)),
                                        planning_horizon=3)
    roots = buffers.tau(1)[:6].select("observation", "history")
    with adapted.to_module(model):
        actions = planner(roots.clone())["action"]
        assert torch.equal(one_hot(roots.clone())["action"], torch.nn.functional.one_hot(actions, 2))
    return losses, dict(model.state_dict()), dict(adapted.flatten_keys().items()), actions


def test_gym_cartpole_with_one_hot_actions_learns_and_plans_as_with_indices() -> None:
    env = TransformedEnv(GymEnv("CartPole-v1"), HistoryWindow(K=1))  # GymEnv's default: a OneHot action spec
    env.set_seed(0)
    recorded = [env.rollout(25) for _ in range(6)]
    assert recorded[0]["action"].shape[-1] == 2 and recorded[0]["action"].ndim == 2  # [T, 2] one-hot
    as_indices = []
    for t in recorded:
        t = t.clone()
        t["action"] = t["action"].argmax(-1)
        as_indices.append(t)
    one_hot, categorical = _learn(recorded, rounds=3), _learn(as_indices, rounds=3)
    assert one_hot[0] == categorical[0]
    for got, expected in zip(one_hot[1:3], categorical[1:3], strict=True):
        assert got.keys() == expected.keys() and all(torch.equal(got[k], expected[k]) for k in got)
    assert torch.equal(one_hot[3], categorical[3])


def test_a_planner_on_an_imagined_env_with_the_real_envs_one_hot_spec_drives_the_gym_env() -> None:
    env = TransformedEnv(GymEnv("CartPole-v1"), HistoryWindow(K=1))
    env.set_seed(0)
    torch.manual_seed(0)
    model = DynamicsModel(state_dim=4, n_actions=env.action_spec, K=1, hidden=(16,))
    imagined = ImaginedEnv(model, upright, fallen, action_spec=env.action_spec)
    assert isinstance(imagined.action_spec, OneHot) and imagined.action_spec.dtype == env.action_spec.dtype
    planner = DiscreteTreeSearchPlanner(imagined, planning_horizon=2)
    state = torch.get_rng_state()
    episode = env.rollout(4, policy=planner)
    assert torch.equal(torch.get_rng_state(), state)  # neither the planner nor TorchRL's projection drew
    assert episode["action"].shape == (episode.shape[0], 2) and bool((episode["action"].sum(-1) == 1).all())
    with pytest.raises(ValueError, match="OneHot spec of the model's 2 actions"):
        ImaginedEnv(model, upright, action_spec=OneHot(3))
