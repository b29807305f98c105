"""What every car shares: the IDM, braking for a speed ahead, and following an explicit lane path."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from pernav.world.network import LaneIndex
from pernav.world.scalars import clamp, wrap_angle

if TYPE_CHECKING:
    from pernav.world.simulation import World


_IDM_ROOTS: dict[float, np.float64] = {}


def idm_acceleration(speed: float, desired: float, gap: float, closing: float, headway: float,
                     a_max: float, b: float) -> float:
    """Intelligent Driver Model (Treiber) acceleration towards a leader ``gap`` metres ahead."""
    ab = a_max * b
    # np.sqrt(a_max * b) remembered per product (a few driver and traffic constants): the same np.float64
    root = _IDM_ROOTS.get(ab) if type(ab) is float and ab > 0.0 else None  # not for zeros (signed) or NaN
    if root is None:
        root = np.sqrt(ab)
        if type(ab) is float and ab > 0.0 and len(_IDM_ROOTS) < 256:
            _IDM_ROOTS[ab] = root
    s_star = 2.0 + speed * headway + speed * closing / (2.0 * root)
    free = 1.0 - (speed / max(desired, 0.1)) ** 4
    return a_max * (free - (max(s_star, 0.0) / max(gap, 0.1)) ** 2)


def braking_for(speed: float, v_max: float, distance: float) -> float:
    """Constant deceleration needed to be at ``v_max`` after ``distance`` metres (0 if none)."""
    if speed <= v_max + 0.5 or distance < 2.0:  # small excesses are absorbed by the turn itself
        return 0.0
    return (speed**2 - v_max**2) / (2.0 * max(distance, 0.5))


class PathCar:
    """Mixin for cars that follow an explicit lane path (``path[0]`` is the current lane)."""

    world: World
    path: list[LaneIndex]
    s: float

    def advance_path(self) -> None:
        """Move to the next lane of the path once past the end of the current one."""
        town = self.world.town
        lane = town.lane(self.path[0])
        self.s = self.coordinates_on(lane)[0]
        while self.s > lane.length and len(self.path) > 1:
            self.s -= lane.length
            self.passed(self.path.pop(0))
            lane = town.lane(self.path[0])
            self.s = self.coordinates_on(lane)[0]
        self.lane_index, self.lane = self.path[0], lane

    def coordinates_on(self, lane) -> tuple[float, float]:
        """``lane.local_coordinates(self.position)``, remembered for the last lane and position: :meth:`advance_path`
        and :meth:`lane_steering` ask the same of the same lane within one act. Keyed on the lane object (lanes never
        change while driving) and the position's exact bytes, so a hit is the value the call would return."""
        key = self.position.tobytes()
        hit = self.__dict__.get("_local_hit")
        if hit is not None and hit[0] is lane and hit[1] == key:
            return hit[2]
        out = lane.local_coordinates(self.position)
        self._local_hit = (lane, key, out)
        return out

    @property
    def direction(self) -> np.ndarray:
        """highway-env's ``[cos(heading), sin(heading)]``, computed once per heading (it is asked for several
        times per frame: leader searches, closing speeds). Read-only, as it is shared by those callers."""
        h = self.heading
        hit = self.__dict__.get("_direction_hit")
        # by identity: floats are immutable, so the same object is the same heading to the bit (the cache holds
        # on to it, so a new heading is always a new object); anything but a float is not cached. Or by an equal
        # value (a car driving straight on gets a new heading object of the same value each frame), but not for
        # zero, where 0.0 == -0.0 and sin(-0.0) is -0.0 (NaN equals nothing)
        if hit is not None and (hit[0] is h or (isinstance(h, float) and hit[0] == h and h != 0.0)):
            return hit[1]
        d = np.array([np.cos(h), np.sin(h)])
        if isinstance(h, float):  # a Python or numpy float (np.float64 is one)
            d.flags.writeable = False
            self._direction_hit = (h, d)
        return d

    def passed(self, lane: LaneIndex) -> None:
        """Called with each lane the car leaves (a hook: the driver's car keeps a trail)."""

    def distance_along(self, k: int) -> float:
        """Distance from the car to the start of ``path[k]``."""
        town = self.world.town
        d = town.lane(self.path[0]).length - self.s
        for i in range(1, k):
            d += town.lane(self.path[i]).length
        return d

    def lane_steering(self, lateral_tau: float) -> float:
        """highway-env's cascaded lateral controller applied to the path (looks into the next lane)."""
        town = self.world.town
        lane = town.lane(self.path[0])
        s, lat = self.coordinates_on(lane)
        ahead = s + max(self.speed, 1.0) * 0.35
        if ahead > lane.length and len(self.path) > 1:
            nxt = town.lane(self.path[1])
            heading = nxt.heading_at(ahead - lane.length)
        else:
            heading = lane.heading_at(ahead)
        v = max(self.speed, 0.5)
        heading_cmd = np.arcsin(clamp(-lat / lateral_tau / v, -1, 1))
        heading_ref = heading + clamp(heading_cmd, -np.pi / 4, np.pi / 4)
        rate = wrap_angle(heading_ref - self.heading) / 0.25
        slip = np.arcsin(clamp(self.LENGTH / 2 / v * rate, -1, 1))
        return float(np.arctan(2 * np.tan(slip)))

    def speed_constraints(self, horizon: float) -> list[tuple[float, float]]:
        """(distance, max speed) of slower lanes ahead on the path within ``horizon`` metres."""
        town = self.world.town
        out = []
        d = town.lane(self.path[0]).length - self.s
        for i in range(1, len(self.path)):
            if d > horizon:
                break
            lane = town.lane(self.path[i])
            out.append((d, self.lane_speed(lane)))
            d += lane.length
        return out

    def lane_speed(self, lane) -> float:
        return float(lane.speed_limit)
