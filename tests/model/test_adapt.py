"""The meta-gradient through the adaptation U(P, tau) (``adapt``): it matches finite differences (float64
gradcheck), and the first-order variant equals a hand-written adaptation step with its gradient detached and
differs from the second-order one.
"""

from __future__ import annotations

from contextlib import nullcontext

import pytest
import torch
from navigation_helpers import S
from navigation_helpers import seeded_model as _model
from tensordict import TensorDict

from pernav.model import adapt, multistep_loss


def _meta_problem(seed: int = 0, T: int = 9, B: int = 3, L: int = 3):
    model = _model(seed, K=3, hidden=(8,)).double()
    g = torch.Generator().manual_seed(seed)

    def transitions(*shape):
        return TensorDict({"history": torch.randn(*shape, 3, 21, generator=g, dtype=torch.float64),
                           "action": torch.randint(7, shape, generator=g),
                           "observation": torch.randn(*shape, S, generator=g, dtype=torch.float64),
                           ("next", "observation"): torch.randn(*shape, S, generator=g, dtype=torch.float64)},
                          list(shape))

    params = TensorDict.from_module(model).detach().clone()
    for key in params.keys(True, True):
        if key[0] == "net":  # the MLP's weights and biases; the normalization buffers stay constant
            params.get(key).requires_grad_()
    return model, params, transitions(T), transitions(B, L)


def _outer(model, params, tau, batch, key, first_order: bool = False):
    def f(tensor):
        p = params.copy()
        p.set(key, tensor)
        adapted = adapt(model, tau, alpha=0.05, L=3, first_order=first_order, params=p)
        return multistep_loss(model, batch, params=adapted)
    return f


@pytest.mark.slow
def test_meta_gradient_matches_finite_differences() -> None:
    model, params, tau, batch = _meta_problem()
    for key in (("net", "0", "bias"), ("net", "2", "weight")):
        theta = params.get(key).detach().clone().requires_grad_()
        assert torch.autograd.gradcheck(_outer(model, params, tau, batch, key), (theta,), eps=1e-6, atol=1e-6)


def test_first_order_drops_the_second_order_term() -> None:
    model, params, tau, batch = _meta_problem(seed=1)
    key = ("net", "0", "weight")
    theta = params.get(key).detach().clone().requires_grad_()
    second, = torch.autograd.grad(_outer(model, params, tau, batch, key)(theta), theta)
    first, = torch.autograd.grad(_outer(model, params, tau, batch, key, first_order=True)(theta), theta)
    # first order by hand: the adaptation gradient detached
    p = params.copy()
    p.set(key, theta)
    keys = [k for k in p.keys(True, True) if p.get(k).requires_grad]
    grads = torch.autograd.grad(multistep_loss(model, _windows(tau, 3), params=p), [p.get(k) for k in keys])
    adapted = p.copy()
    for k, gk in zip(keys, grads, strict=True):
        adapted.set(k, p.get(k) - 0.05 * gk.detach())
    manual, = torch.autograd.grad(multistep_loss(model, batch, params=adapted), theta)
    assert torch.allclose(first, manual, rtol=1e-10, atol=1e-12)
    assert not torch.allclose(first, second, rtol=1e-3, atol=1e-6)


def _windows(tau, L):
    """The L-slices that tile tau (adapt's default, stride L)."""
    index = torch.arange(0, tau.shape[0] - L + 1, L)[:, None] + torch.arange(L)[None]
    return tau[index]


class _Linear(torch.nn.Module):
    """A custom model (no ``n_context``, no ``config()``): the next state from the newest window row."""

    def __init__(self) -> None:
        super().__init__()
        self.net = torch.nn.Linear(S + 7, S)

    def forward(self, history: torch.Tensor) -> torch.Tensor:
        return self.net(history[..., -1, :])


def _linear_loss(model: torch.nn.Module, batch, params=None) -> torch.Tensor:
    with params.to_module(model) if params is not None else nullcontext():
        return ((model(batch["history"]) - batch["next", "observation"]) ** 2).mean()


def test_a_custom_module_with_a_loss_fn_adapts_and_meta_trains() -> None:
    """A plain ``nn.Module`` without ``n_context`` has no context: ``adapt`` steps every parameter, and the FTML meta
    update runs (it raised ``AttributeError: ... 'n_context'``)."""
    from pernav.trainer import FTMLTrainer, RoundBuffers, TrainConfig

    g = torch.Generator().manual_seed(0)
    buffers = RoundBuffers(L=3, seed=0)
    for r in range(2):
        T = 12
        buffers.add(r, TensorDict({"observation": torch.randn(T, S, generator=g),
                                   "action": torch.randint(7, (T,), generator=g),
                                   "history": torch.randn(T, 2, S + 7, generator=g),
                                   ("next", "observation"): torch.randn(T, S, generator=g)}, [T]), tau=True)
    torch.manual_seed(0)
    model = _Linear()
    before = {k: v.clone() for k, v in model.state_dict().items()}
    adapted = adapt(model, buffers.tau(0), alpha=0.1, L=3, loss_fn=_linear_loss, first_order=True)
    assert set(adapted.flatten_keys().keys()) == {"net.weight", "net.bias"}
    assert not torch.equal(adapted["net", "weight"], before["net.weight"])
    trainer = FTMLTrainer(model, buffers, TrainConfig(batch=4, L=3), seed=0, loss_fn=_linear_loss)
    losses = trainer.train(2, meta=True)
    assert len(losses) == 2 and all(torch.isfinite(torch.tensor(losses)))
    assert not torch.equal(model.net.weight, before["net.weight"])
