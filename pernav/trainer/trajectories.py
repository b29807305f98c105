"""What :class:`~pernav.trainer.buffers.RoundBuffers` checks in an add before it writes anything: where the episodes
of a TorchRL batch begin and end, and the entries' dtypes, values and actions.

Episodes are what TorchRL says they are: a ``[B, T]`` batch (a batched env's rollout, a collector's batch) is B
trajectories (time is the last batch dimension), a collector's ``("collector", "traj_ids")`` tells its trajectories
apart, and ``("next", "done")`` ends one (a rollout with ``break_when_any_done=False`` spans several episodes).

Example:
    >>> import torch
    >>> from tensordict import TensorDict
    >>> done = torch.tensor([False, True, False, False, True]).unsqueeze(-1)
    >>> rollout = TensorDict({"observation": torch.arange(5.0).unsqueeze(-1), ("next", "done"): done}, [5])
    >>> [len(e) for e in split_episodes(rollout)]
    [2, 3]
"""

from __future__ import annotations

import torch
from tensordict import TensorDictBase
from tensordict.utils import NestedKey

__all__ = ["DONE_KEY", "TRAJ_IDS_KEY", "cast_losslessly", "check_actions", "check_finite", "split_episodes"]

#: Where TorchRL marks the end of an episode, and where a collector writes each step's trajectory id.
DONE_KEY = ("next", "done")
TRAJ_IDS_KEY = ("collector", "traj_ids")


def split_episodes(data: TensorDictBase) -> list[TensorDictBase]:
    """The ``[T]`` episodes of ``data`` (``[T]``, or ``[..., T]``: each leading index is its own trajectory), in
    order: split by a collector's ``("collector", "traj_ids")``, then after every step whose ``("next", "done")`` is
    set. ``[data]`` itself when it is one episode (no copy). ``ValueError`` for a tensordict without a batch
    dimension."""
    if data.ndim == 0:
        raise ValueError("a trajectory is a [T] tensordict (or a [B, T] batch of them); got batch_size () "
                         "(a single step: add env.rollout(...) or a collector's batch)")
    if data.ndim > 1:
        rows = data.reshape(-1, data.shape[-1])
        return [episode for b in range(rows.shape[0]) for episode in split_episodes(rows[b])]
    keys = data.keys(True)
    pieces = [data]
    if TRAJ_IDS_KEY in keys:
        ids = data.get(TRAJ_IDS_KEY).reshape(data.shape[0], -1)[:, 0]
        order = list(dict.fromkeys(ids.tolist()))  # in order of first appearance
        if len(order) > 1:
            pieces = [data[ids == i] for i in order]
    if DONE_KEY not in keys:
        return pieces
    out = []
    for piece in pieces:
        done = piece.get(DONE_KEY).reshape(piece.shape[0], -1).any(-1)
        ends = (torch.nonzero(done[:-1]).flatten() + 1).tolist()  # the step after a done starts a new episode
        if not ends:
            out.append(piece)
            continue
        bounds = [0, *ends, piece.shape[0]]
        out.extend(piece[a:b] for a, b in zip(bounds[:-1], bounds[1:], strict=True))
    return out


def _lossless(value: torch.Tensor, dtype: torch.dtype) -> bool:
    """Whether ``value`` survives a round trip through ``dtype`` exactly (NaN and infinities where they were)."""
    if value.is_floating_point() and not dtype.is_floating_point and not bool(torch.isfinite(value).all()):
        return False
    back = value.to(dtype).to(value.dtype)
    if value.is_floating_point():
        return bool(torch.isclose(back, value, rtol=0.0, atol=0.0, equal_nan=True).all())
    return bool(torch.equal(back, value))


def cast_losslessly(data: TensorDictBase, dtypes: dict[NestedKey, torch.dtype]) -> TensorDictBase:
    """``data`` (a copy's containers may be replaced in place: pass a fresh ``select(...).clone()``) with each entry
    named in ``dtypes`` cast to that dtype where the cast loses nothing; ``TypeError`` naming every entry whose values
    a cast would change (e.g. float64 observations into float32 storage), and the fix."""
    refused = []
    for key, dtype in dtypes.items():
        value = data.get(key, None)
        if value is None or value.dtype == dtype:
            continue
        if _lossless(value, dtype):
            data.set(key, value.to(dtype))
        else:
            refused.append(f"{key!r} is {value.dtype} but the buffers store {dtype}")
    if refused:
        raise TypeError("the trajectory's values would change in the stored dtype: " + "; ".join(refused) + " (the "
                        "first add fixes each entry's dtype; cast the data yourself, e.g. td.float(), or keep rounds "
                        "of one dtype in buffers of their own)")
    return data


def check_finite(data: TensorDictBase) -> None:
    """``ValueError`` naming every floating-point entry of ``data`` ``[T, ...]`` with a NaN or an infinity (the first
    such step and how many), and the fix."""
    bad = []
    for key, value in data.items(True, True):
        if not isinstance(value, torch.Tensor) or not value.is_floating_point():
            continue
        finite = torch.isfinite(value).reshape(value.shape[0], -1).all(-1)
        if not bool(finite.all()):
            steps = torch.nonzero(~finite).flatten()
            bad.append(f"{key!r} at {steps.numel()} step(s), the first step {int(steps[0])}")
    if bad:
        raise ValueError("the trajectory holds NaN or infinite values: " + "; ".join(bad) + " (a model trained on them "
                         "skips its updates; clean the data, or add(..., allow_nonfinite=True) to keep them)")


def check_actions(action: torch.Tensor, n_actions: int | None, source: str) -> None:
    """``ValueError`` unless every action index is in ``[0, n_actions)`` (``source`` says where ``n_actions`` came
    from); only the lower bound without ``n_actions``."""
    if action.numel() == 0:
        return
    low, high = int(action.min()), int(action.max())
    if low < 0:
        raise ValueError(f"actions must be indices >= 0 (or one-hot), got the minimum {low}")
    if n_actions is not None and high >= n_actions:
        raise ValueError(f"action {high} is out of range for {n_actions} actions ({source}): discrete actions are "
                         f"indices 0..{n_actions - 1} (or one-hot of width {n_actions}); record the env's own actions, "
                         "or give RoundBuffers(n_actions=) the env's action spec")
