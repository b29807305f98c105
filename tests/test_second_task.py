"""The model, adaptation and trainers free of the navigation state: a 2-d linear system whose
dynamics change per round, the EnsembleTrainer on it, and the CartPole recipe end to end (tiny)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
import torch
from tensordict import TensorDict

from pernav.model import DynamicsModel, adapt, multistep_loss, single_step_loss
from pernav.trainer import EnsembleTrainer, FTMLTrainer, RoundBuffers, TrainConfig
from pernav.transforms import HistoryWindow

RECIPE = Path(__file__).resolve().parents[1] / "recipes" / "cartpole_meta.py"


def _linear_trajectory(gain: float, T: int, seed: int) -> TensorDict:
    """x' = 0.9 R x + gain * b(a) for a 2-d state and 3 actions (left, none, right), with K = 1 windows."""
    g = torch.Generator().manual_seed(seed)
    rot = torch.tensor([[0.9, -0.2], [0.2, 0.9]])
    push = torch.tensor([[-1.0, 0.5], [0.0, 0.0], [1.0, 0.5]])
    window = HistoryWindow(K=1, n_actions=3)
    x = torch.randn(2, generator=g)
    actions = torch.randint(3, (T,), generator=g)
    states, nexts = [], []
    for a in actions:
        nxt = rot @ x + gain * push[a]
        states.append(x)
        nexts.append(nxt)
        x = nxt
    states, nexts = torch.stack(states), torch.stack(nexts)
    return TensorDict({"observation": states, "action": actions, "history": window.initial_window(states),
                       ("next", "observation"): nexts}, [T])


def _windows(trajectory: TensorDict, L: int = 3) -> TensorDict:
    T = trajectory.shape[0] - trajectory.shape[0] % L
    return trajectory[:T].reshape(-1, L)


def test_plain_model_learns_a_linear_system_and_adapts_to_a_changed_one() -> None:
    torch.manual_seed(0)
    model = DynamicsModel(state_dim=2, n_actions=3, K=1, hidden=(32,))
    assert model.config()["delta"] == "plain" and DynamicsModel(**model.config()).n_features == model.n_features
    data = torch.cat([_linear_trajectory(1.0, 60, seed) for seed in range(4)])
    model.fit_normalization(data["history"], data["action"], data["next", "observation"])
    batch = _windows(data)
    before = float(multistep_loss(model, batch).detach())
    optimizer = torch.optim.Adam(model.parameters(), lr=3e-3)
    for _ in range(300):
        optimizer.zero_grad()
        multistep_loss(model, batch).backward()
        optimizer.step()
    after = float(multistep_loss(model, batch).detach())
    assert after < before / 10
    # the motor reversed: one gradient step on one trajectory of it lowers its loss on other trajectories
    tau, held_out = _linear_trajectory(-1.0, 30, 10), _windows(_linear_trajectory(-1.0, 60, 11))
    unadapted = float(multistep_loss(model, held_out).detach())
    adapted = adapt(model, tau, alpha=0.05, L=3, first_order=True, backtrack=0.5).detach()
    assert float(multistep_loss(model, held_out, params=adapted).detach()) < unadapted
    # adapt takes the loss it descends: the single-step loss gives a different step
    one_step = adapt(model, tau, alpha=0.05, L=3, first_order=True, loss_fn=single_step_loss)
    assert not torch.equal(one_step["net", "0", "weight"], adapted["net", "0", "weight"])


def test_ftml_and_ensemble_train_a_plain_model() -> None:
    buffers = RoundBuffers(L=3, seed=0)
    for r, gain in enumerate((1.0, -1.0, 0.5, -0.5)):
        buffers.add(r, _linear_trajectory(gain, 30, 2 * r), tau=True)
        buffers.add(r, _linear_trajectory(gain, 30, 2 * r + 1))
    config = TrainConfig(batch=16, L=3, K=1, hidden=[16], alpha=0.05)
    trainer = FTMLTrainer(DynamicsModel(state_dim=2, n_actions=3, K=1, hidden=(16,)), buffers, config, seed=0)
    trainer.fit_normalization()
    losses = trainer.train(40, meta=True)
    assert all(torch.isfinite(torch.tensor(losses))) and sum(losses[-5:]) < sum(losses[:5])
    assert trainer.round_loss(1, adapted=True) < trainer.round_loss(1, adapted=False)
    ensemble = EnsembleTrainer(lambda: DynamicsModel(state_dim=2, n_actions=3, K=1, hidden=(16,)), buffers,
                               config, size=2)
    ensemble.fit_normalization()
    assert all(torch.isfinite(torch.tensor(ensemble.train(3, meta=True))))


def test_delta_layouts_refuse_what_they_cannot_read() -> None:
    with pytest.raises(ValueError, match="14-d navigation state"):
        DynamicsModel(state_dim=2, delta="egocentric")
    with pytest.raises(ValueError, match="unknown delta 'polar'"):
        DynamicsModel(state_dim=2, delta="polar")
    with pytest.raises(ValueError, match="road needs delta='egocentric'"):
        DynamicsModel(state_dim=14, road=4, delta="plain")
    assert DynamicsModel().config()["delta"] == "egocentric"  # the navigation's default is unchanged


@pytest.mark.slow
def test_cartpole_recipe_end_to_end(tmp_path: Path) -> None:
    out = tmp_path / "run"
    small = ["--seeds", "0", "--offline", "2", "--offline-episodes", "2", "--online", "2", "--episodes", "1",
             "--max-steps", "40", "--horizon", "3", "--warm-updates", "20", "--offline-updates", "10",
             "--online-updates", "2"]
    done = subprocess.run([sys.executable, str(RECIPE), str(out), *small], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr[-2000:]
    results = json.loads((out / "results.json").read_text())["returns"]["0"]
    assert set(results) == {"adapt", "meta", "sysid", "random"}
    for method, rounds in results.items():
        assert len(rounds) == 2 and all(0.0 <= r <= 40.0 for episodes in rounds for r in episodes), method
    assert (out / "returns.png").stat().st_size > 1000 and "adapt - sysid" in (out / "summary.md").read_text()
    again = subprocess.run([sys.executable, str(RECIPE), str(out), *small], capture_output=True, text=True)
    assert again.returncode == 2 and "exists" in again.stderr and "Traceback" not in again.stderr


def test_imagined_env_passes_check_env_specs_and_stops_rewarding_after_done() -> None:
    from torchrl.envs import check_env_specs

    from pernav.model import ImaginedEnv
    from pernav.planner import DiscreteTreeSearchPlanner

    torch.manual_seed(0)
    model = DynamicsModel(state_dim=2, n_actions=3, K=1, hidden=(8,))
    env = ImaginedEnv(model, reward_fn=lambda s, a, n: -n.pow(2).sum(-1), termination_fn=lambda n: n[..., 0] > 100)
    check_env_specs(env)
    start = TensorDict({"observation": torch.zeros(4, 2), "history": torch.zeros(4, 1, 5)}, [4])
    rollout = env.rollout(3, auto_reset=False, tensordict=start, break_when_any_done=False)
    assert rollout["next", "observation"].shape == (4, 3, 2) and rollout["next", "reward"].shape == (4, 3, 1)
    # the reward is reward_fn of the imagined transition, the model's own prediction
    with torch.no_grad():
        first = model(start["history"], rollout["action"][:, 0])
    assert torch.allclose(rollout["next", "reward"][:, 0, 0], -first.pow(2).sum(-1))
    assert DiscreteTreeSearchPlanner(env, 2)(start.clone())["action"].shape == (4,)


def test_cartpole_recipe_help_shows_every_default(capsys) -> None:
    import importlib.util

    spec = importlib.util.spec_from_file_location("cartpole_meta", RECIPE)
    recipe = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(recipe)
    with pytest.raises(SystemExit):
        recipe.main(["--help"])
    text = " ".join(capsys.readouterr().out.split())  # the help's line wrapping undone
    for option, default in (("--seeds", "[0, 1, 2, 3, 4]"), ("--offline-episodes", "4"), ("--max-steps", "150"),
                            ("--horizon", "6"), ("--L", "3"), ("--alpha", "0.05"), ("--warm-updates", "300"),
                            ("--online-updates", "30")):
        assert f"{option} " in text and f"(default: {default})" in text, option
    assert text.count("(default: ") == 13  # every option but the positional folder and --help
