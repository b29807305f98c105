"""The play window's views of the world, one per camera of the study's contexts (``Context.camera``).

- ``top``: the north-up map around the car (what ``pernav play`` always showed).
- ``third_person``: a heading-up chase view: the map turned about the car so its heading points up the screen,
  the car low on the screen (the camera behind it) so more of the road ahead is seen.
- ``first_person``: the driver's seat (:mod:`pernav.play.seat`): the road in perspective (the town's lane edges
  projected from the eye onto the screen below a horizon, drawn as pygame polygons), other cars as boxes, the car's
  bonnet at the bottom.

``Fog`` limits what any view shows with distance (``--visual foggy``). A view draws a :class:`Frame` (the cars where
they are this instant, the route ahead), so it can be used without a running drive (both, and the :class:`Camera`
every view is, live in :mod:`pernav.play.camera_base`; they are named here too).

Example (off screen):
    >>> import numpy as np
    >>> import pygame
    >>> from pernav.world.towns import get_town
    >>> town = get_town("Town1")
    >>> route = town.routes[0]
    >>> frame = Frame(ego=route.waypoints[10], heading=0.0, cars=[], route=route.waypoints[10:60],
    ...               destination=route.destination)
    >>> out = pygame.Surface((320, 240))
    >>> make_camera("first_person", town, out.get_size()).draw(out, frame, Fog.for_visual("foggy", "first_person"))
    >>> out.get_at((160, 10))[:3] == PALETTE["fog"]  # the sky is lost in the fog
    True
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from pernav.play.camera_base import Camera, CarShape, Fog, Frame
from pernav.play.scene import PALETTE, TownScene, marking_quads, paint_plan, town_scene
from pernav.play.seat import DriverCamera
from pernav.world.network import Town

__all__ = ["CAMERAS", "Camera", "CarShape", "ChaseCamera", "Fog", "Frame", "PlanCamera", "make_camera"]

CAMERAS = ("top", "third_person", "first_person")  # the values of Context.camera (pernav.world.drivers)
CHASE_ANCHOR = 0.72  # the chase view's car sits this far down the screen: the camera is behind it


# ----- the map views (top, third_person) ------------------------------------------------------------------
class PlanCamera(Camera):
    """The north-up map (``top``): the town seen from above at ``scaling`` pixels per metre, the car at the
    screen's centre. The roads are painted once onto a large surface; each frame shows the part around the car."""

    name = "top"
    anchor = (0.5, 0.5)  # where the car is on the screen (fractions of the width and height)

    def __init__(self, scene: TownScene, size: tuple[int, int], scaling: float = 6.0) -> None:
        import pygame  # lazy: pygame is loaded when a view is made, not when the module is imported

        super().__init__(scene, size)
        self.pygame, self.scaling = pygame, scaling
        self.origin = np.array([scene.bounds[0], scene.bounds[2]])
        self._map: Any = None
        self.anchor_px = np.array([self.anchor[0] * size[0], self.anchor[1] * size[1]])
        self._fog: tuple[Fog, Any, int] | None = None  # the fog, its veil, the veil's half size

    @property
    def map(self) -> Any:
        """The town painted north-up (a large surface, painted at first use)."""
        if self._map is None:
            x0, x1, y0, y1 = self.scene.bounds
            self._map = self.pygame.Surface((int((x1 - x0) * self.scaling), int((y1 - y0) * self.scaling)))
            paint_plan(self._map, self.scene, self.origin, self.scaling)
        return self._map

    def basis(self, frame: Frame) -> np.ndarray:
        return np.eye(2)

    def to_screen(self, frame: Frame, points: np.ndarray) -> np.ndarray:
        """Pixel positions of world ``points`` (``[..., 2]``)."""
        return (points - frame.ego) @ self.basis(frame).T * self.scaling + self.anchor_px

    def _copy_map(self, out: Any, top_left: np.ndarray, size: tuple[int, int]) -> None:
        """Copy the map's ``size`` pixels from ``top_left`` (map pixels) onto ``out`` at (0, 0); grass where the map
        ends."""
        pg = self.pygame
        want = pg.Rect(int(round(top_left[0])), int(round(top_left[1])), *size)
        have = want.clip(self.map.get_rect())
        if have.size != want.size:
            out.fill(PALETTE["offroad"])
        if have.width and have.height:
            out.blit(self.map, (have.x - want.x, have.y - want.y), area=have)

    def _road(self, out: Any, frame: Frame) -> None:
        self._copy_map(out, (frame.ego - self.origin) * self.scaling - self.anchor_px, self.size)

    def draw(self, out: Any, frame: Frame, fog: Fog | None = None) -> None:
        pg = self.pygame
        self._road(out, frame)
        if len(frame.route) > 1:
            pg.draw.lines(out, PALETTE["route"], False, self.to_screen(frame, frame.route).tolist(), 3)
        if frame.destination is not None:
            pg.draw.circle(out, PALETTE["destination"], self.to_screen(frame, frame.destination).tolist(), 6)
        for car in frame.cars:
            self._car(out, frame, car)
        if fog is not None:
            self._fog_overlay(out, fog)

    def _car(self, out: Any, frame: Frame, car: CarShape) -> None:
        """A car from above: its body, a darker windscreen toward its front, a dark outline."""
        f = np.array([math.cos(car.heading), math.sin(car.heading)])
        r = np.array([-f[1], f[0]])
        hl, hw = car.length / 2, car.width / 2
        body = [car.position + a * hl * f + b * hw * r for a, b in ((1, -1), (1, 1), (-1, 1), (-1, -1))]
        glass = [car.position + a * hl * f + b * 0.8 * hw * r for a, b in ((0.55, -1), (0.55, 1), (0.15, 1), (0.15, -1))]
        dark = tuple(int(0.55 * c) for c in car.colour)
        self.pygame.draw.polygon(out, car.colour, self.to_screen(frame, np.array(body)).tolist())
        self.pygame.draw.polygon(out, dark, self.to_screen(frame, np.array(glass)).tolist())
        self.pygame.draw.polygon(out, (30, 30, 30), self.to_screen(frame, np.array(body)).tolist(), 1)

    def _fog_overlay(self, out: Any, fog: Fog) -> None:
        """Fog thickening with the distance from the car: a radial veil made once per fog, centred on the car; beyond
        the square that holds its opaque circle the screen is plain fog (a fill is cheaper than blending)."""
        pg = self.pygame
        if self._fog is None or self._fog[0] != fog:
            reach = int(math.ceil(fog.opaque * self.scaling)) + 1
            yy, xx = np.mgrid[-reach:reach, -reach:reach]
            alpha = fog.alpha(np.hypot(xx + 0.5, yy + 0.5) / self.scaling).astype(np.uint8)
            veil = pg.Surface((2 * reach, 2 * reach), pg.SRCALPHA)
            veil.fill((*PALETTE["fog"], 0))
            pg.surfarray.pixels_alpha(veil)[:] = alpha.T  # surfarray is [x, y]
            self._fog = (fog, veil, reach)
        _, veil, reach = self._fog
        square = veil.get_rect(center=(int(self.anchor_px[0]), int(self.anchor_px[1])))
        w, h = self.size
        for band in (pg.Rect(0, 0, w, square.top), pg.Rect(0, square.bottom, w, h - square.bottom),
                     pg.Rect(0, square.top, square.left, square.height),
                     pg.Rect(square.right, square.top, w - square.right, square.height)):
            if band.width > 0 and band.height > 0:
                out.fill(PALETTE["fog"], band)
        out.blit(veil, square)


class ChaseCamera(PlanCamera):
    """The heading-up chase view (``third_person``): the map turned about the car so that its heading points up the
    screen, the car low on the screen (the camera sits behind it). A left turn ahead bends to the screen's left.

    The town is drawn anew each picture as polygons (its strips and painted lines turned with the camera): turning
    the painted map instead costs up to 12 ms a picture at 45 degrees on this machine's CPUs, polygons a few."""

    name = "third_person"
    anchor = (0.5, CHASE_ANCHOR)

    def __init__(self, scene: TownScene, size: tuple[int, int], scaling: float = 6.0) -> None:
        super().__init__(scene, size, scaling)
        self._reach = math.hypot(*size) / 2 / scaling  # m around the screen's centre that hold the whole screen
        self.marks = marking_quads(scene)

    def basis(self, frame: Frame) -> np.ndarray:
        return np.array([frame.right, -frame.forward])  # screen x: the car's right; screen up: its heading

    def _road(self, out: Any, frame: Frame) -> None:
        pg, scene = self.pygame, self.scene
        w, h = self.size
        out.fill(PALETTE["offroad"])
        basis = self.basis(frame)
        centre = frame.ego + basis.T @ ((np.array([w, h]) / 2 - self.anchor_px) / self.scaling)
        seen = np.flatnonzero(np.linalg.norm(scene.centres - centre, axis=1) - scene.radii < self._reach)
        pixels = self.to_screen(frame, scene.points)  # the whole town at once: a few thousand points
        for left, right, colour in ((0, 3, "kerb"), (1, 2, "road")):  # kerbs first: asphalt covers the inner ones
            for i in seen:
                strip = pixels[scene.offsets[i]:scene.offsets[i + 1]]
                pg.draw.polygon(out, PALETTE[colour], np.concatenate([strip[:, left], strip[::-1, right]]).tolist())
        for quads, colour in self.marks:
            near = np.linalg.norm(quads[:, 0] - centre, axis=1) < self._reach
            for quad in self.to_screen(frame, quads[near]).tolist():
                pg.draw.polygon(out, PALETTE[colour], quad)


def make_camera(name: str, town: Town, size: tuple[int, int], **options: Any) -> Camera:
    """The view ``name`` (one of :data:`CAMERAS`) of ``town`` on a surface of ``size`` pixels."""
    kinds: dict[str, type[Camera]] = {"top": PlanCamera, "third_person": ChaseCamera, "first_person": DriverCamera}
    if name not in kinds:
        raise ValueError(f"unknown camera {name!r}; choose one of {', '.join(CAMERAS)}")
    return kinds[name](town_scene(town), size, **options)
