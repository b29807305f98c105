"""The meta-gradient through the adaptation U(P, tau) (``adapt``): it matches finite differences (float64
gradcheck), and the first-order variant equals a hand-written adaptation step with its gradient detached and
differs from the second-order one.
"""

from __future__ import annotations

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
