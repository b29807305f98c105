"""Headless rgb_array rendering with highway-env's pygame graphics (no display needed)."""

from __future__ import annotations

import os

os.environ.setdefault("PYGAME_HIDE_SUPPORT_PROMPT", "1")  # before pygame loads: its greeting would reach stdout

import numpy as np
import pygame
from highway_env.road.graphics import RoadGraphics, WorldSurface
from highway_env.vehicle.graphics import VehicleGraphics

from pernav.world.constants import ACTION_NAMES


class Renderer:
    """Draws the town around the driver's car, the route ahead and the last instruction."""

    def __init__(self, size: tuple[int, int] = (600, 600), scaling: float = 3.0) -> None:
        pygame.font.init()  # fonts only: pygame.init() would open audio devices
        self.pygame = pygame
        self.size = size
        self.surface = WorldSurface(size, 0, pygame.Surface(size))
        self.surface.scaling = scaling
        self.surface.centering_position = [0.5, 0.5]
        self.font = pygame.font.Font(None, 26)

    def frame(self, env) -> np.ndarray:
        pg, surf, world = self.pygame, self.surface, env.world
        surf.move_display_window_to(world.ego.position)
        RoadGraphics.display(world.road, surf)
        ahead = env.route.waypoints[(env.route.s >= env.progress) & (env.route.s <= env.progress + 250)]
        if len(ahead) > 1:
            pg.draw.lines(surf, (60, 140, 255), False, [surf.vec2pix(p) for p in ahead], 3)
        pg.draw.circle(surf, (255, 80, 80), surf.vec2pix(env.route.destination), 6)
        for car in world.cars:
            VehicleGraphics.display(car, surf, offscreen=True)
        text = f"t={env.time:4.0f}s  {ACTION_NAMES[env.last_instruction]}"
        stats = (f"cost {env.tracking_cost:7.0f}  coll {world.events.vehicle_collisions}  "
                 f"edge {world.events.edge_strikes}  reroutes {env.reroutes}")
        surf.blit(self.font.render(text, True, (255, 255, 255)), (8, 8))
        surf.blit(self.font.render(stats, True, (255, 255, 255)), (8, 32))
        return np.transpose(pg.surfarray.array3d(surf), (1, 0, 2)).copy()

    def close(self) -> None:
        pass
