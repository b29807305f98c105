"""The play window: the town around the car seen through the context's camera, the route ahead, the prompt with
the distance to its manoeuvre, the drive's counter ("Drive 2 of 6"), the speed limit, and the way back when the car
has left its route.

The view follows the drive's context (``--camera``, ``--visual``; :class:`~pernav.world.drivers.Context`): ``top``
the north-up map, ``third_person`` a heading-up chase view, ``first_person`` the driver's seat; ``foggy`` veils
what lies beyond the simulated driver's sight distance (:mod:`pernav.play.cameras`). Cars may be drawn between two
simulation frames (``alpha``) so the picture moves smoothly at more frames than the world has.

Example (no display needed: an off-screen surface):
    >>> from pernav.play.loop import PlayOptions, PlaySession
    >>> session = PlaySession("Town1", 0, options=PlayOptions(n_traffic=2, draw=True))
    >>> session.view.surface.get_size()
    (960, 720)
"""

from __future__ import annotations

import math
import os
import sys
from pathlib import Path
from typing import Any

import numpy as np

from pernav.play.camera_base import CarShape, Fog, Frame
from pernav.play.cameras import make_camera

os.environ.setdefault("PYGAME_HIDE_SUPPORT_PROMPT", "1")

__all__ = ["DisplayError", "PlayView", "frame_of", "hud_texts"]

EGO_COLOR = (50, 200, 0)
OFF_ROUTE = 4.0  # m from the route's line beyond which the way back is shown (the env re-plans at 8 m)
ROUTE_AHEAD = 250.0  # m of the route drawn ahead of the car


class DisplayError(ValueError):
    """No display for the play window."""


class PlayView:
    """A window (``window=True``) or an off-screen surface of ``size`` pixels at ``scaling`` pixels per metre (the
    map views). ``camera`` (``top``, ``third_person``, ``first_person``) and ``visual`` (``foggy`` veils the view)
    default to the drive's context, read at its first :meth:`draw` (again for each drive after :meth:`new_drive`)."""

    def __init__(self, town: Any, size: tuple[int, int] = (960, 720), scaling: float = 6.0, window: bool = False,
                 camera: str | None = None, visual: str | None = None) -> None:
        import pygame  # lazy: pygame is loaded when a window or picture is made, not when the module is imported

        self.pygame = pygame
        self.window = window
        if window:
            if sys.platform.startswith("linux") and not os.environ.get("SDL_VIDEODRIVER") \
                    and not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
                # no X or Wayland display: say so before SDL tries one (it prints its own lines, e.g. about
                # XDG_RUNTIME_DIR, then falls back to drawing off screen)
                raise DisplayError("no display for the play window (neither DISPLAY nor WAYLAND_DISPLAY is set); use "
                                   "--headless, or set SDL_VIDEODRIVER=dummy to draw off screen")
            try:
                pygame.display.init()
                self.surface = pygame.display.set_mode(size)
            except pygame.error as exc:
                raise DisplayError(f"no display for the play window ({exc}); use --headless, or set "
                                   "SDL_VIDEODRIVER=dummy to draw off screen") from None
            driver = pygame.display.get_driver()
            if driver in ("offscreen", "dummy") and os.environ.get("SDL_VIDEODRIVER") != driver:
                # SDL fell back to drawing nowhere: no one would see the window (asked for explicitly, it is fine)
                pygame.display.quit()
                raise DisplayError(f"no display for the play window (SDL fell back to {driver!r}); use --headless, "
                                   "or set SDL_VIDEODRIVER=dummy to draw off screen")
            pygame.display.set_caption("pernav play")
        else:
            self.surface = pygame.Surface(size)
        pygame.font.init()  # fonts only: pygame.init() would open audio devices
        self.size, self.scaling = size, scaling
        self._asked = (camera, visual)  # what the caller chose; None: each drive's context chooses
        self.new_drive(town)
        self.big = pygame.font.Font(None, 54)
        self.font = pygame.font.Font(None, 28)
        self.small = pygame.font.Font(None, 22)

    def new_drive(self, town: Any) -> None:
        """Start drawing a new drive in ``town``: the camera, the fog and the speed limit are chosen again (a
        window kept open across the drives of a session shows each drive's own context and town)."""
        self.town = town
        self.camera_name, self.visual = self._asked
        self.camera: Any = None  # made at the first draw (the drive's context says which)
        self.fog: Any = None
        self.limit_kmh: float | None = None  # the speed limit of the street the car is on (kept through junctions)

    def _choose(self, session: Any) -> None:
        context = getattr(getattr(session.nav, "driver", None), "context", None)
        if self.camera_name is None:
            self.camera_name = context.camera if context is not None else "top"
        if self.visual is None:
            self.visual = context.visual if context is not None else "normal"
        options = {} if self.camera_name == "first_person" else {"scaling": self.scaling}
        self.camera = make_camera(self.camera_name, self.town, self.size, **options)
        self.fog = Fog.for_visual(self.visual, self.camera_name)

    def draw(self, session: Any, alpha: float = 1.0) -> None:
        """Draw ``session``'s world with every car ``alpha`` of the way from its last frame to this one."""
        if self.camera is None:
            self._choose(session)
        frame = frame_of(session, alpha)
        self.camera.draw(self.surface, frame, self.fog)
        self._hud(session)
        self._speed_limit(session)
        self._way_back(session, frame)

    def _hud(self, session: Any) -> None:
        pg, out = self.pygame, self.surface
        w, h = self.size
        texts = hud_texts(session)
        if "prompt" in texts:
            band = pg.Surface((w, 70), pg.SRCALPHA)
            band.fill((0, 0, 0, 170))
            out.blit(band, (0, 0))
            text = self.big.render(texts["prompt"], True, (255, 255, 255))
            out.blit(text, ((w - text.get_width()) // 2, 12))
        if "drive" in texts:  # below the prompt's band, on its own dark box: readable over fog and sky
            text = self.font.render(texts["drive"], True, (255, 255, 255))
            box = pg.Surface((text.get_width() + 16, text.get_height() + 10), pg.SRCALPHA)
            box.fill((0, 0, 0, 170))
            out.blit(box, (10, 80))
            out.blit(text, (18, 85))
        band = pg.Surface((w, 56), pg.SRCALPHA)  # behind the status and the hint: readable over fog and grass
        band.fill((0, 0, 0, 150))
        out.blit(band, (0, h - 56))
        out.blit(self.font.render(texts["status"], True, (255, 255, 255)), (10, h - 52))
        out.blit(self.small.render(texts["hint"], True, (230, 230, 230)), (10, h - 22))

    def _speed_limit(self, session: Any) -> None:
        """A speed-limit sign (the street's limit: a junction's slower connectors keep the street's sign) and the
        car's speed beside it, red when over the limit."""
        pg, out = self.pygame, self.surface
        ego = session.nav.world.ego
        lane = getattr(ego, "lane_index", None)
        if lane is not None and (self.limit_kmh is None or lane not in self.town.lane_junction):
            self.limit_kmh = 10.0 * round(float(self.town.lane(lane).speed_limit) * 3.6 / 10.0)
        if self.limit_kmh is None:
            return
        w = self.size[0]
        centre, radius = (w - 60, 120), 38
        pg.draw.circle(out, (255, 255, 255), centre, radius)
        pg.draw.circle(out, (210, 30, 30), centre, radius, 7)
        text = self.font.render(f"{self.limit_kmh:.0f}", True, (0, 0, 0))
        out.blit(text, (centre[0] - text.get_width() // 2, centre[1] - text.get_height() // 2))
        speed = ego.speed * 3.6
        colour = (255, 70, 70) if speed > self.limit_kmh + 3.0 else (255, 255, 255)
        shown = self.big.render(f"{speed:.0f}", True, colour)
        box = pg.Surface((shown.get_width() + 16, shown.get_height() + 8), pg.SRCALPHA)
        box.fill((0, 0, 0, 150))
        out.blit(box, (centre[0] - radius - box.get_width() - 12, centre[1] - box.get_height() // 2))
        out.blit(shown, (centre[0] - radius - shown.get_width() - 20, centre[1] - shown.get_height() // 2 + 2))

    def _way_back(self, session: Any, frame: Any) -> None:
        """Off the route (or off the road): an arrow to where the route goes on, its distance, and the next
        manoeuvre."""
        pg, out, nav = self.pygame, self.surface, session.nav
        ego = nav.world.ego
        _, off = nav.route.project(ego.position, hint=nav.progress)
        if off <= OFF_ROUTE and not ego.off_road:
            return
        target = nav.route.point_at(nav.progress + 15.0)
        way = self.camera.basis(frame) @ (target - frame.ego)
        way = way / max(float(np.linalg.norm(way)), 1e-9)
        side = np.array([-way[1], way[0]])
        centre, r = np.array([self.size[0] / 2, 135.0]), 42.0
        pg.draw.circle(out, (20, 20, 20), centre.tolist(), r + 6)
        tip, tail = centre + way * r, centre - way * r * 0.8
        neck = centre + way * r * 0.1
        arrow = [tip, neck + side * r * 0.6, neck + side * r * 0.22, tail + side * r * 0.22,
                 tail - side * r * 0.22, neck - side * r * 0.22, neck - side * r * 0.6]
        pg.draw.polygon(out, (60, 140, 255), [p.tolist() for p in arrow])
        lines = [f"back to the route: {off:.0f} m"]
        if math.isfinite(getattr(session, "distance", math.inf)):
            lines.append(f"then {session.next_manoeuvre} in {session.distance:.0f} m")
        for k, line in enumerate(lines):
            text = self.font.render(line, True, (255, 255, 255))
            box = pg.Surface((text.get_width() + 12, text.get_height() + 6), pg.SRCALPHA)
            box.fill((0, 0, 0, 170))
            y = int(centre[1] + r + 12 + 28 * k)
            out.blit(box, (int(centre[0]) - box.get_width() // 2, y - 3))
            out.blit(text, (int(centre[0]) - text.get_width() // 2, y))

    def present(self) -> None:
        """Show the drawn frame in the window (nothing off screen)."""
        if self.window:
            self.pygame.display.flip()

    def screenshot(self, path: str | Path) -> Path:
        """Save what the window shows now as a PNG."""
        path = Path(path)
        self.pygame.image.save(self.surface, str(path))
        return path

    def close(self) -> None:
        if self.window:
            self.pygame.display.quit()


def hud_texts(session: Any) -> dict[str, str]:
    """The texts the HUD draws for ``session``: ``prompt`` (the instruction and its distance, while it holds),
    ``drive`` (the session's counter, e.g. "Drive 2 of 6": its ``progress``, else its ``title``), ``status`` (time,
    speed, cost unless ``hide_cost``, the events' counts unless ``counters`` is False) and ``hint`` (the keys; a stop
    line near). A key is left out when there is nothing to show."""
    nav = session.nav
    ev, ego = nav.world.events, nav.world.ego
    out: dict[str, str] = {}
    prompt = session.prompt_text()
    if prompt is not None:
        out["prompt"] = prompt
    drive = getattr(session, "progress", None) or getattr(session, "title", None)
    if drive:
        out["drive"] = drive
    cost = "" if getattr(session, "hide_cost", False) else f"cost {nav.tracking_cost:6.0f}   "
    counts = (f"collisions {ev.vehicle_collisions}   kerb {ev.edge_strikes}   missed {nav.missed_turns}   "
              f"re-routes {nav.reroutes}") if getattr(session, "counters", True) else ""
    out["status"] = f"t {nav.world.time:5.1f} s   {ego.speed * 3.6:4.0f} km/h   {cost}{counts}".rstrip()
    hint = "arrows/WASD: steer, throttle, brake   P: pause   Esc: stop (asks first)"
    if ego.stop_ahead is not None and ego.stop_ahead < 30.0:
        hint = f"give way: stop line in {ego.stop_ahead:3.0f} m   " + hint
    out["hint"] = hint
    return out


def frame_of(session: Any, alpha: float = 1.0) -> Any:
    """What the views show of ``session`` (a :class:`~pernav.play.loop.PlaySession`) with every car ``alpha`` of
    the way from its last frame to this one: a :class:`~pernav.play.cameras.Frame`."""
    from highway_env.vehicle.graphics import VehicleGraphics  # lazy: it imports pygame

    nav = session.nav
    world = nav.world
    placed = session.interpolated(alpha)
    cars = []
    for car in world.cars:
        pos, heading = placed.get(id(car), (car.position, car.heading))
        ego = car is world.ego
        colour = EGO_COLOR if ego else tuple(VehicleGraphics.get_color(car)[:3])
        cars.append(CarShape(np.asarray(pos, dtype=float), float(heading), float(car.LENGTH), float(car.WIDTH),
                             colour, ego))
    ego_pos, ego_heading = placed[id(world.ego)]
    route = nav.route
    ahead = route.waypoints[(route.s >= nav.progress) & (route.s <= nav.progress + ROUTE_AHEAD)]
    return Frame(np.asarray(ego_pos, dtype=float), float(ego_heading), cars, ahead, route.destination)
