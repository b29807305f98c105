"""One-shot adaptation ``U(P, tau)`` (paper Eq. 2): one gradient step of the L-step loss on one trajectory.

Parameters are handled functionally as a :class:`~tensordict.TensorDict` (``TensorDict.from_module``
layout, buffers included); the adapted parameters are returned as a new TensorDict and swapped into the
model only where they are used (``with adapted.to_module(model): ...``), never by copying the module.
With ``first_order=False`` the step is differentiable (``create_graph=True``), so a loss computed with the
adapted parameters back-propagates to the meta parameters through the adaptation (MAML-style, as FTML
needs); ``first_order=True`` treats the adaptation gradient as a constant.

``backtrack=c`` (test-time ``U``, first order only): halve the step from ``alpha`` (at most three times, to
``alpha / 8``) until it passes the sufficient-decrease (Armijo) test on ``tau`` itself,
``loss(P - a g) <= loss(P) - c a |g|^2``. With ``c = 0.5`` it accepts at most the step to ``tau``'s own
minimum along ``g`` (exact on a quadratic), so it does not overshoot on a driver whose gradient is large
(at online time in the default study on world v1 a fixed ``alpha`` lowered the held-out loss in 27 of 36 rounds,
backtracking in 31; ``docs/research/scripts/step_size_check.py``, docs/research/findings.md "One step, how
long?"). When no halving passes (or ``tau``'s loss is not finite), ``U`` takes no step: the parameters are returned
unchanged, so a backtracked ``U`` never makes ``tau``'s own loss worse, and it says so
(``adapt(..., return_info=True)`` returns an :class:`AdaptInfo` with ``fell_back`` per member).

``max_norm`` (the adaptation gradient's clip) has one default, :data:`MAX_NORM`, shared with
``TrainConfig.max_grad_norm``; ``max_norm=None`` leaves the gradient unclipped.

Example:
    >>> import torch
    >>> from tensordict import TensorDict
    >>> from pernav.model.dynamics import DynamicsModel
    >>> model = DynamicsModel(hidden=(16,))
    >>> T = 12
    >>> tau = TensorDict({"history": torch.randn(T, 5, 21), "action": torch.randint(7, (T,)),
    ...                   "observation": torch.randn(T, 14), ("next", "observation"): torch.randn(T, 14)}, [T])
    >>> adapted = adapt(model, tau, alpha=0.01)
    >>> adapted["net", "0", "weight"].shape == model.net[0].weight.shape
    True
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import torch
from tensordict import TensorDict, TensorDictBase
from tensordict.utils import NestedKey

from pernav.model.actions import with_action_indices
from pernav.model.dynamics import DynamicsModel
from pernav.model.losses import multistep_loss

__all__ = ["MAX_NORM", "AdaptInfo", "LossFn", "adapt", "meta_parameters", "trajectory_windows"]

#: A model loss ``loss_fn(model, batch [B, L], params=None) -> scalar`` (``[E]`` for stacked ensemble params).
LossFn = Callable[..., torch.Tensor]

#: The adaptation gradient's norm clip: ``adapt``'s default ``max_norm`` and ``TrainConfig.max_grad_norm``'s. Typical
#: norms are 5-20; a model whose L-step rollouts diverge on ``tau`` gives thousands (docs/reliability.md).
MAX_NORM = 100.0


@dataclass(frozen=True)
class AdaptInfo:
    """What one ``U(P, tau)`` did (``adapt(..., return_info=True)``), per member for stacked parameters.

    Attributes:
        loss: ``tau``'s loss before the step (``[]``, or ``[E]``).
        step: the step length taken (``alpha``, a halving of it, or 0 where ``U`` fell back).
        fell_back: where no step passed the sufficient-decrease test (``backtrack``): the parameters were returned
            unchanged. Always false with the fixed step (``backtrack=None``), which has no test.
    """

    loss: torch.Tensor
    step: torch.Tensor
    fell_back: torch.Tensor

    @property
    def fallbacks(self) -> int:
        """How many members fell back (0 or 1 for one model)."""
        return int(self.fell_back.sum())


def meta_parameters(model: torch.nn.Module) -> TensorDictBase:
    """The model's parameters and buffers as a TensorDict (the live tensors, so gradients reach them)."""
    return TensorDict.from_module(model)


def trajectory_windows(trajectory: TensorDictBase, L: int, stride: int = 1) -> TensorDictBase:
    """The ``[L]`` slices of consecutive transitions of a ``[T]`` trajectory starting every ``stride`` steps,
    shape ``[N, L]`` (a trajectory shorter than ``L`` gives one slice of length ``T``). ``stride=1``: every
    slice; ``stride=L``: slices that tile the trajectory (each transition predicted once)."""
    if trajectory.ndim != 1:
        raise ValueError(f"a trajectory must be a 1-D tensordict, got batch_size {tuple(trajectory.shape)}")
    T = trajectory.shape[0]
    if T == 0:
        raise ValueError("cannot adapt on an empty trajectory")
    L = min(L, T)
    index = torch.arange(0, T - L + 1, max(int(stride), 1)).unsqueeze(1) + torch.arange(L).unsqueeze(0)
    return trajectory[index]


def adapt(model: DynamicsModel, trajectory: TensorDictBase, alpha: float = 0.01, L: int = 5,
          first_order: bool = False, params: TensorDictBase | None = None, stride: int | None = None,
          max_norm: float | None = MAX_NORM, backtrack: float | None = None,
          loss_fn: LossFn = multistep_loss, action_key: NestedKey = "action",
          return_info: bool = False) -> TensorDictBase | tuple[TensorDictBase, AdaptInfo]:
    """``U(P, tau)``: ``params - alpha * grad L-step-loss(params; tau)`` over the L-slices of ``tau``
    (by default the slices that tile ``tau``, ``stride=L``: every transition is predicted once, at every
    rollout depth 1..L in turn; ``stride=1`` uses every overlapping slice, ~L times the work for the same
    transitions).

    ``params`` defaults to the model's own (meta) parameters; stacked ensemble parameters (batch ``[E]``)
    adapt every member at once. Buffers (normalization statistics) are carried over unchanged. A model with a
    context (``DynamicsModel(context=n)``) adapts only its context vector (CAVIA); the weights stay the meta ones.
    Any ``nn.Module`` adapts with a ``loss_fn`` that reads it; one without ``n_context`` has no context (every
    parameter that requires grad is adapted).

    ``max_norm``: the step's gradient is scaled down to at most this global norm (per member), differentiably
    (default :data:`MAX_NORM`, as ``TrainConfig.max_grad_norm``; ``None``: unclipped). A model whose L-step rollouts
    diverge on ``tau`` has an adaptation gradient of thousands (typically 5-20); unclipped, ``alpha`` times it throws
    the adapted parameters far off and the meta loss overflows.

    ``backtrack``: the Armijo constant ``c`` of the step-halving line search on ``tau`` (module docstring;
    per member for stacked parameters); ``None`` (the paper): the fixed step ``alpha``. With it, a member for which
    no step passes keeps its parameters (``U`` never makes ``tau``'s loss worse).

    ``return_info``: return ``(parameters, AdaptInfo)``, telling whether ``U`` fell back (the study counts those).

    ``loss_fn``: the loss the step descends, ``loss_fn(model, windows [N, L], params=...)``; the paper's L-step
    loss (:func:`~pernav.model.losses.multistep_loss`) by default, e.g. ``single_step_loss`` or your own.

    ``trajectory``'s actions (at ``action_key``) may be categorical or one-hot (TorchRL's ``OneHot``): both give the
    same adapted parameters. A trajectory without ``action_key`` is passed to ``loss_fn`` as it is (a loss with
    keys of its own reads them; :func:`~pernav.model.losses.multistep_loss` reads one-hot actions itself).
    """
    if backtrack is not None and not (0.0 < backtrack < 1.0 and first_order):
        raise ValueError(f"backtrack must be in (0, 1) and needs first_order=True, got {backtrack} "
                         f"(first_order={first_order}): pass adapt(..., first_order=True, backtrack=0.5), or "
                         "backtrack=None for the paper's fixed step")
    if max_norm is not None and not max_norm > 0:
        raise ValueError(f"max_norm must be > 0 (the adaptation gradient's norm clip) or None (unclipped), got {max_norm}")
    params = meta_parameters(model) if params is None else params
    keys = [k for k, v in params.items(True, True) if isinstance(v, torch.Tensor) and v.requires_grad
            and (not getattr(model, "n_context", 0) or k == "context")]  # any nn.Module: no n_context, no context
    if not keys:
        raise ValueError("no parameter requires grad: nothing to adapt")
    # one-hot actions (TorchRL's OneHot spec) as indices, once: a custom loss_fn sees the same windows either way
    if action_key in trajectory.keys(True):
        trajectory = with_action_indices(trajectory, action_key, n_actions=getattr(model, "n_actions", None))
    windows = _on_model(trajectory_windows(trajectory, L, L if stride is None else stride), params)
    with torch.enable_grad():
        loss = loss_fn(model, windows, params=params)
        # stacked ensemble parameters give one loss per member: their sum's gradient is each member's own
        grads = torch.autograd.grad(loss.sum(), [params.get(k) for k in keys], create_graph=not first_order)
        if max_norm is not None:
            lead = params.batch_dims  # 1 for stacked ensemble parameters: one norm per member
            sq = sum(g.pow(2).flatten(lead).sum(-1) for g in grads)
            scale = (max_norm / (sq.sqrt() + 1e-12)).clamp(max=1.0)  # exactly 1 (no change) below max_norm
            grads = [g * scale.reshape(scale.shape + (1,) * (g.ndim - lead)) for g in grads]
    if backtrack is None:
        adapted = _step(params, keys, grads, alpha)
        if not return_info:
            return adapted
        loss0 = loss.detach()
        return adapted, AdaptInfo(loss0, torch.full_like(loss0, alpha), torch.zeros_like(loss0, dtype=torch.bool))
    adapted, info = _backtracked(model, windows, params, keys, grads, loss.detach(), alpha, backtrack, loss_fn)
    return (adapted, info) if return_info else adapted


def _on_model(data: TensorDictBase, params: TensorDictBase) -> TensorDictBase:
    """``data`` on the device of ``params`` and with their floating dtype (a float64 or CUDA model adapts on the
    data a float32 CPU env recorded); ``data`` itself when it already is."""
    reference = next((v for v in params.values(True, True) if isinstance(v, torch.Tensor) and v.is_floating_point()),
                     None)
    if reference is None:
        return data
    return to_model(data, reference.device, reference.dtype)


def to_model(data: TensorDictBase, device: torch.device, dtype: torch.dtype) -> TensorDictBase:
    """``data`` moved to ``device`` and its floating-point entries cast to ``dtype``; ``data`` itself (no copy)
    when nothing needs to change, so a model already on the data's device and dtype computes exactly as before."""
    leaves = [(k, v) for k, v in data.items(True, True) if isinstance(v, torch.Tensor)]
    if all(v.device == device and (not v.is_floating_point() or v.dtype == dtype) for _, v in leaves):
        return data
    out = data.to(device) if any(v.device != device for _, v in leaves) else data.clone(False)
    for key, value in out.items(True, True):
        if isinstance(value, torch.Tensor) and value.is_floating_point() and value.dtype != dtype:
            out.set(key, value.to(dtype))
    return out


def _step(params: TensorDictBase, keys: list, grads: list, step: float | torch.Tensor) -> TensorDictBase:
    """``params - step * grads`` (``step`` a number, or one per member, ``[E]``)."""
    adapted = params.copy()  # shallow: buffers are shared, parameters replaced below
    lead = params.batch_dims
    for k, g in zip(keys, grads, strict=True):
        a = step.reshape(step.shape + (1,) * (g.ndim - lead)) if isinstance(step, torch.Tensor) else step
        adapted.set(k, params.get(k) - a * g)
    return adapted


@torch.no_grad()
def _backtracked(model: DynamicsModel, windows: TensorDictBase, params: TensorDictBase, keys: list, grads: list,
                 loss0: torch.Tensor, alpha: float, c: float, loss_fn: LossFn = multistep_loss,
                 halvings: int = 3) -> tuple[TensorDictBase, AdaptInfo]:
    """Each member's largest step in ``alpha, alpha/2, ...`` that passes the Armijo test; a member for which none
    does keeps its parameters (no step)."""
    lead = params.batch_dims
    g2 = sum(g.pow(2).flatten(lead).sum(-1) for g in grads)
    step = torch.full_like(loss0, alpha / 2 ** halvings)
    settled = torch.zeros_like(loss0, dtype=torch.bool)
    for i in range(halvings + 1):
        a = alpha / 2 ** i
        ok = loss_fn(model, windows, params=_step(params, keys, grads, a)) <= loss0 - c * a * g2
        step = torch.where(ok & ~settled, torch.full_like(step, a), step)
        settled |= ok
        if bool(settled.all()):
            break
    adapted = _step(params, keys, grads, step)
    fell_back = ~settled
    if bool(fell_back.any()):  # no step passed: those members keep their parameters exactly
        for k in keys:
            old = params.get(k)
            adapted.set(k, torch.where(fell_back.reshape(fell_back.shape + (1,) * (old.ndim - lead)), old,
                                       adapted.get(k)))
    return adapted.detach(), AdaptInfo(loss0, torch.where(fell_back, torch.zeros_like(step), step), fell_back)
