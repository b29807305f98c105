"""The navigation's prediction layout: the 14-d state read in the car's frame (:class:`EgocentricDifferences`,
:func:`ego_delta`) and the road ahead a model may read (:func:`road_points`). :class:`~pernav.model.DynamicsModel`
uses it for ``delta="egocentric"`` (``"auto"`` with a 14-d state); any other state uses the plain layout.
"""

from __future__ import annotations

import torch
from tensordict import TensorDictBase

from pernav.env.layout import ROUTE_BEHIND, ROUTE_SPACING, STATE_DIM, STATE_KEYS

__all__ = ["GX", "GY", "HEADING", "ROAD_MAX", "VX", "VY", "X", "Y", "EgocentricDifferences", "apply_delta",
           "ego_delta", "road_of", "road_points", "wrap_angle"]

X, Y, VX, VY, HEADING, GX, GY = (STATE_KEYS.index(k) for k in ("x", "y", "vx", "vy", "heading", "goal_x", "goal_y"))
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
