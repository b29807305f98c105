"""The navigation's parts of the model layer: its model env and world model, and its egocentric layout.

:func:`make_world_model` wraps a :class:`~pernav.model.dynamics.DynamicsModel` into TorchRL's
``WorldModelWrapper(transition, reward)``: the transition reads ``"history"`` and ``"action"`` and writes the
imagined next ``"observation"`` and the shifted ``"history"``; the reward is minus the env's tracking cost
(:func:`pernav.world.cost.tracking_cost`) of the imagined position against the previous state's goal.
:class:`ImaginedNavigationEnv` turns it into an env, so imagined rollouts are ordinary ``env.rollout``
calls, from any batch of real (observation, history) pairs. Adapted parameters are swapped in with
``with params.to_module(model): ...`` (:func:`pernav.model.losses.using`). The 14-d state's egocentric layout
(:class:`EgocentricDifferences`, :func:`ego_delta`, :func:`road_points`) lives in :mod:`pernav.model.egocentric`
and is exported here too.

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
from torch import nn
from torchrl.data import Categorical, Composite, Unbounded
from torchrl.envs import ModelBasedEnvBase
from torchrl.modules import WorldModelWrapper

from pernav.model.dynamics import DynamicsModel
from pernav.model.egocentric import GX, GY, X, Y, road_points
from pernav.model.imagined import PlainWorldModel, model_device
from pernav.model.losses import using
from pernav.world.cost import tracking_cost

__all__ = ["ImaginedNavigationEnv", "make_world_model", "route_index"]

ROUTE_REACH = 8  # route points (3 m each) the car may advance in one imagined step; 2 back (no jumps)


def route_index(state: torch.Tensor, route: torch.Tensor, index: torch.Tensor) -> torch.Tensor:
    """The car's projection on the route ``[P, 2]`` for ``state`` ``[..., 14]``: the nearest route point among
    those near the previous projection ``index`` ``[...]`` (2 back to ``ROUTE_REACH`` ahead: no jumps).

    >>> route = torch.stack([torch.arange(10.0) * 3, torch.zeros(10)], -1)
    >>> state = torch.zeros(14); state[0] = 6.2
    >>> int(route_index(state, route, torch.tensor(1)))
    2
    """
    # only the points near the previous projection: a step's distances cost 11, not P
    near = (index.unsqueeze(-1) + torch.arange(-2, ROUTE_REACH + 1)).clamp(0, route.shape[0] - 1)  # ties go low
    d = (route[near] - state[..., None, [X, Y]]).norm(dim=-1)
    return near.gather(-1, d.argmin(-1, keepdim=True)).squeeze(-1)


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
        # slices, not index lists: this runs once per level of every planner search
        position = history[..., -1, X:Y + 1]
        goal = history[..., -2, GX:GY + 1]
        return -tracking_cost(position, goal).unsqueeze(-1)


def make_world_model(model: DynamicsModel) -> PlainWorldModel:
    """``WorldModelWrapper`` of ``model`` (a :class:`~pernav.model.imagined.PlainWorldModel`): (history, action)
    -> (observation, history), reward."""
    if model.K < 2:
        raise ValueError("the world model needs K >= 2 (the reward reads the previous state's goal)")
    return PlainWorldModel((_Transition(model), ["history", "action"], ["observation", "history"]),
                           (_TrackingReward(), ["history"], ["reward"]))


class ImaginedNavigationEnv(ModelBasedEnvBase):
    """Imagined navigation: steps are predicted by the world model; any batch size.

    Reset needs a starting point: pass ``tensordict`` with ``"observation"`` and ``"history"`` (e.g. a
    real env's current tensordict). The episode never ends by itself (the planner decides the horizon).
    """

    def __init__(self, world_model: WorldModelWrapper, device: str | torch.device | None = None) -> None:
        # the world model's device (None), or the one it already lives on: never moved in place under its owner
        super().__init__(world_model, device=model_device(world_model, device, type(self).__name__))
        model = world_model[0].module.model
        self.dynamics: DynamicsModel = model
        width = model.state_dim + model.n_actions
        dtype = model.out_mean.dtype  # a float64 model imagines float64 states
        obs = Composite(observation=Unbounded((model.state_dim,), dtype=dtype),
                        history=Unbounded((model.K, width), dtype=dtype))
        self.observation_spec = obs
        self.state_spec = obs.clone()
        self.action_spec = Categorical(model.n_actions)
        self.reward_spec = Unbounded((1,), dtype=dtype)

    @torch.no_grad()
    def imagine(self, root: TensorDictBase, sequences: torch.Tensor, params: list[TensorDictBase | None] | None = None
                ) -> tuple[torch.Tensor, torch.Tensor]:
        """Imagined positions and goals of action ``sequences`` ``[N, H]`` from one real ``root`` (with
        ``"history"``): ``([M, N, H, 2], [M, N, H, 2])``, one row ``M`` per parameter set in ``params``
        (an ensemble, adapted or not; ``None``: the model's own parameters). A model that reads the road
        (``DynamicsModel(road=n)``) gets, at every imagined step, the route points ahead of the imagined car's
        projection on the route (:func:`road_points`).

        >>> import torch
        >>> from tensordict import TensorDict
        >>> env = ImaginedNavigationEnv(make_world_model(DynamicsModel(hidden=(8,))))
        >>> pos, goal = env.imagine(TensorDict({"history": torch.zeros(5, 21)}, []), torch.zeros(3, 4, dtype=torch.long))
        >>> pos.shape
        torch.Size([1, 3, 4, 2])
        """
        N, H = sequences.shape
        ensemble = bool(params) and len(params) > 1 and all(p is not None for p in params)
        members = [None] if ensemble or not params else list(params)
        road = self.dynamics.road  # a model that reads the road gets it, like the goals, from the route
        route = root["route_ahead"].float() if road else None
        stacked = torch.stack(list(params)) if ensemble else None
        positions, goals = [], []
        for member in members:  # an ensemble runs all members at once: one pass
            lead = (len(params), N) if ensemble else (N,)
            hist = root["history"].float().expand(*lead, *root["history"].shape).clone()
            if route is not None:  # the car's projection on the route now: the nearest point
                index = torch.cdist(root["history"][-1, [X, Y]].float().unsqueeze(0), route).argmin().expand(lead)
            pos, goal = [], []
            with using(self.dynamics, member):
                for h in range(H):
                    action = sequences[:, h].expand(lead)
                    ahead = road_points(route, road, index) if road else None
                    state = (self.dynamics.ensemble_forward(hist, sequences[:, h], stacked, ahead) if ensemble
                             else self.dynamics(hist, action, ahead))
                    if road:  # the car's projection: where the road of the next step starts
                        index = route_index(state, route, index)
                    hist = self.dynamics.next_window(hist, action, state)
                    pos.append(state[..., [X, Y]])
                    goal.append(state[..., [GX, GY]])
            positions.append(torch.stack(pos, -2))
            goals.append(torch.stack(goal, -2))
        if ensemble:
            return positions[0], goals[0]
        return torch.stack(positions), torch.stack(goals)

    def _reset(self, tensordict: TensorDictBase | None = None, **kwargs) -> TensorDictBase:
        has = tensordict is not None and {"history", "observation"} <= set(tensordict.keys())
        if tensordict is not None and not has and ("history" in tensordict.keys() or "observation" in tensordict.keys()):
            raise ValueError("ImaginedNavigationEnv.reset needs both 'observation' and 'history' "
                             "(imagined rollouts start from real states)")
        if not has:  # no start given (spec checks, tests): the zero state, its window of (0, no action) rows
            shape = tensordict.shape if tensordict is not None else self.batch_size
            out = self.state_spec.zero(shape)
        else:
            out = tensordict.select("observation", "history").clone()
        out.set("done", torch.zeros(*out.shape, 1, dtype=torch.bool, device=out.device))
        out.set("terminated", torch.zeros(*out.shape, 1, dtype=torch.bool, device=out.device))
        return out
