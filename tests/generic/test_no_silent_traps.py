"""No silent traps for a TorchRL user: an ``ImaginedEnv`` writes the actions the env it drives takes (its action spec
from ``env=`` or from the model built on the env's spec; a mismatch is refused by name); ``delta="auto"`` reads a
state in the navigation's car frame only when the state is the navigation's, by its names, not its width; a window of
another K is refused naming K; the trainer reads its keys from the buffers and its K, hidden and L from the model and
buffers, each given once.
"""

from __future__ import annotations

import pytest
import torch
from tensordict import TensorDict, TensorDictBase
from torchrl.data import Categorical, OneHot
from torchrl.envs import GymEnv, TransformedEnv

from pernav.env.layout import STATE_KEYS
from pernav.model import DynamicsModel, ImaginedEnv
from pernav.planner import DiscreteTreeSearchPlanner
from pernav.trainer import FTMLTrainer, RoundBuffers, TrainConfig
from pernav.transforms import HistoryWindow


def upright(state, action, next_state):
    return 1.0 - (next_state[..., 2] / 0.21) ** 2


class _Recording(TransformedEnv):
    """CartPole that records the action tensors it is stepped with."""

    def __init__(self, K: int = 1) -> None:
        super().__init__(GymEnv("CartPole-v1"), HistoryWindow(K=K))
        self.taken: list[torch.Tensor] = []

    def _step(self, tensordict: TensorDictBase) -> TensorDictBase:
        self.taken.append(tensordict["action"].clone())
        return super()._step(tensordict)


@pytest.mark.parametrize("how", ["env", "model's spec"])
def test_the_planner_writes_the_one_hot_actions_the_gym_env_takes(how: str) -> None:
    env = _Recording()
    env.set_seed(0)
    torch.manual_seed(0)
    model = DynamicsModel(state_dim=4, n_actions=env.action_spec, K=1, hidden=(16,))
    imagined = ImaginedEnv(model, upright, env=env) if how == "env" else ImaginedEnv(model, upright)
    assert isinstance(imagined.action_spec, OneHot)
    planner = DiscreteTreeSearchPlanner(imagined, planning_horizon=2)
    episode = env.rollout(6, policy=planner)
    taken = torch.stack(env.taken)
    assert taken.shape == (episode.shape[0], 2) and bool((taken.sum(-1) == 1).all())  # never [0, 0]
    assert torch.equal(taken, episode["action"])


def test_an_imagined_env_refuses_an_env_it_cannot_stand_in_for() -> None:
    env = TransformedEnv(GymEnv("CartPole-v1"), HistoryWindow(K=2))
    with pytest.raises(ValueError, match=r"'history' is \(2, 6\), the model's \(1, 6\).*HistoryWindow\(K=1\)"):
        ImaginedEnv(DynamicsModel(state_dim=4, n_actions=2, K=1, hidden=(8,)), upright, env=env)
    with pytest.raises(ValueError, match=r"the model takes 3 discrete actions.*n_actions=env.action_spec"):
        ImaginedEnv(DynamicsModel(state_dim=4, n_actions=3, K=2, hidden=(8,)), upright, env=env)
    with pytest.raises(ValueError, match=r"differs from the action spec of env"):
        ImaginedEnv(DynamicsModel(state_dim=4, n_actions=2, K=2, hidden=(8,)), upright, env=env,
                    action_spec=Categorical(2))
    assert isinstance(ImaginedEnv(DynamicsModel(state_dim=4, n_actions=2, K=2, hidden=(8,)), upright).action_spec,
                      Categorical)  # a model built from a number, no env: categorical, as before


def _linear_14(T: int = 200, seed: int = 0) -> TensorDict:
    """A 14-d linear system with 3 actions (K = 1): nothing of the navigation but the width."""
    g = torch.Generator().manual_seed(seed)
    A = 0.9 * torch.eye(14) + 0.05 * torch.randn(14, 14, generator=g)
    states = torch.randn(T, 14, generator=g)
    actions = torch.randint(3, (T,), generator=g)
    history = torch.cat([states, torch.zeros(T, 3)], -1).unsqueeze(1)
    return TensorDict({"observation": states, "action": actions, "history": history,
                       ("next", "observation"): states @ A.T + 0.1 * actions.unsqueeze(-1)}, [T])


def test_delta_auto_is_egocentric_only_for_the_navigations_state_by_its_names() -> None:
    assert DynamicsModel(state_dim=14, n_actions=3, K=1).delta_layout.name == "plain"
    assert DynamicsModel(state_dim=[f"x{i}" for i in range(14)], n_actions=3).delta_layout.name == "plain"
    assert DynamicsModel().delta_layout.name == "egocentric"  # the navigation's own, as the study builds it
    assert DynamicsModel(state_dim=STATE_KEYS, n_actions=21).delta_layout.name == "egocentric"
    saved = DynamicsModel(n_actions=7, K=5, hidden=(8,)).config()  # a study's checkpoint names its delta
    assert saved["delta"] == "egocentric" and DynamicsModel(**saved).delta_layout.name == "egocentric"
    with pytest.raises(ValueError, match=r"delta='egocentric' reads the navigation's state"):
        DynamicsModel(state_dim=[f"x{i}" for i in range(14)], delta="egocentric")
    data = _linear_14()
    model = DynamicsModel(state_dim=14, n_actions=3, K=1, hidden=(8,))
    model.fit_normalization(data["history"], data["action"], data["next", "observation"])
    torch.testing.assert_close(model.out_mean, (data["next", "observation"] - data["observation"]).mean(0))


def test_a_window_of_another_k_is_refused_naming_k() -> None:
    model = DynamicsModel(state_dim=4, n_actions=2, K=1, hidden=(8,))
    with pytest.raises(ValueError, match=r"DynamicsModel\(K=1, state_dim=4, n_actions=2\) reads a history window "
                                         r"\[\.\.\., 1, 6\].*got \(5, 3, 6\).*HistoryWindow\(K=1\)"):
        model(torch.zeros(5, 3, 6), torch.zeros(5, dtype=torch.long))
    buffers = RoundBuffers(L=3)
    t = TensorDict({"observation": torch.zeros(9, 4), "action": torch.zeros(9, dtype=torch.long),
                    "history": torch.zeros(9, 3, 6), ("next", "observation"): torch.zeros(9, 4)}, [9])
    buffers.add(0, t, tau=True)
    trainer = FTMLTrainer(model, buffers, TrainConfig(batch=4))
    with pytest.raises(ValueError, match=r"HistoryWindow\(K=1\)"):
        trainer.fit_normalization()


def test_the_trainer_reads_its_keys_from_the_buffers() -> None:
    env = TransformedEnv(GymEnv("CartPole-v1"), HistoryWindow(K=1, in_keys=["observation"], out_keys=["window"]))
    env.set_seed(0)
    torch.manual_seed(0)
    renamed = RoundBuffers(L=3, seed=0, history_key="window")
    default = RoundBuffers(L=3, seed=0)
    for r in range(3):
        t = env.rollout(30)
        renamed.add(r, t, tau=True)
        as_default = t.clone()
        as_default.rename_key_("window", "history")
        as_default.rename_key_(("next", "window"), ("next", "history"))
        default.add(r, as_default, tau=True)

    def trained(buffers: RoundBuffers) -> tuple[list[float], float]:
        torch.manual_seed(0)
        model = DynamicsModel(state_dim=4, n_actions=2, K=1, hidden=(16,))
        trainer = FTMLTrainer(model, buffers, TrainConfig(batch=8, alpha=0.05), seed=0)  # no loss_fn, no K, L
        trainer.fit_normalization()
        return trainer.train(3, meta=False) + trainer.train(3, meta=True), trainer.round_loss(1, adapted=True)

    assert trained(renamed) == trained(default)
