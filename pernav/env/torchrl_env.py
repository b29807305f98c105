"""TorchRL wrapper of :class:`~pernav.env.navigation.NavigationEnv` and its rule-based policies as modules.

The wrapper is a :class:`torchrl.envs.GymWrapper` with a ``Categorical`` action spec, the reset options
(route, user, context) applied on every reset, and the numeric ``info`` entries written into the
tensordict with declared specs (:data:`INFO_DTYPES`). Reward is ``-step_cost``.

Example:
    >>> from pernav.env.torchrl_env import explore_module, make_torchrl_env
    >>> opts = {"route": 3, "user": "user2"}
    >>> env = make_torchrl_env("Town1", config={"n_traffic": 2}, options=opts, seed=0)
    >>> td = env.rollout(5, policy=explore_module())
    >>> td["observation"].shape, td["action"].dtype
    (torch.Size([5, 14]), torch.int64)
    >>> bool((td["action"] == td["explore_action"]).all())
    True
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModule
from torch import nn
from torchrl.data import Composite, TensorSpec, Unbounded
from torchrl.envs import EnvBase, GymWrapper
from torchrl.envs.gym_like import BaseInfoDictReader

from pernav.env.layout import EXPLORE_POINTS, EXPLORE_SPEEDS
from pernav.env.navigation import FRAME_KEYS, NavigationEnv

__all__ = [
    "INFO_DTYPES",
    "NavigationInfoReader",
    "NavigationTorchRLEnv",
    "explore_module",
    "info_action_module",
    "make_torchrl_env",
    "navigation_of",
    "oracle_module",
    "planning_arrays",
]

#: The numeric ``info`` entries copied into the tensordict (shape ``()`` each) and their dtypes.
INFO_DTYPES: dict[str, torch.dtype] = {
    "explore_action": torch.int64,
    "oracle_action": torch.int64,
    "step_cost": torch.float32,
    "tracking_cost": torch.float32,
    "vehicle_collisions": torch.int64,
    "edge_strikes": torch.int64,
    "collisions": torch.int64,
    "missed_turns": torch.int64,
    "wrong_turns": torch.int64,
    "reroutes": torch.int64,
    "extra_distance": torch.float32,
    "completed": torch.bool,
    "time": torch.float32,
    "distance_to_junction": torch.float32,
    "in_roundabout": torch.bool,
    "near_roundabout": torch.bool,
    # what the navigation senses between decisions (docs/simulator.md, "What the navigation senses"): whether a
    # prompt played this step, when it began and when its audio ended (simulated s; -1 when none played), and the
    # car's frames (the "frames" array, :data:`~pernav.env.navigation.FRAME_KEYS`)
    "played": torch.bool,
    "prompt_start": torch.float32,
    "prompt_end": torch.float32,
}


class NavigationInfoReader(BaseInfoDictReader):
    """Writes the numeric entries of NavigationEnv's ``info`` dict into the tensordict.

    The default TorchRL reader fails on python-float infos; this one converts each key of ``dtypes``
    to a 0-d tensor of the declared dtype and raises ``KeyError`` if the env does not report it.

    >>> import torch
    >>> from tensordict import TensorDict
    >>> reader = NavigationInfoReader({"step_cost": torch.float32, "completed": torch.bool})
    >>> td = reader({"step_cost": 0.5, "completed": False, "next_manoeuvre": "left"}, TensorDict())
    >>> td["step_cost"], td["completed"]
    (tensor(0.5000), tensor(False))
    """

    def __init__(self, dtypes: Mapping[str, torch.dtype] | None = None,
                 arrays: Mapping[str, tuple[tuple[int, ...], torch.dtype]] | None = None) -> None:
        self.dtypes = dict(INFO_DTYPES if dtypes is None else dtypes)
        self.arrays = dict(arrays or {})  # key -> (shape, dtype) of array-valued entries
        specs = {key: Unbounded(shape=(), dtype=dtype) for key, dtype in self.dtypes.items()}
        specs.update({key: Unbounded(shape=shape, dtype=dtype) for key, (shape, dtype) in self.arrays.items()})
        self._info_spec = Composite(specs, shape=())

    def __call__(self, info_dict: dict[str, Any], tensordict: TensorDictBase) -> TensorDictBase:
        device = tensordict.device
        for key, dtype in {**self.dtypes, **{k: d for k, (_, d) in self.arrays.items()}}.items():
            if key not in info_dict:
                raise KeyError(f"NavigationEnv info has no {key!r}; it reports {sorted(info_dict)}")
            tensordict.set(key, torch.as_tensor(info_dict[key], dtype=dtype, device=device))
        return tensordict

    @property
    def info_spec(self) -> dict[str, TensorSpec]:
        return self._info_spec


class NavigationTorchRLEnv(GymWrapper):
    """``GymWrapper`` that passes ``reset_options`` (route/user/context) to every ``reset``.

    An explicit ``env.reset(options=...)`` overrides them for that call. Use :func:`make_torchrl_env`.
    """

    def __init__(self, env: NavigationEnv, reset_options: Mapping[str, Any] | None = None,
                 **kwargs: Any) -> None:
        super().__init__(env=env, categorical_action_encoding=True, **kwargs)
        self.reset_options: dict[str, Any] = dict(reset_options or {})

    @property
    def navigation(self) -> NavigationEnv:
        """The :class:`NavigationEnv` this wrapper drives (the world, the route, the driver): the public way to it."""
        return self._env

    def set_reset_options(self, options: Mapping[str, Any] | None) -> None:
        """Replace the options used by later resets (dispatched to workers inside batched envs)."""
        self.reset_options = dict(options or {})

    def _reset(self, tensordict: TensorDictBase | None = None, **kwargs: Any) -> TensorDictBase:
        options = self.__dict__.get("reset_options")
        if options and "options" not in kwargs:
            kwargs["options"] = dict(options)
        return super()._reset(tensordict, **kwargs)


def make_torchrl_env(town: str = "Town1", config: dict[str, Any] | None = None,
                     options: Mapping[str, Any] | None = None, seed: int | None = None,
                     device: str | torch.device = "cpu") -> EnvBase:
    """A TorchRL env around ``NavigationEnv(town, config)``; ``options`` are used at every reset.

    ``options``: ``{"route": 0-9, "user": "user1".."user7" | mapping | path, "context": {...}}``.
    For per-worker options in a batched env use ``create_env_kwargs``:

    >>> from torchrl.envs import SerialEnv
    >>> env = SerialEnv(2, make_torchrl_env, create_env_kwargs=[
    ...     {"config": {"n_traffic": 2}, "options": {"route": r}} for r in (0, 1)])
    >>> env.reset()["observation"].shape
    torch.Size([2, 14])
    """
    nav = NavigationEnv(town=town, config=config)
    env = NavigationTorchRLEnv(nav, reset_options=options, device=device)
    dtypes = None
    if nav.config["belief"] is not None:
        dtypes = {**INFO_DTYPES, "belief_action": torch.int64}
        if not isinstance(nav.config["belief"], dict):  # a belief updated within the drive: what it says now
            dtypes["belief_reaction"] = torch.float32
    env.set_info_dict_reader(NavigationInfoReader(dtypes, arrays=planning_arrays(nav.config, nav.n_actions)))
    if seed is not None:
        env.set_seed(seed)
    return env


def navigation_of(env: EnvBase) -> NavigationEnv:
    """The :class:`NavigationEnv` inside a TorchRL env made by :func:`make_torchrl_env`, transformed or not.

    >>> navigation_of(make_torchrl_env(config={"n_traffic": 2})).town.name
    'Town1'
    """
    base = getattr(env, "base_env", env)
    if not isinstance(base, NavigationTorchRLEnv):
        raise TypeError(f"env: expected an env made by make_torchrl_env (a NavigationTorchRLEnv inside), got "
                        f"{type(base).__name__}")
    return base.navigation


def planning_arrays(config: Mapping[str, Any], n_actions: int) -> dict[str, tuple[tuple[int, ...], torch.dtype]]:
    """Shapes and dtypes of the array entries of ``info``: the planning context (see :mod:`pernav.env.planning`) and
    the car's frames between decisions."""
    H, S = int(config["plan_horizon"]), int(config["plan_shift"])
    table = {"explore_table": ((len(EXPLORE_SPEEDS), EXPLORE_POINTS), torch.int64)} if config.get("explore_table") \
        else {}
    if config.get("route_boxes"):
        table["route_boxes"] = ((2,), torch.float32)
    return {**table,
        "plan_goals": ((H, 2), torch.float32),
        "explore_plan": ((H + 2 * S,), torch.int64),
        "action_mask": ((H, n_actions), torch.bool),
        "explore_future": ((int(config["future_steps"]),), torch.int64),
        "route_ahead": ((int(config["route_points"]), 2), torch.float32),
        "frames": ((int(config["frequency"]), len(FRAME_KEYS)), torch.float32),
    }


class _AsAction(nn.Module):
    """Copies an integer action entry (so the policy's output does not alias the info entry)."""

    def forward(self, action: torch.Tensor) -> torch.Tensor:
        return action.to(torch.int64).clone()


def info_action_module(key: str, out_key: str = "action") -> TensorDictModule:
    """A policy that plays the action the env reports under ``key`` (a Categorical int64 action)."""
    return TensorDictModule(_AsAction(), in_keys=[key], out_keys=[out_key])


def explore_module(key: str = "explore_action") -> TensorDictModule:
    """The rule-based explore policy: reads ``"explore_action"``, writes ``"action"``.

    >>> env = make_torchrl_env(config={"n_traffic": 2}, seed=1)
    >>> td = explore_module()(env.reset())
    >>> td["action"] == td["explore_action"]
    tensor(True)
    """
    return info_action_module(key)


def oracle_module() -> TensorDictModule:
    """The oracle policy (knows the driver): reads ``"oracle_action"``, writes ``"action"``."""
    return info_action_module("oracle_action")
