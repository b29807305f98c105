"""The dynamics model hosted by TorchRL: a ``WorldModelWrapper`` and a ``ModelBasedEnvBase`` subclass.

:func:`make_world_model` wraps a :class:`~pernav.model.dynamics.DynamicsModel` into TorchRL's
``WorldModelWrapper(transition, reward)``: the transition reads ``"history"`` and ``"action"`` and writes the
imagined next ``"observation"`` and the shifted ``"history"``; the reward is minus the env's tracking cost
(:func:`pernav.world.cost.tracking_cost`) of the imagined position against the previous state's goal.
:class:`ImaginedNavigationEnv` turns it into an env, so imagined rollouts are ordinary ``env.rollout``
calls, from any batch of real (observation, history) pairs. Adapted parameters are swapped in with
``with params.to_module(model): ...`` (:func:`pernav.model.losses.using`).

Example:
    >>> import torch
    >>> from tensordict import TensorDict
    >>> from pernav.model.dynamics import DynamicsModel
    >>> model = DynamicsModel(hidden=(16,))
    >>> env = ImaginedNavigationEnv(make_world_model(model))
    >>> start = TensorDict({"observation": torch.zeros(3, 14), "history": torch.zeros(3, 5, 21)}, [3])
    >>> td = env.rollout(4, auto_reset=False, tensordict=start, break_when_any_done=False)
    >>> td.shape, td["next", "reward"].shape
    (torch.Size([3, 4]), torch.Size([3, 4, 1]))
"""

from __future__ import annotations

import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModule
from torch import nn
from torchrl.data import Categorical, Composite, Unbounded
from torchrl.envs import ModelBasedEnvBase
from torchrl.modules import WorldModelWrapper

from pernav.model.dynamics import GX, GY, DynamicsModel, X, Y
from pernav.model.losses import using
from pernav.world.cost import tracking_cost

__all__ = ["ImaginedNavigationEnv", "make_world_model"]


class _Transition(nn.Module):
    def __init__(self, model: DynamicsModel) -> None:
        super().__init__()
        self.model = model

    def forward(self, history: torch.Tensor, action: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        next_state = self.model(history, action)
        return next_state, self.model.next_window(history, action, next_state)


class _TrackingReward(nn.Module):
    """``-tracking_cost(s_{t+1} position, goal of s_t)`` read from the shifted window."""

    def forward(self, history: torch.Tensor) -> torch.Tensor:
        position = history[..., -1, [X, Y]]
        goal = history[..., -2, [GX, GY]]
        return -tracking_cost(position, goal).unsqueeze(-1)


def make_world_model(model: DynamicsModel) -> WorldModelWrapper:
    """``WorldModelWrapper`` of ``model``: (history, action) -> (observation, history), reward."""
    if model.K < 2:
        raise ValueError("the world model needs K >= 2 (the reward reads the previous state's goal)")
    transition = TensorDictModule(_Transition(model), in_keys=["history", "action"],
                                  out_keys=["observation", "history"])
    reward = TensorDictModule(_TrackingReward(), in_keys=["history"], out_keys=["reward"])
    return WorldModelWrapper(transition, reward)


class ImaginedNavigationEnv(ModelBasedEnvBase):
    """Imagined navigation: steps are predicted by the world model; any batch size.

    Reset needs a starting point: pass ``tensordict`` with ``"observation"`` and ``"history"`` (e.g. a
    real env's current tensordict). The episode never ends by itself (the planner decides the horizon).
    """

    def __init__(self, world_model: WorldModelWrapper, device: str | torch.device = "cpu") -> None:
        super().__init__(world_model, device=device)
        model = world_model[0].module.model
        self.dynamics: DynamicsModel = model
        width = model.state_dim + model.n_actions
        obs = Composite(observation=Unbounded((model.state_dim,)), history=Unbounded((model.K, width)))
        self.observation_spec = obs
        self.state_spec = obs.clone()
        self.action_spec = Categorical(model.n_actions)
        self.reward_spec = Unbounded((1,))

    @torch.no_grad()
    def imagine(self, root: TensorDictBase, sequences: torch.Tensor,
                params: list[TensorDictBase | None] | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        """Imagined positions and goals of action ``sequences`` ``[N, H]`` from one real ``root`` (with
        ``"history"``): ``([M, N, H, 2], [M, N, H, 2])``, one row ``M`` per parameter set in ``params``
        (an ensemble, adapted or not; ``None``: the model's own parameters).

        >>> import torch
        >>> from tensordict import TensorDict
        >>> env = ImaginedNavigationEnv(make_world_model(DynamicsModel(hidden=(8,))))
        >>> pos, goal = env.imagine(TensorDict({"history": torch.zeros(5, 21)}, []), torch.zeros(3, 4, dtype=torch.long))
        >>> pos.shape
        torch.Size([1, 3, 4, 2])
        """
        N, H = sequences.shape
        if params and len(params) > 1 and all(p is not None for p in params):  # an ensemble: all members at once
            stacked = torch.stack(list(params))
            hist = root["history"].float().expand(len(params), N, *root["history"].shape).clone()
            pos, goal = [], []
            for h in range(H):
                state = self.dynamics.ensemble_forward(hist, sequences[:, h], stacked)
                hist = self.dynamics.next_window(hist, sequences[:, h].expand(hist.shape[:2]), state)
                pos.append(state[..., [X, Y]])
                goal.append(state[..., [GX, GY]])
            return torch.stack(pos, 2), torch.stack(goal, 2)
        positions, goals = [], []
        for member in params if params else [None]:
            hist = root["history"].float().expand(N, *root["history"].shape).clone()
            pos, goal = [], []
            with using(self.dynamics, member):
                for h in range(H):
                    state = self.dynamics(hist, sequences[:, h])
                    hist = self.dynamics.next_window(hist, sequences[:, h], state)
                    pos.append(state[:, [X, Y]])
                    goal.append(state[:, [GX, GY]])
            positions.append(torch.stack(pos, 1))
            goals.append(torch.stack(goal, 1))
        return torch.stack(positions), torch.stack(goals)

    def _reset(self, tensordict: TensorDictBase | None = None, **kwargs) -> TensorDictBase:
        if tensordict is None or "history" not in tensordict.keys() or "observation" not in tensordict.keys():
            raise ValueError("ImaginedNavigationEnv.reset needs a tensordict with 'observation' and 'history' "
                             "(imagined rollouts start from real states)")
        out = tensordict.select("observation", "history").clone()
        out.set("done", torch.zeros(*out.shape, 1, dtype=torch.bool, device=out.device))
        out.set("terminated", torch.zeros(*out.shape, 1, dtype=torch.bool, device=out.device))
        return out
