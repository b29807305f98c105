"""What the play window draws of a town, as world-space geometry shared by every view.

A town is sampled once into strips (every lane's paved surface with its kerb) and markings (the dashed centre
line and lane separators, stop lines, give-way lines at roundabouts, yellow junction boxes). The north-up map
paints them once onto a large surface (:func:`paint_plan`); the driver's-seat view projects the same points every
frame. Colours are chosen so road, kerb, off-road and markings differ at a glance.

Example:
    >>> from pernav.world.towns import get_town
    >>> scene = town_scene(get_town("Town1"))
    >>> len(scene.strips) > 100, scene.dashes.shape[1:]
    (True, (2, 2))
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from highway_env.road.lane import LineType

from pernav.world.network import Town
from pernav.world.simulation import World
from pernav.world.towns import LANE_WIDTH

__all__ = ["PALETTE", "TownScene", "marking_quads", "paint_plan", "town_scene"]

# one palette for every view; markings are pure white (a test and a person both look for them)
PALETTE: dict[str, tuple[int, int, int]] = {
    "offroad": (86, 118, 74),  # grass: nowhere to drive
    "kerb": (196, 192, 178),
    "road": (72, 74, 80),  # asphalt
    "marking": (255, 255, 255),
    "box": (236, 196, 40),  # yellow junction box
    "route": (60, 140, 255),
    "destination": (255, 80, 80),
    "sky": (150, 190, 235),
    "fog": (206, 210, 214),
    "ego": (50, 200, 0),
}

STEP = 2.0  # m between the samples of a lane
KERB = 0.45  # m of kerb drawn beyond a paved edge
DASH, GAP = 3.0, 3.0  # m of a centre-line dash and of the gap after it
STRIPE = 0.3  # m, width of dashed lines
STOP_LINE = 0.5  # m, width of a stop line
BOX_LINE = 0.3  # m, width of a junction box's yellow lines


@dataclass(frozen=True)
class TownScene:
    """A town's drawable geometry in world metres (x right, y down, as the simulator).

    ``strips``: per lane a ``[N, 4, 2]`` array of samples along it: kerb-left, road-left, road-right, kerb-right
    edge points; ``points`` all of them end to end, strip ``i`` at ``points[offsets[i]:offsets[i + 1]]`` (a view
    transforms the town at once). ``centres`` / ``radii`` bound each strip (for culling). Markings are segments
    ``[K, 2, 2]`` with a width in metres: ``dashes`` (white, thin), ``stop_lines`` (white, wide), ``box_lines`` (yellow).
    """

    strips: list[np.ndarray]
    points: np.ndarray
    offsets: np.ndarray
    centres: np.ndarray
    radii: np.ndarray
    dashes: np.ndarray
    stop_lines: np.ndarray
    box_lines: np.ndarray
    bounds: tuple[float, float, float, float]


def _lanes(town: Town) -> list[tuple[tuple[str, str, int], Any]]:
    graph = town.network.graph
    return [((a, b, k), lane) for a in graph for b in graph[a] for k, lane in enumerate(graph[a][b])]


def _sample(lane: Any, half: float) -> np.ndarray:
    """``[N, 4, 2]`` edge points of ``lane`` paved ``half`` metres either side of its centre line."""
    n = max(2, math.ceil(lane.length / STEP) + 1)
    s = np.linspace(0.0, lane.length, n)
    offsets = (-half - KERB, -half, half, half + KERB)
    return np.array([[lane.position(si, o) for o in offsets] for si in s])


def _dashed(lane: Any, lateral: float) -> list[np.ndarray]:
    """Dashes along ``lane`` at ``lateral`` metres from its centre line (positive: right)."""
    out, s = [], GAP / 2
    while s < lane.length:
        end = min(s + DASH, lane.length)
        out.append(np.array([lane.position(s, lateral), lane.position(end, lateral)]))
        s += DASH + GAP
    return out


def _across(lane: Any, s: float, pieces: int = 1) -> list[np.ndarray]:
    """A line across ``lane`` at ``s`` (split into ``pieces`` dashes: a give-way line)."""
    half = lane.width_at(s) / 2
    cuts = np.linspace(-half, half, 2 * pieces) if pieces > 1 else np.array([-half, half])
    return [np.array([lane.position(s, a), lane.position(s, b)]) for a, b in zip(cuts[::2], cuts[1::2], strict=True)]


def _box(town: Town) -> list[np.ndarray]:
    """Yellow criss-cross boxes over the paved centre of every junction where a driver chooses."""
    out = []
    for j in town.junctions.values():
        if j.kind != "cross" or not j.is_decision:
            continue
        # the north-south road paves +-its lanes x width across, the east-west road likewise along y: their
        # crossing is paved even at a T junction
        half = np.array([max(j.arms.get(a, 0) for a in "NS"), max(j.arms.get(a, 0) for a in "EW")]) * LANE_WIDTH
        corners = [j.center + np.array(v) * (half - 0.4) for v in ((-1, -1), (1, -1), (1, 1), (-1, 1))]
        out += [np.array([corners[i], corners[(i + 1) % 4]]) for i in range(4)]
        out += [np.array([corners[0], corners[2]]), np.array([corners[1], corners[3]])]
    return out


def _segments(items: list[np.ndarray]) -> np.ndarray:
    return np.array(items, dtype=float).reshape(-1, 2, 2)


def _build(town: Town) -> TownScene:
    strips, dashes, stops = [], [], []
    for index, lane in _lanes(town):
        junction = town.lane_junction.get(index)
        in_box = junction is not None and town.junctions[junction].kind == "cross"
        # inside a cross junction the world paves a little beyond the connectors (World.BOX_PAVING)
        half = LANE_WIDTH / 2 + (World.BOX_PAVING if in_box else 0.0)
        strips.append(_sample(lane, half))
        left, right = lane.line_types
        # the centre line is shared by both directions: draw it once, from the lane heading east or south-ish
        heading = lane.heading_at(0.0)
        if left == LineType.STRIPED and index[2] == 0 and -math.pi / 2 <= heading < math.pi / 2:
            dashes += _dashed(lane, -lane.width_at(0.0) / 2)
        if right == LineType.STRIPED:
            dashes += _dashed(lane, lane.width_at(0.0) / 2)
        end = town.junction_of_node(index[1])
        if junction is None and end is not None and end.kind == "cross" and end.is_decision:
            stops += _across(lane, lane.length - 0.3)  # the stop line where a street enters a junction box
        elif end is not None and end.kind == "roundabout" and ":i" in index[0] and ":r" in index[1]:
            stops += _across(lane, lane.length - 0.3, pieces=4)  # give way to the ring
    centres = np.array([s[:, 1:3].reshape(-1, 2).mean(0) for s in strips])
    radii = np.array([np.linalg.norm(s.reshape(-1, 2) - c, axis=1).max() for s, c in zip(strips, centres, strict=True)])
    offsets = np.concatenate([[0], np.cumsum([len(s) for s in strips])])
    return TownScene(strips, np.concatenate(strips), offsets, centres, radii, _segments(dashes), _segments(stops),
                     _segments(_box(town)), town.bounds(margin=60.0))


_SCENES: dict[int, tuple[Town, TownScene]] = {}  # id(town) -> (town kept alive, so the id stays its own, scene)


def town_scene(town: Town) -> TownScene:
    """The drawable geometry of ``town``, built once per town."""
    if id(town) not in _SCENES:
        _SCENES[id(town)] = (town, _build(town))
    return _SCENES[id(town)][1]


def paint_plan(surface: Any, scene: TownScene, origin: np.ndarray, scaling: float) -> None:
    """Paint ``scene`` north-up onto ``surface`` (a pygame Surface whose top-left pixel is the world point
    ``origin``, at ``scaling`` pixels per metre): grass, kerbs, asphalt, then the markings."""
    import pygame  # lazy: pygame is loaded when a view paints, not when the module is imported

    def px(points: np.ndarray) -> list[tuple[float, float]]:
        return [tuple(p) for p in ((points - origin) * scaling).tolist()]

    surface.fill(PALETTE["offroad"])
    for layer, colour in (((0, 3), "kerb"), ((1, 2), "road")):  # every kerb first: asphalt covers inner kerbs
        for strip in scene.strips:
            pygame.draw.polygon(surface, PALETTE[colour], px(np.concatenate([strip[:, layer[0]],
                                                                            strip[::-1, layer[1]]])))
    for segments, width, colour in ((scene.dashes, STRIPE, "marking"), (scene.stop_lines, STOP_LINE, "marking"),
                                    (scene.box_lines, BOX_LINE, "box")):
        w = max(1, round(width * scaling))
        for a, b in ((segments - origin) * scaling).tolist():
            pygame.draw.line(surface, PALETTE[colour], a, b, w)


def _quads(segments: np.ndarray, width: float) -> np.ndarray:
    """``[K, 4, 2]`` corners of painted lines ``width`` metres wide along ``segments`` (``[K, 2, 2]``)."""
    if not len(segments):
        return np.zeros((0, 4, 2))
    along = segments[:, 1] - segments[:, 0]
    side = np.stack([-along[:, 1], along[:, 0]], axis=1)
    side *= width / 2 / np.maximum(np.linalg.norm(side, axis=1, keepdims=True), 1e-9)
    a, b = segments[:, 0], segments[:, 1]
    return np.stack([a - side, b - side, b + side, a + side], axis=1)


def marking_quads(scene: TownScene) -> list[tuple[np.ndarray, str]]:
    """The painted lines of ``scene`` as ``[K, 4, 2]`` quads with their palette colour (views that draw polygons)."""
    return [(_quads(scene.dashes, STRIPE), "marking"), (_quads(scene.stop_lines, STOP_LINE), "marking"),
            (_quads(scene.box_lines, BOX_LINE), "box")]
