"""Keys configurable where TorchRL's own parts make them so: ``HistoryWindow(in_keys=, out_keys=)`` (its older
``state_key=``/``out_key=`` still work) and the observation/action/history keys of ``RoundBuffers``, the losses,
``adapt`` and ``ImaginedEnv``. Data under other names gives exactly what the default names give."""

from __future__ import annotations

import functools

import pytest
import torch
from tensordict import TensorDictBase
from torchrl.envs import GymEnv, RenameTransform, TransformedEnv

from pernav.model import DynamicsModel, ImaginedEnv, adapt, multistep_loss, single_step_loss
from pernav.planner import DiscreteTreeSearchPlanner
from pernav.trainer import FTMLTrainer, RoundBuffers, TrainConfig
from pernav.transforms import HistoryWindow

NAMES = {"observation": "obs", "action": "act", "history": "window"}
KEYS = {"observation_key": "obs", "action_key": "act", "history_key": "window"}


def upright(state, action, next_state):
    return 1.0 - (next_state[..., 2] / 0.21) ** 2


def _renamed(td: TensorDictBase) -> TensorDictBase:
    out = td.clone()
    for old, new in NAMES.items():
        out.rename_key_(old, new)
        if ("next", old) in out.keys(True):
            out.rename_key_(("next", old), ("next", new))
    return out


def _recorded(n: int = 4, T: int = 20) -> list[TensorDictBase]:
    env = TransformedEnv(GymEnv("CartPole-v1", categorical_action_encoding=True), HistoryWindow(K=2))
    env.set_seed(0)
    torch.manual_seed(0)
    return [env.rollout(T) for _ in range(n)]


@pytest.mark.parametrize("window", [dict(in_keys=["obs"], out_keys=["window"]), dict(state_key="obs", out_key="window"),
                                    dict(in_keys="obs", out_keys="window")])
def test_history_window_takes_in_keys_and_out_keys_like_catframes(window: dict) -> None:
    """A renamed observation (TorchRL's RenameTransform) windowed under ``in_keys``/``out_keys`` (or the older
    names) gives the default window under the new names."""
    def rollout(env):
        env.set_seed(0)
        torch.manual_seed(0)
        return env.rollout(6)

    default = rollout(TransformedEnv(GymEnv("CartPole-v1", categorical_action_encoding=True), HistoryWindow(K=3)))
    env = TransformedEnv(GymEnv("CartPole-v1", categorical_action_encoding=True),
                         RenameTransform(["observation"], ["obs"], create_copy=False))
    env.append_transform(HistoryWindow(K=3, **window))
    renamed = rollout(env)
    assert torch.equal(renamed["window"], default["history"])
    assert torch.equal(renamed["next", "window"], default["next", "history"])
    assert env.observation_spec["window"] == default_spec() and "history" not in env.observation_spec.keys()


def default_spec():
    return TransformedEnv(GymEnv("CartPole-v1"), HistoryWindow(K=3)).observation_spec["history"]


def test_history_window_refuses_several_keys_and_disagreeing_names() -> None:
    with pytest.raises(ValueError, match="one key"):
        HistoryWindow(in_keys=["a", "b"])
    with pytest.raises(ValueError, match="disagree"):
        HistoryWindow(out_keys=["a"], out_key="b")
    assert HistoryWindow(in_keys=[("next", "x")]).state_key == ("next", "x")  # a tuple is one nested key
    assert "in_keys=['obs']" in repr(HistoryWindow(state_key="obs"))


@pytest.mark.parametrize("where", ["reset", "observation_spec", "state_spec"])
def test_a_wrong_observation_key_names_it_and_the_envs_observations(where: str) -> None:
    env = TransformedEnv(GymEnv("CartPole-v1"), HistoryWindow(K=2, in_keys=["pixels"]))
    with pytest.raises(KeyError, match=r"no observation 'pixels'.*\['observation'\]"):
        env.reset() if where == "reset" else getattr(env, where)


def _learn(trajectories: list[TensorDictBase], keys: dict) -> tuple:
    """Buffers, FTML (plain and meta), ``adapt``, the losses and a tree search on ``ImaginedEnv``, all under
    ``keys``; every number they give."""
    buffers = RoundBuffers(L=3, seed=0, **keys)
    for k, t in enumerate(trajectories):
        buffers.add(k % 2, t, tau=k < 2)
    torch.manual_seed(0)
    model = DynamicsModel(state_dim=4, n_actions=2, K=2, hidden=(16,))
    loss = functools.partial(multistep_loss, **keys)
    trainer = FTMLTrainer(model, buffers, TrainConfig(batch=6, L=3, K=2, hidden=[16], alpha=0.05), seed=0,
                          loss_fn=loss)
    trainer.fit_normalization()
    losses = trainer.train(2, meta=False) + trainer.train(2, meta=True) + [trainer.round_loss(1, adapted=True)]
    tau = trajectories[1]  # straight from the env (no buffer): adapt reads its actions at action_key
    adapted = adapt(model, tau, alpha=0.05, L=3, first_order=True, loss_fn=loss,
                    action_key=keys.get("action_key", "action")).detach()
    single = single_step_loss(model, buffers.sample(0, 2), **keys)
    env = ImaginedEnv(model, upright, **keys)
    planner = DiscreteTreeSearchPlanner(env, 2, action_key=keys.get("action_key", "action"))
    roots = tau[:4].select(keys.get("observation_key", "observation"), keys.get("history_key", "history"))
    with adapted.to_module(model):
        actions = planner(roots.clone())[keys.get("action_key", "action")]
    return losses, float(single.detach()), dict(adapted.flatten_keys().items()), actions


def test_renamed_keys_give_what_the_default_names_give() -> None:
    recorded = _recorded()
    default, renamed = _learn(recorded, {}), _learn([_renamed(t) for t in recorded], KEYS)
    assert default[0] == renamed[0] and default[1] == renamed[1]
    assert default[2].keys() == renamed[2].keys() and all(torch.equal(default[2][k], renamed[2][k]) for k in default[2])
    assert torch.equal(default[3], renamed[3])


def test_renamed_buffers_refuse_the_default_names_and_keep_their_keys_on_load(tmp_path) -> None:
    recorded = _recorded(2)
    buffers = RoundBuffers(L=3, **KEYS)
    with pytest.raises(KeyError, match=r"missing \['obs', 'act', 'window', \('next', 'obs'\)\]"):
        buffers.add(0, recorded[0])
    buffers.add(0, _renamed(recorded[0]), tau=True)
    buffers.save(tmp_path)
    loaded = RoundBuffers.load(tmp_path)
    assert loaded.keys == ("obs", "act", "window", ("next", "obs"))
    assert torch.equal(loaded.sample(0, 2)["window"], buffers.sample(0, 2)["window"])
    assert set(buffers.data(0).keys()) >= {"obs", "act", "window"} and "observation" not in buffers.data(0).keys()
