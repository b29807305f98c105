"""pernav's TorchRL parts on tasks other than the towns: HistoryWindow on any env (CartPole, Pendulum, FrozenLake),
light imports, refusals of what a part cannot use, short trajectories, and the model, adaptation and trainers on a
2-d linear system whose dynamics change per round, with the CartPole recipe end to end (tiny)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
import torch
from tensordict import TensorDict
from torchrl.data import Categorical, Composite, Unbounded
from torchrl.envs import EnvBase, GymEnv, TransformedEnv
from torchrl.envs.utils import check_env_specs

from pernav.model import DynamicsModel, ImaginedNavigationEnv, adapt, make_world_model, multistep_loss, single_step_loss
from pernav.trainer import EnsembleTrainer, FTMLTrainer, RoundBuffers, TrainConfig
from pernav.transforms import HistoryWindow

RECIPE = Path(__file__).resolve().parents[2] / "recipes" / "cartpole_meta.py"


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


@pytest.mark.slow
def test_learning_side_imports_no_simulator():
    # one interpreter for the four: if all of them together load none of the heavy modules, none of them does
    code = ("import sys, pernav.transforms, pernav.model, pernav.planner, pernav.trainer; "
            "heavy = {'highway_env', 'pygame', 'matplotlib'}; print(sorted({m.split('.')[0] for m in sys.modules} & heavy))")
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


# ----- RoundBuffers with trajectories shorter than L ----------------------------------------------------------
def _numbered(start: int, T: int, K: int = 1) -> TensorDict:
    """A 4-d ``[T]`` trajectory whose first observation entry is its global step number ``start + t``."""
    obs = torch.zeros(T, 4)
    obs[:, 0] = torch.arange(start, start + T, dtype=torch.float32)
    obs[:, 1:] = torch.randn(T, 3, generator=torch.Generator().manual_seed(start))
    return TensorDict({"observation": obs, "action": torch.arange(T) % 2, "history": torch.randn(T, K, 6),
                       ("next", "observation"): obs + 0.1}, [T])


def test_round_buffers_skip_trajectories_shorter_than_L_and_count_them(caplog):
    from pernav.trainer import RoundBuffers

    buffers = RoundBuffers(L=10, seed=0)
    buffers.add(0, _numbered(0, 5), tau=True)  # the round's tau may be short: it is still stored and adapted on
    with caplog.at_level("WARNING", logger="pernav.trainer"):
        buffers.add(0, _numbered(5, 40))
        buffers.add(0, _numbered(45, 3))
    assert "shorter than L=10" in caplog.text
    assert buffers.short == {0: 2} and buffers.lengths == {0: [5, 40, 3]} and len(buffers.data(0)) == 48
    windows = buffers.sample(0, 64)
    assert windows.shape == (64, 10)
    step = windows["observation"][..., 0]
    assert ((step >= 5) & (step < 45)).all() and (step.diff(dim=1) == 1).all()  # all from the 40-step one


def test_ftml_trains_on_short_random_episodes_beside_longer_ones():
    from pernav.trainer import FTMLTrainer, RoundBuffers, TrainConfig

    buffers, g, start = RoundBuffers(L=10, seed=0), torch.Generator().manual_seed(0), 0
    for r in range(3):  # random-policy CartPole-like episodes of 9-13 steps
        for e in range(4):
            T = 13 if e == 1 else int(torch.randint(9, 14, (), generator=g))
            buffers.add(r, _numbered(start, T), tau=e == 0)
            start += T
    torch.manual_seed(0)  # the model's initial weights: from the global RNG, which earlier tests in a worker move
    model = DynamicsModel(state_dim=4, n_actions=2, K=1, hidden=(8,), delta="plain")
    trainer = FTMLTrainer(model, buffers, TrainConfig(batch=8, L=10, K=1, hidden=[8]), seed=0)
    trainer.fit_normalization()
    losses = trainer.train(3, meta=False) + trainer.train(3, meta=True)
    assert len(losses) == 6 and all(torch.isfinite(torch.tensor(losses)))


def test_round_buffers_refuse_a_round_without_a_trajectory_of_L_steps():
    from pernav.trainer import RoundBuffers

    buffers = RoundBuffers(L=10, seed=0)
    buffers.add(0, _numbered(0, 5), tau=True)
    buffers.add(0, _numbered(5, 7))
    buffers.add(1, _numbered(12, 10))
    with pytest.raises(ValueError, match=r"round 0 has no trajectory of L=10 steps.*lengths: \[5, 7\]"):
        buffers.sample(0, 4)
    assert buffers.sample(1, 4).shape == (4, 10)  # exactly L is enough


def test_round_buffers_sample_long_trajectories_as_before(tmp_path):
    """With every trajectory at least L long, the windows are those of the sampler before short trajectories
    were skipped (strict_length=False), draw for draw: the study's results depend on them."""
    from torchrl.data import LazyTensorStorage, SliceSampler, TensorDictReplayBuffer

    from pernav.trainer import RoundBuffers

    def filled(cls_buffers: RoundBuffers) -> RoundBuffers:
        start = 0
        for r, lengths in ((0, (12, 5, 30)), (1, (4, 9))):
            for k, T in enumerate(lengths):
                cls_buffers.add(r, _numbered(start, T), tau=k == 0)
                start += T
        return cls_buffers

    buffers = filled(RoundBuffers(L=4, seed=7))
    # the starts drawn by the code before this change (recorded), and the same draws replayed with its sampler
    starts = [buffers.sample(r, 3)["observation"][:, 0, 0].long().tolist() for r in (0, 1, 0)]
    assert starts == [[13, 36, 13], [52, 53, 56], [0, 0, 12]]
    buffers, old = filled(RoundBuffers(L=4, seed=7)), {}
    for r in buffers.rounds:
        old[r] = TensorDictReplayBuffer(storage=LazyTensorStorage(buffers.capacity),
                                        sampler=SliceSampler(slice_len=4, traj_key="traj", strict_length=False))
        old[r].extend(buffers.data(r))
    generator = torch.Generator().manual_seed(7)
    for r in (0, 1, 1, 0, 0, 1):
        with torch.random.fork_rng():
            torch.manual_seed(int(torch.randint(2**62, (), generator=generator)))
            expected = old[r].sample(batch_size=16 * 4).reshape(16, 4)
        got = buffers.sample(r, 16)
        assert torch.equal(got["observation"], expected["observation"]) and torch.equal(got["traj"], expected["traj"])
    buffers.save(tmp_path / "rb")
    assert RoundBuffers.load(tmp_path / "rb").lengths == buffers.lengths


def test_imagined_envs_never_move_the_callers_model():
    """``ModelBasedEnvBase`` moves its world model in place: a model env on another device than its model is
    refused (the caller's model and optimizer stay where they are); by default the env takes the model's device."""
    from pernav.model import ImaginedEnv

    model = DynamicsModel(state_dim=3, n_actions=2, K=1, hidden=(8,))
    for make in (lambda m, **kw: ImaginedEnv(m, lambda s, a, n: n[..., 0], **kw),
                 lambda m, **kw: ImaginedNavigationEnv(make_world_model(DynamicsModel(hidden=(8,))), **kw)):
        with pytest.raises(ValueError, match=r"device='meta'\) would move the model \(on cpu\) in place"):
            make(model, device="meta")
    assert all(p.device.type == "cpu" for p in model.parameters())
    on_meta = model.to("meta")
    env = ImaginedEnv(on_meta, lambda s, a, n: n[..., 0])
    assert env.device.type == "meta" and env.observation_spec["observation"].device.type == "meta"
    assert ImaginedEnv(on_meta, lambda s, a, n: n[..., 0], device="meta").dynamics is on_meta
    double = ImaginedEnv(DynamicsModel(state_dim=3, n_actions=2, K=1, hidden=(8,)).double(), lambda s, a, n: n[..., 0])
    assert double.observation_spec["history"].dtype == torch.float64


def test_dynamics_model_refuses_continuous_actions():
    from torchrl.data import Bounded, OneHot

    assert DynamicsModel(state_dim=3, n_actions=Categorical(4), K=1, hidden=(8,)).n_actions == 4
    assert DynamicsModel(state_dim=3, n_actions=OneHot(5), K=1, hidden=(8,)).n_actions == 5
    with pytest.raises(ValueError, match=r"discrete actions .* continuous action spec Bounded\w*\(shape=\(1,\)"):
        DynamicsModel(state_dim=3, n_actions=Bounded(-2.0, 2.0, (1,)), K=1, hidden=(8,))
    model = DynamicsModel(state_dim=3, n_actions=1, K=1, hidden=(8,))  # Pendulum's torque as "one action"
    history = torch.zeros(2, 1, 4)
    with pytest.raises(ValueError, match=r"floating-point action of shape \(2, 1\) that is not one-hot"):
        model(history, torch.tensor([[-2.0], [2.0]]))
    assert model(history, torch.tensor([[1.0], [1.0]])).shape == (2, 3)  # one-hot over one action
    two = DynamicsModel(state_dim=3, n_actions=2, K=1, hidden=(8,))
    assert torch.equal(two(torch.zeros(2, 1, 5), torch.tensor([[0.0, 1.0], [1.0, 0.0]])),
                       two(torch.zeros(2, 1, 5), torch.tensor([1, 0])))


def test_dynamics_model_float64_windows_need_a_float64_model():
    model = DynamicsModel(state_dim=3, n_actions=2, K=2, hidden=(8,))
    window, action = torch.randn(4, 2, 5, dtype=torch.float64), torch.tensor([0, 1, 1, 0])
    with pytest.raises(TypeError, match=r"a torch.float64 window for a torch.float32 model; convert one to the other"):
        model(window, action)
    model.double()
    model.fit_normalization(window, action, torch.randn(4, 3, dtype=torch.float64))
    assert model(window, action).dtype == torch.float64


def test_history_window_records_a_scalar_observation_as_one_column():
    """FrozenLake's observation is a cell index (Categorical, shape ()): one column of the window."""
    env = TransformedEnv(GymEnv("FrozenLake-v1", categorical_action_encoding=True), HistoryWindow(K=2))
    check_env_specs(env, seed=0)
    data = env.rollout(4)
    assert data["history"].shape == (data.shape[0], 2, 1 + 4)
    assert torch.equal(data["next", "history"][:, -1, 0], data["next", "observation"].float())
    assert torch.equal(data["next", "history"][:, -2, 1:].argmax(-1), data["action"])


@pytest.mark.slow
def test_generic_packages_export_generic_parts_and_load_no_navigation():
    """``pernav.planner`` loads neither the navigation's cost nor its layout; the navigation's parts live in
    their own modules, and the packages still name them."""
    code = ("import sys, pernav.planner, pernav.transforms; "
            "print(sorted({'pernav.world.cost', 'pernav.env.layout', 'pernav.planner.tree_search'} & set(sys.modules)))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]", out.stdout
    import pernav.model
    import pernav.planner
    from pernav.model import egocentric
    from pernav.model import navigation as model_navigation
    from pernav.planner import navigation as planner_navigation

    navigation = {"ImaginedNavigationEnv", "make_world_model", "ego_delta", "EgocentricDifferences", "TreeSearchPlanner",
                  "RetimingPlanner", "build_planner"}
    assert not navigation & {*pernav.model.__all__, *pernav.planner.__all__}
    assert {"LossFn", "DynamicsModel", "ImaginedEnv", "PlainWorldModel"} <= set(pernav.model.__all__)
    assert pernav.model.ImaginedNavigationEnv is model_navigation.ImaginedNavigationEnv  # the package paths
    assert pernav.model.ego_delta is egocentric.ego_delta
    assert pernav.planner.TreeSearchPlanner is planner_navigation.TreeSearchPlanner
    assert pernav.planner.build_planner is planner_navigation.build_planner
    assert "pernav.env" not in (pernav.transforms.HistoryWindow.__doc__ or "")  # its example needs no simulator


# ----- the model, adaptation and trainers on a 2-d linear system ------------------------------------------------
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


@pytest.mark.slow
def test_ftml_and_ensemble_train_a_plain_model() -> None:
    buffers = RoundBuffers(L=3, seed=0)
    for r, gain in enumerate((1.0, -1.0, 0.5, -0.5)):
        buffers.add(r, _linear_trajectory(gain, 30, 2 * r), tau=True)
        buffers.add(r, _linear_trajectory(gain, 30, 2 * r + 1))
    config = TrainConfig(batch=16, L=3, K=1, hidden=[16], alpha=0.05)
    trainer = FTMLTrainer(DynamicsModel(state_dim=2, n_actions=3, K=1, hidden=(16,)), buffers, config, seed=0)
    trainer.fit_normalization()
    losses = trainer.train(120, meta=True)  # 25-40 % lower over the last 5 steps than the first 5, for 12 seeds
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
def test_cartpole_recipe_end_to_end(tmp_path: Path, capsys) -> None:
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
    # run again into the same folder: refused, nothing overwritten (in this process: no second start-up)
    from recipes.cartpole_meta import main as recipe

    before = {p.name: p.read_bytes() for p in out.iterdir() if p.is_file()}
    assert recipe([str(out), *small]) == 2
    assert "exists" in capsys.readouterr().err
    assert {p.name: p.read_bytes() for p in out.iterdir() if p.is_file()} == before


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
