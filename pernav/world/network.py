"""A built town's lane network, as routing and the cars query it: lane indices, the compass arms of a junction
and the turn between two of them, the junctions, the :class:`Town` and its spatial hash of lanes.

The five towns' maps and how a town is built from one are in :mod:`pernav.world.towns` (``get_town``). Coordinates
are highway-env's screen frame: x right, **y down**; a positive heading change is a right turn.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field

import numpy as np
from highway_env.road.lane import AbstractLane, CircularLane, StraightLane
from highway_env.road.road import RoadNetwork

LaneIndex = tuple[str, str, int]

DIRS: dict[str, np.ndarray] = {
    "E": np.array([1.0, 0.0]),
    "S": np.array([0.0, 1.0]),
    "W": np.array([-1.0, 0.0]),
    "N": np.array([0.0, -1.0]),
}
OPP = {"E": "W", "W": "E", "N": "S", "S": "N"}
ANGLE = {"E": 0.0, "S": np.pi / 2, "W": np.pi, "N": -np.pi / 2}


def right_normal(v: np.ndarray) -> np.ndarray:
    """Unit vector to the right of direction ``v`` in the y-down screen frame."""
    return np.array([-v[1], v[0]])


def turn_direction(in_arm: str, out_arm: str) -> str:
    """'straight', 'left' or 'right' for a car entering from ``in_arm`` and leaving by ``out_arm``.

    >>> turn_direction("W", "S")  # heading east, leaving south: a right turn (y down)
    'right'
    """
    if out_arm == OPP[in_arm]:
        return "straight"
    travel = -DIRS[in_arm]
    return "right" if np.allclose(DIRS[out_arm], right_normal(travel)) else "left"


@dataclass
class Junction:
    """A node of the town map: a cross/T junction ('cross') or a roundabout ('roundabout')."""

    id: str
    kind: str
    center: np.ndarray
    arms: dict[str, int] = field(default_factory=dict)  # arm letter -> lanes per direction on that arm
    size: float = 12.0  # box half-size (cross) or ring radius + spoke (roundabout)

    @property
    def is_decision(self) -> bool:
        """True where a driver has a choice (3+ arms or a roundabout); 2-arm nodes are bends."""
        return self.kind == "roundabout" or len(self.arms) >= 3

    def in_node(self, arm: str) -> str:
        return f"{self.id}:i{arm}"

    def out_node(self, arm: str) -> str:
        return f"{self.id}:o{arm}"


@dataclass
class Town:
    """A built town: the lane network, its junctions, lane successors and the fixed routes."""

    name: str
    network: RoadNetwork
    junctions: dict[str, Junction]
    successors: dict[LaneIndex, list[LaneIndex]]
    lane_junction: dict[LaneIndex, str]  # connector/ring/spoke lanes -> junction id
    road_lanes: list[LaneIndex]  # lanes of streets between junctions (spawn places)
    description: str = ""
    routes: list = field(default_factory=list)  # list[routing.Route], filled by towns.get_town

    @property
    def has_roundabout(self) -> bool:
        return any(j.kind == "roundabout" for j in self.junctions.values())

    def lane(self, index: LaneIndex) -> AbstractLane:
        return self.network.graph[index[0]][index[1]][index[2]]

    def junction_of_node(self, node: str) -> Junction | None:
        return self.junctions.get(node.split(":")[0]) if ":" in node else None

    @functools.cached_property
    def lane_grid(self) -> LaneGrid:
        return LaneGrid(self)

    def bounds(self, margin: float = 30.0) -> tuple[float, float, float, float]:
        pts = np.array([j.center for j in self.junctions.values()])
        return (
            pts[:, 0].min() - margin,
            pts[:, 0].max() + margin,
            pts[:, 1].min() - margin,
            pts[:, 1].max() + margin,
        )


def _lane_distance(lane: AbstractLane, position: np.ndarray) -> tuple[float, np.float64]:
    """``position``'s coordinate along ``lane`` and its distance to the lane's centre line: the hypot of the lateral
    offset and the distance beyond an end (what :class:`LaneGrid`'s lookups compare)."""
    s, lat = lane.local_coordinates(position)
    return s, np.hypot(lat, max(0.0, -s, s - lane.length))


def _reach_bounds(lane: AbstractLane) -> tuple | None:
    """What bounds a lane's distance (:meth:`LaneGrid.distance_to_road`'s hypot of the lateral offset and the
    distance beyond an end) from below: a straight lane's box ("straight", xmin, xmax, ymin, ymax) or an arc's
    circle ("arc", cx, cy, radius) as Python floats; None for other lanes (no bound)."""
    if type(lane) is StraightLane:
        (x0, y0), (x1, y1) = lane.start.tolist(), lane.end.tolist()
        return "straight", min(x0, x1), max(x0, x1), min(y0, y1), max(y0, y1)
    if type(lane) is CircularLane:
        cx, cy = lane.center.tolist()
        return "arc", cx, cy, float(lane.radius)
    return None


class LaneGrid:
    """Spatial hash of lanes: which lanes pass near a point. Makes closest-lane queries local
    (highway-env searches every lane of the network, the bottleneck in a town)."""

    CELL = 12.0

    def __init__(self, town: Town) -> None:
        self.town = town
        cells: dict[tuple[int, int], set] = {}
        for index in town.successors:
            lane = town.lane(index)
            for s in np.arange(0.0, lane.length + 1.0, 2.0):
                p = lane.position(min(s, lane.length), 0.0)
                cx, cy = int(np.floor(p[0] / self.CELL)), int(np.floor(p[1] / self.CELL))
                for dx in (-1, 0, 1):
                    for dy in (-1, 0, 1):
                        cells.setdefault((cx + dx, cy + dy), set()).add(index)
        self.cells = {k: sorted(v) for k, v in cells.items()}

    @functools.cached_property
    def reach_bounds(self) -> dict[LaneIndex, tuple | None]:
        """Each lane's :func:`_reach_bounds` (the lanes of :attr:`cells`)."""
        return {index: _reach_bounds(self.town.lane(index)) for index in self.town.successors}

    def near(self, position: np.ndarray) -> list[LaneIndex]:
        key = (int(np.floor(position[0] / self.CELL)), int(np.floor(position[1] / self.CELL)))
        return self.cells.get(key, [])

    def closest(self, position: np.ndarray, heading: float | None = None) -> tuple[LaneIndex | None, float]:
        """Closest lane to ``position`` (preferring lanes aligned with ``heading``) and the absolute
        lateral distance to its centre line (inf when no lane is near)."""
        best, best_score, best_lat = None, np.inf, np.inf
        for index in self.near(position):
            lane = self.town.lane(index)
            s, dist = _lane_distance(lane, position)
            score = dist
            if heading is not None:
                dh = abs((lane.heading_at(np.clip(s, 0, lane.length)) - heading + np.pi) % (2 * np.pi) - np.pi)
                score += 2.0 * dh
            if score < best_score:
                best, best_score, best_lat = index, score, dist
        return best, best_lat

    def within(self, position: np.ndarray, reach: float) -> bool:
        """``distance_to_road(position) <= reach``, to the same answer, found faster: it stops at the first lane
        close enough, and skips the projection on a lane whose :func:`_reach_bounds` put it surely beyond
        ``reach`` (by over 1e-6 m, far above the rounding of either computation)."""
        x, y = float(position[0]), float(position[1])
        reach_bounds = self.reach_bounds
        for index in self.near(position):
            bounds = reach_bounds[index]
            if bounds is not None:
                if bounds[0] == "straight":  # the segment lies in its box: off the box, off the segment
                    _, xmin, xmax, ymin, ymax = bounds
                    if max(xmin - x, x - xmax, ymin - y, y - ymax) > reach + 1e-6:
                        continue
                else:  # an arc: the lane's distance is at least |radius - distance to the centre|
                    _, cx, cy, radius = bounds
                    ax, ay = abs(x - cx), abs(y - cy)  # the distance to the centre is in [max(ax, ay), ax + ay]
                    if max(ax, ay) - radius > reach + 1e-6 or radius - (ax + ay) > reach + 1e-6:
                        continue
            if float(_lane_distance(self.town.lane(index), position)[1]) <= reach:
                return True
        return np.inf <= reach  # distance_to_road's answer when no lane is near (or all are NaN)

    def distance_to_road(self, position: np.ndarray) -> float:
        """Distance from ``position`` to the nearest lane centre line (inf off the map)."""
        best = np.inf
        for index in self.near(position):
            best = min(best, float(_lane_distance(self.town.lane(index), position)[1]))
        return best
