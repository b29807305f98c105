"""Junction right of way: one arm at a time through a cross junction; roundabout entries yield to the ring."""

from __future__ import annotations

import numpy as np
from highway_env.vehicle.kinematics import Vehicle

from pernav.world.network import ANGLE, Town
from pernav.world.scalars import wrap_angle
from pernav.world.towns import RING_MERGE_ANGLE, RING_RADIUS
from pernav.world.vehicles import PathCar


class RightOfWay:
    """Junction right-of-way: a cross junction is held by cars of one arm at a time (they pass in
    a platoon); a roundabout entry yields to cars on the ring near the merge point."""

    def __init__(self, town: Town) -> None:
        self.town = town
        self.holders: dict[str, dict[int, str]] = {j: {} for j in town.junctions}
        self.world_cars: list = []  # the cars of the current frame (set by World.frame)

    def release_stale(self, cars: list[Vehicle]) -> None:
        alive = None
        for jid, holders in self.holders.items():
            if not holders:  # most junctions are free: nothing to release (nor to look up)
                continue
            if alive is None:
                alive = {id(c): c for c in cars}
            for key in list(holders):
                car = alive.get(key)
                if car is None or not self._involved(car, jid):
                    del holders[key]

    def _involved(self, car: PathCar, jid: str) -> bool:
        lane = car.path[0]
        if self.town.lane_junction.get(lane) == jid:
            return True
        return lane[1].startswith(f"{jid}:i")

    def may_enter_cross(self, car: PathCar, jid: str, arm: str) -> bool:
        holders = self.holders[jid]
        if any(a != arm for k, a in holders.items() if k != id(car)):
            return False
        holders[id(car)] = arm
        return True

    def ring_clear(self, car: PathCar, jid: str, arm: str) -> bool:
        j = self.town.junctions[jid]
        merge = ANGLE[arm] - RING_MERGE_ANGLE
        for other in self.world_cars:
            if other is car:
                continue
            if self.town.lane_junction.get(other.path[0]) != jid or ":r" not in other.path[0][0]:
                continue
            phi = np.arctan2(other.position[1] - j.center[1], other.position[0] - j.center[0])
            delta = wrap_angle(phi - merge) * RING_RADIUS  # > 0: upstream (circulation decreases phase)
            if -7.0 < delta < 16.0:
                return False
        return True
