"""The generic DiscreteTreeSearchPlanner against brute force, and the paper planner (now a configuration of it)
against the decisions it recorded in tests/data/paper_planner.pt.

The toy env: a random nonlinear system with a per-action reward and a ``done`` flag, as a ``ModelBasedEnvBase``
(stepped through its world model) and as a plain stateless ``EnvBase`` (stepped with ``env.step``).
"""

from __future__ import annotations

import itertools
from pathlib import Path

import pytest
import torch
from tensordict import TensorDict
from tensordict.nn import TensorDictModule
from torch import nn
from torchrl.data import Categorical, Composite, OneHot, Unbounded
from torchrl.envs import EnvBase, ModelBasedEnvBase, check_env_specs
from torchrl.modules import WorldModelWrapper

from pernav.model import DynamicsModel
from pernav.model.navigation import ImaginedNavigationEnv, make_world_model
from pernav.planner import DiscreteTreeSearchPlanner, TreeSearchPlanner

D, A = 3, 4
FIXTURE = Path(__file__).parents[1] / "data" / "paper_planner.pt"
# costs reach ~1e4 m^2 from the fixture's explosive models; another CPU rounds the MLP's matrix products
# differently (3e-4 relative seen across two x86-64 machines), so costs are compared to this tolerance
COST_RTOL = 1e-3


class _Dynamics(nn.Module):
    """x' = tanh(W_a x + b_a); reward -(|x' - target|^2) + c_a; done when x'_0 > 0.8."""

    def __init__(self, seed: int, one_hot: bool = False) -> None:
        super().__init__()
        g = torch.Generator().manual_seed(seed)
        self.W = torch.randn(A, D, D, generator=g) * 0.9
        self.b = torch.randn(A, D, generator=g) * 0.5
        self.c = torch.randn(A, generator=g) * 0.3
        self.target = torch.randn(D, generator=g) * 0.5
        self.one_hot = one_hot

    def index(self, action: torch.Tensor) -> torch.Tensor:
        return action.long().argmax(-1) if self.one_hot else action  # OneHot(A)'s actions are bool

    def forward(self, x: torch.Tensor, action: torch.Tensor):
        a = self.index(action)
        nxt = torch.tanh((self.W[a] @ x.unsqueeze(-1)).squeeze(-1) + self.b[a])
        reward = -((nxt - self.target) ** 2).sum(-1, keepdim=True) + self.c[a].unsqueeze(-1)
        return nxt, reward, (nxt[..., :1] > 0.8)


class _Reward(nn.Module):
    def forward(self, reward: torch.Tensor) -> torch.Tensor:
        return reward


def _specs(env, one_hot: bool) -> None:
    env.observation_spec = Composite(x=Unbounded((D,)), shape=env.batch_size)
    env.action_spec = OneHot(A) if one_hot else Categorical(A)
    env.reward_spec = Unbounded((1,))


class ToyModelEnv(ModelBasedEnvBase):
    def __init__(self, dynamics: _Dynamics) -> None:
        transition = TensorDictModule(dynamics, in_keys=["x", "action"], out_keys=["x", "step_reward", "done"])
        super().__init__(WorldModelWrapper(transition, TensorDictModule(_Reward(), ["step_reward"], ["reward"])))
        _specs(self, dynamics.one_hot)

    def _reset(self, tensordict=None, **kwargs):
        shape = tensordict.shape if tensordict is not None else self.batch_size
        return TensorDict({"x": torch.zeros(*shape, D), "done": torch.zeros(*shape, 1, dtype=torch.bool),
                           "terminated": torch.zeros(*shape, 1, dtype=torch.bool)}, shape)


class ToyEnv(EnvBase):
    """The same system as a plain stateless env (its state is the input tensordict)."""

    batch_locked = False

    def __init__(self, dynamics: _Dynamics) -> None:
        super().__init__()
        self.dynamics = dynamics
        _specs(self, dynamics.one_hot)

    def _reset(self, tensordict=None, **kwargs):
        shape = tensordict.shape if tensordict is not None else self.batch_size
        return TensorDict({"x": torch.zeros(*shape, D), "done": torch.zeros(*shape, 1, dtype=torch.bool),
                           "terminated": torch.zeros(*shape, 1, dtype=torch.bool)}, shape)

    def _step(self, tensordict):
        x, reward, done = self.dynamics(tensordict["x"], tensordict["action"])
        return TensorDict({"x": x, "reward": reward, "done": done, "terminated": done}, tensordict.shape)

    def _set_seed(self, seed):
        return seed


class Value(nn.Module):
    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return 2.0 * x[..., 1:2]


def _brute_force(dyn: _Dynamics, x0: torch.Tensor, H: int, mask: torch.Tensor | None, value: bool):
    """Every allowed sequence rolled out on its own; the best (first on ties) sequence and return per root."""
    best_seqs, best_rets = [], []
    for b in range(x0.shape[0]):
        sets = [[a for a in range(A) if mask is None or bool(mask[b, h, a] if mask.ndim == 3 else mask[b, a])]
                for h in range(H)]
        best, best_ret = None, -float("inf")
        for seq in itertools.product(*sets):
            x, ret, alive = x0[b], 0.0, True
            for a in seq:
                act = torch.nn.functional.one_hot(torch.tensor(a), A) if dyn.one_hot else torch.tensor(a)
                x, r, done = dyn(x, act)
                ret += float(r) if alive else 0.0
                alive = alive and not bool(done)
            if value and alive:
                ret += float(2.0 * x[1])
            if ret > best_ret + 1e-6:  # strictly better: ties keep the earlier sequence
                best, best_ret = seq, ret
        best_seqs.append(best)
        best_rets.append(best_ret)
    return torch.tensor(best_seqs), torch.tensor(best_rets)


@pytest.mark.parametrize("model_based", [True, False])
@pytest.mark.parametrize("H,mask_kind,one_hot,value", [(1, None, False, False), (2, "all", False, False),
                                                       (3, "level", False, True), (3, None, True, False),
                                                       (4, "level", True, False), (4, "all", False, True)])
def test_equals_brute_force(model_based: bool, H: int, mask_kind: str | None, one_hot: bool, value: bool) -> None:
    for seed in range(3):
        dyn = _Dynamics(seed, one_hot)
        env = ToyModelEnv(dyn) if model_based else ToyEnv(dyn)
        g = torch.Generator().manual_seed(100 + seed)
        B = 5
        roots = TensorDict({"x": torch.randn(B, D, generator=g)}, [B])
        mask = None
        if mask_kind is not None:
            mask = torch.rand(B, H, A, generator=g) < 0.6 if mask_kind == "level" else torch.rand(B, A, generator=g) < 0.6
            mask[..., 1] = True  # at least one action everywhere
            roots["mask"] = mask
        value_module = TensorDictModule(Value(), ["x"], ["state_value"]) if value else None
        planner = DiscreteTreeSearchPlanner(env, H, mask_key="mask" if mask is not None else None,
                                            value_module=value_module)
        seqs, rets = _brute_force(dyn, roots["x"], H, mask, value)
        result = planner.search(roots.clone())
        assert torch.equal(result.actions, seqs)
        assert torch.allclose(result.returns, rets.float(), atol=1e-4)
        action = planner(roots.clone())["action"]
        first = action.long().argmax(-1) if one_hot else action
        assert torch.equal(first, seqs[:, 0])
        if mask is not None:
            assert bool((mask[torch.arange(B), 0, first] if mask.ndim == 3 else mask[torch.arange(B), first]).all())
        if H > 1:  # shared prefixes: fewer env steps than a flat enumeration of the same tree
            assert result.evaluations < H * B * A ** H


def test_batched_leading_dims_equal_one_by_one() -> None:
    dyn = _Dynamics(7)
    planner = DiscreteTreeSearchPlanner(ToyModelEnv(dyn), 3, mask_key="mask")
    g = torch.Generator().manual_seed(0)
    roots = TensorDict({"x": torch.randn(2, 3, D, generator=g), "mask": torch.rand(2, 3, A, generator=g) < 0.5}, [2, 3])
    roots["mask"][..., 2] = True
    batched = planner(roots.clone())["action"]
    assert batched.shape == (2, 3)
    for i, j in itertools.product(range(2), range(3)):
        assert int(planner(roots[i, j].clone())["action"]) == int(batched[i, j])


@pytest.mark.parametrize("H", [2, 3, 4])
def test_full_beam_equals_exhaustive_and_narrow_beam_is_no_better(H: int) -> None:
    for seed in range(3):
        env = ToyModelEnv(_Dynamics(seed))
        roots = TensorDict({"x": torch.randn(6, D, generator=torch.Generator().manual_seed(seed))}, [6])
        full = DiscreteTreeSearchPlanner(env, H).search(roots.clone())
        wide = DiscreteTreeSearchPlanner(env, H, beam_width=A ** H).search(roots.clone())
        assert torch.equal(wide.actions, full.actions) and torch.equal(wide.returns, full.returns)
        narrow = DiscreteTreeSearchPlanner(env, H, beam_width=2).search(roots.clone())
        assert bool((narrow.returns <= full.returns + 1e-6).all()) and narrow.evaluations < full.evaluations


def test_refuses_continuous_actions_and_bad_arguments() -> None:
    env = ToyModelEnv(_Dynamics(0))
    with pytest.raises(ValueError, match="planning_horizon"):
        DiscreteTreeSearchPlanner(env, 0)
    with pytest.raises(ValueError, match="beam_width"):
        DiscreteTreeSearchPlanner(env, 2, beam_width=0)
    env.action_spec = Unbounded((1,))
    with pytest.raises(TypeError, match="Categorical or OneHot"):
        DiscreteTreeSearchPlanner(env, 2)


@pytest.mark.parametrize("B", [1, 3])
def test_refuses_roots_with_no_allowed_action(B: int) -> None:
    """An all-false mask (for a root, or at one level of a per-level mask) leaves no sequence to plan: refused,
    naming the roots, instead of action 0 with a return of -inf."""
    planner = DiscreteTreeSearchPlanner(ToyModelEnv(_Dynamics(0)), 2, mask_key="mask")
    roots = TensorDict({"x": torch.zeros(B, D), "mask": torch.ones(B, A, dtype=torch.bool)}, [B])
    roots["mask"][B - 1] = False
    with pytest.raises(ValueError, match=rf"no allowed action at level 0 for root\(s\) \[{B - 1}\]"):
        planner(roots.clone())
    per_level = TensorDict({"x": torch.zeros(B, D), "mask": torch.ones(B, 2, A, dtype=torch.bool)}, [B])
    per_level["mask"][0, 1] = False  # the second level of the first root
    with pytest.raises(ValueError, match=r"at level 1 for root\(s\) \[0\]"):
        planner(per_level.clone())
    per_level["mask"][0, 1, 3] = True  # one action is enough
    assert planner(per_level.clone())["action"].shape == (B,)


def test_toy_env_specs_pass() -> None:
    check_env_specs(ToyModelEnv(_Dynamics(0)))


# ----- the paper planner: the same decisions as the search it replaced ------------------------------------------
@pytest.mark.slow
@pytest.mark.parametrize("index", range(5))
def test_paper_planner_decides_as_before(index: int) -> None:
    """Decisions recorded with the paper planner (tests/data/make_paper_planner_fixture.py, which runs on the
    current tree): the same model and roots give the same actions and sequences, all roots at once and one
    at a time (as the study calls it), and one root at a time the same costs to COST_RTOL."""
    case = torch.load(FIXTURE, weights_only=False)[index]
    options = dict(case["case"])
    model = DynamicsModel(n_actions=options.pop("n_actions"), hidden=(32, 32))
    model.load_state_dict(case["model"])
    roots = TensorDict(case["roots"], [case["actions"].shape[0]])
    planner = TreeSearchPlanner(ImaginedNavigationEnv(make_world_model(model)), **options)
    assert torch.equal(planner(roots.clone())["action"], case["actions"])
    assert torch.equal(planner.last.actions, case["sequences"])
    for i in range(0, roots.shape[0], 3):
        assert int(planner(roots[i].clone())["action"]) == int(case["actions"][i])
        torch.testing.assert_close(-planner.last.returns[0], case["costs"][i], rtol=COST_RTOL, atol=0.0)


# ----- the env's own step: termination, params, a world model called as TensorDictModule calls it ---------------
class _Line(nn.Module):  # x' = x + a - 1: action 0 steps left, 1 stays, 2 steps right
    def forward(self, x: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
        return x + (action.unsqueeze(-1) - 1).to(x.dtype)

    def walk(self, x: torch.Tensor, action: torch.Tensor, step: float = 1.0) -> torch.Tensor:
        return x + step * (action.unsqueeze(-1) - 1).to(x.dtype)


class _Position(nn.Module):  # reward: the new position
    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return x.clone()


class WallEnv(ModelBasedEnvBase):
    """A line world whose own ``_step`` ends the episode at the wall x >= 2 (the world model knows no wall)."""

    def __init__(self, transition: TensorDictModule | None = None, dtype: torch.dtype = torch.float32,
                 device: str | torch.device = "cpu") -> None:
        transition = transition or TensorDictModule(_Line(), ["x", "action"], ["x"])
        super().__init__(WorldModelWrapper(transition, TensorDictModule(_Position(), ["x"], ["reward"])),
                         device=device)
        self.observation_spec = Composite(x=Unbounded((1,), dtype=dtype))
        self.action_spec = Categorical(3)
        self.reward_spec = Unbounded((1,), dtype=dtype)

    def _reset(self, tensordict=None, **kwargs):
        return tensordict

    def _step(self, tensordict):
        out = super()._step(tensordict)
        out.set("done", out["x"] >= 2)
        out.set("terminated", out["x"] >= 2)
        return out


def _rollout_brute_force(env, roots: TensorDict, H: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Every sequence played by ``env.rollout`` (stopping at done, as TorchRL's planners score), per root: the
    first best sequence and its summed reward."""
    seqs, rets = [], []
    for b in range(roots.shape[0]):
        best, best_ret = None, -float("inf")
        for seq in itertools.product(range(3), repeat=H):
            actions = [torch.tensor(a, device=roots.device) for a in seq]
            played = env.rollout(H, auto_reset=False, tensordict=roots[b].clone(), actions=actions,
                                 break_when_any_done=True)
            ret = float(played["next", "reward"].sum())
            if ret > best_ret + 1e-9:
                best, best_ret = seq, ret
        seqs.append(best)
        rets.append(best_ret)
    return torch.tensor(seqs), torch.tensor(rets, dtype=torch.float64)


@pytest.mark.parametrize("H", [1, 2, 3, 4])
def test_env_step_override_planned_as_rollout_brute_force(H: int) -> None:
    """An env whose own ``_step`` ends the episode at x >= 2 (reward x): the planner scores it as ``env.rollout``
    plays it. From x = 1 the best four steps are (1, 1, 1, 2), return 5 (not (2, 2, 2, 2), 14, as if the
    episode never ended)."""
    env = WallEnv()
    roots = TensorDict({"x": torch.tensor([[1.0], [0.0], [-1.0]])}, [3])
    seqs, rets = _rollout_brute_force(env, roots, H)
    planner = DiscreteTreeSearchPlanner(env, H)
    assert not planner.fast_path  # the env's step is not its world model alone
    result = planner.search(roots.clone())
    assert torch.equal(result.actions, seqs)
    torch.testing.assert_close(result.returns.double(), rets)
    if H == 4:
        assert seqs[0].tolist() == [1, 1, 1, 2] and float(rets[0]) == 5.0


def test_world_model_called_as_its_tensordict_module_calls_it() -> None:
    """A stage with ``method=``/``method_kwargs=`` (or keyword in_keys) is run by the env as TensorDictModule runs
    it, not as a bare ``module(*inputs)``."""
    class Plain(WallEnv):  # TorchRL's own step: the world model alone
        _step = ModelBasedEnvBase._step

    walk = TensorDictModule(_Line(), ["x", "action"], ["x"], method="walk", method_kwargs={"step": 2.0})
    keywords = TensorDictModule(_Line(), {"x": "x", "action": "action"}, ["x"])
    roots = TensorDict({"x": torch.tensor([[0.0], [3.0]])}, [2])
    for transition, expected in ((walk, [[2, 2], [2, 2]]), (keywords, [[2, 2], [2, 2]])):
        env = Plain(transition)
        planner = DiscreteTreeSearchPlanner(env, 2)
        result = planner.search(roots.clone())
        seqs, rets = _rollout_brute_force(env, roots, 2)
        assert result.actions.tolist() == expected and torch.equal(result.actions, seqs)
        torch.testing.assert_close(result.returns.double(), rets)
    assert float(DiscreteTreeSearchPlanner(Plain(walk), 1).search(roots[:1].clone()).returns[0]) == 2.0  # step 2


def test_fast_path_only_where_it_is_the_env_step() -> None:
    """The plain-tensor path (a PlainWorldModel in an env whose step is its world model) gives the env.step
    path's decisions, and is left for the env's step when the env has its own ``_step`` or world model params."""
    from pernav.model import ImaginedEnv

    class Stepped(ImaginedEnv):
        def _step(self, tensordict):
            return super()._step(tensordict)

    torch.manual_seed(0)
    model = DynamicsModel(state_dim=3, n_actions=3, K=2, hidden=(8,))
    args = (lambda s, a, n: -n[..., 0].abs(), lambda n: n[..., 1] > 0.3)
    fast, stepped = DiscreteTreeSearchPlanner(ImaginedEnv(model, *args), 3), DiscreteTreeSearchPlanner(
        Stepped(model, *args), 3)
    assert fast.fast_path and not stepped.fast_path
    g = torch.Generator().manual_seed(1)
    roots = TensorDict({"observation": torch.randn(4, 3, generator=g), "history": torch.randn(4, 2, 6, generator=g)},
                       [4])
    a, b = fast.search(roots.clone()), stepped.search(roots.clone())
    assert torch.equal(a.actions, b.actions)
    torch.testing.assert_close(a.returns, b.returns)
    env = ImaginedEnv(model, *args)
    env.world_model_params = TensorDict.from_module(env.world_model)
    assert not DiscreteTreeSearchPlanner(env, 2).fast_path


# ----- devices and dtypes: every tensor the search makes follows the roots -------------------------------------
def _imagined_env(dtype: torch.dtype = torch.float32, device: str = "cpu"):
    from pernav.model import ImaginedEnv

    torch.manual_seed(0)
    model = DynamicsModel(state_dim=3, n_actions=3, K=2, hidden=(8,)).to(device=device, dtype=dtype)
    return ImaginedEnv(model, lambda s, a, n: -n[..., 0].abs(), lambda n: n[..., 1] > 0.3)


def _imagined_roots(dtype: torch.dtype = torch.float32, device: str = "cpu") -> TensorDict:
    g = torch.Generator().manual_seed(1)
    return TensorDict({"observation": torch.randn(4, 3, generator=g).to(dtype),
                       "history": torch.randn(4, 2, 6, generator=g).to(dtype),
                       "mask": torch.rand(4, 3, generator=g) < 0.7}, [4], device=device)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
@pytest.mark.parametrize("make", ["imagined", "wall"])
def test_search_makes_its_tensors_on_the_roots_device(make: str, dtype: torch.dtype) -> None:
    """With the default device elsewhere (``meta``), a search on CPU roots still runs on the CPU and decides as
    before: no tensor is made without ``device=``. A float64 env is planned in float64."""
    if make == "imagined":
        env, roots, H = _imagined_env(dtype), _imagined_roots(dtype), 3
        roots["mask"][:, 0] = True
    else:
        env, H = WallEnv(dtype=dtype), 3
        roots = TensorDict({"x": torch.tensor([[1.0], [0.0]], dtype=dtype), "mask": torch.tensor(
            [[True, True, True], [True, False, True]])}, [2])
    planners = [DiscreteTreeSearchPlanner(env, H, mask_key=key) for key in (None, "mask")]
    expected = [p.search(roots.clone()) for p in planners]
    with torch.device("meta"):
        found = [p.search(roots.clone()) for p in planners]
        actions = planners[1](roots.clone())["action"]
    for e, f in zip(expected, found, strict=True):
        assert f.actions.device.type == "cpu" and torch.equal(f.actions, e.actions)
        assert f.returns.dtype == dtype and torch.equal(f.returns, e.returns)
    assert torch.equal(actions, expected[1].actions[:, 0])
    if make == "wall":
        seqs, rets = _rollout_brute_force(env, roots.exclude("mask"), H)
        assert torch.equal(expected[0].actions, seqs)


def test_allowed_follows_the_roots_device() -> None:
    planner = DiscreteTreeSearchPlanner(WallEnv(device="meta"), 2)
    roots = TensorDict({"x": torch.zeros(3, 1)}, [3]).to("meta")
    assert planner.allowed(roots, 0).device.type == "meta"


@pytest.mark.parametrize("device", ["cpu", pytest.param("cuda", marks=pytest.mark.skipif(
    not torch.cuda.is_available(), reason="no CUDA device here"))])
def test_planner_equals_rollout_brute_force_on_the_env_device(device: str) -> None:
    env = WallEnv(device=device)
    roots = TensorDict({"x": torch.tensor([[1.0], [-1.0]])}, [2], device=device)
    seqs, rets = _rollout_brute_force(env, roots, 3)
    result = DiscreteTreeSearchPlanner(env, 3).search(roots.clone())
    assert result.actions.device.type == device
    assert torch.equal(result.actions.cpu(), seqs)
    torch.testing.assert_close(result.returns.double().cpu(), rets)
    imagined, start = _imagined_env(device=device), _imagined_roots(device=device)
    planned = DiscreteTreeSearchPlanner(imagined, 2)(start.exclude("mask"))
    assert planned["action"].device.type == device
