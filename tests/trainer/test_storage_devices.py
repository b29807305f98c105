"""RoundBuffers on TorchRL's replay machinery: in-memory and memory-mapped storage give the same windows for the same
seed, ``len()`` counts transitions, a save/load continues the same draws, and the buffers, the trainer, ``adapt``
and the model env work with a float64 model on data a float32 env recorded (the CPU stand-in for a model on
another device).
"""

from __future__ import annotations

import json
import shutil

import pytest
import torch
from tensordict import TensorDict
from torchrl.envs import GymEnv, RenameTransform, TransformedEnv

from pernav.model import DynamicsModel, ImaginedEnv, adapt
from pernav.planner import DiscreteTreeSearchPlanner
from pernav.trainer import EnsembleTrainer, FTMLTrainer, RoundBuffers, TrainConfig
from pernav.transforms import HistoryWindow


def _linear(T: int, seed: int, gain: float = 0.9) -> TensorDict:
    """A [T] trajectory of a 2-d linear system with 3 actions, K = 1 (float32, as an env records it)."""
    g = torch.Generator().manual_seed(seed)
    states = torch.randn(T, 2, generator=g)
    actions = torch.randint(3, (T,), generator=g)
    nexts = gain * states + (actions.unsqueeze(-1) - 1.0)
    history = torch.cat([states, torch.nn.functional.one_hot(actions * 0, 3).float()], -1).unsqueeze(1)
    return TensorDict({"observation": states, "action": actions, "history": history,
                       ("next", "observation"): nexts}, [T])


def _fill(buffers: RoundBuffers) -> RoundBuffers:
    for k in range(6):
        buffers.add(k % 3, _linear(10 + 3 * k, seed=k), tau=k < 3)
    return buffers


def test_memory_and_memmap_storage_draw_the_same_windows(tmp_path) -> None:
    memory, memmap = _fill(RoundBuffers(L=3, seed=4)), _fill(RoundBuffers(L=3, seed=4, storage="memmap"))
    assert len(memory) == len(memmap) == sum(10 + 3 * k for k in range(6))
    for _ in range(3):
        for r in memory.rounds:
            assert (memory.sample(r, 20) == memmap.sample(r, 20)).all()
    memmap.save(tmp_path / "saved")
    assert json.loads((tmp_path / "saved" / "manifest.json").read_text())["storage"] == "memmap"
    loaded = RoundBuffers.load(tmp_path / "saved")
    shutil.rmtree(tmp_path / "saved")  # the loaded buffers do not read the checkpoint's files any more
    assert loaded.storage == "memmap" and loaded.lengths == memmap.lengths
    for r in memory.rounds:  # a save/load continues the same draws
        assert (loaded.sample(r, 20) == memory.sample(r, 20)).all()
    loaded.add(0, _linear(9, seed=9))
    assert loaded.lengths[0][-1] == 9


def test_a_sampling_transform_sees_every_window() -> None:
    buffers = _fill(RoundBuffers(L=3, seed=0, transform=RenameTransform(["observation"], ["state"])))
    windows = buffers.sample(1, 5)
    assert windows.shape == (5, 3) and "state" in windows.keys() and "observation" not in windows.keys()


def test_a_float64_model_trains_adapts_and_plans_on_float32_data() -> None:
    buffers = _fill(RoundBuffers(L=3, seed=0))
    assert buffers.data(0)["observation"].dtype == torch.float32
    torch.manual_seed(0)
    model = DynamicsModel(state_dim=2, n_actions=3, K=1, hidden=(16,)).double()
    trainer = FTMLTrainer(model, buffers, TrainConfig(batch=8, alpha=0.05), seed=0)
    trainer.fit_normalization()
    assert model.in_mean.dtype == torch.float64
    losses = trainer.train(3, meta=False) + trainer.train(3, meta=True)
    assert all(torch.isfinite(torch.tensor(losses)))
    assert trainer.round_loss(1, adapted=True) > 0
    params = adapt(model, buffers.tau(1), alpha=0.05, L=3, first_order=True, backtrack=0.5)
    assert params["net", "0", "weight"].dtype == torch.float64
    ensemble = EnsembleTrainer(lambda: DynamicsModel(state_dim=2, n_actions=3, K=1, hidden=(16,)).double(), buffers,
                               TrainConfig(batch=8, alpha=0.05), size=2)
    ensemble.fit_normalization()
    assert all(torch.isfinite(torch.tensor(ensemble.train(2, meta=True))))
    assert len(ensemble.parameters(buffers.tau(0), adapted=True, alpha=0.05)) == 2


def test_a_float64_model_plans_for_a_float32_gym_env() -> None:
    env = TransformedEnv(GymEnv("CartPole-v1"), HistoryWindow(K=1))
    env.set_seed(0)
    torch.manual_seed(0)
    model = DynamicsModel(state_dim=4, n_actions=env.action_spec, K=1, hidden=(16,)).double()
    imagined = ImaginedEnv(model, lambda s, a, n: -n[..., 2].abs(), env=env)
    planner = DiscreteTreeSearchPlanner(imagined, planning_horizon=2)
    episode = env.rollout(5, policy=planner)
    assert episode["observation"].dtype == torch.float32 and episode["action"].shape[-1] == 2


@pytest.mark.parametrize("storage", ["memory", "memmap"])
def test_buffers_take_a_device(storage) -> None:
    buffers = _fill(RoundBuffers(L=3, seed=0, storage=storage, device="cpu"))
    assert buffers.device == torch.device("cpu") and buffers.sample(0, 2)["observation"].device.type == "cpu"
    assert buffers.tau(0)["observation"].device.type == "cpu"
