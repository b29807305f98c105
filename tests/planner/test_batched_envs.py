"""DiscreteTreeSearchPlanner on an env built with a batch size (whose ``step`` takes exactly that shape), against
brute force over ``env.rollout`` on the same roots; and its one clear error for a mask of the wrong width and for
roots on the ``meta`` device."""

from __future__ import annotations

import itertools

import pytest
import torch
from tensordict import TensorDict
from tensordict.nn import TensorDictModule
from torch import nn
from torchrl.data import Categorical, Composite, OneHot, Unbounded
from torchrl.envs import ModelBasedEnvBase
from torchrl.modules import WorldModelWrapper

from pernav.planner import DiscreteTreeSearchPlanner

A = 3


class _Line(nn.Module):  # x' = x + a - 1: action 0 steps left, 1 stays, 2 steps right
    def forward(self, x: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
        index = action.long().argmax(-1) if action.dtype == torch.bool else action
        return x + (index.unsqueeze(-1) - 1).to(x.dtype)


class _Position(nn.Module):  # reward: the new position
    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return x.clone()


class SlotWalls(ModelBasedEnvBase):
    """A line world of ``batch_size=(len(walls),)`` whose own ``_step`` ends slot ``i``'s episode at its own wall
    ``x >= walls[i]`` (so a root is scored right only in its own slot); the world model knows no wall."""

    def __init__(self, walls: tuple[float, ...] = (2.0, 3.0, 1.0), one_hot: bool = False) -> None:
        n = len(walls)
        super().__init__(WorldModelWrapper(TensorDictModule(_Line(), ["x", "action"], ["x"]),
                                           TensorDictModule(_Position(), ["x"], ["reward"])), batch_size=(n,))
        self.observation_spec = Composite(x=Unbounded((n, 1)), shape=(n,))
        self.action_spec = OneHot(A, shape=(n, A)) if one_hot else Categorical(A, shape=(n,))
        self.reward_spec = Unbounded((n, 1))
        self.walls = torch.tensor(walls).unsqueeze(-1)

    def _reset(self, tensordict=None, **kwargs):
        return tensordict

    def _step(self, tensordict):
        out = super()._step(tensordict)
        wall = out["x"] >= self.walls
        out.set("done", wall)
        out.set("terminated", wall.clone())
        return out


def _rollout_brute_force(env: SlotWalls, roots: TensorDict, H: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Every sequence played by ``env.rollout`` on all roots at once (each in its slot), stopping each root's
    reward at its ``done`` as TorchRL's planners score: the first best sequence and its return per root."""
    B = roots.shape[0]
    best = [None] * B
    best_ret = torch.full((B,), -float("inf"), dtype=torch.float64)
    for seq in itertools.product(range(A), repeat=H):
        actions = [env.action_spec.encode(torch.full((B,), a)) if isinstance(env.action_spec, OneHot)
                   else torch.full((B,), a) for a in seq]
        played = env.rollout(H, auto_reset=False, tensordict=roots.clone(), actions=actions,
                             break_when_any_done=False)
        done = played["next", "done"].squeeze(-1)  # [B, H]
        alive = torch.cat([torch.ones(B, 1, dtype=torch.bool), ~done[:, :-1].cumsum(-1).bool()], -1)
        ret = (played["next", "reward"].squeeze(-1) * alive).sum(-1).double()
        for b in range(B):
            if float(ret[b]) > float(best_ret[b]) + 1e-9:
                best[b], best_ret[b] = seq, ret[b]
    return torch.tensor(best), best_ret


def _roots() -> TensorDict:
    return TensorDict({"x": torch.tensor([[1.0], [0.0], [-1.0]])}, [3])


@pytest.mark.parametrize("one_hot", [False, True])
@pytest.mark.parametrize("H", [1, 2, 3])
def test_an_env_with_a_batch_size_is_planned_per_root_as_rollout_brute_force(H: int, one_hot: bool) -> None:
    """Three roots on an env of ``batch_size=(3,)``: each root is searched in its own slot (its own wall), and the
    decisions and returns equal brute force over ``env.rollout``."""
    env = SlotWalls(one_hot=one_hot)
    roots = _roots()
    seqs, rets = _rollout_brute_force(env, roots, H)
    planner = DiscreteTreeSearchPlanner(env, H)
    assert not planner.fast_path  # its own _step
    result = planner.search(roots.clone())
    assert torch.equal(result.actions, seqs)
    torch.testing.assert_close(result.returns.double(), rets)
    action = planner(roots.clone())["action"]
    assert action.shape == env.action_spec.shape and action.dtype == env.action_spec.dtype
    first = action.long().argmax(-1) if one_hot else action
    assert torch.equal(first, seqs[:, 0])
    if H == 3:  # the walls differ per slot, so the same start is planned differently in each slot
        assert seqs.tolist() == [[1, 1, 2], [2, 2, 2], [2, 1, 2]]  # slot 2 ends at x >= 1: a tie, the first wins


def test_a_batched_env_with_a_mask_and_roots_in_groups_of_its_batch() -> None:
    """Six roots ``[2, 3]`` on an env of ``batch_size=(3,)``: each row of three is planned as ``env.rollout`` plays
    it; a mask prunes per root as on an env without a batch size."""
    env = SlotWalls()
    roots = torch.stack([_roots(), TensorDict({"x": torch.tensor([[-2.0], [1.0], [0.5]])}, [3])])
    planner = DiscreteTreeSearchPlanner(env, 2)
    result = planner.search(roots.reshape(-1).clone())
    for row in range(2):
        seqs, rets = _rollout_brute_force(env, roots[row], 2)
        assert torch.equal(result.actions[3 * row: 3 * row + 3], seqs)
        torch.testing.assert_close(result.returns[3 * row: 3 * row + 3].double(), rets)
    masked = _roots().set("mask", torch.tensor([[True, True, False]] * 3))
    planned = DiscreteTreeSearchPlanner(env, 2, mask_key="mask").search(masked)
    assert not bool((planned.actions == 2).any())


def test_roots_that_do_not_fill_the_batch_are_refused() -> None:
    with pytest.raises(ValueError, match=r"exactly \(3,\).*got 2 roots"):
        DiscreteTreeSearchPlanner(SlotWalls(), 2).search(_roots()[:2])


@pytest.mark.parametrize("shape", [(3, 4), (3, 2), (1, 2), (3, 2, 4)])
def test_a_mask_of_the_wrong_width_names_its_width_and_the_actions(shape: tuple[int, ...]) -> None:
    roots = TensorDict({"x": torch.zeros(shape[0], 1), "mask": torch.ones(shape, dtype=torch.bool)}, [shape[0]])
    planner = DiscreteTreeSearchPlanner(_Unbatched(), 2, mask_key="mask")
    with pytest.raises(ValueError, match=rf"width {shape[-1]} .* 3 actions"):
        planner.search(roots)
    with pytest.raises(ValueError, match=rf"width {shape[-1]} .* 3 actions"):
        planner(roots)


def test_a_mask_with_too_few_level_rows_or_no_action_dimension_is_refused() -> None:
    planner = DiscreteTreeSearchPlanner(_Unbatched(), 3, mask_key="mask")
    short = TensorDict({"x": torch.zeros(2, 1), "mask": torch.ones(2, 2, 3, dtype=torch.bool)}, [2])
    with pytest.raises(ValueError, match="2 level row.*3 levels"):
        planner.search(short)
    flat = TensorDict({"x": torch.zeros(2, 1), "mask": torch.ones(2, dtype=torch.bool)}, [2])
    with pytest.raises(ValueError, match=r"\[\.\.\., A\] or \[\.\.\., H, A\]"):
        planner.search(flat)


def test_roots_on_the_meta_device_give_one_clear_error() -> None:
    planner = DiscreteTreeSearchPlanner(_Unbatched(), 2)
    roots = TensorDict({"x": torch.zeros(3, 1)}, [3]).to("meta")
    with pytest.raises(ValueError, match="'meta' device"):
        planner.search(roots)
    with pytest.raises(ValueError, match="'meta' device"):
        planner(roots)


class _Unbatched(SlotWalls):
    """The same line world without a batch size (no wall)."""

    def __init__(self) -> None:
        ModelBasedEnvBase.__init__(self, WorldModelWrapper(TensorDictModule(_Line(), ["x", "action"], ["x"]),
                                                           TensorDictModule(_Position(), ["x"], ["reward"])))
        self.observation_spec = Composite(x=Unbounded((1,)))
        self.action_spec = Categorical(A)
        self.reward_spec = Unbounded((1,))

    _step = ModelBasedEnvBase._step
