"""DiscreteTreeSearchPlanner writes its action as the env's spec does (a bool one-hot for ``OneHot``, ``[..., 1]``
for ``Categorical(n, shape=(1,))``, the spec's dtype), so TorchRL's ``MPCPlannerBase.forward`` keeps it as it is and
never draws from the global torch generator; specs that are not one discrete action are refused by name.
"""

from __future__ import annotations

import pytest
import torch
from tensordict import TensorDict
from tensordict.nn import TensorDictModule
from torch import nn
from torchrl.data import Binary, Bounded, Categorical, Composite, MultiCategorical, MultiOneHot, OneHot, Unbounded
from torchrl.envs import ModelBasedEnvBase
from torchrl.modules import WorldModelWrapper

from pernav.planner import DiscreteTreeSearchPlanner


class Walk(nn.Module):  # a walker on a line: action 0 steps left, 1 stays, 2 steps right
    def __init__(self, one_hot: bool) -> None:
        super().__init__()
        self.one_hot = one_hot

    def forward(self, x: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
        a = action.long().argmax(-1) if self.one_hot else action.reshape(x.shape[:-1])
        return x + (a.unsqueeze(-1) - 1).to(x.dtype)


class Near(nn.Module):  # reward: minus the distance to 3
    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return -(x - 3).abs()


class Line(ModelBasedEnvBase):
    def __init__(self, spec) -> None:
        one_hot = isinstance(spec, OneHot)
        super().__init__(WorldModelWrapper(TensorDictModule(Walk(one_hot), ["x", "action"], ["x"]),
                                           TensorDictModule(Near(), ["x"], ["reward"])))
        self.observation_spec = Composite(x=Unbounded((1,)))
        self.action_spec = spec
        self.reward_spec = Unbounded((1,))

    def _reset(self, td=None, **kwargs):
        return td


def roots(shape: tuple[int, ...]) -> TensorDict:
    x = torch.tensor([0.0, 5.0, 3.0, 1.0, 4.0, 2.0])[: torch.Size(shape).numel()].reshape(*shape, 1)
    return TensorDict({"x": x}, list(shape))


EXPECTED = torch.tensor([2, 0, 1, 2, 0, 2])  # towards 3, staying there


@pytest.mark.parametrize("shape", [(6,), (2, 3), (1,)])
def test_a_one_hot_spec_gets_its_bool_one_hot_and_the_global_generator_is_untouched(shape: tuple[int, ...]) -> None:
    planner = DiscreteTreeSearchPlanner(Line(OneHot(3)), planning_horizon=2)
    torch.manual_seed(0)
    state = torch.get_rng_state()
    action = planner(roots(shape))["action"]
    assert torch.equal(torch.get_rng_state(), state)
    assert action.dtype == torch.bool and action.shape == (*shape, 3)
    assert torch.equal(action.long().argmax(-1).reshape(-1), EXPECTED[: action.shape[:-1].numel()])
    assert Line(OneHot(3)).action_spec.is_in(action.reshape(-1, 3))


@pytest.mark.parametrize("spec,shape", [(Categorical(3), ()), (Categorical(3, shape=(1,)), (1,)),
                                        (Categorical(3, dtype=torch.int32), ()), (OneHot(3, dtype=torch.int64), (3,))])
def test_the_action_has_the_specs_shape_and_dtype(spec, shape: tuple[int, ...]) -> None:
    planner = DiscreteTreeSearchPlanner(Line(spec), planning_horizon=2)
    state = torch.get_rng_state()
    action = planner(roots((2, 3)))["action"]
    assert torch.equal(torch.get_rng_state(), state)
    assert action.dtype == spec.dtype and action.shape == (2, 3, *shape)
    first = action.long().argmax(-1) if isinstance(spec, OneHot) else action.reshape(2, 3)
    assert torch.equal(first.reshape(-1).long(), EXPECTED)


@pytest.mark.parametrize("spec", [MultiCategorical([3, 3]), Binary(3), MultiOneHot([2, 3]), Categorical(3, shape=(2,))])
def test_specs_of_several_actions_are_refused_by_name(spec) -> None:
    with pytest.raises(TypeError, match=rf"{type(spec).__name__}.*not supported"):
        DiscreteTreeSearchPlanner(Line(spec), planning_horizon=2)


def test_a_continuous_spec_points_to_torchrls_planners() -> None:
    with pytest.raises(TypeError, match="Bounded.*CEMPlanner"):
        DiscreteTreeSearchPlanner(Line(Bounded(-1.0, 1.0, (1,))), planning_horizon=2)
