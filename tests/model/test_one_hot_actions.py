"""One-hot actions (TorchRL's ``OneHot`` spec, ``GymEnv``'s default) train as their indices do: the same data as
one-hot (int64, bool or float) and as indices gives identical L-step and one-step losses, ensemble losses, adapted
parameters (first and second order, backtracking) and FTML updates; a malformed one-hot is refused naming one-hot.
"""

from __future__ import annotations

import pytest
import torch
from tensordict import TensorDict

from pernav.model import DynamicsModel, adapt, multistep_loss, single_step_loss
from pernav.model.actions import action_indices
from pernav.trainer import FTMLTrainer, RoundBuffers, TrainConfig

S, A, K = 4, 3, 2


def model(seed: int = 0) -> DynamicsModel:
    torch.manual_seed(seed)
    return DynamicsModel(state_dim=S, n_actions=A, K=K, hidden=(16,), delta="plain")


def data(shape: tuple[int, ...], seed: int = 0) -> TensorDict:
    g = torch.Generator().manual_seed(seed)
    obs = torch.randn(*shape, S, generator=g)
    return TensorDict({"observation": obs, "action": torch.randint(A, shape, generator=g),
                       "history": torch.randn(*shape, K, S + A, generator=g),
                       ("next", "observation"): obs + 0.1 * torch.randn(*shape, S, generator=g)}, list(shape))


def one_hot(td: TensorDict, dtype: torch.dtype = torch.long) -> TensorDict:
    out = td.clone()
    out["action"] = torch.nn.functional.one_hot(td["action"], A).to(dtype)
    return out


def test_action_indices_reads_categorical_and_one_hot_actions() -> None:
    indices = torch.tensor([[2, 0], [1, 1]])
    assert action_indices(indices, (2, 2)) is indices  # the index path is untouched
    for dtype in (torch.long, torch.bool, torch.float64):
        encoded = torch.nn.functional.one_hot(indices, 3).to(dtype)
        assert torch.equal(action_indices(encoded, (2, 2), n_actions=3), indices)
    assert torch.equal(action_indices(indices.unsqueeze(-1), (2, 2)), indices)
    assert torch.equal(action_indices(indices.double(), (2, 2)), indices)
    assert torch.equal(action_indices(torch.ones(2, 1, dtype=torch.long), (2,), n_actions=1), torch.zeros(2).long())
    with pytest.raises(ValueError, match="not one-hot"):
        action_indices(torch.tensor([[1, 1, 0]]), (1,))
    with pytest.raises(ValueError, match="not one-hot"):
        action_indices(torch.tensor([[0.5, 0.5, 0.0]]), (1,))
    with pytest.raises(ValueError, match="one-hot width of 3 for a model of 4 actions"):
        action_indices(torch.tensor([[0, 1, 0]]), (1,), n_actions=4)
    with pytest.raises(ValueError, match="continuous"):
        action_indices(torch.tensor([0.3, 1.0]), (2,))
    with pytest.raises(ValueError, match="leading dimensions"):
        action_indices(torch.zeros(3, 2, 2), (2,))


@pytest.mark.parametrize("dtype", [torch.long, torch.bool, torch.float32])
def test_one_hot_and_indices_give_the_same_losses(dtype: torch.dtype) -> None:
    net, batch = model(), data((6, 3))
    encoded = one_hot(batch, dtype)
    assert torch.equal(multistep_loss(net, encoded), multistep_loss(net, batch))
    assert torch.equal(single_step_loss(net, encoded), single_step_loss(net, batch))
    weights = torch.rand(6, generator=torch.Generator().manual_seed(1))
    assert torch.equal(multistep_loss(net, encoded, weights=weights), multistep_loss(net, batch, weights=weights))
    stacked = torch.stack([TensorDict.from_module(model(seed)) for seed in range(3)])  # an ensemble's members
    assert torch.equal(multistep_loss(net, encoded, params=stacked), multistep_loss(net, batch, params=stacked))


@pytest.mark.parametrize("options", [{"first_order": False}, {"first_order": True},
                                     {"first_order": True, "backtrack": 0.5, "max_norm": 1.0}, {"stride": 1}])
def test_one_hot_and_indices_adapt_to_the_same_parameters(options: dict) -> None:
    net, tau = model(), data((11,), seed=2)
    by_index = adapt(net, tau, alpha=0.05, L=3, **options)
    by_one_hot = adapt(net, one_hot(tau, torch.bool), alpha=0.05, L=3, **options)
    for key in by_index.keys(True, True):
        assert torch.equal(by_one_hot.get(key), by_index.get(key)), key
    if not options.get("first_order", False):  # the second-order step still reaches the meta parameters
        loss = multistep_loss(net, data((4, 3), seed=3), params=by_one_hot)
        assert bool(torch.autograd.grad(loss, net.net[0].weight)[0].abs().sum() > 0)


def test_a_malformed_one_hot_is_refused_by_the_losses_and_adapt() -> None:
    net, batch = model(), one_hot(data((4, 3)))
    batch["action"][0, 1] = 1  # every action at once
    with pytest.raises(ValueError, match="one-hot"):
        multistep_loss(net, batch)
    with pytest.raises(ValueError, match="one-hot"):
        adapt(net, batch[0], L=3)
    with pytest.raises(ValueError, match="for a model of 3 actions"):
        multistep_loss(net, TensorDict({**data((4, 3)).to_dict(), "action": torch.zeros(4, 3, 5)}, [4, 3]))


def test_ftml_on_one_hot_data_equals_ftml_on_its_indices() -> None:
    runs = []
    for encode in (False, True):
        buffers = RoundBuffers(L=3, seed=0)
        for round_ in range(3):
            for k in range(2):
                t = data((12,), seed=10 * round_ + k)
                buffers.add(round_, one_hot(t) if encode else t, tau=k == 0)
        trainer = FTMLTrainer(model(), buffers, TrainConfig(batch=8, L=3, K=K, hidden=[16], alpha=0.05), seed=0)
        trainer.fit_normalization()
        losses = [trainer.plain_update() for _ in range(3)] + [trainer.meta_update() for _ in range(3)]
        runs.append((losses, {k: v.clone() for k, v in trainer.model.state_dict().items()}))
    assert runs[0][0] == runs[1][0]
    assert all(torch.equal(runs[0][1][k], runs[1][1][k]) for k in runs[0][1])
