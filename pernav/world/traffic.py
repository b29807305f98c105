"""IDM traffic on random lane paths, with right of way and a following car with a perception delay."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from highway_env.road.lane import CircularLane
from highway_env.vehicle.behavior import IDMVehicle
from highway_env.vehicle.kinematics import Vehicle

from pernav.world.network import LaneIndex
from pernav.world.scalars import clamp
from pernav.world.vehicles import PathCar, braking_for, idm_acceleration

if TYPE_CHECKING:
    from pernav.world.driver_car import DriverCar
    from pernav.world.simulation import World

class TrafficCar(PathCar, IDMVehicle):
    """IDM traffic (highway-env ``IDMVehicle``) on a random lane path, with right-of-way."""

    def __init__(self, world: World, lane: LaneIndex, s: float, speed: float, desired: float,
                 follow: DriverCar | None = None, headway: float = 1.5, reaction: float = 0.0) -> None:
        town = world.town
        ln = town.lane(lane)
        super().__init__(world.road, ln.position(s, 0.0), ln.heading_at(s), speed, target_lane_index=lane,
                         enable_lane_change=False)
        self.world = world
        self.path = [lane]
        self.s = s
        self.desired = desired
        self.stuck_time = 0.0
        # a follower drives behind the navigated car on its lanes, with its own headway and a
        # perception-reaction delay (the IDM with reaction time: Treiber, Kesting & Helbing 2006)
        self.follow = follow  # the car it follows (perceived late), whose lanes it takes while ``tracking``
        self.tracking = follow is not None
        self.headway = headway
        self.lag = max(int(round(reaction / world.dt)), 0)
        self.odometer = 0.0
        self.seen: list[tuple[float, float, float, float]] = []  # (odometer, gap, its speed, its acceleration)
        self.extend()

    def on_state_update(self) -> None:  # highway-env searches every lane here; we follow the path
        pass

    def extend(self) -> None:
        if self.tracking and self._extend_following():
            return
        succ = self.world.town.successors
        rng = self.world.rng
        while len(self.path) < 5:
            options = succ[self.path[-1]]
            if len(options) > 1 and any(":r" in o[1] and o[1].endswith("e") for o in options):
                # on the ring: take an exit with probability 0.45, else keep circling
                exits = [o for o in options if ":o" in o[1]]
                stay = [o for o in options if o not in exits]
                options = exits if (exits and rng.random() < 0.45) or not stay else stay
            self.path.append(options[int(rng.integers(len(options)))])

    def _extend_following(self) -> bool:
        """Extend the path with the lanes the followed car took after ours; False (and stops
        tracking it) once the followed car is on lanes this car's path does not lead to."""
        seq = self.follow.trail + self.follow.path
        last = self.path[-1]
        idx = max((i for i, lane in enumerate(seq) if lane == last), default=None)
        if idx is None:
            self.tracking = False
            return False
        self.path.extend(seq[idx + 1: idx + 6 - len(self.path)])
        return True

    def perceived(self, gap: float, lead_v: float, lead_a: float) -> tuple[float, float]:
        """The followed car as this driver sees it: as it was a reaction time ago, extrapolated with the
        speed and deceleration it had then (the anticipation of Treiber's Human Driver Model). A car ahead
        that brakes steadily is seen where it is; a sudden hard brake is seen a reaction time late."""
        self.seen = [*self.seen[-self.lag:], (self.odometer, gap, lead_v, lead_a)]
        if len(self.seen) <= self.lag:
            return gap, lead_v
        odo, gap_then, v, a = self.seen[0]
        t = self.lag * self.world.dt
        if a < 0 and v + a * t < 0:  # seen to stop within the reaction time
            moved, v_now = v * v / (-2 * a), 0.0
        else:
            moved, v_now = v * t + 0.5 * a * t * t, v + a * t
        return gap_then - (self.odometer - odo) + moved, v_now

    def lane_speed(self, lane) -> float:
        limit = float(lane.speed_limit)
        if isinstance(lane, CircularLane):
            return min(limit, 7.0)
        return limit

    def act(self, action=None) -> None:
        self.advance_path()
        self.extend()
        world = self.world
        desired = min(self.desired, self.lane_speed(self.lane))
        acc = idm_acceleration(self.speed, desired, np.inf, 0.0, 1.5, 2.5, 4.0)
        for d, vmax in self.speed_constraints(40.0):
            need = braking_for(self.speed, vmax, d)
            if need > 1.0:
                acc = min(acc, -need)
        leader, gap = world.leader_of(self)
        if leader is not None:
            lead_v = float(np.dot(leader.velocity, self.direction))
            if leader is self.follow and self.lag:
                gap, lead_v = self.perceived(gap, lead_v, leader.accel)
            acc = min(acc, idm_acceleration(self.speed, desired, gap, self.speed - lead_v, self.headway, 2.5, 4.0))
        stop = world.stop_line(self)
        if stop is not None:
            acc = min(acc, idm_acceleration(self.speed, desired, stop, self.speed, 1.0, 2.5, 4.0))
        steering = clamp(self.lane_steering(0.6), -self.MAX_STEERING_ANGLE, self.MAX_STEERING_ANGLE)
        Vehicle.act(self, {"steering": steering, "acceleration": clamp(acc, -7.0, 3.0)})

    def step(self, dt: float) -> None:
        Vehicle.step(self, dt)
        self.speed = max(self.speed, 0.0)
        self.odometer += self.speed * dt
        self.stuck_time = self.stuck_time + dt if self.speed < 0.2 else 0.0
