"""The driver's-seat view (``first_person``): the road in perspective, drawn with pygame polygons.

The eye sits above the car's seat, looking along its heading; every sample of the town's lane edges
(:class:`~pernav.play.scene.TownScene`) is projected at once onto the screen below a horizon, the lanes in the field
of view are filled as polygons (kerb, then asphalt), their edges cut at a near plane; painted lines, the route as a
band on the road, other cars as boxes, the car's bonnet at the bottom. Fog thickens row by row with the distance of
the road seen in that row.

Example (off screen):
    >>> import pygame
    >>> from pernav.play.cameras import Frame, make_camera
    >>> from pernav.world.towns import get_town
    >>> town = get_town("Town1")
    >>> route = town.routes[0]
    >>> camera = make_camera("first_person", town, (320, 240))
    >>> camera.draw(pygame.Surface((320, 240)), Frame(ego=route.waypoints[10], heading=0.0))
    >>> round(camera.horizon)
    96
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from pernav.play.camera_base import Camera, CarShape, Fog, Frame
from pernav.play.scene import PALETTE, TownScene, marking_quads

__all__ = ["DriverCamera"]

ROUTE_WIDTH = 1.2  # m, the route drawn on the road
MARK_FAR = 80.0  # m, painted lines are drawn up to this far (farther they would be a pixel or two)


class DriverCamera(Camera):
    """The view from the driver's seat: the eye ``eye_height`` metres above the road, looking along the car's
    heading with a horizontal field of view of ``fov`` degrees; the road in perspective out to ``far`` metres."""

    name = "first_person"

    def __init__(self, scene: TownScene, size: tuple[int, int], fov: float = 75.0, eye_height: float = 1.2,
                 horizon: float = 0.4, near: float = 0.5, far: float = 160.0) -> None:
        import pygame  # lazy: pygame is loaded when a view is made, not when the module is imported

        super().__init__(scene, size)
        self.pygame = pygame
        w, h = size
        self.focal = w / 2 / math.tan(math.radians(fov) / 2)  # pixels per metre at one metre's depth
        self.spread = w / 2 / self.focal  # metres to the side per metre ahead at the screen's edge
        self.eye_height, self.near, self.far = eye_height, near, far
        self.cx, self.horizon = w / 2, horizon * h
        self._fog: tuple[Fog, Any, int] | None = None  # the fog, its veil, the veil's first row
        self.marks = marking_quads(scene)
        hood = 0.86 * h  # the bonnet hides the road nearer than about 2.5 m
        self.bonnet = [(0.04 * w, h), (0.96 * w, h), (0.8 * w, hood), (0.2 * w, hood)]

    def basis(self, frame: Frame) -> np.ndarray:
        return np.array([frame.right, -frame.forward])  # as the chase view: ahead is up

    def _eye(self, frame: Frame) -> np.ndarray:
        return frame.ego - 0.3 * frame.forward  # the seat is a little behind the car's centre

    def _camera(self, frame: Frame, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(depth ahead, metres to the right) of world ``points`` (``[..., 2]``) from the eye."""
        rel = points - self._eye(frame)
        return rel @ frame.forward, rel @ frame.right

    def _project(self, depth: np.ndarray, lateral: np.ndarray, height: float | np.ndarray = 0.0) -> np.ndarray:
        """Screen pixels of points ``depth`` m ahead, ``lateral`` m right, ``height`` m above the road."""
        d = np.maximum(depth, self.near)
        xy = np.stack([self.cx + self.focal * lateral / d, self.horizon + self.focal * (self.eye_height - height) / d],
                      axis=-1)
        return np.clip(xy, -30000, 30000)  # points just past the near plane far off to a side

    def _edge(self, depth: np.ndarray, lateral: np.ndarray, run: slice) -> np.ndarray:
        """An edge's pixels over the samples ``run``, each end cut at the near plane where the edge crosses it."""
        d, x = list(depth[run]), list(lateral[run])
        for outside, inside, at in ((run.start - 1, run.start, 0), (run.stop, run.stop - 1, len(d))):
            if 0 <= outside < len(depth) and depth[outside] < self.near <= depth[inside]:
                t = (self.near - depth[outside]) / (depth[inside] - depth[outside])
                d.insert(at, self.near)
                x.insert(at, lateral[outside] + t * (lateral[inside] - lateral[outside]))
        return self._project(np.array(d), np.array(x))

    def _ribbon(self, left: tuple[np.ndarray, ...], right: tuple[np.ndarray, ...]) -> list[list[list[float]]]:
        """Screen polygons of a ribbon on the road between two edges sampled side by side, each edge given as its
        (depth, lateral, pixels) per sample: the parts ahead of the near plane."""
        visible = (left[0] > self.near) & (right[0] > self.near)
        if visible.all():  # the common case: all of it ahead
            return [np.concatenate([left[2], right[2][::-1]]).tolist()]
        if visible.sum() < 2:
            return []
        # runs of consecutive visible samples: a lane may pass out of view and come back (a roundabout)
        cuts = np.flatnonzero(np.diff(np.concatenate([[0], visible.astype(np.int8), [0]])))
        polys = []
        for a, b in zip(cuts[::2], cuts[1::2], strict=True):
            if b - a >= 2:
                run = slice(int(a), int(b))
                edge_l, edge_r = self._edge(left[0], left[1], run), self._edge(right[0], right[1], run)
                polys.append(np.concatenate([edge_l, edge_r[::-1]]).tolist())
        return polys

    def draw(self, out: Any, frame: Frame, fog: Fog | None = None) -> None:
        pg = self.pygame
        w, h = self.size
        far = self.far if fog is None else min(self.far, fog.opaque + 10.0)
        out.fill(PALETTE["sky"], pg.Rect(0, 0, w, int(self.horizon)))
        out.fill(PALETTE["offroad"], pg.Rect(0, int(self.horizon), w, h - int(self.horizon)))
        scene, eye = self.scene, self._eye(frame)
        rel = scene.centres - eye
        depth_c, lateral_c = rel @ frame.forward, rel @ frame.right
        # strips within reach, ahead of the eye, and not wholly beside the field of view (with their radius to spare)
        near = ((np.hypot(depth_c, lateral_c) - scene.radii < far) & (depth_c + scene.radii > self.near)
                & (np.abs(lateral_c) - scene.radii < (depth_c + scene.radii) * self.spread))
        # every sample of the town at once (a few thousand points): the per-lane work is then slicing
        depth, lateral = self._camera(frame, scene.points)
        pixels = self._project(depth, lateral)
        spans = [(int(scene.offsets[i]), int(scene.offsets[i + 1])) for i in np.flatnonzero(near)]
        # a kerb-wide ribbon under each lane's asphalt (two thin kerb bands per lane cost more calls than pixels),
        # all kerbs before any asphalt: where lanes meet, asphalt covers the inner kerbs
        for left, right, colour in ((0, 3, "kerb"), (1, 2, "road")):
            for a, b in spans:
                edges = [(depth[a:b, k], lateral[a:b, k], pixels[a:b, k]) for k in (left, right)]
                for poly in self._ribbon(*edges):
                    pg.draw.polygon(out, PALETTE[colour], poly)
        if len(frame.route) > 1:
            self._route(out, frame)
        for quads, colour in self.marks:  # painted lines farther than MARK_FAR would be a pixel or two: not drawn
            self._marks(out, frame, quads, PALETTE[colour], min(far, MARK_FAR))
        if fog is not None:
            self._fog_overlay(out, fog)
        for car in sorted((c for c in frame.cars if not c.ego), key=lambda c: -float((c.position - eye) @ frame.forward)):
            self._car(out, frame, car, fog)
        pg.draw.polygon(out, tuple(int(0.8 * c) for c in PALETTE["ego"]), self.bonnet)

    def _marks(self, out: Any, frame: Frame, quads: np.ndarray, colour: tuple, far: float) -> None:
        """Painted lines on the road (``[K, 4, 2]`` corners) ahead of the car and nearer than ``far``."""
        if not len(quads):
            return
        depth, lateral = self._camera(frame, quads)
        keep = (depth.max(1) > self.near) & (depth.min(1) < far) & (np.abs(lateral).min(1) < far)
        # a corner behind the eye is pulled onto the near plane: only under the bonnet, where nobody sees it
        for poly in self._project(depth[keep], lateral[keep]).tolist():
            self.pygame.draw.polygon(out, colour, poly)

    def _route(self, out: Any, frame: Frame) -> None:
        """The route as a blue band on the road, ``ROUTE_WIDTH`` wide."""
        pts = frame.route
        tangent = np.gradient(pts, axis=0)
        tangent /= np.maximum(np.linalg.norm(tangent, axis=1, keepdims=True), 1e-9)
        normal = np.stack([-tangent[:, 1], tangent[:, 0]], axis=1) * ROUTE_WIDTH / 2
        edges = []
        for side in (pts - normal, pts + normal):
            depth, lateral = self._camera(frame, side)
            edges.append((depth, lateral, self._project(depth, lateral)))
        for poly in self._ribbon(*edges):
            self.pygame.draw.polygon(out, PALETTE["route"], poly)

    def _car(self, out: Any, frame: Frame, car: CarShape, fog: Fog | None) -> None:
        """Another car as a box (its sides, and its roof when below the eye), faded into the fog by its distance."""
        f = np.array([math.cos(car.heading), math.sin(car.heading)])
        r = np.array([-f[1], f[0]])
        base = np.array([car.position + a * car.length / 2 * f + b * car.width / 2 * r
                         for a, b in ((1, -1), (1, 1), (-1, 1), (-1, -1))])
        depth, lateral = self._camera(frame, base)
        if depth.min() <= self.near or np.abs(lateral).min() > 3 * depth.max():
            return  # beside or behind the eye
        height = 1.5 if car.length < 5.0 else 1.9
        colour = np.array(car.colour, dtype=float)
        if fog is not None:
            a = float(fog.alpha(np.array(depth.mean()))) / 255.0
            colour = (1 - a) * colour + a * np.array(PALETTE["fog"])
        low, high = self._project(depth, lateral), self._project(depth, lateral, height)
        sides = sorted(range(4), key=lambda i: -(depth[i] + depth[(i + 1) % 4]))
        for i in sides:  # far sides first: the near ones cover them
            j = (i + 1) % 4
            shade = 0.9 if i % 2 == 0 else 0.7  # front and back lighter than the long sides
            poly = [low[i].tolist(), low[j].tolist(), high[j].tolist(), high[i].tolist()]
            self.pygame.draw.polygon(out, tuple(int(shade * c) for c in colour), poly)
        if height < self.eye_height:
            self.pygame.draw.polygon(out, tuple(int(c) for c in colour), high.tolist())

    def _fog_overlay(self, out: Any, fog: Fog) -> None:
        """Fog by the distance of the road seen in each row: rows beyond ``fog.opaque`` (and the sky) are plain fog,
        the rows between clear and opaque are blended with a veil made once per fog."""
        pg = self.pygame
        w, h = self.size
        if self._fog is None or self._fog[0] != fog:
            rows = np.arange(h) + 0.5
            below = rows - self.horizon
            distance = np.where(below > 0, self.focal * self.eye_height / np.maximum(below, 1e-9), np.inf)
            alpha = fog.alpha(distance)
            top, bottom = int(np.argmax(alpha < 255)), int(np.argmax(alpha <= 0)) if (alpha <= 0).any() else h
            veil = pg.Surface((w, max(bottom - top, 1)), pg.SRCALPHA)
            veil.fill((*PALETTE["fog"], 0))
            pg.surfarray.pixels_alpha(veil)[:] = alpha[None, top:top + veil.get_height()].astype(np.uint8)
            self._fog = (fog, veil, top)
        _, veil, top = self._fog
        out.fill(PALETTE["fog"], pg.Rect(0, 0, w, top))
        out.blit(veil, (0, top))
