"""The navigation DynamicsModel saved and loaded (its normalization fitted on a real drive, a state_dict round
trip gives the same predictions), and the imagined env's rollout equals stepping the model and its window by hand,
with the reward the distance to the previous state's goal.
"""

from __future__ import annotations

import torch
from navigation_helpers import FAST, TOWN1, S
from navigation_helpers import seeded_model as _model
from tensordict import TensorDict

from pernav.model import DynamicsModel
from pernav.model.navigation import ImaginedNavigationEnv, make_world_model
from pernav.trainer.collect import history_env


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
