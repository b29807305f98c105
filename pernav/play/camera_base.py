"""What every view of the play window draws and how it is asked to: the instant it shows (:class:`Frame`: the cars
as :class:`CarShape`, the route ahead), the fog of the context's weather (:class:`Fog`) and the interface of a view
(:class:`Camera`). The views themselves: :mod:`pernav.play.cameras` (the map views and :func:`make_camera`),
:mod:`pernav.play.seat` (the driver's seat).

Example:
    >>> Fog.for_visual("normal", "top") is None
    True
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from pernav.play.scene import TownScene
from pernav.world.drivers import Context, DriverProfile, resolve

__all__ = ["Camera", "CarShape", "Fog", "Frame"]


@dataclass(frozen=True)
class CarShape:
    """A car as a view draws it: centre (m), heading (rad, y down), length and width (m), colour, and whether it is
    the person's own car."""

    position: np.ndarray
    heading: float
    length: float
    width: float
    colour: tuple[int, int, int]
    ego: bool = False


@dataclass
class Frame:
    """What a view shows at one instant: the person's car (position, heading), every car, the route's waypoints
    ahead of the car (``[n, 2]``, in order) and the destination."""

    ego: np.ndarray
    heading: float
    cars: list[CarShape] = field(default_factory=list)
    route: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    destination: np.ndarray | None = None

    @property
    def forward(self) -> np.ndarray:
        return np.array([math.cos(self.heading), math.sin(self.heading)])

    @property
    def right(self) -> np.ndarray:  # y down: the right of heading east is south
        return np.array([-math.sin(self.heading), math.cos(self.heading)])


@dataclass(frozen=True)
class Fog:
    """Visibility with distance: clear up to ``clear`` metres, then thickening to the fog colour at ``opaque``
    metres and beyond.

    >>> fog = Fog(clear=10.0, opaque=30.0)
    >>> fog.alpha(np.array([5.0, 20.0, 50.0])).tolist()
    [0.0, 127.5, 255.0]
    """

    clear: float
    opaque: float

    def alpha(self, distance: np.ndarray) -> np.ndarray:
        """Opacity (0 clear .. 255 fog colour) at ``distance`` metres."""
        return 255.0 * np.clip((distance - self.clear) / (self.opaque - self.clear), 0.0, 1.0)

    @staticmethod
    def for_visual(visual: str, camera: str) -> Fog | None:
        """The fog of a context's ``visual`` condition seen through ``camera`` (None: clear): opaque at the sight
        distance the simulated driver has in that context (:func:`pernav.world.drivers.resolve`, 30-49 m in fog),
        thinning to clear at 40 % of it."""
        if visual != "foggy":
            return None
        sight = resolve(DriverProfile(), Context(camera=camera, visual=visual)).sight_distance
        return Fog(clear=0.4 * sight, opaque=sight)


class Camera(ABC):
    """A view of a town on a surface of ``size`` pixels."""

    name: str

    def __init__(self, scene: TownScene, size: tuple[int, int]) -> None:
        self.scene, self.size = scene, size

    @abstractmethod
    def draw(self, out: Any, frame: Frame, fog: Fog | None = None) -> None:
        """Draw ``frame`` onto the pygame surface ``out`` (every pixel), fogged by ``fog``."""

    @abstractmethod
    def basis(self, frame: Frame) -> np.ndarray:
        """``[2, 2]``: a world direction times this is its direction on the screen (x right, y down)."""
