"""Model-learning losses: the paper's L-step loss (Eq. 4) and a single-step loss, with optional functional
parameters (any :class:`~tensordict.TensorDict` of the model's parameters, e.g. adapted ones).

A batch is a tensordict of shape ``[B, L]`` of consecutive transitions of one trajectory each (what
:class:`~pernav.trainer.buffers.RoundBuffers` samples), with ``"history"``, ``"action"``, ``"observation"``
and ``("next", "observation")``, and for a model that reads the road ``"road"`` (or the env's ``"route_ahead"``).
Actions are categorical (``[B, L]``) or one-hot (``[B, L, A]``, TorchRL's ``OneHot``): the same data gives the same
loss either way (:func:`~pernav.model.actions.action_indices`). Other entry names are given with
``observation_key=``, ``action_key=`` and ``history_key=`` (e.g. ``functools.partial(multistep_loss,
observation_key="obs")`` as a trainer's ``loss_fn``); the next state is read at ``("next", observation_key)``.

Example:
    >>> import torch
    >>> from tensordict import TensorDict
    >>> from pernav.model.dynamics import DynamicsModel
    >>> model = DynamicsModel(hidden=(16,))
    >>> B, L = 8, 5
    >>> batch = TensorDict({"history": torch.randn(B, L, 5, 21), "action": torch.randint(7, (B, L)),
    ...                     "observation": torch.randn(B, L, 14),
    ...                     ("next", "observation"): torch.randn(B, L, 14)}, [B, L])
    >>> multistep_loss(model, batch).shape
    torch.Size([])
"""

from __future__ import annotations

from contextlib import nullcontext

import torch
from tensordict import TensorDictBase
from tensordict.utils import NestedKey

from pernav.model.actions import action_indices
from pernav.model.dynamics import DynamicsModel
from pernav.model.egocentric import road_of

__all__ = ["multistep_loss", "single_step_loss", "using"]


def using(model: torch.nn.Module, params: TensorDictBase | None):
    """Context in which ``model`` runs with ``params`` (``TensorDict.from_module`` layout) swapped in.

    Gradients flow to ``params``; the module's own parameters are restored on exit.
    """
    return nullcontext() if params is None else params.to_module(model)


def _rollout_loss(model: DynamicsModel, batch: TensorDictBase, ensemble: TensorDictBase | None = None,
                  weights: torch.Tensor | None = None, keys: tuple[NestedKey, NestedKey, NestedKey] = (
                      "observation", "action", "history")) -> torch.Tensor:
    """The L-step loss of ``model`` (a scalar), or with ``ensemble`` (stacked member parameters, batch
    ``[E]``) every member's at once (``[E]``): the same batch, each member rolling out its own predictions.
    ``weights`` (``[B]``, or ``[E, B]`` per member) weigh the windows (a weighted mean over the batch).
    ``keys``: the observation, action and history entries."""
    observation_key, action_key, history_key = keys
    history = batch[history_key][:, 0]
    actions = action_indices(batch[action_key], batch.shape, getattr(model, "n_actions", None))  # one-hot: indices
    states = batch[observation_key]
    next_states = batch.get(("next", observation_key) if isinstance(observation_key, str)
                            else ("next", *observation_key))
    # the road at every step is the one ahead of the *true* car (what the data stores), while imagine() gives
    # the road ahead of the imagined car: later steps here see the true car's progress through the road's
    # first point (a partly teacher-forced loss; storing more of the route would let it track the prediction)
    road = road_of(batch) if model.road else None
    S = model.state_dim
    if ensemble is None:
        mean, std = model.out_mean, model.out_std
        loss = history.new_zeros(())
    else:  # a leading member dimension everywhere
        E = ensemble.shape[0]
        history = history.expand(E, *history.shape)
        mean, std = ensemble["out_mean"].unsqueeze(1), ensemble["out_std"].unsqueeze(1)
        loss = history.new_zeros(E)
    steps = batch.shape[1]
    for step in range(steps):
        action = actions[:, step].expand(history.shape[:-2])
        window = model.with_action(history, action)
        step_road = None if road is None else road[:, step]
        pred = (model.normalized_delta(window, step_road) if ensemble is None
                else model.ensemble_normalized_delta(window, ensemble, step_road))
        # the true difference, in the frame of the true previous state (Eq. 4: compare differences)
        target = (model.delta_layout.difference(states[:, step], next_states[:, step]) - mean) / std
        err = ((pred - target) ** 2).sum(-1)  # [B] or [E, B]
        if weights is None:
            loss = loss + err.mean(-1)
        else:  # a member whose windows all weigh 0 gets loss 0 (no gradient) from this batch
            loss = loss + (err * weights).sum(-1) / weights.sum(-1).clamp_min(1e-12)
        if step + 1 < steps:
            current = history[..., -1, :S]
            predicted = model.delta_layout.apply(current, pred * std + mean)
            history = model.next_window(history, action, predicted)
    return loss / steps


def multistep_loss(model: DynamicsModel, batch: TensorDictBase, params: TensorDictBase | None = None,
                   weights: torch.Tensor | None = None, *, observation_key: NestedKey = "observation",
                   action_key: NestedKey = "action", history_key: NestedKey = "history") -> torch.Tensor:
    """The L-step loss (Eq. 4): roll the model forward autoregressively from the true window at the
    start of each ``[L]`` slice with the true actions, and compare predicted and true state differences
    (normalized differences in the model's ``delta`` layout, squared error, averaged over steps and batch).

    ``params`` with a batch dimension (an ensemble's stacked parameters, ``[E]``) gives every member's loss,
    ``[E]``, in one batched pass (equal to each member's own loss). ``weights`` (``[B]``, or ``[E, B]`` with an
    ensemble) make it a weighted mean over the windows (bootstrap resampling, :meth:`EnsembleTrainer.fine_tuned`).
    ``observation_key``/``action_key``/``history_key``: the batch's entry names (module docstring)."""
    if batch.ndim != 2:
        raise ValueError(f"multistep_loss expects a [B, L] batch, got batch_size {tuple(batch.shape)}")
    keys = (observation_key, action_key, history_key)
    if params is not None and params.batch_dims > 0:
        return _rollout_loss(model, batch, ensemble=params, weights=weights, keys=keys)
    with using(model, params):
        return _rollout_loss(model, batch, weights=weights, keys=keys)


def single_step_loss(model: DynamicsModel, batch: TensorDictBase, params: TensorDictBase | None = None, *,
                     observation_key: NestedKey = "observation", action_key: NestedKey = "action",
                     history_key: NestedKey = "history") -> torch.Tensor:
    """One-step prediction loss on every transition of the batch (each from its true window); the keys as in
    :func:`multistep_loss`."""
    flat = batch.reshape(-1).unsqueeze(1)
    with using(model, params):
        return _rollout_loss(model, flat, keys=(observation_key, action_key, history_key))
