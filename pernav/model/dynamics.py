"""The deterministic dynamics model (paper §4.2, docs/study.md): of car-plus-driver, or of any discrete-action system.

Input: the :class:`~pernav.transforms.HistoryWindow` of the last K (state, action) pairs, with the action
about to be taken written into the newest row. Output: the next state. How the window is read and how a
prediction becomes the next state is one swappable object (``delta``): for the navigation's 14-d state,
:class:`EgocentricDifferences` (the window in the frame of the newest state: positions, velocities and goals
relative to the car and rotated by its heading; the MLP predicts the next-state difference in that frame);
for any other state, :class:`PlainDifferences` (the flat window; ``next_state - state``). Inputs and
differences are normalized; the statistics are buffers of the module: saved, loaded and swapped with it.

Example:
    >>> import torch
    >>> model = DynamicsModel(n_actions=7, K=5, hidden=(32, 32))
    >>> history = torch.zeros(4, 5, 14 + 7)
    >>> model(history, torch.tensor([0, 1, 2, 3])).shape
    torch.Size([4, 14])
    >>> cartpole = DynamicsModel(state_dim=4, n_actions=2, K=2, hidden=(32,))  # plain differences
    >>> cartpole(torch.zeros(8, 2, 4 + 2), torch.zeros(8, dtype=torch.long)).shape
    torch.Size([8, 4])
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from tensordict import TensorDictBase
from torch import nn
from torchrl.data import Categorical, OneHot, TensorSpec
from torchrl.modules import MLP

from pernav.env.layout import ROUTE_BEHIND, ROUTE_SPACING
from pernav.transforms.history import HistoryWindow

__all__ = ["DELTAS", "ROAD_MAX", "STATE_DIM", "DynamicsModel", "EgocentricDifferences", "PlainDifferences", "apply_delta",
           "ego_delta", "road_of", "road_points", "wrap_angle"]

STATE_DIM = 14
X, Y, VX, VY, HEADING, GX, GY = 0, 1, 3, 4, 6, 9, 10
PAIRS = ((X, Y), (VX, VY), (GX, GY))  # planar vectors rotated into the car's frame
ROAD_STRIDE = 2  # route points (ROUTE_SPACING = 3 m apart) from one road point to the next: 6 m
ROAD_MAX = 16  # road points stored with the data (90 m ahead); a model reads the first ``road`` of them
HERE = round(ROUTE_BEHIND / ROUTE_SPACING)  # the car's projection in the env's ``route_ahead``


def road_points(route: torch.Tensor, n: int = ROAD_MAX, index: torch.Tensor | None = None) -> torch.Tensor:
    """``[..., n, 2]``: ``n`` points of the planned route every ``ROAD_STRIDE * ROUTE_SPACING`` m from the car's
    projection on it, the road a :class:`DynamicsModel` with ``road=n`` reads. ``route`` is the env's
    ``route_ahead`` (``[..., P, 2]``, the car's projection at point ``HERE``) or, with ``index`` (``[...]``, the
    projection of each imagined car), one route ``[P, 2]`` shared by a batch. Points past the route's end repeat it.

    >>> route = torch.stack([torch.arange(96.0) * 3 - 15, torch.zeros(96)], -1)  # straight, car at x = 0
    >>> road_points(route, 3)[:, 0].tolist()
    [0.0, 6.0, 12.0]
    >>> road_points(route, 2, index=torch.tensor([5, 94]))[:, :, 0].tolist()
    [[0.0, 6.0], [267.0, 270.0]]
    """
    P = route.shape[-2]
    if index is None:
        return route[..., (HERE + ROAD_STRIDE * torch.arange(n)).clamp(max=P - 1), :]
    if route.ndim != 2:
        raise ValueError(f"road_points with an index needs one route [P, 2], got {tuple(route.shape)}")
    return route[(index.unsqueeze(-1) + ROAD_STRIDE * torch.arange(n)).clamp(max=P - 1)]


def wrap_angle(a: torch.Tensor) -> torch.Tensor:
    """Angle in [-pi, pi)."""
    return torch.remainder(a + torch.pi, 2 * torch.pi) - torch.pi


def road_of(data: TensorDictBase) -> torch.Tensor | None:
    """The road points of transitions: stored ``"road"``, else :func:`road_points` of the env's
    ``"route_ahead"`` (a raw drive), else ``None`` (data without a route, for models that do not read it)."""
    if "road" in data.keys():
        return data["road"]
    return road_points(data["route_ahead"]) if "route_ahead" in data.keys() else None


def _rotate(points: torch.Tensor, angle: torch.Tensor) -> torch.Tensor:
    """Planar vectors ``[..., n, 2]`` rotated by ``angle`` ``[...]``."""
    c, s = torch.cos(angle)[..., None, None], torch.sin(angle)[..., None, None]
    px, py = points[..., 0:1], points[..., 1:2]
    return torch.cat([c * px - s * py, s * px + c * py], dim=-1)


def _rotate_pairs(state: torch.Tensor, angle: torch.Tensor) -> torch.Tensor:
    """``[..., 3, 2]``: the (x, y), (vx, vy) and (goal_x, goal_y) pairs of ``state`` rotated by ``angle``."""
    return _rotate(torch.stack([state[..., X:Y + 1], state[..., VX:VY + 1], state[..., GX:GY + 1]], dim=-2), angle)


def _assemble(pairs: torch.Tensor, state: torch.Tensor, heading: torch.Tensor) -> torch.Tensor:
    """A 14-vector from rotated pairs ``[..., 3, 2]``, the other entries of ``state`` and a heading entry."""
    return torch.cat([pairs[..., 0, :], state[..., 2:3], pairs[..., 1, :], state[..., 5:6], heading.unsqueeze(-1),
                      state[..., 7:9], pairs[..., 2, :], state[..., 11:]], dim=-1)


def ego_delta(state: torch.Tensor, next_state: torch.Tensor) -> torch.Tensor:
    """``next_state - state`` with position, velocity and goal changes rotated into ``state``'s frame.

    >>> s = torch.zeros(14); s[6] = torch.pi / 2           # heading +90°
    >>> n = s.clone(); n[1] = 2.0                            # moved 2 m along +y (straight ahead)
    >>> torch.allclose(ego_delta(s, n)[:2], torch.tensor([2.0, 0.0]), atol=1e-6)
    True
    """
    d = next_state - state
    return _assemble(_rotate_pairs(d, -state[..., HEADING]), d, wrap_angle(d[..., HEADING]))


def apply_delta(state: torch.Tensor, delta: torch.Tensor) -> torch.Tensor:
    """Inverse of :func:`ego_delta`: the next state from ``state`` and an egocentric difference."""
    world = _assemble(_rotate_pairs(delta, state[..., HEADING]), delta, delta[..., HEADING])
    return state + world


class EgocentricDifferences:
    """How the navigation model reads a window and predicts: the 14-d navigation state in the car's frame.

    Features: per row, position, velocity and goal relative to the newest state's position and rotated by
    its heading, sin/cos of the heading difference, the other state entries and the action; then the road
    points (if any) in the same frame. The prediction is the next state's :func:`ego_delta`.

    >>> layout = EgocentricDifferences()
    >>> layout.feature_size(K=5, state_dim=14, n_actions=7, road=0)
    110
    """

    name = "egocentric"

    def check(self, state_dim: int, road: int) -> None:
        if state_dim != STATE_DIM:
            raise ValueError(f"delta='egocentric' reads the {STATE_DIM}-d navigation state, got state_dim={state_dim}; "
                             "use delta='plain' for another state")

    def feature_size(self, K: int, state_dim: int, n_actions: int, road: int) -> int:
        return K * (state_dim + 1 + n_actions) + 2 * road

    def features(self, states: torch.Tensor, actions: torch.Tensor, road: torch.Tensor | None) -> torch.Tensor:
        now = states[..., -1:, :]
        theta = now[..., HEADING]
        S = states.shape[-1]
        origin = torch.cat([now[..., X:Y + 1], now.new_zeros(*now.shape[:-1], GX - Y - 1),
                            now[..., X:Y + 1], now.new_zeros(*now.shape[:-1], S - GY - 1)], dim=-1)
        pairs = _rotate_pairs(states - origin, -theta)  # vx, vy are not shifted: the origin is 0 there
        dtheta = states[..., HEADING] - theta
        feats = torch.cat([pairs.flatten(-2), states[..., 2:3], states[..., 5:6], torch.sin(dtheta).unsqueeze(-1),
                           torch.cos(dtheta).unsqueeze(-1), states[..., 7:9], states[..., 11:], actions], dim=-1)
        if road is None:
            return feats.flatten(-2)
        ahead = _rotate(road - now[..., X:Y + 1], -theta[..., 0])
        return torch.cat([feats.flatten(-2), ahead.flatten(-2)], dim=-1)  # ahead has the window's batch (via now)

    def difference(self, state: torch.Tensor, next_state: torch.Tensor) -> torch.Tensor:
        return ego_delta(state, next_state)

    def apply(self, state: torch.Tensor, delta: torch.Tensor) -> torch.Tensor:
        return apply_delta(state, delta)


class PlainDifferences:
    """How a model of any state reads a window and predicts: the flat window (states and actions) as it is,
    and the plain difference ``next_state - state`` (MBRL's usual choice; Nagabandi et al. 2018).

    >>> layout = PlainDifferences()
    >>> s, n = torch.tensor([1.0, 2.0]), torch.tensor([1.5, 1.0])
    >>> layout.difference(s, n).tolist(), layout.apply(s, layout.difference(s, n)).tolist()
    ([0.5, -1.0], [1.5, 1.0])
    """

    name = "plain"

    def check(self, state_dim: int, road: int) -> None:
        if road:
            raise ValueError(f"road needs delta='egocentric' (the road is read in the car's frame), got road={road}")

    def feature_size(self, K: int, state_dim: int, n_actions: int, road: int) -> int:
        return K * (state_dim + n_actions)

    def features(self, states: torch.Tensor, actions: torch.Tensor, road: torch.Tensor | None) -> torch.Tensor:
        return torch.cat([states, actions], dim=-1).flatten(-2)

    def difference(self, state: torch.Tensor, next_state: torch.Tensor) -> torch.Tensor:
        return next_state - state

    def apply(self, state: torch.Tensor, delta: torch.Tensor) -> torch.Tensor:
        return state + delta


#: The prediction layouts by name (``DynamicsModel(delta=...)``).
DELTAS = {"egocentric": EgocentricDifferences, "plain": PlainDifferences}


def _discrete_actions(n_actions: int | TensorSpec) -> int:
    """The number of actions of an int or a discrete action spec; ``ValueError`` for a continuous spec."""
    if not isinstance(n_actions, TensorSpec):
        return int(n_actions)
    if isinstance(n_actions, (Categorical, OneHot)):
        return int(n_actions.space.n)
    raise ValueError(f"DynamicsModel models discrete actions (n_actions: an int, a Categorical or a OneHot spec); "
                     f"got the continuous action spec {type(n_actions).__name__}(shape={tuple(n_actions.shape)}, "
                     f"dtype={n_actions.dtype}): its actions would be one-hot encoded and lost")


def _check_one_hot(action: torch.Tensor, n_actions: int) -> None:
    """``ValueError`` unless a floating-point ``action`` is one-hot over ``n_actions`` (a continuous action is not)."""
    if action.shape[-1:] != (n_actions,) or not bool(((action == 0) | (action == 1)).all() and (action.sum(-1) == 1).all()):
        raise ValueError(f"DynamicsModel takes discrete actions (integers [...] or one-hot [..., {n_actions}]); got a "
                         f"floating-point action of shape {tuple(action.shape)} that is not one-hot: a continuous "
                         "action would be one-hot encoded and lost")


def _safe_std(x: torch.Tensor) -> torch.Tensor:
    """Per-column std; a column constant in the data (e.g. no roundabout in this town) gets 1, not a tiny
    value that would blow up when the column varies later."""
    std = x.std(0) if x.shape[0] > 1 else torch.ones_like(x[0])
    return torch.where(std < 1e-3, torch.ones_like(std), std)


class DynamicsModel(nn.Module):
    """MLP dynamics ``(history window, action) -> next state`` predicting egocentric differences.

    Args:
        state_dim: state size (14, the paper's state; any size with ``delta="plain"``).
        n_actions: 7, or 21 with playback speed (any number of discrete actions), or the env's action spec
            (``Categorical`` or ``OneHot``; a continuous spec is refused: the model one-hot encodes its actions).
        K: history length (rows of the window).
        hidden: hidden layer widths ([256, 256, 256] in the paper).
        road: points of the planned route ahead it also reads (:func:`road_points`, 6 m apart, at most
            ``ROAD_MAX``; 0: none, the paper's model). Then every prediction needs ``road`` ``[..., road, 2]``
            (world frame; expressed in the car's frame like the goal): where the road turns, which the driver's
            next second depends on and the state alone does not tell.
        context: size of a learned context vector fed to the first layer beside the features (0: none, the
            paper's model). With a context, ``U`` adapts only it (CAVIA, Zintgraf et al. 2019: the driver as a
            few numbers the meta-trained network has learned to read, instead of a step on every weight).
        delta: how the window is read and a prediction becomes the next state: ``"egocentric"``
            (:class:`EgocentricDifferences`, the 14-d navigation state), ``"plain"`` (:class:`PlainDifferences`),
            ``"auto"`` (egocentric for a 14-d state, else plain) or an object with the same methods.

    The window convention is :class:`~pernav.transforms.HistoryWindow`'s: the newest row holds the current
    state and a zero action; :meth:`forward` writes ``action`` there. :meth:`next_window` shifts a window
    by one imagined step, exactly as the transform does in the real env.

    >>> m = DynamicsModel(hidden=(16,))
    >>> w = torch.randn(3, 5, 21)
    >>> m.next_window(w, torch.tensor([1, 2, 0]), torch.randn(3, 14)).shape
    torch.Size([3, 5, 21])
    """

    def __init__(self, state_dim: int = STATE_DIM, n_actions: int | TensorSpec = 7, K: int = 5,
                 hidden: Sequence[int] = (256, 256, 256), road: int = 0, context: int = 0,
                 delta: str | EgocentricDifferences | PlainDifferences = "auto") -> None:
        super().__init__()
        n_actions = _discrete_actions(n_actions)
        if int(state_dim) < 1 or int(n_actions) < 1:
            raise ValueError(f"state_dim and n_actions must be >= 1, got {state_dim} and {n_actions}")
        if isinstance(delta, str):
            if delta == "auto":
                delta = "egocentric" if int(state_dim) == STATE_DIM else "plain"
            if delta not in DELTAS:
                raise ValueError(f"unknown delta {delta!r}; choose one of auto, {', '.join(DELTAS)}")
            delta = DELTAS[delta]()
        self.delta_layout = delta
        delta.check(int(state_dim), int(road))
        if not 0 <= int(road) <= ROAD_MAX:
            raise ValueError(f"road must be between 0 and {ROAD_MAX} (route points the model reads), got {road}")
        if int(context) < 0:
            raise ValueError(f"context must be >= 0 (the size of the learned context vector), got {context}")
        self.state_dim, self.n_actions, self.K, self.road = int(state_dim), int(n_actions), int(K), int(road)
        self.n_context = int(context)
        self.hidden = tuple(int(h) for h in hidden)
        self.window = HistoryWindow(K=self.K, n_actions=self.n_actions)
        self.n_features = delta.feature_size(self.K, self.state_dim, self.n_actions, self.road)
        if self.n_context:  # zeros: the meta update learns its initial value along with the weights
            self.context = nn.Parameter(torch.zeros(self.n_context))
        self.net = MLP(in_features=self.n_features + self.n_context, out_features=state_dim,
                       num_cells=list(self.hidden), activation_class=nn.ReLU)
        self.register_buffer("in_mean", torch.zeros(self.n_features))
        self.register_buffer("in_std", torch.ones(self.n_features))
        self.register_buffer("out_mean", torch.zeros(state_dim))
        self.register_buffer("out_std", torch.ones(state_dim))

    # ----- window <-> features -------------------------------------------------------------------
    def with_action(self, history: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
        """The window with ``action`` (categorical ``[...]`` or one-hot) in its newest row."""
        if action.is_floating_point():  # a one-hot action, or a continuous one the one-hot code would drop
            _check_one_hot(action, self.n_actions)
        one_hot = self.window._one_hot(action, history.ndim - 2).to(history.dtype)
        newest = torch.cat([history[..., -1, : self.state_dim], one_hot], dim=-1).unsqueeze(-2)
        return torch.cat([history[..., :-1, :], newest], dim=-2)

    def features(self, window: torch.Tensor, road: torch.Tensor | None = None) -> torch.Tensor:
        """Flat features of a window with its action, ``[..., n_features]``, as the model's ``delta`` object
        reads it (:class:`EgocentricDifferences`, :class:`PlainDifferences`)."""
        if window.dtype != self.in_mean.dtype:
            raise TypeError(f"DynamicsModel: a {window.dtype} window for a {self.in_mean.dtype} model; convert one "
                            f"to the other (model.to({window.dtype}), or the data)")
        if self.road and (road is None or road.shape[-2] < self.road):
            raise ValueError(f"this model reads {self.road} road points ahead: pass road [..., >= {self.road}, 2] "
                             f"(road_points of the route), got {None if road is None else tuple(road.shape)}")
        return self.delta_layout.features(window[..., : self.state_dim], window[..., self.state_dim:],
                                          road[..., : self.road, :] if self.road else None)

    # ----- prediction ----------------------------------------------------------------------------
    def normalized_delta(self, window: torch.Tensor, road: torch.Tensor | None = None) -> torch.Tensor:
        """The MLP's output: the normalized egocentric next-state difference for a window with action."""
        x = (self.features(window, road) - self.in_mean) / self.in_std
        if self.n_context:
            x = torch.cat([x, self.context.expand(*x.shape[:-1], self.n_context)], dim=-1)
        return self.net(x)

    def delta(self, window: torch.Tensor, road: torch.Tensor | None = None) -> torch.Tensor:
        return self.normalized_delta(window, road) * self.out_std + self.out_mean

    def normalize_delta(self, delta: torch.Tensor) -> torch.Tensor:
        return (delta - self.out_mean) / self.out_std

    def forward(self, history: torch.Tensor, action: torch.Tensor, road: torch.Tensor | None = None) -> torch.Tensor:
        """Next state ``[..., 14]`` after taking ``action`` with window ``history`` (and ``road``, a model
        with ``road``)."""
        window = self.with_action(history, action)
        return self.delta_layout.apply(history[..., -1, : self.state_dim], self.delta(window, road))

    def ensemble_forward(self, history: torch.Tensor, action: torch.Tensor, params: TensorDictBase,
                         road: torch.Tensor | None = None) -> torch.Tensor:
        """:meth:`forward` of ``E`` members at once: ``history`` ``[E, N, K, W]``, ``action`` ``[N]`` or
        ``[E, N]``, ``params`` the members' parameters stacked (``torch.stack`` of ``TensorDict.from_module``
        layouts, batch ``[E]``); returns ``[E, N, 14]``, equal to running each member in turn. The window
        transforms run once on the whole batch and the MLP layers as batched matrix products, so an
        ensemble costs about one model's time per imagined step (the planner's decision time).

        >>> from tensordict import TensorDict
        >>> m = DynamicsModel(hidden=(8,))
        >>> p = torch.stack([TensorDict.from_module(m).detach()] * 2)
        >>> m.ensemble_forward(torch.zeros(2, 3, 5, 21), torch.zeros(3, dtype=torch.long), p).shape
        torch.Size([2, 3, 14])
        """
        window = self.with_action(history, action.expand(history.shape[:-2]))
        delta = self.ensemble_normalized_delta(window, params, road) * params["out_std"].unsqueeze(1) \
            + params["out_mean"].unsqueeze(1)
        return self.delta_layout.apply(history[..., -1, : self.state_dim], delta)

    def ensemble_normalized_delta(self, window: torch.Tensor, params: TensorDictBase,
                                  road: torch.Tensor | None = None) -> torch.Tensor:
        """:meth:`normalized_delta` of ``E`` members at once: ``window`` ``[E, N, K, W]`` (with actions),
        ``params`` stacked as in :meth:`ensemble_forward`; ``[E, N, 14]``. Differentiable in ``params``
        (how :class:`~pernav.trainer.ensemble.EnsembleTrainer` trains all members in one pass)."""
        E = params.shape[0]
        x = (self.features(window, road) - params["in_mean"].unsqueeze(1)) / params["in_std"].unsqueeze(1)  # [E, N, F]
        if self.n_context:
            context = params["context"].reshape(E, *(1,) * (x.ndim - 2), self.n_context)
            x = torch.cat([x, context.expand(*x.shape[:-1], self.n_context)], dim=-1)
        for name, layer in self.net.named_children():
            if isinstance(layer, nn.Linear):
                weight, bias = params["net", name, "weight"], params["net", name, "bias"]
                x = torch.baddbmm(bias.reshape(E, 1, -1), x, weight.transpose(1, 2))
            else:
                x = layer(x)
        return x

    def next_window(self, history: torch.Tensor, action: torch.Tensor, next_state: torch.Tensor) -> torch.Tensor:
        """``history`` shifted by one step: ``action`` recorded, ``(next_state, 0)`` appended."""
        return self.window.next_window(history, action, next_state, batch_dims=history.ndim - 2)

    @torch.no_grad()
    def fit_normalization(self, history: torch.Tensor, action: torch.Tensor, next_state: torch.Tensor,
                          road: torch.Tensor | None = None) -> None:
        """Set the input/output statistics from data (``[N, K, D]``, ``[N]``, ``[N, 14]``; ``[N, R, 2]``)."""
        feats = self.features(self.with_action(history, action), road)
        delta = self.delta_layout.difference(history[..., -1, : self.state_dim], next_state)
        self.in_mean.copy_(feats.mean(0))
        self.in_std.copy_(_safe_std(feats))
        self.out_mean.copy_(delta.mean(0))
        self.out_std.copy_(_safe_std(delta))

    def config(self) -> dict:
        """Constructor arguments (saved with checkpoints)."""
        return {"state_dim": self.state_dim, "n_actions": self.n_actions, "K": self.K, "hidden": list(self.hidden),
                "road": self.road, "context": self.n_context, "delta": self.delta_layout.name}
