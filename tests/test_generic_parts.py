"""pernav's TorchRL parts on other tasks than the towns (issue #32): HistoryWindow on any env, light imports,
the imagined navigation env's specs."""

import subprocess
import sys

import pytest
import torch
from tensordict import TensorDict
from torchrl.data import Categorical, Composite, Unbounded
from torchrl.envs import EnvBase, GymEnv, TransformedEnv
from torchrl.envs.utils import check_env_specs

from pernav.model import DynamicsModel, ImaginedNavigationEnv, make_world_model
from pernav.transforms import HistoryWindow


def test_history_window_reads_the_number_of_actions_from_the_spec():
    env = TransformedEnv(GymEnv("CartPole-v1", categorical_action_encoding=True), HistoryWindow(K=3))
    check_env_specs(env, seed=0)
    td = env.rollout(4)
    assert td["history"].shape == (4, 3, 4 + 2)
    taken = td["next", "history"][:, -2, 4:]
    assert torch.equal(taken.argmax(-1), td["action"]) and torch.equal(taken.sum(-1), torch.ones(4))


def test_history_window_records_continuous_actions_exactly():
    env = TransformedEnv(GymEnv("Pendulum-v1"), HistoryWindow(K=3))
    check_env_specs(env, seed=0)
    td = env.rollout(5)
    assert td["history"].shape == (5, 3, 3 + 1)
    assert torch.equal(td["next", "history"][:, -2, 3:], td["action"].to(td["history"].dtype))
    # a one-hot encoder on a continuous action is refused, naming what to do
    with pytest.raises(ValueError, match="continuous"):
        TransformedEnv(GymEnv("Pendulum-v1"), HistoryWindow(K=3, n_actions=7)).observation_spec  # noqa: B018


class _Float64Walk(EnvBase):
    """A 3-d float64 random walk with two actions: +1 or -1 on every coordinate."""

    def __init__(self):
        super().__init__()
        self.observation_spec = Composite(observation=Unbounded((3,), dtype=torch.float64))
        self.action_spec = Categorical(2)
        self.reward_spec = Unbounded((1,))

    def _reset(self, tensordict=None):
        return TensorDict({"observation": torch.zeros(3, dtype=torch.float64)}, [])

    def _step(self, tensordict):
        obs = tensordict["observation"] + (2.0 * tensordict["action"].double() - 1.0)
        return TensorDict({"observation": obs, "reward": torch.zeros(1), "done": torch.zeros(1, dtype=torch.bool),
                           "terminated": torch.zeros(1, dtype=torch.bool)}, [])

    def _set_seed(self, seed):
        return seed


def test_history_window_keeps_a_float64_observation():
    env = TransformedEnv(_Float64Walk(), HistoryWindow(K=2))
    assert env.observation_spec["history"].dtype == torch.float64
    check_env_specs(env, seed=0)
    td = env.rollout(3)
    assert td["next", "history"].dtype == torch.float64
    assert torch.equal(td["next", "history"][:, -1, :3], td["next", "observation"])


def test_history_window_without_an_env_needs_n_actions():
    with pytest.raises(ValueError, match="pass n_actions"):
        HistoryWindow(K=2).initial_window(torch.zeros(3))
    assert HistoryWindow(K=2, n_actions=3).initial_window(torch.zeros(4)).shape == (2, 7)


def test_imagined_navigation_env_passes_check_env_specs():
    env = ImaginedNavigationEnv(make_world_model(DynamicsModel(hidden=(8,))))
    check_env_specs(env)
    with pytest.raises(ValueError, match="both"):
        env.reset(TensorDict({"history": torch.zeros(5, 21)}, []))


@pytest.mark.parametrize("module", ["pernav.transforms", "pernav.model", "pernav.planner", "pernav.trainer"])
def test_learning_side_imports_no_simulator(module):
    code = (f"import sys, {module}; heavy = {{'highway_env', 'pygame', 'matplotlib'}}; "
            "print(sorted({m.split('.')[0] for m in sys.modules} & heavy))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]", out.stdout


def test_packages_export_their_public_names():
    import pernav.env
    import pernav.trainer
    import pernav.world

    assert {"FTMLTrainer", "TrainConfig", "EnsembleTrainer", "RoundBuffers", "history_env"} <= set(pernav.trainer.__all__)
    assert callable(pernav.trainer.history_env) and pernav.world.get_town("Town1").name == "Town1"
    assert "NavigationEnv" in dir(pernav.env)
    with pytest.raises(AttributeError, match="no attribute"):
        pernav.world.not_a_name  # noqa: B018


@pytest.mark.parametrize("bad", [7, -1])
def test_history_window_refuses_an_action_outside_its_range(bad):
    window = HistoryWindow(K=2, n_actions=7)
    with pytest.raises(ValueError, match=r"action out of range \[0, 6\]"):
        window.next_window(torch.zeros(3, 2, 21), torch.tensor([0, bad, 1]), torch.zeros(3, 14))
