"""ImaginedEnv: any :class:`~pernav.model.dynamics.DynamicsModel` as a TorchRL model env, with your task's reward.

The transition reads ``"history"`` (the :class:`~pernav.transforms.HistoryWindow`), ``"observation"`` and
``"action"`` and writes the predicted next ``"observation"``, the shifted ``"history"``, the ``"reward"``
``reward_fn(state, action, next_state)`` and ``"done"``/``"terminated"`` from ``termination_fn(next_state)``
(never, without one). So a planner (:class:`~pernav.planner.DiscreteTreeSearchPlanner`) or ``env.rollout``
imagines with the learned model and scores with the task's known reward, as in model-based RL (PETS, GrBAL);
adapted parameters are swapped in with ``with params.to_module(model): ...``. The navigation's own model env,
with its tracking reward and route-aware imagination, is :class:`~pernav.model.navigation.ImaginedNavigationEnv`.

Example:
    >>> import torch
    >>> from tensordict import TensorDict
    >>> model = DynamicsModel(state_dim=4, n_actions=2, K=2, hidden=(16,))
    >>> env = ImaginedEnv(model, reward_fn=lambda s, a, n: -n[..., 2].abs(),
    ...                   termination_fn=lambda n: n[..., 2].abs() > 0.21)
    >>> start = TensorDict({"observation": torch.zeros(3, 4), "history": torch.zeros(3, 2, 6)}, [3])
    >>> env.rollout(5, auto_reset=False, tensordict=start, break_when_any_done=False)["next", "reward"].shape
    torch.Size([3, 5, 1])
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModule
from tensordict.utils import NestedKey
from torch import nn
from torchrl.data import Categorical, Composite, OneHot, Unbounded
from torchrl.envs import EnvBase, ModelBasedEnvBase
from torchrl.modules import WorldModelWrapper

from pernav.model.actions import action_indices
from pernav.model.dynamics import DynamicsModel

__all__ = ["ImaginedEnv", "PlainWorldModel", "model_device"]

RewardFn = Callable[[torch.Tensor, torch.Tensor, torch.Tensor], torch.Tensor]
TerminationFn = Callable[[torch.Tensor], torch.Tensor]


Stage = tuple[nn.Module, Sequence[NestedKey], Sequence[NestedKey]]


class PlainWorldModel(WorldModelWrapper):
    """TorchRL's ``WorldModelWrapper(transition, reward)`` of two plain modules, also steppable without a TensorDict.

    ``transition`` and ``reward`` are ``(module, in_keys, out_keys)``: the module takes its in_keys' tensors as
    positional arguments and returns its out_keys' tensors (one, or a tuple in that order), exactly as
    ``TensorDictModule(module, in_keys, out_keys)`` calls it. :meth:`tensor_step` runs the same modules on a
    dict of tensors: what :class:`~pernav.planner.DiscreteTreeSearchPlanner` calls in an env whose step is its
    world model alone (no TensorDict per call: a third of a decision's time at the navigation's size).

    >>> wm = PlainWorldModel((nn.Identity(), ["x"], ["y"]), (nn.Identity(), ["y"], ["reward"]))
    >>> wm.tensor_step({"x": torch.ones(2)})["reward"].tolist()
    [1.0, 1.0]
    """

    def __init__(self, transition: Stage, reward: Stage) -> None:
        stages = [TensorDictModule(module, in_keys=list(in_keys), out_keys=list(out_keys))
                  for module, in_keys, out_keys in (transition, reward)]
        super().__init__(*stages)
        self._plain = tuple((list(s.in_keys), list(s.out_keys), s.module) for s in stages)

    def tensor_step(self, data: dict) -> dict:
        """``data`` (``{key: tensor}``: the state entries and the action) updated with both stages' outputs, as
        calling the module on a TensorDict of ``data`` would."""
        data = dict(data)
        for in_keys, out_keys, module in self._plain:
            out = module(*(data[k] for k in in_keys))
            data.update(zip(out_keys, out if isinstance(out, tuple) else (out,), strict=True))
        return data


def model_device(model: nn.Module, device: str | torch.device | None = None, owner: str = "ImaginedEnv") -> torch.device:
    """The device of a model env around ``model``: the model's own (``device=None``), or ``device`` where the model
    already lives. A model elsewhere is refused, not moved: ``ModelBasedEnvBase`` moves its world model in place,
    which would move the caller's model (and the optimizer's parameters) under them.

    >>> model_device(nn.Linear(2, 2)).type
    'cpu'
    """
    tensors = [*model.parameters(), *model.buffers()]
    here = tensors[0].device if tensors else torch.device("cpu")
    if device is None:
        return here
    device = torch.device(device)
    if device.type != here.type or (device.index is not None and here.index is not None and device.index != here.index):
        raise ValueError(f"{owner}(device={str(device)!r}) would move the model (on {here}) in place; move it "
                         f"yourself first (model.to({str(device)!r})), or leave device=None to use the model's device")
    return here


class _Imagine(nn.Module):
    """One imagined step: next state, next window, reward and done."""

    def __init__(self, model: DynamicsModel, reward_fn: RewardFn, termination_fn: TerminationFn | None,
                 one_hot: bool = False) -> None:
        super().__init__()
        self.model, self.reward_fn, self.termination_fn, self.one_hot = model, reward_fn, termination_fn, one_hot

    def forward(self, observation: torch.Tensor, history: torch.Tensor, action: torch.Tensor):
        like = self.model.out_mean  # a real env's float32 state into a float64 (or another device's) model
        if history.dtype != like.dtype or history.device != like.device:
            history = history.to(device=like.device, dtype=like.dtype)
        if observation.dtype != like.dtype or observation.device != like.device:
            observation = observation.to(device=like.device, dtype=like.dtype)
        action = action.to(like.device)
        if self.one_hot:  # a OneHot spec's actions: the model and reward_fn read indices either way
            action = action_indices(action, history.shape[:-2], self.model.n_actions)
        action = action.reshape(history.shape[:-2]) if action.numel() == history.shape[:-2].numel() else action
        next_state = self.model(history, action)
        window = self.model.next_window(history, action, next_state)
        reward = self.reward_fn(observation, action, next_state).reshape(*history.shape[:-2], 1)
        if self.termination_fn is None:
            done = torch.zeros(*history.shape[:-2], 1, dtype=torch.bool, device=history.device)
        else:
            done = self.termination_fn(next_state).reshape(*history.shape[:-2], 1).bool()
        return next_state, window, reward.to(next_state.dtype), done, done.clone()


def _check_env(env: EnvBase, model: DynamicsModel, observation_key: NestedKey, history_key: NestedKey,
               action_key: NestedKey) -> Categorical | OneHot:
    """``env``'s action spec (at ``action_key``) after checking that ``model`` can stand in for ``env``: a discrete
    spec of the model's number of actions, an observation of the model's state size and a history window of its
    ``K``; ``ValueError`` naming what differs and the fix."""
    spec = env.full_action_spec[action_key] if action_key in env.full_action_spec.keys(True) else None
    if type(spec) not in (Categorical, OneHot) or spec.space.n != model.n_actions:
        raise ValueError(f"ImaginedEnv(env=): the env's action spec at {action_key!r} is {spec}, but the model takes "
                         f"{model.n_actions} discrete actions (Categorical or OneHot): build the model with "
                         "DynamicsModel(n_actions=env.action_spec)")
    observations = env.observation_spec
    expected = {observation_key: (model.state_dim,),
                history_key: (model.K, model.state_dim + model.n_actions)}
    for key, shape in expected.items():
        got = tuple(observations[key].shape[-len(shape):]) if key in observations.keys(True) else None
        if got != shape:
            raise ValueError(f"ImaginedEnv(env=): the env's {key!r} is {got if got is not None else 'missing'}, the "
                             f"model's {shape} (state_dim={model.state_dim}, K={model.K}, n_actions={model.n_actions}): "
                             f"give the env a HistoryWindow(K={model.K}) and the model the env's state size, or name "
                             "the entries with observation_key=/history_key=")
    return _bare(spec)


def _bare(spec: Categorical | OneHot) -> Categorical | OneHot:
    """The spec without its env's batch dimensions and device."""
    return type(spec)(int(spec.space.n), dtype=spec.dtype)


class ImaginedEnv(ModelBasedEnvBase):
    """A learned model's imagination as a TorchRL env (any batch size); see the module docstring.

    Args:
        model: the dynamics model (any ``state_dim``, ``n_actions``).
        reward_fn: ``(state [..., S], action [...] (categorical), next_state [..., S]) -> reward [...]``.
        termination_fn: ``next_state -> bool [...]`` (an imagined failure ends the rollout's reward), or ``None``.
        device: the env's device: the model's (``None``), or the device the model already lives on (a model
            elsewhere is refused, not moved in place: :func:`model_device`).
        action_spec: a ``Categorical(n_actions)`` or ``OneHot(n_actions)`` spec, e.g. the real env's (``GymEnv``'s
            default), so that a planner on this env writes the actions the real env takes; ``reward_fn`` reads
            indices either way. ``None`` (the default): ``env``'s, else the spec the model was built from
            (``DynamicsModel(n_actions=env.action_spec)``), else ``Categorical(n_actions)``.
        env: the real env this model env stands in for (a planner on it drives ``env``): its action spec is taken,
            and its observation and history window are checked against the model's (``ValueError`` naming the
            entry and the fix).
        observation_key, history_key, action_key: the entry names (the real env's and its
            :class:`~pernav.transforms.HistoryWindow`'s, e.g. ``in_keys``/``out_keys``); a planner on this env takes
            the same ``action_key``.

    Reset needs a starting point (``observation_key`` and ``history_key``, e.g. a real env's current tensordict);
    without one it starts from the zero state.
    """

    def __init__(self, model: DynamicsModel, reward_fn: RewardFn, termination_fn: TerminationFn | None = None,
                 device: str | torch.device | None = None, action_spec: Categorical | OneHot | None = None, *,
                 observation_key: NestedKey = "observation", history_key: NestedKey = "history",
                 action_key: NestedKey = "action", env: EnvBase | None = None) -> None:
        device = model_device(model, device, type(self).__name__)
        if env is not None:
            env_spec = _check_env(env, model, observation_key, history_key, action_key)
            if action_spec is not None and (type(action_spec), action_spec.space.n) != (type(env_spec),
                                                                                        env_spec.space.n):
                raise ValueError(f"ImaginedEnv(action_spec={action_spec}) differs from the action spec of env "
                                 f"({env_spec}): give one of them")
            action_spec = env_spec
        elif action_spec is None:
            action_spec = getattr(model, "action_spec", None)  # the spec the model was built from, if any
        if action_spec is not None and (type(action_spec) not in (Categorical, OneHot)
                                        or action_spec.space.n != model.n_actions):
            raise ValueError(f"ImaginedEnv(action_spec=) must be a Categorical or OneHot spec of the model's "
                             f"{model.n_actions} actions, got {action_spec} (give the real env's, or env=)")
        one_hot = isinstance(action_spec, OneHot)  # rebuilt without the real env's batch dimensions and device
        action_spec = (OneHot(model.n_actions, dtype=action_spec.dtype) if one_hot else
                       Categorical(model.n_actions) if action_spec is None else
                       Categorical(model.n_actions, dtype=action_spec.dtype))
        transition = (_Imagine(model, reward_fn, termination_fn, one_hot), [observation_key, history_key, action_key],
                      [observation_key, history_key, "reward", "done", "terminated"])
        keep = (nn.Identity(), ["reward"], ["reward"])  # the reward is computed with the step
        super().__init__(PlainWorldModel(transition, keep), device=device)
        self.dynamics = model
        dtype = model.out_mean.dtype  # a float64 model imagines float64 states
        self._start_keys = [observation_key, history_key]  # what reset copies from a starting point
        obs = Composite()
        obs[observation_key] = Unbounded((model.state_dim,), dtype=dtype)
        obs[history_key] = Unbounded((model.K, model.state_dim + model.n_actions), dtype=dtype)
        self.observation_spec = obs
        self.state_spec = obs.clone()
        if action_key == "action":
            self.action_spec = action_spec
        else:  # TorchRL's way to name the action: the full spec's key
            self.full_action_spec = Composite({action_key: action_spec})
        self.reward_spec = Unbounded((1,), dtype=dtype)

    def _reset(self, tensordict: TensorDictBase | None = None, **kwargs) -> TensorDictBase:
        given = tensordict is not None and all(key in tensordict.keys(True) for key in self._start_keys)
        if given:  # a real env's state, in the model's dtype and on its device (a float64 or CUDA model)
            out = tensordict.select(*self._start_keys).clone()
            for key in self._start_keys:
                spec = self.observation_spec[key]
                value = out.get(key)
                if value.dtype != spec.dtype or value.device != spec.device:
                    out.set(key, value.to(device=spec.device, dtype=spec.dtype))
        else:
            out = self.state_spec.zero(tensordict.shape if tensordict is not None else self.batch_size)
        out.set("done", torch.zeros(*out.shape, 1, dtype=torch.bool, device=out.device))
        out.set("terminated", torch.zeros(*out.shape, 1, dtype=torch.bool, device=out.device))
        return out
