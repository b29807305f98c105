"""The play window: the town around the car, the route ahead, the prompt with the distance to its manoeuvre.

Drawn with highway-env's pygame graphics; the town's roads are drawn once onto a large surface and each frame
shows the part around the car (drawing every lane each frame would cost more than the simulation). Cars may be
drawn between two simulation frames (``alpha``) so the picture moves smoothly at more frames than the world has.

Example (no display needed: an off-screen surface):
    >>> from pernav.play.loop import PlaySession
    >>> session = PlaySession("Town1", 0, n_traffic=2, draw=True)
    >>> session.view.surface.get_size()
    (960, 720)
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np

os.environ.setdefault("PYGAME_HIDE_SUPPORT_PROMPT", "1")

__all__ = ["DisplayError", "PlayView"]

EGO_COLOR = (50, 200, 0)
PROMPT_SECONDS = 5.0  # a played prompt stays on screen this long after its audio


class DisplayError(ValueError):
    """No display for the play window."""


class PlayView:
    """A window (``window=True``) or an off-screen surface of ``size`` pixels at ``scaling`` pixels per metre."""

    def __init__(self, town: Any, size: tuple[int, int] = (960, 720), scaling: float = 6.0, window: bool = False) -> None:
        import pygame
        from highway_env.road.graphics import RoadGraphics, WorldSurface

        self.pygame = pygame
        self.window = window
        if window:
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
        self.world = WorldSurface(size, 0, pygame.Surface(size))
        self.world.scaling = scaling
        # the town's roads, drawn once
        x0, x1, y0, y1 = town.bounds(margin=60.0)
        self.road_origin = np.array([x0, y0])
        road = WorldSurface((int((x1 - x0) * scaling), int((y1 - y0) * scaling)), 0,
                            pygame.Surface((int((x1 - x0) * scaling), int((y1 - y0) * scaling))))
        road.scaling, road.origin = scaling, self.road_origin
        RoadGraphics.display(_RoadOnly(town.network), road)
        self.road = road
        self.big = pygame.font.Font(None, 54)
        self.font = pygame.font.Font(None, 28)
        self.small = pygame.font.Font(None, 22)

    def draw(self, session: Any, alpha: float = 1.0) -> None:
        """Draw ``session``'s world with every car ``alpha`` of the way from its last frame to this one."""
        from highway_env.vehicle.graphics import VehicleGraphics

        from pernav.world.layout import ACTION_NAMES

        pg, surf, nav = self.pygame, self.world, session.nav
        world = nav.world
        placed = session.interpolated(alpha)
        ego_pos = placed[id(world.ego)][0]
        surf.move_display_window_to(ego_pos)
        surf.fill(surf.GREY)
        offset = (surf.origin - self.road_origin) * self.scaling
        surf.blit(self.road, (0, 0), area=pg.Rect(int(offset[0]), int(offset[1]), *self.size))
        route = nav.route
        ahead = route.waypoints[(route.s >= nav.progress) & (route.s <= nav.progress + 250)]
        if len(ahead) > 1:
            pg.draw.lines(surf, (60, 140, 255), False, [surf.vec2pix(p) for p in ahead], 3)
        pg.draw.circle(surf, (255, 80, 80), surf.vec2pix(route.destination), 6)
        for car in world.cars:
            pos, heading = placed.get(id(car), (car.position, car.heading))
            saved = car.position, car.heading
            car.position, car.heading = pos, heading  # drawn where it is between two frames
            if car is world.ego:
                car.color = EGO_COLOR
            try:
                VehicleGraphics.display(car, surf, offscreen=True)
            finally:
                car.position, car.heading = saved
        out = self.surface
        out.blit(surf, (0, 0))
        self._hud(session, ACTION_NAMES)

    def _hud(self, session: Any, names: tuple[str, ...]) -> None:
        pg, out, nav = self.pygame, self.surface, session.nav
        w, h = self.size
        prompt = session.prompt_text()
        if prompt is not None:
            band = pg.Surface((w, 70), pg.SRCALPHA)
            band.fill((0, 0, 0, 170))
            out.blit(band, (0, 0))
            text = self.big.render(prompt, True, (255, 255, 255))
            out.blit(text, ((w - text.get_width()) // 2, 12))
        ev, ego = nav.world.events, nav.world.ego
        cost = "" if getattr(session, "hide_cost", False) else f"cost {nav.tracking_cost:6.0f}   "
        status = (f"t {nav.world.time:5.1f} s   {ego.speed * 3.6:4.0f} km/h   {cost}"
                  f"collisions {ev.vehicle_collisions}   kerb {ev.edge_strikes}   missed {nav.missed_turns}   "
                  f"re-routes {nav.reroutes}")
        band = pg.Surface((w, 30), pg.SRCALPHA)
        band.fill((0, 0, 0, 150))
        out.blit(band, (0, h - 56))
        out.blit(self.font.render(status, True, (255, 255, 255)), (10, h - 52))
        hint = "arrows/WASD: steer, throttle, brake   P: pause   Esc: stop (asks first)"
        if ego.stop_ahead is not None and ego.stop_ahead < 30.0:
            hint = f"give way: stop line in {ego.stop_ahead:3.0f} m   " + hint
        out.blit(self.small.render(hint, True, (230, 230, 230)), (10, h - 22))

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


class _RoadOnly:
    """What ``RoadGraphics.display`` reads of a road: its network."""

    def __init__(self, network: Any) -> None:
        self.network = network
