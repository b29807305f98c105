"""The deterministic dynamics model (paper §4.2, docs/study.md): of car-plus-driver, or of any discrete-action system.

Input: the :class:`~pernav.transforms.HistoryWindow` of the last K (state, action) pairs, with the action
about to be taken written into the newest row. Output: the next state. How the window is read and how a
prediction becomes the next state is one swappable object (``delta``): for the navigation's 14-d state,
:class:`~pernav.model.egocentric.EgocentricDifferences` (the window in the frame of the newest state: positions,
velocities and goals relative to the car and rotated by its heading; the MLP predicts the next-state difference
in that frame);
for any other state, :class:`PlainDifferences` (the flat window; ``next_state - state``). Which one ``delta="auto"``
(the default) picks is decided by the state's entry names, not its width: the navigation's layout only for the
navigation's state (``state_dim=STATE_KEYS``, the default); a state given by its size alone (``state_dim=14``) is
read plainly. Inputs and differences are normalized; the statistics are buffers of the module: saved, loaded and
swapped with it.

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
from typing import Any

import torch
from tensordict import TensorDictBase
from torch import nn
from torchrl.data import Categorical, OneHot, TensorSpec
from torchrl.modules import MLP

from pernav.env.layout import STATE_KEYS
from pernav.model.egocentric import ROAD_MAX, EgocentricDifferences
from pernav.transforms.history import HistoryWindow

__all__ = ["DELTAS", "DynamicsModel", "PlainDifferences", "n_discrete_actions"]


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


def n_discrete_actions(n_actions: int | TensorSpec) -> int:
    """The number of actions of an int or a discrete action spec (``Categorical``, ``OneHot``); ``ValueError`` for a
    continuous spec.

    >>> n_discrete_actions(OneHot(3)), n_discrete_actions(5)
    (3, 5)
    """
    if not isinstance(n_actions, TensorSpec):
        return int(n_actions)
    if isinstance(n_actions, (Categorical, OneHot)):
        return int(n_actions.space.n)
    raise ValueError(f"DynamicsModel models discrete actions (n_actions: an int, a Categorical or a OneHot spec); "
                     f"got the continuous action spec {type(n_actions).__name__}(shape={tuple(n_actions.shape)}, "
                     f"dtype={n_actions.dtype}): its actions would be one-hot encoded and lost")


def _bare_spec(n_actions: Any) -> Categorical | OneHot | None:
    """A discrete action spec without its env's batch dimensions and device (``None`` for a number)."""
    if isinstance(n_actions, OneHot):
        return OneHot(int(n_actions.space.n), dtype=n_actions.dtype)
    if isinstance(n_actions, Categorical):
        return Categorical(int(n_actions.space.n), dtype=n_actions.dtype)
    return None


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
        state_dim: the state's size, or the names of its entries in order; the default, the navigation's
            :data:`~pernav.env.layout.STATE_KEYS` (14 entries, read in the car's frame with ``delta="auto"``). Any
            other state (a size, or other names) is read plainly unless ``delta`` says otherwise.
        n_actions: 7, or 21 with playback speed (any number of discrete actions), or the env's action spec
            (``Categorical`` or ``OneHot``; a continuous spec is refused: the model one-hot encodes its actions). A
            spec is remembered (:attr:`action_spec`): an :class:`~pernav.model.ImaginedEnv` of this model takes it.
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
            ``"auto"`` (egocentric for the navigation's state, named by ``STATE_KEYS``; plain for any other) or an
            object with the same methods.

    The window convention is :class:`~pernav.transforms.HistoryWindow`'s: the newest row holds the current
    state and a zero action; :meth:`forward` writes ``action`` there. :meth:`next_window` shifts a window
    by one imagined step, exactly as the transform does in the real env.

    >>> m = DynamicsModel(hidden=(16,))
    >>> w = torch.randn(3, 5, 21)
    >>> m.next_window(w, torch.tensor([1, 2, 0]), torch.randn(3, 14)).shape
    torch.Size([3, 5, 21])
    """

    def __init__(self, state_dim: int | Sequence[str] = STATE_KEYS, n_actions: int | TensorSpec = 7, K: int = 5,
                 hidden: Sequence[int] = (256, 256, 256), road: int = 0, context: int = 0,
                 delta: str | EgocentricDifferences | PlainDifferences = "auto") -> None:
        super().__init__()
        #: the action spec the model was built from (``Categorical`` / ``OneHot``), or ``None`` for a number
        self.action_spec = _bare_spec(n_actions)
        n_actions = n_discrete_actions(n_actions)
        #: the state's entry names, where given (``state_dim`` as names); ``None`` for a state given by its size
        self.state_keys = None if isinstance(state_dim, int) else tuple(str(k) for k in state_dim)
        state_dim = int(state_dim) if self.state_keys is None else len(self.state_keys)
        if int(state_dim) < 1 or int(n_actions) < 1 or int(K) < 1:
            raise ValueError(f"state_dim, n_actions and K must be >= 1, got {state_dim}, {n_actions} and {K}")
        if isinstance(delta, str):
            if delta == "auto":  # by the state's names, not its width: a 14-d state of another task is plain
                delta = "egocentric" if self.state_keys == STATE_KEYS else "plain"
            if delta not in DELTAS:
                raise ValueError(f"unknown delta {delta!r}; choose one of auto, {', '.join(DELTAS)}")
            delta = DELTAS[delta]()
        if delta.name == "egocentric" and self.state_keys not in (None, STATE_KEYS):
            raise ValueError(f"delta='egocentric' reads the navigation's state {STATE_KEYS}, got the state "
                             f"{self.state_keys}; use delta='plain' for another state")
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
    def check_window(self, window: torch.Tensor, name: str = "history") -> None:
        """``ValueError`` naming the model's ``K``, ``state_dim`` and ``n_actions`` unless ``window`` is a
        ``[..., K, state_dim + n_actions]`` history window (a :class:`~pernav.transforms.HistoryWindow`'s)."""
        expected = (self.K, self.state_dim + self.n_actions)
        if tuple(window.shape[-2:]) != expected or window.ndim < 2:
            raise ValueError(f"DynamicsModel(K={self.K}, state_dim={self.state_dim}, n_actions={self.n_actions}) reads "
                             f"a {name} window [..., {expected[0]}, {expected[1]}] (K rows of state and one-hot "
                             f"action); got {tuple(window.shape)}: build the env's HistoryWindow(K={self.K}) for this "
                             "model, or the model with the data's K, state size and number of actions")


    def with_action(self, history: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
        """The window with ``action`` (categorical ``[...]`` or one-hot) in its newest row."""
        self.check_window(history, "history")
        if action.is_floating_point():  # a one-hot action, or a continuous one the one-hot code would drop
            _check_one_hot(action, self.n_actions)
        one_hot = self.window._one_hot(action, history.ndim - 2).to(history.dtype)
        newest = torch.cat([history[..., -1, : self.state_dim], one_hot], dim=-1).unsqueeze(-2)
        return torch.cat([history[..., :-1, :], newest], dim=-2)

    def features(self, window: torch.Tensor, road: torch.Tensor | None = None) -> torch.Tensor:
        """Flat features of a window with its action, ``[..., n_features]``, as the model's ``delta`` object
        reads it (:class:`EgocentricDifferences`, :class:`PlainDifferences`)."""
        self.check_window(window, "window")
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
