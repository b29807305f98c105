"""The simulated world: a driver who hears voice instructions, IDM traffic with right-of-way, events.

One :class:`World` holds a town's highway-env ``Road``, the driver's car (:class:`DriverCar`) and
traffic (:class:`TrafficCar`), both highway-env vehicles. ``World.frame()`` advances one simulation
frame; the gymnasium env runs ``frequency`` frames per policy step.

How timing matters (docs/simulator.md): an instruction is acted on after its audio plus the driver's reaction
time; the driver commits to a branch ``decision_time`` seconds before a junction; a turn instruction
that arrives after that makes it swerve (hard braking, running wide: curb strikes, collisions) or miss
the turn; one heard too early is forgotten after ``memory`` seconds or applied at an earlier junction.

Example:
    >>> from pernav.world.towns import get_town
    >>> from pernav.world.drivers import resolve, named_user, Context
    >>> town = get_town("Town1")
    >>> world = World(town, resolve(named_user("user1"), Context()), town.routes[0], seed=0)
    >>> for _ in range(10):
    ...     world.frame()
    >>> world.ego.speed > 0
    True
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np
from highway_env import utils
from highway_env.road.lane import CircularLane
from highway_env.road.road import Road
from highway_env.vehicle.behavior import IDMVehicle
from highway_env.vehicle.kinematics import Vehicle

from pernav.world.drivers import Driver
from pernav.world.layout import audio_duration
from pernav.world.routing import Route
from pernav.world.towns import (
    ANGLE,
    LANE_WIDTH,
    RING_MERGE_ANGLE,
    RING_RADIUS,
    SPEED_RING,
    LaneIndex,
    Town,
    turn_direction,
)

#: the world's version: 2 adds per-prompt reaction times, a following car with a perception delay, gap
#: acceptance in lane changes and the truck's earlier set-up (docs/simulator.md, "World v2")
WORLD_VERSION = 2

# --------------------------------------------------------------------------------------------------
# Instructions

@dataclass
class Heard:
    """An instruction the driver understood: usable from ``active_at`` until ``expires_at``."""

    instruction: int
    heard_at: float
    active_at: float
    expires_at: float

    @property
    def direction(self) -> str | None:
        return {1: "left", 2: "right", 3: "left", 4: "right"}.get(self.instruction)


@dataclass
class Events:
    """Counters of what happened to the driver's car."""

    vehicle_collisions: int = 0
    edge_strikes: int = 0
    traffic_collisions: int = 0  # traffic-traffic (should stay 0)
    harsh_brakes: int = 0
    swerves: int = 0
    forgotten: int = 0  # instructions that faded from memory unused
    discarded: int = 0  # instructions dropped on entering a junction (too late for it)
    misunderstood: int = 0
    ignored: int = 0
    log: list = field(default_factory=list)


# --------------------------------------------------------------------------------------------------
# Helpers shared by all cars


def _wrap(a: float) -> float:
    return (a + np.pi) % (2 * np.pi) - np.pi


def _clamp(x: float, lo: float, hi: float) -> float:
    """``np.clip`` of one scalar, to the same value (NaN passes through), ~10x faster: the simulator clamps
    several scalars per car and frame, which made ``np.clip`` 14 % of an episode's time."""
    return float(min(max(x, lo), hi))


def idm_acceleration(speed: float, desired: float, gap: float, closing: float, headway: float,
                     a_max: float, b: float) -> float:
    """Intelligent Driver Model (Treiber) acceleration towards a leader ``gap`` metres ahead."""
    s_star = 2.0 + speed * headway + speed * closing / (2.0 * np.sqrt(a_max * b))
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
        self.s = lane.local_coordinates(self.position)[0]
        while self.s > lane.length and len(self.path) > 1:
            self.s -= lane.length
            self.passed(self.path.pop(0))
            lane = town.lane(self.path[0])
            self.s = lane.local_coordinates(self.position)[0]
        self.lane_index, self.lane = self.path[0], lane

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
        s, lat = lane.local_coordinates(self.position)
        ahead = s + max(self.speed, 1.0) * 0.35
        if ahead > lane.length and len(self.path) > 1:
            nxt = town.lane(self.path[1])
            heading = nxt.heading_at(ahead - lane.length)
        else:
            heading = lane.heading_at(ahead)
        v = max(self.speed, 0.5)
        heading_cmd = np.arcsin(_clamp(-lat / lateral_tau / v, -1, 1))
        heading_ref = heading + _clamp(heading_cmd, -np.pi / 4, np.pi / 4)
        rate = _wrap(heading_ref - self.heading) / 0.25
        slip = np.arcsin(_clamp(self.LENGTH / 2 / v * rate, -1, 1))
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


# --------------------------------------------------------------------------------------------------
# Right of way


class RightOfWay:
    """Junction right-of-way: a cross junction is held by cars of one arm at a time (they pass in
    a platoon); a roundabout entry yields to cars on the ring near the merge point."""

    def __init__(self, town: Town) -> None:
        self.town = town
        self.holders: dict[str, dict[int, str]] = {j: {} for j in town.junctions}
        self.world_cars: list = []  # the cars of the current frame (set by World.frame)

    def release_stale(self, cars: list[Vehicle]) -> None:
        alive = {id(c): c for c in cars}
        for jid, holders in self.holders.items():
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
            delta = _wrap(phi - merge) * RING_RADIUS  # > 0: upstream (circulation decreases phase)
            if -7.0 < delta < 16.0:
                return False
        return True


# --------------------------------------------------------------------------------------------------
# Traffic


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
        steering = _clamp(self.lane_steering(0.6), -self.MAX_STEERING_ANGLE, self.MAX_STEERING_ANGLE)
        Vehicle.act(self, {"steering": steering, "acceleration": _clamp(acc, -7.0, 3.0)})

    def step(self, dt: float) -> None:
        Vehicle.step(self, dt)
        self.speed = max(self.speed, 0.0)
        self.odometer += self.speed * dt
        self.stuck_time = self.stuck_time + dt if self.speed < 0.2 else 0.0


# --------------------------------------------------------------------------------------------------
# A person at the wheel (pernav.play): the extension point of the driver's car


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


# --------------------------------------------------------------------------------------------------
# The driver's car


class DriverCar(PathCar, Vehicle):
    """The navigated car, driven by a simulated driver who knows only what it has heard."""

    SWERVE_REACH = 0.35  # a late turn is still tried this fraction of the way through a junction box
    SKID_RATIO = 1.5  # lateral acceleration asked / grip beyond which a swerving car slides
    SKID_TIME = 0.3  # s of sliding that carries the car over the kerb

    def __init__(self, world: World, driver: Driver, lane: LaneIndex, s: float) -> None:
        town = world.town
        ln = town.lane(lane)
        super().__init__(world.road, ln.position(s, 0.0), ln.heading_at(s), 0.0)
        self.LENGTH, self.WIDTH = driver.vehicle.length, driver.vehicle.width
        self.world = world
        self.driver = driver
        self.path = [lane]
        self.s = s
        self.lane_index, self.lane = lane, ln
        self.steer = 0.0
        self.accel = 0.0
        self.brake_input = 0.0
        self.heard: list[Heard] = []
        self.committed: set[str] = set()  # decision nodes already decided
        self.swerving_until = -1.0
        self.skid_time = 0.0  # s the tyres have been saturated during the current swerve
        self.ran_wide = False  # a swerve slid the car wide over the kerb (counted once per swerve)
        self.off_road = False
        self.in_contact: set[int] = set()
        self.last_choice: dict[str, str] = {}  # decision node -> movement taken
        self.box: str | None = None  # junction whose lanes the car is on
        self.approach_options: dict[str, dict[str, list[LaneIndex]]] = {}  # movements seen at commit
        self.trail: list[LaneIndex] = []  # the last lanes the car left (a follower drives along them)
        # a person's controls (pernav.play): when set, they drive the car and the simulated driver only listens
        self.external: ExternalControls | None = None
        self.entered_arm: str | None = None  # arm of the cross junction a person's car entered last
        self.stop_ahead: float | None = None  # m to a stop line the person should respect (None: none)

    def on_state_update(self) -> None:
        pass

    def passed(self, lane: LaneIndex) -> None:
        self.trail = [*self.trail[-7:], lane]

    # ----- hearing ----------------------------------------------------------------------------
    def hear(self, instruction: int, playback: str, now: float) -> None:
        """The instruction was played: understood (or misheard) and acted on after audio + reaction."""
        if instruction == 0:
            return
        d, ev = self.driver, self.world.events
        heard, swapped, complied = self.world.driver_rng.random(3)  # four draws per play, always
        reaction = d.reaction_draw(float(self.world.driver_rng.standard_normal()))  # this prompt's reaction
        if heard > d.understanding(playback):
            if instruction in (1, 2, 3, 4) and swapped < 0.5:  # misheard left <-> right
                instruction = {1: 2, 2: 1, 3: 4, 4: 3}[instruction]
                ev.misunderstood += 1
            else:
                ev.misunderstood += 1
                return
        if complied > d.compliance:
            ev.ignored += 1
            return
        active = now + audio_duration(instruction, playback) + reaction
        if instruction in (1, 2):  # a new turn instruction replaces older ones
            self.heard = [h for h in self.heard if h.instruction not in (1, 2, 6)]
        elif instruction in (3, 4):
            self.heard = [h for h in self.heard if h.instruction not in (3, 4)]
        elif instruction == 6:
            self.heard = [h for h in self.heard if h.instruction not in (1, 2)]
        self.heard.append(Heard(instruction, now, active, active + d.memory))

    def active(self, now: float, kinds: tuple[int, ...]) -> Heard | None:
        for h in reversed(self.heard):
            if h.instruction in kinds and h.active_at <= now < h.expires_at:
                return h
        return None

    def forget(self, now: float) -> None:
        for h in self.heard:
            if h.expires_at <= now:
                self.world.events.forgotten += 1
        self.heard = [h for h in self.heard if h.expires_at > now]

    def consume(self, kinds: tuple[int, ...], now: float) -> None:
        self.heard = [h for h in self.heard if not (h.instruction in kinds and h.active_at <= now)]

    # ----- perception of the path ---------------------------------------------------------------
    def extend_forced(self, horizon: float = 120.0) -> None:
        """Append lanes with a single successor (no decision) up to ``horizon`` metres ahead."""
        succ = self.world.town.successors
        while self.distance_along(len(self.path)) < horizon:
            options = succ[self.path[-1]]
            if len(options) != 1 or self._branches(self.path[-1]) > 1:
                return
            self.path.append(options[0])

    def _branches(self, lane: LaneIndex) -> int:
        """Movements the road of ``lane`` offers at its end: on a multi-lane approach to a cross
        junction each lane may lead elsewhere (left lane: left, right lane: right), so the choice
        of movement includes the lanes beside the driver's own."""
        town = self.world.town
        n = len(town.network.graph[lane[0]][lane[1]])
        if n == 1 or ":i" not in lane[1]:
            return len(town.successors[lane])
        j = town.junction_of_node(lane[1])
        if j is None or j.kind != "cross":
            return len(town.successors[lane])
        return len({nxt for k in range(n) for nxt in town.successors[(lane[0], lane[1], k)]})

    def decision_node(self) -> tuple[str, float] | None:
        """The next node where the driver must choose, and the distance to it."""
        last = self.path[-1]
        if self._branches(last) > 1:
            return last[1], self.distance_along(len(self.path))
        return None

    def _options(self, node: str) -> dict[str, list[LaneIndex]]:
        """Movements available at ``node`` from the current road: movement -> lanes to append."""
        town = self.world.town
        last = self.path[-1]
        jid = node.split(":")[0]
        options: dict[str, list[LaneIndex]] = {}
        if ":r" in node:  # ring exit point: exit or keep circling
            for nxt in town.successors[last]:
                options["exit" if ":o" in nxt[1] else "stay"] = [nxt]
            return options
        arm_in = node.split(":i")[1]
        siblings = [(last[0], last[1], k) for k in range(len(town.network.graph[last[0]][last[1]]))]
        # own lane first: prefer movements that do not need a lane change
        for lane in sorted(siblings, key=lambda x: x != last):
            for nxt in town.successors[lane]:
                move = self._movement(nxt, jid, arm_in)
                if move not in options:
                    options[move] = [lane, nxt] if lane != last else [nxt]
        return options

    def _movement(self, first: LaneIndex, jid: str, arm_in: str) -> str:
        town = self.world.town
        lane = first
        while not lane[1].startswith(f"{jid}:o"):
            lane = town.successors[lane][0]
        return turn_direction(arm_in, lane[1].split(":o")[1])

    def commit(self, node: str, now: float, late: bool = False) -> None:
        """Choose the branch at ``node`` from what the driver has heard, and extend the path."""
        # two draws per decision, always; a late re-commit (swerve) is the same decision made again
        # on a turn instruction and draws nothing, so that the k-th decision of two policies driving
        # the same seed faces the same draws whether or not one of them made the driver swerve
        follow_prep, pick = (0.0, 0.0) if late else self.world.guess_rng.random(2)
        options = self._options(node)
        turn = self.active(now, (1, 2))
        prep = self.active(now, (3, 4))
        if ":r" in node:
            choice = "exit" if turn is not None and "exit" in options else "stay"
            if choice == "exit":
                self.consume((1, 2), now)
        else:
            choice = None
            if turn is not None and turn.direction in options:
                choice = turn.direction
                self.consume((1, 2, 3, 4), now)
            elif prep is not None and prep.direction in options and follow_prep < 0.5:
                choice = prep.direction
                self.consume((3, 4), now)
            if choice is None:
                choice = "straight" if "straight" in options else sorted(options)[int(pick * len(options))]
        self.approach_options[node] = options
        lanes = options[choice]
        if len(lanes) == 2:  # a hurried lane change right before the junction: no time to wait for a gap
            self.path[-1] = lanes[0]
            lanes = lanes[1:]
        self.path.extend(lanes)
        self.committed.add(node)
        self.last_choice[node] = choice
        if late:
            self.swerving_until = now + 3.0
            self.world.events.swerves += 1

    def recommit(self, node: str, k: int, now: float) -> None:
        """A turn instruction arrived after the branch was chosen: swerve into it (docs/simulator.md)."""
        del self.path[k:]
        self.committed.discard(node)
        self.commit(node, now, late=True)
        self.extend_forced()

    # ----- control ------------------------------------------------------------------------------
    def act(self, action=None) -> None:
        if self.external is not None:  # a person drives (pernav.play): the simulated driver only listens
            self._act_external()
            return
        self._act_simulated()

    def _act_simulated(self) -> None:
        """The simulated driver's frame: path decisions from what it heard, speed and steering."""
        world, d = self.world, self.driver
        now = world.time
        self.advance_path()
        self.forget(now)
        self.extend_forced()
        v = max(self.speed, 0.0)
        v_seen = v * d.speed_misjudgement
        town = world.town

        # branch decisions
        node_dist = self.decision_node()
        if node_dist is not None:
            node, dist = node_dist
            if dist <= max(d.decision_time * v, 4.0):
                self.commit(node, now)
                self.extend_forced()
        turn = self.active(now, (1, 2))
        # late instruction after the commit: swerve if still before the stop line or just past it
        # (docs/simulator.md: harsh braking, sharp steering, running wide), otherwise the turn is missed
        approach = self.path[0][1]
        if turn is not None and approach in self.committed and ":i" in approach and len(self.path) > 1:
            dist = town.lane(self.path[0]).length - self.s
            if dist > 0.0 and self.last_choice.get(approach) != turn.direction:
                if turn.direction in self._options_at(1, approach):
                    self.recommit(approach, 1, now)
        elif turn is not None and self.path[0][0] in self.committed and ":i" in self.path[0][0] \
                and self.s < self.SWERVE_REACH * town.lane(self.path[0]).length \
                and self.last_choice.get(self.path[0][0]) == "straight":
            # already in the box, going straight: a panicked driver still yanks the wheel while the
            # turn's exit is ahead (at speed the car cannot make it: it runs wide over the kerb)
            node = self.path[0][0]
            lanes = self.approach_options[node].get(turn.direction)
            if lanes:
                self.path = list(lanes[-1:])
                self.last_choice[node] = turn.direction
                self.swerving_until = now + 3.0
                world.events.swerves += 1
                self.advance_path()
                self.extend_forced()
        # entering a junction box: what was heard before it was meant for this junction
        in_box = town.lane_junction.get(self.path[0])
        if in_box is not None and in_box != self.box and town.junctions[in_box].kind == "cross":
            dropped = [h for h in self.heard if h.instruction in (1, 2, 3, 4) and h.heard_at < now]
            world.events.discarded += len(dropped)
            self.heard = [h for h in self.heard if h not in dropped]
        self.box = in_box

        # speed: cruise, slower lanes, planned turns, roundabouts, leader, right of way
        limit = self.lane_speed(self.lane)
        cruise = limit * d.speed_factor
        acc = idm_acceleration(v, cruise, np.inf, 0.0, d.time_headway, d.comfort_accel, d.comfort_decel)
        needs = []
        for dist, vmax in self.speed_constraints(max(d.sight_distance, 60.0)):
            needs.append(braking_for(v_seen, vmax, dist - 1.0))
        nd = self.decision_node()
        if nd is not None and ":i" in nd[0]:
            node, dist = nd
            j = town.junction_of_node(node)
            expect = self.active(now, (1, 2)) or self.active(now, (3, 4))
            if j is not None and dist < d.sight_distance:
                if j.kind == "roundabout":
                    needs.append(braking_for(v_seen, self.ring_speed(), dist))
                elif expect is not None:
                    target = d.turn_speed if expect.instruction in (1, 2) else 0.5 * (d.turn_speed + cruise)
                    needs.append(braking_for(v_seen, target, dist))
        if self.active(now, (5,)) is not None and nd is not None:
            j = town.junction_of_node(nd[0])
            if j is not None and j.kind == "roundabout":
                needs.append(braking_for(v_seen, self.ring_speed(), nd[1]))
        prep = self.active(now, (3, 4))
        if prep is not None and town.lane_junction.get(self.path[0]) is None:
            acc = min(acc, idm_acceleration(v, 0.75 * cruise, np.inf, 0, 1, d.comfort_accel, d.comfort_decel))
            self.lane_for(prep.direction)
        elif (heard_turn := self.active(now, (1, 2))) is not None:  # a turn without its "prepare": its lane
            self.lane_for(heard_turn.direction)
        need = max(needs, default=0.0)
        harsh_limit = d.vehicle.max_decel
        if need > 0.55 * d.comfort_decel:
            if need > 1.5 * d.comfort_decel and self.accel > -d.comfort_decel:
                world.events.harsh_brakes += 1
            acc = min(acc, -min(need, harsh_limit))
        leader, gap = world.leader_of(self)
        if leader is not None:
            closing = v - float(np.dot(leader.velocity, self.direction))
            acc = min(acc, idm_acceleration(v, cruise, gap, closing, d.time_headway, d.comfort_accel,
                                            d.comfort_decel))
        stop = world.stop_line(self)
        if stop is not None:
            acc = min(acc, idm_acceleration(v, cruise, stop, v, 1.0, d.comfort_accel, d.comfort_decel))
        if now < self.swerving_until:
            acc = min(acc, -0.8 * harsh_limit) if v > d.turn_speed else acc
        acc = _clamp(acc, -harsh_limit, d.comfort_accel * 1.5)

        steer_cmd = self.lane_steering(d.steering_tau)
        if now < self.swerving_until - 1.5:  # panic: a sharp, over-corrected yank of the wheel
            steer_cmd *= 1.8
        if d.keyboard:  # on/off keys: pedals in steps, steering ramps at a fixed rate
            acc = 0.0 if abs(acc) < 0.4 else (d.comfort_accel * 1.3 if acc > 0 else min(acc * 1.25, -1.5))
            acc = max(acc, -harsh_limit)
            err = steer_cmd - self.steer
            if abs(err) > 0.035:
                self.steer += np.sign(err) * min(abs(err), 1.6 * world.dt)
        else:
            self.steer += (steer_cmd - self.steer) * min(1.0, world.dt / 0.12)
        self.steer = _clamp(self.steer, -d.vehicle.max_steering, d.vehicle.max_steering)
        self.accel = acc
        self.brake_input = _clamp(-acc / harsh_limit, 0.0, 1.0)
        self.action = {"steering": self.steer, "acceleration": acc}

    # ----- a person at the wheel (pernav.play) --------------------------------------------------------
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
        target = _clamp(inputs.steer, -1.0, 1.0) * max_steer
        if not inputs.digital:
            steer = self.steer + (target - self.steer) * min(1.0, dt / self.WHEEL_LAG)
        elif target != 0.0:
            err = target - self.steer
            steer = self.steer + float(np.sign(err)) * min(abs(err), self.KEY_STEER_RATE * dt)
        else:
            steer = self.steer - float(np.sign(self.steer)) * min(abs(self.steer), self.KEY_CENTRE_RATE * dt)
        return _clamp(steer, -max_steer, max_steer)

    def accel_of(self, inputs: ControlInput) -> float:
        """The acceleration (m/s^2) that ``inputs`` ask for."""
        veh = self.driver.vehicle
        throttle, brake = _clamp(inputs.throttle, 0.0, 1.0), _clamp(inputs.brake, 0.0, 1.0)
        if throttle == 0.0 and brake == 0.0:
            return -self.ROLLING if self.speed > 0.0 else 0.0
        full_brake = veh.max_decel * (self.KEY_BRAKE if inputs.digital else 1.0)
        return throttle * self.KEY_THROTTLE * veh.accel_scale - brake * full_brake

    def apply_inputs(self, inputs: ControlInput) -> None:
        """Set the steering and acceleration of this frame from a person's controls (the same physics follow)."""
        self.steer = self.steer_after(inputs)
        self.accel = self.accel_of(inputs)
        self.brake_input = _clamp(inputs.brake, 0.0, 1.0)
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
            dh = abs(_wrap(lane.heading_at(_clamp(s, 0.0, lane.length)) - self.heading))
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
            world.row.holders[jid].setdefault(id(self), self.entered_arm)

    def _options_at(self, k: int, node: str) -> dict[str, list[LaneIndex]]:
        saved = self.path[k:]
        del self.path[k:]
        try:
            return self._options(node)
        finally:
            self.path.extend(saved)

    def ring_speed(self) -> float:
        return min(SPEED_RING, self.driver.turn_speed + 1.0)

    def lane_speed(self, lane) -> float:
        limit = float(lane.speed_limit)
        if isinstance(lane, CircularLane):
            return min(limit, self.driver.turn_speed) if lane.radius < 18 else min(limit, self.ring_speed())
        return limit

    def lane_for(self, direction: str | None) -> None:
        """Get into the lane a coming turn needs (left lane for left, right lane for right)."""
        town = self.world.town
        cur = self.path[0]
        if town.lane_junction.get(cur) is not None or direction is None:
            return
        n = len(town.network.graph[cur[0]][cur[1]])
        if n < 2:
            return
        want = 0 if direction == "left" else n - 1
        target = (cur[0], cur[1], want)
        if cur[2] != want and len(self.path) == 1 and self.gap_free(target):
            self.path[0] = target

    def gap_free(self, lane: LaneIndex) -> bool:
        """Gap acceptance before a lane change in time: no car beside, none just ahead, none closing in
        from behind within its 1 s of travel (a driver with time looks and waits for a gap)."""
        half = self.LENGTH / 2
        for other in self.world.traffic:
            if other.path[0] != lane:
                continue
            ds = other.s - self.s
            room = half + other.LENGTH / 2 + 2.0
            if -room - max(other.speed - self.speed, 0.0) - 0.5 * other.speed < ds < room:
                return False
        return True

    def step(self, dt: float) -> None:
        """Kinematic bicycle with a friction circle: braking hard leaves little grip for turning,
        and beyond the lateral grip the car runs wide."""
        v = self.speed
        veh = self.driver.vehicle
        beta = np.arctan(0.5 * np.tan(self.steer))
        yaw_rate = v * np.sin(beta) / (self.LENGTH / 2)
        total = max(veh.max_decel, veh.max_lateral_accel) + 0.5
        lateral = min(veh.max_lateral_accel, np.sqrt(max(total**2 - self.accel**2, 1.0)))
        grip = lateral / max(v, 0.1)
        # a late swerve that asks the tyres for well beyond their grip (sharp steering while braking
        # hard, at speed) slides: the car runs wide over the kerb (docs/simulator.md, "too late")
        swerving = self.world.time < self.swerving_until
        if swerving and abs(yaw_rate) * v > self.SKID_RATIO * lateral:
            self.skid_time += dt
        else:
            self.skid_time = 0.0
        if not swerving:
            self.ran_wide = False
        elif self.skid_time >= self.SKID_TIME:
            self.ran_wide = True
        yaw_rate = _clamp(yaw_rate, -grip, grip)
        self.position = self.position + v * np.array([np.cos(self.heading + beta), np.sin(self.heading + beta)]) * dt
        self.heading = _wrap(self.heading + yaw_rate * dt)
        self.speed = max(0.0, v + self.accel * dt)


# --------------------------------------------------------------------------------------------------
# The world


def _path_ahead(town: Town, path: tuple[LaneIndex, ...]) -> tuple[dict, list[float], dict]:
    """For a car's next lanes ``path``: each lane's index, the path distance to its start, and the lanes that
    leave the same nodes (they overlap at first: treat them as the car's own). Fixed per town and path, so
    cached on the town: rebuilding it made up a third of :meth:`World.leader_of`."""
    cache = town.__dict__.setdefault("_path_ahead_cache", {})
    hit = cache.get(path)
    if hit is None:
        ahead = {lane: i for i, lane in enumerate(path)}
        starts = [0.0]
        for i in range(1, len(path)):
            starts.append(starts[-1] + town.lane(path[i - 1]).length)
        graph = town.network.graph
        siblings: dict = {}
        for k, lane in enumerate(path[1:], start=1):
            for to, lanes in graph[lane[0]].items():
                for i in range(len(lanes)):
                    siblings.setdefault((lane[0], to, i), k)
        hit = cache[path] = (ahead, starts, siblings)
    return hit


class World:
    """A town, a driver's car on a route, traffic around it, right-of-way and event counters."""

    BOX_PAVING = 0.75  # m of paving beyond the connector lanes' edges inside a junction box
    # A car following the navigated one (world v2): on town streets someone is often right behind you.
    # Chance per second that one joins when none follows; its time headway (urban car following: a large
    # share of headways below 1 s, Vogel 2003, Accid. Anal. Prev. 35) and its perception-reaction delay to
    # the braking of the car ahead (expected ~0.75 s, unexpected ~1.25 s, surprise ~1.5 s and longer when
    # looking elsewhere: Green 2000, Transp. Hum. Factors 2) are drawn per follower.
    FOLLOW_RATE = 0.2
    FOLLOW_HEADWAY = (0.5, 1.2)
    FOLLOW_REACTION = (1.0, 2.0)
    FOLLOW_DROP = 80.0  # m behind the navigated car beyond which a follower is just traffic

    def __init__(self, town: Town, driver: Driver, route: Route, seed: int = 0, n_traffic: int = 8,
                 frequency: int = 10) -> None:
        self.town = town
        self.rng = np.random.default_rng(seed)
        # the driver's own randomness (hearing, compliance, guesses) has its own stream, so that two
        # policies driving the same seed face the same draws for the k-th instruction they play
        self.driver_rng = np.random.default_rng([seed, 1])
        self.guess_rng = np.random.default_rng([seed, 2])  # the driver's guesses at junctions
        self.follow_rng = np.random.default_rng([seed, 3])  # followers: when one joins, its headway, delay
        self.follower: TrafficCar | None = None
        self.road = Road(network=town.network, np_random=np.random.RandomState(seed))
        self.dt = 1.0 / frequency
        self.time = 0.0
        self.events = Events()
        self.row = RightOfWay(town)
        self.ego = DriverCar(self, driver, route.lanes[0], route.start_s)
        self.ego.speed = 0.0
        self.road.vehicles.append(self.ego)
        self.n_traffic = n_traffic
        self.traffic: list[TrafficCar] = []
        for _ in range(n_traffic):
            self.spawn_traffic(initial=True)

    @property
    def cars(self) -> list[Vehicle]:
        return self.road.vehicles

    # ----- branching (a true-dynamics model plans on copies of the live world) ------------------
    def shared(self) -> dict[int, Any]:
        """A ``copy.deepcopy`` memo of what a copy shares with this world: the town, its lanes, the
        driver and every route (never mutated while driving)."""
        memo: dict[int, Any] = {id(self.town): self.town, id(self.town.network): self.town.network,
                                id(self.ego.driver): self.ego.driver}
        for ends in self.town.network.graph.values():
            for lanes in ends.values():
                memo.update({id(lane): lane for lane in lanes})
        memo.update({id(r): r for r in self.town.routes})
        return memo

    def after_copy(self, memo: dict[int, Any], seed: int | None = None) -> None:
        """Fix a deep copy made with ``memo``: state keyed by ``id(car)`` (right-of-way holders, the
        driver's contacts) re-keyed to the copied cars, and, with ``seed``, fresh random streams so the
        copy does not know the original's future draws (mishearing, compliance, guesses, traffic)."""
        new_id = {old: id(new) for old, new in memo.items() if isinstance(new, Vehicle)}
        for jid, holders in self.row.holders.items():
            self.row.holders[jid] = {new_id.get(k, k): arm for k, arm in holders.items()}
        self.ego.in_contact = {new_id.get(k, k) for k in self.ego.in_contact}
        if seed is not None:
            self.rng = np.random.default_rng([seed, 10])
            self.driver_rng = np.random.default_rng([seed, 11])
            self.guess_rng = np.random.default_rng([seed, 12])
            self.follow_rng = np.random.default_rng([seed, 13])
            self.road.np_random = np.random.RandomState(seed & 0x7FFFFFFF)

    # ----- traffic population -----------------------------------------------------------------
    def spawn_traffic(self, initial: bool = False) -> None:
        town, rng = self.town, self.rng
        for _ in range(50):
            lane_i = town.road_lanes[int(rng.integers(len(town.road_lanes)))]
            lane = town.lane(lane_i)
            if lane.length < 40:
                continue
            s = float(rng.uniform(10.0, lane.length - 25.0))
            p = lane.position(s, 0.0)
            dist_ego = np.linalg.norm(p - self.ego.position)
            if not (40.0 < dist_ego < (220.0 if initial else 260.0)) or (not initial and dist_ego < 90.0):
                continue
            if any(np.linalg.norm(p - c.position) < 25.0 for c in self.cars):
                continue
            desired = float(lane.speed_limit * rng.uniform(0.8, 1.0))
            car = TrafficCar(self, lane_i, s, desired * 0.8, desired)
            self.traffic.append(car)
            self.road.vehicles.append(car)
            return

    def remove(self, car: TrafficCar) -> None:
        self.traffic.remove(car)
        self.road.vehicles.remove(car)

    def spawn_follower(self) -> None:
        """A car joins behind the navigated one on its lane, at its headway and the same speed."""
        ego, town, rng = self.ego, self.town, self.follow_rng
        headway, reaction = rng.uniform(*self.FOLLOW_HEADWAY), rng.uniform(*self.FOLLOW_REACTION)
        lane_i = ego.path[0]
        if town.lane_junction.get(lane_i) is not None or ego.speed < 3.0:
            return
        lane = town.lane(lane_i)
        s = ego.s - (2.0 + ego.speed * headway + (ego.LENGTH + Vehicle.LENGTH) / 2)
        if s < 2.0:
            return
        p = lane.position(s, 0.0)
        if any(np.linalg.norm(p - c.position) < 10.0 for c in self.traffic):
            return
        car = TrafficCar(self, lane_i, s, ego.speed, float(lane.speed_limit), follow=ego, headway=headway,
                         reaction=reaction)
        self.traffic.append(car)
        self.road.vehicles.append(car)
        self.follower = car

    def maintain_follower(self) -> None:
        f = self.follower
        if f is not None and (f not in self.traffic or not f.tracking
                              or np.linalg.norm(f.position - self.ego.position) > self.FOLLOW_DROP):
            f.tracking = False
            self.follower = None
        if self.follower is None and self.FOLLOW_RATE > 0 and self.follow_rng.random() < self.FOLLOW_RATE:
            self.spawn_follower()

    def maintain_traffic(self) -> None:
        for car in list(self.traffic):
            far = np.linalg.norm(car.position - self.ego.position) > 300.0
            if far or car.stuck_time > 40.0 or car.crashed:
                self.remove(car)
        self.maintain_follower()
        while sum(c is not self.follower for c in self.traffic) < self.n_traffic:
            before = len(self.traffic)
            self.spawn_traffic()
            if len(self.traffic) == before:
                break

    # ----- perception shared by all cars ------------------------------------------------------
    def leader_of(self, car: PathCar) -> tuple[Vehicle | None, float]:
        """Nearest car ahead: on the car's own lane path, or in its corridor straight ahead."""
        best, best_gap = None, np.inf
        ahead, starts, siblings = _path_ahead(self.town, tuple(car.path[:4]))
        h = car.direction
        px, py = car.position
        for other in self.cars:
            if other is car:
                continue
            ox, oy = other.position
            if abs(ox - px) > 60.0 or abs(oy - py) > 60.0:  # hypot >= either leg: surely beyond 60 m
                continue
            rel = other.position - car.position
            dist = float(np.hypot(*rel))
            if dist > 60.0:
                continue
            half = (car.LENGTH + other.LENGTH) / 2
            k = ahead.get(other.path[0])
            if k is None and other.s < 15.0:
                k = siblings.get(other.path[0])
            gap = np.inf
            if k is not None:
                along = starts[k] + other.s - car.s
                if along > 0:
                    gap = along - half
            lon = float(np.dot(rel, h))
            lat = abs(float(rel[0] * h[1] - rel[1] * h[0]))
            # the corridor catches crossing and same-way cars; an oncoming car (waiting at the stop
            # line of the arm a turning car leaves by) is in the other lane, not in the way
            oncoming = float(np.dot(other.direction, h)) < -0.5
            if 0 < lon < 35.0 and lat < (car.WIDTH + other.WIDTH) / 2 + 0.4 and not oncoming:
                gap = min(gap, lon - half)
            if gap < best_gap:
                best, best_gap = other, gap
        return best, best_gap

    def stop_line(self, car: PathCar) -> float | None:
        """Distance to a stop line the car must respect (junction held by another arm, or ring
        traffic at a roundabout entry), or None."""
        town = self.town
        d = town.lane(car.path[0]).length - car.s
        for i in range(1, min(len(car.path), 4)):
            prev, lane = car.path[i - 1], car.path[i]
            jid = town.lane_junction.get(lane)
            if jid is not None and town.lane_junction.get(prev) is None:
                if d > 35.0:
                    return None
                j = town.junctions[jid]
                arm = prev[1].split(":i")[1]
                if j.kind == "roundabout":
                    entry_len = town.lane(lane).length
                    if not self.row.ring_clear(car, jid, arm):
                        return max(d + entry_len - 3.0, 0.1)
                    return None
                if not j.is_decision:
                    return None
                if not self.row.may_enter_cross(car, jid, arm):
                    return max(d - 1.0, 0.1)
                return None
            d += town.lane(lane).length
        return None

    # ----- simulation -------------------------------------------------------------------------
    def frame(self) -> None:
        """One simulation frame: decisions, dynamics, collisions and curb strikes."""
        self.row.world_cars = self.cars
        self.row.release_stale(self.cars)
        for car in self.cars:
            car.act()
        for car in self.cars:
            car.step(self.dt)
        self.time += self.dt
        self._collisions()
        self._curb()

    def _collisions(self) -> None:
        cars = self.cars
        pos = np.array([c.position for c in cars])
        ego = self.ego
        # every pair's centre distance in one pass (pairs i < j in row-major order, as a loop over i would)
        near = np.sqrt(((pos[:, None, :] - pos[None, :, :]) ** 2).sum(-1)) < 6.5
        for i, j in zip(*np.nonzero(np.triu(near, k=1)), strict=True):
            a, b = cars[i], cars[j]
            if not utils.are_polygons_intersecting(a.polygon(), b.polygon(), np.zeros(2), np.zeros(2))[0]:
                if ego in (a, b):
                    ego.in_contact.discard(id(b if a is ego else a))
                continue
            if ego in (a, b):
                other = b if a is ego else a
                if id(other) not in ego.in_contact:
                    ego.in_contact.add(id(other))
                    self.events.vehicle_collisions += 1
                    self.events.log.append(("collision", round(self.time, 1)))
                    ego.speed *= 0.3
                    other.crashed = True
            elif not (a.crashed and b.crashed):
                self.events.traffic_collisions += 1
                a.crashed = b.crashed = True

    def _curb(self) -> None:
        ego = self.ego
        off = ego.ran_wide or self._over_edge(ego)
        if off and not ego.off_road:
            self.events.edge_strikes += 1
            self.events.log.append(("edge", round(self.time, 1)))
            ego.speed *= 0.6
        ego.off_road = off

    def _over_edge(self, car: PathCar) -> bool:
        """The car's body is more than 0.75 m over the road edge: a side of the car (its centre
        line ± (width/2 - 0.75)) lies outside every lane. Checking the sides, not the centre, keeps
        a lane change between two parallel lanes on the road. Inside a junction box the paved
        area is the union of its connector lanes (plus a little paving between them): the corners
        are kerbs, which a car cutting a turn short, or running wide out of it, mounts."""
        grid = self.town.lane_grid
        inside = LANE_WIDTH / 2 - car.WIDTH / 2 + 0.75  # centre this close to a lane: sides on it
        if grid.distance_to_road(car.position) <= inside:
            return False
        edge = LANE_WIDTH / 2 + (self.BOX_PAVING if self._in_box(car.position, 2.0) else 0.0)
        h = car.heading
        normal = np.array([-np.sin(h), np.cos(h)]) * (car.WIDTH / 2 - 0.75)
        return any(grid.distance_to_road(car.position + sign * normal) > edge for sign in (1, -1))

    def _in_box(self, p: np.ndarray, beyond: float = -1.0) -> bool:
        """``p`` lies in a cross junction's box (grown by ``beyond`` metres: its rounded corners)."""
        for j in self.town.junctions.values():
            if j.kind == "cross" and np.max(np.abs(p - j.center)) < j.size + beyond:
                return True
        return False
