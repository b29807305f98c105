"""Discrete actions at the training boundary: one-hot (TorchRL's ``OneHot`` spec, ``GymEnv``'s default) or
categorical, always read as action indices by the buffers, the losses and the adaptation.

The model one-hot encodes its actions itself (:meth:`~pernav.model.DynamicsModel.with_action`), so the data keeps
one form, the indices: a trajectory recorded with one-hot actions gives exactly the losses and adapted parameters
of the same trajectory recorded with indices. Categorical actions pass through untouched (the same tensor).

Example:
    >>> import torch
    >>> action_indices(torch.tensor([[0, 1, 0], [1, 0, 0]]), (2,)).tolist()
    [1, 0]
    >>> action_indices(torch.tensor([2, 0]), (2,)).tolist()
    [2, 0]
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from tensordict import TensorDictBase
from tensordict.utils import NestedKey

__all__ = ["action_indices", "with_action_indices"]


def _refuse(action: torch.Tensor, batch_shape: tuple[int, ...], why: str) -> ValueError:
    return ValueError(f"action of shape {tuple(action.shape)} and dtype {action.dtype} for a batch "
                      f"{batch_shape}: {why}; discrete actions are categorical indices {batch_shape} (or "
                      f"{(*batch_shape, 1)}) or one-hot {(*batch_shape, 'A')} (one 1 per step, the rest 0)")


def action_indices(action: torch.Tensor, batch_shape: Sequence[int], n_actions: int | None = None) -> torch.Tensor:
    """The action indices ``batch_shape`` of categorical (``batch_shape`` or ``[..., 1]``) or one-hot
    (``[..., A]``, any dtype, bool included) actions. Indices already of shape ``batch_shape`` are returned as they
    are (integers, or floats that hold whole numbers, cast to ``long``); a ``[..., 1]`` trailing dimension is dropped.

    ``ValueError`` (naming one-hot) for a width-``A`` action that is not one-hot, for an ``A`` other than
    ``n_actions`` (when given), and for any other shape; a floating-point action that is not whole numbers is a
    continuous one, which a discrete model cannot read.
    """
    batch_shape = tuple(batch_shape)
    shape = tuple(action.shape)
    if shape[: len(batch_shape)] != batch_shape or len(shape) > len(batch_shape) + 1:
        raise _refuse(action, batch_shape, "its leading dimensions are not the batch's")
    if n_actions == 1 and shape[len(batch_shape):] == (1,):  # one action: the one-hot [..., 1] is index 0
        return torch.zeros(batch_shape, dtype=torch.long, device=action.device)
    if len(shape) == len(batch_shape) or shape[-1] == 1:  # categorical
        if action.is_floating_point():
            if not bool((action == action.round()).all()):
                raise _refuse(action, batch_shape, "floating-point values that are not whole numbers (continuous "
                                                   "actions?)")
            action = action.long()
        return action.reshape(batch_shape) if len(shape) > len(batch_shape) else action
    width = shape[-1]
    if n_actions is not None and width != int(n_actions):
        raise _refuse(action, batch_shape, f"a one-hot width of {width} for a model of {n_actions} actions")
    ones = action == 1
    if not bool((ones | (action == 0)).all() and (ones.sum(-1) == 1).all()):
        raise _refuse(action, batch_shape, f"a width-{width} last dimension that is not one-hot")
    return ones.long().argmax(-1)


def with_action_indices(data: TensorDictBase, action_key: NestedKey = "action",
                        n_actions: int | None = None) -> TensorDictBase:
    """``data`` with its ``action_key`` entry as indices (:func:`action_indices` over ``data``'s batch): ``data``
    itself when the actions already are indices of the batch's shape, else a shallow copy with the entry replaced."""
    action = data.get(action_key)
    indices = action_indices(action, data.shape, n_actions)
    if indices is action:
        return data
    out = data.clone(False)  # new containers (a nested key too), the same tensors
    out.set(action_key, indices)
    return out
