"""HistoryWindow: the last K (state, action) pairs as one tensordict entry, with no hidden state."""

from __future__ import annotations

from collections.abc import Sequence

import torch
from tensordict import TensorDictBase
from tensordict.utils import NestedKey
from torchrl.data import Composite, OneHot, Unbounded
from torchrl.envs.transforms import Transform

__all__ = ["HistoryWindow"]


def _one_key(keys: NestedKey | Sequence[NestedKey] | None, alias: NestedKey | None, names: tuple[str, str],
             default: NestedKey) -> NestedKey:
    """The one key of ``in_keys``/``out_keys`` (a key, or a list of one key) or of its older alias (``state_key``,
    ``out_key``), ``default`` when neither is given; ``ValueError`` for several keys or two different ones."""
    if keys is not None:
        listed = [keys] if isinstance(keys, (str, tuple)) else list(keys)  # a tuple is one nested key, as in TorchRL
        if len(listed) != 1:
            raise ValueError(f"HistoryWindow records one observation into one window: {names[0]} must be one key, "
                             f"got {listed} (concatenate several first, e.g. torchrl's CatTensors)")
        if alias is not None and alias != listed[0]:
            raise ValueError(f"HistoryWindow: {names[0]}={listed} and {names[1]}={alias!r} disagree; give one of them "
                             f"({names[1]} is the older name of {names[0]})")
        return listed[0]
    return default if alias is None else alias


class HistoryWindow(Transform):
    """The last ``K`` (state, one-hot action) pairs under ``out_keys``, shape ``[..., K, S + n_actions]``.

    Convention, at time ``t`` (the root of a step's tensordict)::

        history[..., i, :S] = s_{t-K+1+i}
        history[..., i, S:] = one_hot(a_{t-K+1+i})     for i < K-1
        history[..., K-1, S:] = 0                      (a_t is not chosen yet)

    so the newest row holds the current observation and an all-zero action ("no action yet"). A step
    shifts the window by one row, writes the action just taken into the former newest row and appends
    ``(s_{t+1}, 0)``: ``td["next", out_key][..., K-2, :]`` is ``(s_t, a_t)`` and row ``K-1`` is
    ``(s_{t+1}, 0)``. At reset every row is ``(s_0, 0)``: rows before the episode start repeat the first
    observation with zero actions. With ``K == 1`` the window never holds an action.

    The window lives only in the tensordict (it is also declared as a state entry, so batched envs send
    it to their workers), so the transform works inside or around ``SerialEnv``/``ParallelEnv``, with
    ``env.rollout`` and collectors, and replay samples carry it like any other key. Actions may be
    categorical (``[...]`` or ``[..., 1]`` integers) or one-hot (``[..., n_actions]``); ``n_actions`` is read
    from the env's action spec unless given. A continuous action (a floating-point spec, e.g. Pendulum's) is
    recorded as it is: the action part of a row is the action itself. The window's dtype is the observation
    spec's (float32 for integer observations). A scalar observation (shape ``()``, e.g. FrozenLake's cell index, a
    ``Categorical``) is one column of the window, its value; one-hot encode it first to give the model its category.

    Keys, as in TorchRL's ``CatFrames``: ``in_keys`` (one observation, default ``["observation"]``) and ``out_keys``
    (one window, default ``["history"]``); ``state_key=``/``out_key=`` are their older names and still work. An
    observation the env does not have is a ``KeyError`` naming it and the env's observations.

    Example:
        >>> from torchrl.envs import GymEnv, TransformedEnv
        >>> env = TransformedEnv(GymEnv("CartPole-v1", categorical_action_encoding=True), HistoryWindow(K=4))
        >>> td = env.rollout(3)
        >>> td["history"].shape
        torch.Size([3, 4, 6])
        >>> bool((td["next", "history"][1, -1, :4] == td["next", "observation"][1]).all())
        True
        >>> int(td["next", "history"][1, -2, 4:].argmax()) == int(td["action"][1])
        True
        >>> HistoryWindow(K=4, in_keys=["observation"], out_keys=["window"]).out_key  # TorchRL's key arguments
        'window'
    """

    def __init__(self, K: int = 5, state_key: NestedKey | None = None, action_key: NestedKey = "action",
                 n_actions: int | None = None, out_key: NestedKey | None = None, *,
                 in_keys: Sequence[NestedKey] | None = None, out_keys: Sequence[NestedKey] | None = None) -> None:
        if K < 1:
            raise ValueError(f"K must be >= 1, got {K}")
        if n_actions is not None and n_actions < 1:
            raise ValueError(f"n_actions must be >= 1, got {n_actions}")
        state_key = _one_key(in_keys, state_key, ("in_keys", "state_key"), "observation")
        out_key = _one_key(out_keys, out_key, ("out_keys", "out_key"), "history")
        super().__init__(in_keys=[state_key], out_keys=[out_key])
        self.K = int(K)
        self.state_key = state_key
        self.action_key = action_key
        self._n_actions = None if n_actions is None else int(n_actions)
        self._from_spec = n_actions is None  # read (and re-read) from the env's action spec
        self.continuous = False  # set from the env's action spec: record actions as they are
        self.out_key = out_key

    @property
    def n_actions(self) -> int:
        """Width of a row's action part: the number of discrete actions (one-hot), or a continuous action's
        size. Read from the env's action spec unless given."""
        if self._n_actions is None:
            self._read_action_spec()
        return self._n_actions

    def _read_action_spec(self) -> None:
        parent = self.parent
        if parent is None:
            raise ValueError("HistoryWindow(n_actions=None) reads the number of actions from its env's action spec: "
                             "put it in a TransformedEnv, or pass n_actions")
        spec = parent.full_action_spec.get(self.action_key, None)
        if spec is None:
            raise KeyError(f"HistoryWindow: the env has no action {self.action_key!r}")
        n = getattr(getattr(spec, "space", None), "n", None)
        if isinstance(spec, OneHot) or (n is not None and not spec.dtype.is_floating_point):
            self._n_actions, self.continuous = int(n), False
        elif spec.dtype.is_floating_point:  # continuous: its values, as they are
            extra = spec.shape[len(parent.batch_size):]
            self._n_actions, self.continuous = int(torch.Size(extra).numel()), True
        else:
            raise ValueError(f"HistoryWindow: action {self.action_key!r} ({type(spec).__name__}, {spec.dtype}) is "
                             "neither discrete (Categorical, OneHot) nor continuous (floating point)")

    # ----- window arithmetic --------------------------------------------------------------------
    @staticmethod
    def _vector(state: torch.Tensor, batch_dims: int) -> torch.Tensor:
        """``state`` ``[..., S]``: a scalar observation (no dimension beyond the batch) as one column."""
        return state.unsqueeze(-1) if state.ndim == batch_dims else state

    def _row(self, state: torch.Tensor) -> torch.Tensor:
        """``(state, zeros)`` as one row, shape ``[..., 1, S + n_actions]``, in the state's floating dtype
        (float32 for integer states)."""
        state = state if state.is_floating_point() else state.to(torch.float32)
        zeros = state.new_zeros(*state.shape[:-1], self.n_actions)
        return torch.cat([state, zeros], dim=-1).unsqueeze(-2)

    def _one_hot(self, action: torch.Tensor, batch_dims: int) -> torch.Tensor:
        """``[..., n_actions]`` float one-hot of a categorical (``[...]``/``[..., 1]``) or one-hot action."""
        extra = tuple(action.shape[batch_dims:])
        batch = action.shape[:batch_dims]
        if self.continuous:  # recorded as it is
            return action.reshape(*batch, self.n_actions).to(torch.get_default_dtype() if not action.is_floating_point()
                                                             else action.dtype)
        if self.n_actions == 1 and extra in ((), (1,)):
            return action.new_ones(*batch, 1, dtype=torch.float32)
        if extra == (self.n_actions,):
            return action.to(torch.get_default_dtype() if not action.is_floating_point() else action.dtype)
        if extra not in ((), (1,)):
            raise ValueError(f"action {self.action_key!r} of shape {tuple(action.shape)} is neither "
                             f"categorical nor one-hot over {self.n_actions} actions")
        try:  # one_hot checks the range itself (no second pass over the actions: this runs in every planner step)
            one_hot = torch.nn.functional.one_hot(action.reshape(batch).long(), self.n_actions)
        except RuntimeError:
            raise ValueError(f"action out of range [0, {self.n_actions - 1}]: n_actions does not match the env") from None
        return one_hot.to(torch.float32)

    def initial_window(self, state: torch.Tensor) -> torch.Tensor:
        """The window at reset: ``K`` copies of ``(state, 0)``."""
        row = self._row(state)
        return row.expand(*row.shape[:-2], self.K, row.shape[-1]).clone()

    def next_window(self, window: torch.Tensor, action: torch.Tensor, next_state: torch.Tensor,
                    batch_dims: int | None = None) -> torch.Tensor:
        """Shift ``window`` by one: record ``action`` in its newest row and append ``(next_state, 0)``."""
        new_row = self._row(next_state).to(device=window.device, dtype=window.dtype)
        if self.K == 1:
            return new_row
        batch_dims = window.ndim - 2 if batch_dims is None else batch_dims
        n_state = window.shape[-1] - self.n_actions
        one_hot = self._one_hot(action, batch_dims).to(device=window.device, dtype=window.dtype).unsqueeze(-2)
        actions = torch.cat([window[..., 1:-1, n_state:], one_hot], dim=-2)
        kept = torch.cat([window[..., 1:, :n_state], actions], dim=-1)
        return torch.cat([kept, new_row], dim=-2)

    # ----- Transform API ------------------------------------------------------------------------
    def _no_state(self, keys: Sequence[NestedKey]) -> KeyError:
        return KeyError(f"HistoryWindow: the env has no observation {self.state_key!r} (in_keys / state_key); its "
                        f"observations: {sorted(keys, key=str)}")

    def _state(self, tensordict: TensorDictBase) -> torch.Tensor:
        state = tensordict.get(self.state_key, None)
        if state is None:
            flags = ("done", "terminated", "truncated")
            raise self._no_state([k for k in tensordict.keys(True, True) if (k if isinstance(k, str) else k[-1])
                                  not in flags])
        return self._vector(state, tensordict.batch_dims)

    def _reset(self, tensordict: TensorDictBase, tensordict_reset: TensorDictBase) -> TensorDictBase:
        # Partial resets of batched envs: TransformedEnv keeps the old window of the envs not reset.
        state = self._state(tensordict_reset)
        tensordict_reset.set(self.out_key, self.initial_window(state))
        return tensordict_reset

    def _step(self, tensordict: TensorDictBase, next_tensordict: TensorDictBase) -> TensorDictBase:
        window = tensordict.get(self.out_key, None)
        if window is None:
            raise KeyError(f"HistoryWindow: {self.out_key!r} is missing from the step input; "
                           "start from env.reset() of the TransformedEnv")
        action = tensordict.get(self.action_key)
        state = self._state(next_tensordict)
        window = self.next_window(window, action, state, batch_dims=tensordict.batch_dims)
        next_tensordict.set(self.out_key, window)
        return next_tensordict

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        """Outside an env (e.g. on replay samples) the window is already a key: nothing to compute."""
        if self.out_key not in tensordict.keys(include_nested=True):
            raise KeyError(f"HistoryWindow.forward: {self.out_key!r} not in the tensordict; the window is "
                           "built by the env (TransformedEnv) and carried as a key")
        return tensordict

    def _spec(self, spec: Composite) -> Unbounded:
        if self.state_key not in spec.keys(True, True):
            raise self._no_state(list(spec.keys(True, True)))
        state_spec = spec[self.state_key]
        features = state_spec.shape[len(spec.shape):]  # beyond the env's batch: () for a scalar observation
        if len(features) > 1:
            raise ValueError(f"HistoryWindow records vector observations [..., S] (or scalars); observation "
                             f"{self.state_key!r} has shape {tuple(features)} per step ({type(state_spec).__name__}): "
                             "flatten it first (torchrl's FlattenObservation)")
        width = (features[0] if features else 1) + self.n_actions
        # the window's dtype is the observation's (float64 stays float64), float32 for integer observations
        dtype = state_spec.dtype if state_spec.dtype.is_floating_point else torch.float32
        return Unbounded(shape=(*spec.shape, self.K, width), dtype=dtype, device=state_spec.device)

    def _check_action_spec(self) -> None:
        parent = self.parent
        if parent is None:
            return
        if self._from_spec:
            self._read_action_spec()
            return
        spec = parent.full_action_spec.get(self.action_key, None)
        if spec is not None and spec.dtype.is_floating_point and not isinstance(spec, OneHot):
            raise ValueError(f"HistoryWindow(n_actions={self._n_actions}) one-hot encodes discrete actions, but "
                             f"action {self.action_key!r} is continuous ({type(spec).__name__}, {spec.dtype}); "
                             "leave n_actions=None to record continuous actions as they are")
        n = getattr(getattr(spec, "space", None), "n", None)
        if n is not None and int(n) != self._n_actions:
            raise ValueError(f"HistoryWindow(n_actions={self._n_actions}) but the env has {int(n)} actions")

    def transform_observation_spec(self, observation_spec: Composite) -> Composite:
        self._check_action_spec()
        observation_spec[self.out_key] = self._spec(observation_spec)
        return observation_spec

    def transform_input_spec(self, input_spec: Composite) -> Composite:
        input_spec = input_spec.clone()
        state_spec = input_spec.get("full_state_spec", None)
        if state_spec is None:
            state_spec = Composite(shape=input_spec.shape, device=input_spec.device)
        parent = self.parent
        observation_spec = parent.output_spec["full_observation_spec"] if parent is not None else None
        if observation_spec is None or self.state_key not in observation_spec.keys(True, True):
            raise self._no_state([] if observation_spec is None else list(observation_spec.keys(True, True)))
        state_spec[self.out_key] = self._spec(observation_spec)
        input_spec["full_state_spec"] = state_spec
        return input_spec

    def __repr__(self) -> str:
        return (f"{type(self).__name__}(K={self.K}, in_keys={[self.state_key]!r}, "
                f"action_key={self.action_key!r}, n_actions={None if self._from_spec else self._n_actions}, "
                f"out_keys={[self.out_key]!r})")
