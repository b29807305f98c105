"""A person at the wheel (pernav.play): the controls read each frame and what the car does with them."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Protocol

import numpy as np

from pernav.world.network import LaneIndex
from pernav.world.scalars import clamp, wrap_angle
from pernav.world.towns import LANE_WIDTH

if TYPE_CHECKING:
    from pernav.world.driver_car import DriverCar

@dataclass(frozen=True)
class ControlInput:
    """One frame of a person's controls. ``steer`` -1 (full left) .. 1 (full right), ``throttle`` and ``brake``
    0 .. 1; ``digital``: on/off keys (the wheel turns at a fixed rate while a key is held and centres when it is
    released; the pedals are all or nothing) rather than a wheel and pedals (the car follows their positions).

    >>> ControlInput(steer=-1.0, throttle=1.0, digital=True).steer
    -1.0
    """

    steer: float = 0.0
    throttle: float = 0.0
    brake: float = 0.0
    digital: bool = False


class ExternalControls(Protocol):
    """What drives a :class:`DriverCar` instead of its simulated driver (``car.external``): ``read`` is asked for
    the controls once per frame. ``keeps_lanes``: the car's lane on a multi-lane road is the controls' own choice
    (the scripted bot changes lanes on the simulated driver's decisions) rather than found from where the car is."""

    keeps_lanes: bool

    def read(self, car: DriverCar) -> ControlInput: ...


class PersonAtTheWheel:
    """The driver's car's frames when a person drives it (``car.external``): find the lanes under the car, apply
    the controls, claim right of way; the simulated driver only listens. A mixin of
    :class:`~pernav.world.driver_car.DriverCar`."""

    KEY_STEER_RATE = 0.9  # rad/s the wheel turns while a steering key is held
    KEY_CENTRE_RATE = 1.2  # rad/s it returns to the centre once released
    KEY_THROTTLE = 2.5  # m/s^2 of a pressed throttle key (x the vehicle's accel_scale), as full pedal
    KEY_BRAKE = 0.7  # share of the vehicle's emergency deceleration a brake key gives (a full pedal: all of it)
    ROLLING = 0.3  # m/s^2 of drag with no pedal pressed
    WHEEL_LAG = 0.12  # s, the car's response to a wheel (as the simulated wheel driver's)
    SWITCH_MARGIN = 0.5  # m a neighbouring lane must fit better before the car is placed on it (no flicker)

    def _act_external(self) -> None:
        """A frame driven by ``self.external``: find the lanes the car is on, read and apply the controls, and
        claim right of way like any car (whether to stop is the person's affair)."""
        self.locate(keep_lane=self.external.keeps_lanes)
        self.apply_inputs(self.external.read(self))
        self.claim_right_of_way()

    def steer_after(self, inputs: ControlInput) -> float:
        """The steering angle (rad) after one frame of ``inputs`` (no state changes)."""
        max_steer, dt = self.driver.vehicle.max_steering, self.world.dt
        target = clamp(inputs.steer, -1.0, 1.0) * max_steer
        if not inputs.digital:
            steer = self.steer + (target - self.steer) * min(1.0, dt / self.WHEEL_LAG)
        elif target != 0.0:
            err = target - self.steer
            steer = self.steer + float(np.sign(err)) * min(abs(err), self.KEY_STEER_RATE * dt)
        else:
            steer = self.steer - float(np.sign(self.steer)) * min(abs(self.steer), self.KEY_CENTRE_RATE * dt)
        return clamp(steer, -max_steer, max_steer)

    def accel_of(self, inputs: ControlInput) -> float:
        """The acceleration (m/s^2) that ``inputs`` ask for."""
        veh = self.driver.vehicle
        throttle, brake = clamp(inputs.throttle, 0.0, 1.0), clamp(inputs.brake, 0.0, 1.0)
        if throttle == 0.0 and brake == 0.0:
            return -self.ROLLING if self.speed > 0.0 else 0.0
        full_brake = veh.max_decel * (self.KEY_BRAKE if inputs.digital else 1.0)
        return throttle * self.KEY_THROTTLE * veh.accel_scale - brake * full_brake

    def apply_inputs(self, inputs: ControlInput) -> None:
        """Set the steering and acceleration of this frame from a person's controls (the same physics follow)."""
        self.steer = self.steer_after(inputs)
        self.accel = self.accel_of(inputs)
        self.brake_input = clamp(inputs.brake, 0.0, 1.0)
        self.action = {"steering": self.steer, "acceleration": self.accel}

    def simulated_controls(self) -> tuple[float, float]:
        """(steering, acceleration) the simulated driver would choose now, from what it heard; its path decisions
        (branches, lane changes) are made on the car's path as when it drives. The scripted bot's brain: the
        wheel stays where it is (the bot's keys move it)."""
        steer = self.steer
        self._act_simulated()
        want = (self.steer, self.accel)
        self.steer = steer
        return want

    def _fit(self, index: LaneIndex) -> float:
        """How far the car is from lane ``index`` (m off its centre line or beyond its ends, plus 2 m per rad of
        heading difference); a lane that is the first piece of a junction's chain of pieces (a turn: stub, arc,
        stub) counts the whole chain."""
        town = self.world.town
        best = np.inf
        junction = town.lane_junction.get(index)
        for _ in range(4):
            lane = town.lane(index)
            s, lat = lane.local_coordinates(self.position)
            ds = max(0.0, -s, s - lane.length)
            dh = abs(wrap_angle(lane.heading_at(clamp(s, 0.0, lane.length)) - self.heading))
            best = min(best, float(np.hypot(lat, ds)) + 2.0 * dh)
            nxt = town.successors[index]
            if len(nxt) != 1 or junction is None or town.lane_junction.get(nxt[0]) != junction:
                break
            index = nxt[0]
        return best

    def _enter(self, index: LaneIndex) -> None:
        """The car is on lane ``index`` now (a person's choice): the path restarts there, and a lane leaving a
        node with several ways out records the movement taken there (as the simulated driver's commit does)."""
        town = self.world.town
        self.path = [index]
        node = index[0]
        ways = town.network.graph.get(node, {})
        if len(ways) > 1:
            if ":r" in node:
                choice = "exit" if ":o" in index[1] else "stay"
            else:
                jid = town.lane_junction.get(index)
                choice = self._movement(index, jid, node.split(":i")[1]) if jid and ":i" in node else None
            if choice is not None:
                self.committed.add(node)
                self.last_choice[node] = choice
        if ":i" in node:
            self.entered_arm = node.split(":i")[1]
        self.advance_path()

    def locate(self, keep_lane: bool = False) -> None:
        """Find the lanes under a person-driven car: along its path while it follows it, the best fitting way on
        at the end of the path (the person's choice at a junction or a roundabout exit), the lane the car moved to
        (another movement through a junction box; another lane of the road unless ``keep_lane``), and anywhere in
        town when it is far from all of them."""
        town = self.world.town
        graph = town.network.graph
        self.advance_path()
        if len(self.path) == 1 and self.s > self.lane.length:
            cur = self.path[0]
            ahead = [nxt for k in range(len(graph[cur[0]][cur[1]])) for nxt in town.successors[(cur[0], cur[1], k)]]
            if ahead:
                self._enter(min(ahead, key=self._fit))
        cur = self.path[0]
        here = self._fit(cur)
        others = [(cur[0], to, k) for to, lanes in graph[cur[0]].items() for k in range(len(lanes))]
        others = [o for o in others if o != cur and not (keep_lane and o[:2] == cur[:2])]
        if others:
            best = min(others, key=self._fit)
            if self._fit(best) < here - self.SWITCH_MARGIN:
                self._enter(best)
                here = self._fit(best)
        if here > 1.5 * LANE_WIDTH:  # far from all of them: anywhere in town (a U-turn, a cut through a corner)
            index, _ = town.lane_grid.closest(self.position, self.heading)
            if index is not None and index != self.path[0]:
                self._enter(index)
        self.extend_forced()
        self.box = town.lane_junction.get(self.path[0])

    def claim_right_of_way(self) -> None:
        """Ask for the junction ahead as any car does (``stop_ahead``: the stop line to respect, if any), and hold
        a cross junction's box while in it, granted or not: the others wait for a car already inside."""
        world, town = self.world, self.world.town
        self.stop_ahead = world.stop_line(self)
        jid = town.lane_junction.get(self.path[0])
        if jid is not None and town.junctions[jid].kind == "cross" and self.entered_arm is not None:
            world.right_of_way.holders[jid].setdefault(id(self), self.entered_arm)
