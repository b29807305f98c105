"""A* routing over the lane graph, routes as waypoint lists, and the fixed routes of each town.

highway-env only has BFS by hop count (and it enumerates every simple path when the goal is
unreachable); navigation needs the metric-shortest route, so this module runs A* over lane lengths.

Example:
    >>> from pernav.world.towns import get_town
    >>> town = get_town("Town1")
    >>> route = town.routes[0]
    >>> route.length > 900 and len(route.manoeuvres) >= 3
    True
"""

from __future__ import annotations

import heapq
from dataclasses import dataclass, field

import numpy as np
from highway_env.road.road import RoadNetwork

from pernav.world.constants import GOAL_LOOKAHEAD_S, WAYPOINT_SPACING
from pernav.world.network import LaneIndex, Town, turn_direction


class RouteError(ValueError):
    """No route exists between the requested places."""


def _node_positions(network: RoadNetwork) -> dict[str, np.ndarray]:
    pos: dict[str, np.ndarray] = {}
    for a, tos in network.graph.items():
        for b, lanes in tos.items():
            pos.setdefault(a, lanes[0].position(0.0, 0.0))
            pos.setdefault(b, lanes[0].position(lanes[0].length, 0.0))
    return pos


def astar(network: RoadNetwork, start: str, goal: str) -> list[str]:
    """Metric-shortest node path from ``start`` to ``goal`` (edge cost: shortest lane length).

    Raises :class:`RouteError` at once when ``goal`` cannot be reached (the search is over a
    finite graph and visits each node at most once).

    >>> from highway_env.road.lane import StraightLane
    >>> net = RoadNetwork()
    >>> net.add_lane("a", "b", StraightLane([0, 0], [10, 0]))
    >>> astar(net, "a", "b")
    ['a', 'b']
    """
    graph = network.graph
    if start not in graph and start != goal:
        raise RouteError(f"no route: start node {start!r} has no outgoing lanes")
    pos = _node_positions(network)
    if goal not in pos:
        raise RouteError(f"no route: goal node {goal!r} is not in the network")

    def h(n: str) -> float:
        return float(np.linalg.norm(pos[n] - pos[goal]))

    frontier = [(h(start), 0.0, start)]
    came: dict[str, str | None] = {start: None}
    cost = {start: 0.0}
    while frontier:
        _, g, node = heapq.heappop(frontier)
        if node == goal:
            path = [node]
            while came[path[-1]] is not None:
                path.append(came[path[-1]])
            return path[::-1]
        if g > cost[node]:
            continue
        for nxt, lanes in graph.get(node, {}).items():
            ng = g + min(lane.length for lane in lanes)
            if ng < cost.get(nxt, np.inf):
                cost[nxt], came[nxt] = ng, node
                heapq.heappush(frontier, (ng + h(nxt), ng, nxt))
    raise RouteError(f"no route from {start!r} to {goal!r}: destination unreachable")


@dataclass
class Manoeuvre:
    """A decision along a route: at junction ``junction`` the route goes ``kind``.

    ``kind``: 'left' | 'right' | 'straight' (cross/T junction), 'enter' (roundabout entry),
    'exit' | 'pass' (roundabout exit taken / passed). ``s`` is the route distance of the decision
    node (the stop line, or the ring exit point)."""

    kind: str
    junction: str
    s: float
    node: str
    next_node: str
    decision: bool = True  # False for the forced movement of a 2-arm bend


@dataclass
class Route:
    """A lane sequence with waypoints, manoeuvres and goal-waypoint selection."""

    lanes: list[LaneIndex]
    start_s: float
    end_s: float
    waypoints: np.ndarray = field(repr=False)
    s: np.ndarray = field(repr=False)
    lane_start: np.ndarray = field(repr=False)
    manoeuvres: list[Manoeuvre] = field(default_factory=list)
    name: str = ""

    @property
    def length(self) -> float:
        return float(self.s[-1])

    @property
    def destination(self) -> np.ndarray:
        return self.waypoints[-1]

    @property
    def roads(self) -> set[tuple[str, str]]:
        return {(a, b) for a, b, _ in self.lanes}

    def point_at(self, s: float) -> np.ndarray:
        i = int(np.clip(np.searchsorted(self.s, s), 0, len(self.s) - 1))
        return self.waypoints[i]

    def goal_waypoint(self, progress: float, speed: float) -> np.ndarray:
        """The goal waypoint selected by the current speed: where the car should be one policy step
        from now if it kept its speed along the route."""
        return self.point_at(progress + max(speed * GOAL_LOOKAHEAD_S, WAYPOINT_SPACING))

    def project(self, position: np.ndarray, hint: float | None = None, window: float = 60.0) -> tuple[float, float]:
        """Route distance of the waypoint closest to ``position`` and the distance to it; with a
        ``hint`` the search is restricted to [hint - 20, hint + window] metres (no jumps to a
        parallel street)."""
        if hint is None:
            lo, hi = 0, len(self.s)
        else:
            lo = int(np.searchsorted(self.s, hint - 20.0))
            hi = int(np.searchsorted(self.s, hint + window)) + 1
        d = np.linalg.norm(self.waypoints[lo:hi] - position, axis=1)
        i = int(np.argmin(d))
        return float(self.s[lo + i]), float(d[i])

    def upcoming(self, progress: float, horizon: float = np.inf) -> list[Manoeuvre]:
        """Decision manoeuvres ahead of ``progress`` within ``horizon`` metres."""
        return [m for m in self.manoeuvres if m.decision and progress < m.s <= progress + horizon]

    def lane_at(self, progress: float) -> LaneIndex:
        i = int(np.clip(np.searchsorted(self.lane_start, progress, side="right") - 1, 0, len(self.lanes) - 1))
        return self.lanes[i]


def _assign_lanes(town: Town, nodes: list[str], last_id: int) -> list[LaneIndex]:
    """Concrete lanes for a node path, chosen backwards so every lane leads into the next one (or
    into a parallel lane of it: the driver changes lane on the way)."""
    graph = town.network.graph
    lanes: list[LaneIndex] = [(nodes[-2], nodes[-1], last_id)]
    for a, b in zip(reversed(nodes[:-2]), reversed(nodes[1:-1]), strict=True):
        nxt = lanes[-1]
        parallel = [(nxt[0], nxt[1], k) for k in range(len(graph[nxt[0]][nxt[1]]))]
        n = len(graph[a][b])
        ok = [j for j in range(n) if nxt in town.successors[(a, b, j)]]
        ok = ok or [j for j in range(n) if any(p in town.successors[(a, b, j)] for p in parallel)]
        if not ok:
            raise RouteError(f"no lane of {a}->{b} leads into {nxt}")
        lanes.append((a, b, nxt[2] if nxt[2] in ok else ok[-1]))
    lanes.reverse()
    return lanes


def _manoeuvres(town: Town, lanes: list[LaneIndex], lane_start: np.ndarray) -> list[Manoeuvre]:
    out = []
    nodes = [lanes[0][0]] + [b for _, b, _ in lanes]
    node_s = {i + 1: float(lane_start[i] + town.lane(lanes[i]).length) for i in range(len(lanes))}
    for i, node in enumerate(nodes[:-1]):
        if i == 0 or ":" not in node:
            continue
        jid, tag = node.split(":", 1)
        j = town.junctions.get(jid)
        if j is None:
            continue
        s = node_s[i]
        if tag.startswith("i"):
            arm_in = tag[1]
            if j.kind == "roundabout":
                out.append(Manoeuvre("enter", jid, s, node, nodes[i + 1]))
                continue
            for later in nodes[i + 1 :]:
                if later.startswith(f"{jid}:o"):
                    kind = turn_direction(arm_in, later.split(":o")[1])
                    out.append(Manoeuvre(kind, jid, s, node, later, decision=j.is_decision))
                    break
        elif tag.startswith("r") and tag.endswith("x"):
            nxt = nodes[i + 1]
            out.append(Manoeuvre("exit" if nxt.startswith(f"{jid}:o") else "pass", jid, s, node, nxt))
    return out


def route_from_lanes(town: Town, lanes: list[LaneIndex], start_s: float, end_s: float, name: str = "") -> Route:
    """Waypoints and manoeuvres for a lane sequence; the route starts ``start_s`` metres into the
    first lane and ends ``end_s`` metres into the last one."""
    pts, ss, lane_start = [], [], []
    total = 0.0
    for i, index in enumerate(lanes):
        lane = town.lane(index)
        a = start_s if i == 0 else 0.0
        b = end_s if i == len(lanes) - 1 else lane.length
        lane_start.append(total - a)
        grid = np.arange(a, b, WAYPOINT_SPACING)
        for x in grid:
            pts.append(lane.position(x, 0.0))
            ss.append(total + (x - a))
        total += b - a
    pts.append(town.lane(lanes[-1]).position(end_s, 0.0))
    ss.append(total)
    lane_start_arr = np.asarray(lane_start)
    route = Route(lanes, start_s, end_s, np.asarray(pts), np.asarray(ss), lane_start_arr, name=name)
    route.manoeuvres = _manoeuvres(town, lanes, lane_start_arr)
    return route


def plan_route(town: Town, start: LaneIndex, start_s: float, goals: list[tuple[LaneIndex, float]],
               name: str = "") -> Route:
    """A* route from ``start_s`` metres into lane ``start`` through each ``(lane, s)`` goal in turn.

    >>> from pernav.world.towns import get_town
    >>> town = get_town("Town1")
    >>> r = plan_route(town, town.road_lanes[0], 5.0, [(town.road_lanes[-1], 30.0)])
    >>> r.lanes[0] == town.road_lanes[0]
    True
    """
    nodes = [start[0], start[1]]
    for goal, _ in goals:
        if goal[:2] == (nodes[-2], nodes[-1]):
            continue
        leg = astar(town.network, nodes[-1], goal[0])
        nodes += leg[1:] + [goal[1]]
    lanes = _assign_lanes(town, nodes, goals[-1][0][2])
    return route_from_lanes(town, lanes, start_s, goals[-1][1], name)


ROUTE_LENGTH = (1050.0, 1450.0)  # ~2 minutes at typical town speed


def _acceptable(town: Town, route: Route) -> bool:
    if not ROUTE_LENGTH[0] <= route.length <= ROUTE_LENGTH[1]:
        return False
    roads = [(a, b) for a, b, _ in route.lanes]
    if len(set(roads)) != len(roads):
        return False
    undirected = [frozenset((a.split(":")[0], b.split(":")[0])) for a, b in roads if a.split(":")[0] != b.split(":")[0]]
    if len(set(undirected)) != len(undirected):  # never drive a street twice (there and back)
        return False
    kinds = [m.kind for m in route.manoeuvres if m.decision]
    turns = sum(k in ("left", "right") for k in kinds) + kinds.count("enter")
    if turns < 3 or "left" not in kinds or "right" not in kinds:
        return False
    return not (town.has_roundabout and "enter" not in kinds)


def make_routes(town: Town, count: int = 10, seed: int = 0) -> list[Route]:
    """The town's fixed routes: start → via → destination, each leg A*-shortest, about two minutes
    long, with at least three manoeuvres, both turn directions and, where the town has one, a
    roundabout passage. Deterministic for a given town and seed."""
    rng = np.random.default_rng(seed)
    roads = [r for r in town.road_lanes if r[2] == 0]
    routes: list[Route] = []
    for _ in range(20000):
        a, v, b = (roads[i] for i in rng.choice(len(roads), 3, replace=False))
        try:
            lane_b = town.lane(b)
            route = plan_route(town, a, 5.0, [(v, town.lane(v).length / 2), (b, lane_b.length / 2)],
                               name=f"{town.name}/{len(routes)}")
        except RouteError:
            continue
        if _acceptable(town, route) and all(r.lanes[0][:2] != route.lanes[0][:2] for r in routes):
            routes.append(route)
            if len(routes) == count:
                return routes
    raise RuntimeError(f"{town.name}: could only make {len(routes)} routes")
