"""Towns built from highway-env lanes: junctions, roundabouts, multi-lane roads and fixed routes.

A town is described by a small ASCII map (nodes on even rows/columns, links between them) and turned
into a highway-env :class:`~highway_env.road.road.RoadNetwork` plus the metadata the driver, the
routing and the policies need (junction kinds, movements, lane successors).

Coordinates are highway-env's screen frame: x right, **y down**; a positive heading change is a right
turn. Traffic drives on the right. The built town (``Town``), its junctions and lane queries are in
:mod:`pernav.world.network`; the routes in :mod:`pernav.world.routing`.

Example:
    >>> town = get_town("Town3")
    >>> len(town.routes), town.has_roundabout
    (10, True)
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
from highway_env.road.lane import AbstractLane, CircularLane, LineType, StraightLane
from highway_env.road.road import RoadNetwork

from pernav.world.constants import TOWN_NAMES
from pernav.world.network import ANGLE, DIRS, OPP, Junction, LaneIndex, Town, right_normal, turn_direction
from pernav.world.routing import make_routes

LANE_WIDTH = 4.0
SPEED_1LANE = 13.9  # 50 km/h town streets
SPEED_2LANE = 16.7  # 60 km/h avenues
SPEED_TURN = 9.0  # nominal limit on turn connectors (drivers slow further by their own turn speed)
SPEED_RING = 8.0
RING_RADIUS = 20.0
RING_SPOKE = 16.0  # distance from the ring to the arm's end nodes
RING_MERGE_ANGLE = np.deg2rad(28.0)


@dataclass
class TownSpec:
    """ASCII description of a town. Nodes: 'X' junction, 'O' roundabout; links: '-' '|' one lane per
    direction, '=' 'H' two lanes per direction; ' ' nothing. ``xs``/``ys`` are node coordinates."""

    name: str
    rows: list[str]
    xs: list[float]
    ys: list[float]
    description: str = ""


TOWN_MAPS: dict[str, TownSpec] = {
    "Town1": TownSpec(
        "Town1",
        ["X-X-X-X", "| | | |", "X-X-X-X", "| | | |", "X-X-X-X"],
        [0, 150, 290, 440],
        [0, 140, 280],
        "Regular grid of one-lane streets: 4-way junctions inside, T junctions on the edges.",
    ),
    "Town2": TownSpec(
        "Town2",
        ["X-X-X-X", "| | | |", "X-X-X X", "| |   |", "X-X-X-X", "  | | |", "  X-X-X"],
        [0, 130, 270, 400],
        [0, 130, 250, 380],
        "Irregular small town dominated by T junctions and long blocks.",
    ),
    "Town3": TownSpec(
        "Town3",
        ["X-X-X-X", "| | | |", "X=X-O-X", "| | | |", "X-X-X-X"],
        [0, 160, 320, 480],
        [0, 150, 300],
        "Grid with a central roundabout and a two-lane avenue on the west side.",
    ),
    "Town4": TownSpec(
        "Town4",
        ["X-X-X-X-X", "| | | | |", "X-O-X-O-X", "| | | | |", "X=X=X=X=X"],
        [0, 140, 280, 420, 560],
        [0, 150, 300],
        "Two roundabouts and a two-lane boulevard along the south edge.",
    ),
    "Town5": TownSpec(
        "Town5",
        ["X-X-X-X-X", "| H | H |", "X=X=X=X=X", "| H | H |", "X-X-X-X-X"],
        [0, 130, 270, 400, 540],
        [0, 150, 300],
        "Downtown: two-lane avenues crossing two-lane boulevards, one-lane side streets.",
    ),
}
if tuple(TOWN_MAPS) != TOWN_NAMES:  # the light list (pernav.world.constants) names these maps, in order
    raise RuntimeError(f"TOWN_MAPS {tuple(TOWN_MAPS)} differ from pernav.world.constants.TOWN_NAMES")


class TownError(ValueError):
    """A bad town name or route index."""


# --------------------------------------------------------------------------------------------------
# Construction


def _parse(spec: TownSpec) -> tuple[dict[str, Junction], list[tuple[str, str, str, int]]]:
    """Junctions and links ``(junction_a, arm_a, junction_b, lanes)`` from the ASCII map."""
    rows = [r.ljust(max(len(r) for r in spec.rows)) for r in spec.rows]
    junctions: dict[str, Junction] = {}
    for r in range(0, len(rows), 2):
        for c in range(0, len(rows[r]), 2):
            ch = rows[r][c]
            if ch in "XO":
                jid = f"J{r // 2}{c // 2}"
                center = np.array([spec.xs[c // 2], spec.ys[r // 2]], dtype=float)
                junctions[jid] = Junction(jid, "roundabout" if ch == "O" else "cross", center)
    links = []
    for r in range(len(rows)):
        for c in range(len(rows[r])):
            ch = rows[r][c]
            if r % 2 == 0 and c % 2 == 1 and ch in "-=":
                a, b = f"J{r // 2}{(c - 1) // 2}", f"J{r // 2}{(c + 1) // 2}"
                links.append((a, "E", b, 2 if ch == "=" else 1))
            elif r % 2 == 1 and c % 2 == 0 and ch in "|H":
                a, b = f"J{(r - 1) // 2}{c // 2}", f"J{(r + 1) // 2}{c // 2}"
                links.append((a, "S", b, 2 if ch == "H" else 1))
    for a, arm, b, lanes in links:
        if a not in junctions or b not in junctions:
            raise TownError(f"town {spec.name}: link {a}-{b} does not join two nodes")
        junctions[a].arms[arm] = lanes
        junctions[b].arms[OPP[arm]] = lanes
    for j in junctions.values():
        if len(j.arms) < 2:
            raise TownError(f"town {spec.name}: node {j.id} is a dead end")
        if j.kind == "roundabout":
            if any(n > 1 for n in j.arms.values()):
                raise TownError(f"town {spec.name}: roundabout {j.id} arms must be one-lane")
            j.size = RING_RADIUS + RING_SPOKE
        else:
            j.size = 11.0 + 4.0 * (max(j.arms.values()) - 1) + 1.0
    return junctions, links


class _Builder:
    def __init__(self, name: str) -> None:
        self.name = name
        self.net = RoadNetwork()
        self.successors: dict[LaneIndex, list[LaneIndex]] = {}
        self.lane_junction: dict[LaneIndex, str] = {}
        self.road_lanes: list[LaneIndex] = []
        self.cross_ends: dict[str, dict] = {}  # junction -> (out arm, out lane) -> connector ends
        self.ring_exits: dict[tuple[str, str], LaneIndex] = {}  # (roundabout, arm) -> exit spoke

    def add(self, a: str, b: str, lane: AbstractLane, junction: str | None = None) -> LaneIndex:
        self.net.add_lane(a, b, lane)
        index = (a, b, len(self.net.graph[a][b]) - 1)
        self.successors.setdefault(index, [])
        if junction is not None:
            self.lane_junction[index] = junction
        return index

    def link(self, a: LaneIndex, b: LaneIndex) -> None:
        if b not in self.successors[a]:
            self.successors[a].append(b)

    def chain(self, jid: str, start: str, end: str, key: str, pieces: list[AbstractLane]) -> list[LaneIndex]:
        """Add consecutive pieces between ``start`` and ``end`` through fresh intermediate nodes."""
        nodes = [start] + [f"{jid}:{key}.{i}" for i in range(1, len(pieces))] + [end]
        idx = [self.add(nodes[i], nodes[i + 1], p, jid) for i, p in enumerate(pieces)]
        for x, y in zip(idx, idx[1:], strict=False):
            self.link(x, y)
        return idx


def _turn_pieces(p: np.ndarray, u: np.ndarray, q: np.ndarray, v: np.ndarray, speed: float) -> list:
    """Straight stub + quarter circle + straight stub from point p (heading u) to q (heading v)."""
    corner = p + np.dot(q - p, u) * u
    a1, a2 = float(np.dot(corner - p, u)), float(np.dot(q - corner, v))
    r = min(a1, a2)
    a, b = corner - r * u, corner + r * v
    center = a + r * v
    right = np.allclose(v, right_normal(u))
    start = float(np.arctan2(-v[1], -v[0]))
    end = start + (np.pi / 2 if right else -np.pi / 2)
    none = [LineType.NONE, LineType.NONE]
    pieces: list[AbstractLane] = []
    if a1 - r > 0.05:
        pieces.append(StraightLane(p, a, width=LANE_WIDTH, line_types=none, speed_limit=speed))
    pieces.append(CircularLane(center, r, start, end, clockwise=right, width=LANE_WIDTH, line_types=none,
                               speed_limit=speed))
    if a2 - r > 0.05:
        pieces.append(StraightLane(b, q, width=LANE_WIDTH, line_types=none, speed_limit=speed))
    return pieces


def _lane_offset(k: int) -> float:
    return (k + 0.5) * LANE_WIDTH


def _road_line_types(k: int, n: int) -> list:
    left = LineType.STRIPED if k == 0 else LineType.NONE
    right = LineType.CONTINUOUS_LINE if k == n - 1 else LineType.STRIPED
    return [left, right]


def _arm_point(j: Junction, arm: str, incoming: bool, k: int) -> np.ndarray:
    d = DIRS[arm]
    travel = -d if incoming else d
    return j.center + j.size * d + _lane_offset(k) * right_normal(travel)


def _build_cross(bld: _Builder, j: Junction) -> dict[tuple[str, int], list[LaneIndex]]:
    """Connectors of a cross/T junction; returns the first connector lanes per (in arm, in lane)."""
    firsts: dict[tuple[str, int], list[LaneIndex]] = {}
    ends: dict[tuple[str, int], list[tuple[LaneIndex, str, int]]] = {}
    for a, na in j.arms.items():
        outs = [b for b in j.arms if b != a]
        for k in range(na):
            moves = []
            for b in outs:
                kind = turn_direction(a, b)
                if kind == "straight" or (kind == "left" and k == 0) or (kind == "right" and k == na - 1):
                    moves.append(b)
            if not moves:  # e.g. the right lane of a two-lane road ending in a left bend
                moves = outs
            for b in moves:
                nb = j.arms[b]
                kind = turn_direction(a, b)
                kb = min(k, nb - 1) if kind == "straight" else (0 if kind == "left" else nb - 1)
                p, q = _arm_point(j, a, True, k), _arm_point(j, b, False, kb)
                u, v = -DIRS[a], DIRS[b]
                if kind == "straight":
                    pieces = [StraightLane(p, q, width=LANE_WIDTH, line_types=[LineType.NONE] * 2,
                                           speed_limit=SPEED_1LANE if nb == 1 else SPEED_2LANE)]
                else:
                    pieces = _turn_pieces(p, u, q, v, SPEED_TURN)
                if len(pieces) == 1:
                    idx = [bld.add(j.in_node(a), j.out_node(b), pieces[0], j.id)]
                else:
                    idx = bld.chain(j.id, j.in_node(a), j.out_node(b), f"{a}{b}{k}", pieces)
                firsts.setdefault((a, k), []).append(idx[0])
                ends.setdefault((b, kb), []).append((idx[-1], b, kb))
    bld.cross_ends[j.id] = ends
    return firsts


def _build_roundabout(bld: _Builder, j: Junction) -> dict[tuple[str, int], list[LaneIndex]]:
    """Ring (counter-clockwise on screen, i.e. right-hand traffic), entry and exit spokes."""
    c, R, dm = j.center, RING_RADIUS, RING_MERGE_ANGLE
    arms = sorted(j.arms, key=lambda a: -ANGLE[a])  # circulation order: decreasing phase
    none = [LineType.NONE, LineType.NONE]
    ring_lines = [LineType.CONTINUOUS_LINE, LineType.CONTINUOUS_LINE]

    def ring_point(phase: float) -> np.ndarray:
        return c + R * np.array([np.cos(phase), np.sin(phase)])

    ring_idx: dict[str, tuple[LaneIndex, LaneIndex]] = {}
    for i, a in enumerate(arms):
        nxt = arms[(i + 1) % len(arms)]
        th, th_next = ANGLE[a], ANGLE[nxt]
        while th_next >= th - dm:  # wrap so the phase keeps decreasing
            th_next -= 2 * np.pi
        # through the arm: exit point (th + dm) -> entry point (th - dm)
        through = bld.add(f"{j.id}:r{a}x", f"{j.id}:r{a}e",
                          CircularLane(c, R, th + dm, th - dm, clockwise=False, width=LANE_WIDTH,
                                       line_types=ring_lines, speed_limit=SPEED_RING), j.id)
        between = bld.add(f"{j.id}:r{a}e", f"{j.id}:r{nxt}x",
                          CircularLane(c, R, th - dm, th_next + dm, clockwise=False, width=LANE_WIDTH,
                                       line_types=ring_lines, speed_limit=SPEED_RING), j.id)
        ring_idx[a] = (through, between)
    for i, a in enumerate(arms):
        prev = arms[i - 1]
        bld.link(ring_idx[a][0], ring_idx[a][1])
        bld.link(ring_idx[prev][1], ring_idx[a][0])
    firsts = {}
    for a in arms:
        th = ANGLE[a]
        entry = bld.add(j.in_node(a), f"{j.id}:r{a}e",
                        StraightLane(_arm_point(j, a, True, 0), ring_point(th - dm), width=LANE_WIDTH,
                                     line_types=none, speed_limit=SPEED_RING), j.id)
        exit_ = bld.add(f"{j.id}:r{a}x", j.out_node(a),
                        StraightLane(ring_point(th + dm), _arm_point(j, a, False, 0), width=LANE_WIDTH,
                                     line_types=none, speed_limit=SPEED_RING), j.id)
        bld.link(entry, ring_idx[a][1])
        prev = arms[arms.index(a) - 1]
        bld.link(ring_idx[prev][1], exit_)
        firsts[(a, 0)] = [entry]
        bld.ring_exits[(j.id, a)] = exit_
    return firsts


def build_town(spec: TownSpec) -> Town:
    """Build the lane network of ``spec`` (no routes)."""
    junctions, links = _parse(spec)
    bld = _Builder(spec.name)
    firsts: dict[str, dict] = {}
    for j in junctions.values():
        firsts[j.id] = _build_roundabout(bld, j) if j.kind == "roundabout" else _build_cross(bld, j)
    # connector/exit ends per (junction, out arm, out lane)
    ends: dict[tuple[str, str, int], list[LaneIndex]] = {}
    for jid, table in bld.cross_ends.items():
        for (b, kb), lst in table.items():
            ends.setdefault((jid, b, kb), []).extend(idx for idx, _, _ in lst)
    for (jid, a), idx in bld.ring_exits.items():
        ends.setdefault((jid, a, 0), []).append(idx)
    for a, arm, b, n in links:
        ja, jb = junctions[a], junctions[b]
        for src, s_arm, dst, d_arm in ((ja, arm, jb, OPP[arm]), (jb, OPP[arm], ja, arm)):
            speed = SPEED_1LANE if n == 1 else SPEED_2LANE
            for k in range(n):
                start = _arm_point(src, s_arm, False, k)
                end = _arm_point(dst, d_arm, True, k)
                idx = bld.add(src.out_node(s_arm), dst.in_node(d_arm),
                              StraightLane(start, end, width=LANE_WIDTH, line_types=_road_line_types(k, n),
                                           speed_limit=speed))
                bld.road_lanes.append(idx)
                for e in ends.get((src.id, s_arm, k), []):
                    bld.link(e, idx)
                for f in firsts[dst.id].get((d_arm, k), []):
                    bld.link(idx, f)
    return Town(spec.name, bld.net, junctions, bld.successors, bld.lane_junction, bld.road_lanes,
                spec.description)


@functools.cache
def get_town(name: str) -> Town:
    """The named town with its ten fixed routes (cached: towns are immutable once built)."""
    if name not in TOWN_MAPS:
        raise TownError(f"unknown town {name!r}; choose one of {', '.join(TOWN_NAMES)}")
    town = build_town(TOWN_MAPS[name])
    town.routes = make_routes(town)
    return town
