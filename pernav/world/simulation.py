"""The simulated world: a driver who hears voice instructions, IDM traffic with right-of-way, events.

The parts live in their own modules (events, vehicles, right_of_way, traffic, controls, driver_car) and are
imported from there; this module holds the :class:`World`. One :class:`World` holds a town's highway-env ``Road``,
the driver's car (:class:`DriverCar`) and traffic (:class:`TrafficCar`), both highway-env vehicles.
``World.frame()`` advances one simulation frame; the gymnasium env runs ``frequency`` frames per policy step.

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

from typing import Any

import numpy as np
from highway_env import utils
from highway_env.road.road import Road
from highway_env.vehicle.kinematics import Vehicle

from pernav.world.driver_car import DriverCar
from pernav.world.drivers import Driver
from pernav.world.events import Events
from pernav.world.network import LaneIndex, Town
from pernav.world.right_of_way import RightOfWay
from pernav.world.routing import Route
from pernav.world.towns import LANE_WIDTH
from pernav.world.traffic import TrafficCar
from pernav.world.vehicles import PathCar

__all__ = ["World"]


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


def _stop_plan(town: Town, path: tuple[LaneIndex, ...]) -> tuple[float, list[float], tuple | None]:
    """For a car's next lanes ``path`` (at most four), what :meth:`World.stop_line` walks through: the first lane's
    length, the lengths it adds before the first lane that enters a junction, and that entry (junction id, the
    node it is entered from, the entering lane) or None. Fixed per town and path (lanes never change), so cached
    on the town."""
    cache = town.__dict__.setdefault("_stop_plan_cache", {})
    hit = cache.get(path)
    if hit is None:
        lengths: list[float] = []
        entry = None
        for i in range(1, len(path)):
            prev, lane = path[i - 1], path[i]
            jid = town.lane_junction.get(lane)
            if jid is not None and town.lane_junction.get(prev) is None:
                entry = (jid, prev[1], lane)
                break
            lengths.append(town.lane(lane).length)
        hit = cache[path] = (town.lane(path[0]).length, lengths, entry)
    return hit


class World:
    """A town, a driver's car on a route, traffic around it, right-of-way and event counters."""

    BOX_PAVING = 0.75  # m of paving beyond the connector lanes' edges inside a junction box
    # A car following the navigated one: on town streets someone is often right behind you.
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
        self.right_of_way = RightOfWay(town)
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
        for jid, holders in self.right_of_way.holders.items():
            self.right_of_way.holders[jid] = {new_id.get(k, k): arm for k, arm in holders.items()}
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
        ahead = None  # the car's path ahead and heading: worked out at the first car within 60 m (often none is)
        # positions as Python floats: the same IEEE differences as numpy's, without a numpy scalar per operation;
        # within frame()'s act loop (nobody moves there) every car's are read once per frame, not once per pair
        px, py = car.position.tolist()
        positions = self._act_positions
        if positions is None:
            positions = [(other, *other.position.tolist()) for other in self.cars]
        for other, ox, oy in positions:
            if other is car:
                continue
            rx, ry = ox - px, oy - py  # the components of ``other.position - car.position``, to the bit
            # abs(rx) > 60.0 or abs(ry) > 60.0 (hypot >= either leg: surely beyond 60 m), without calling abs
            if rx > 60.0 or rx < -60.0 or ry > 60.0 or ry < -60.0:
                continue
            # ``np.hypot(rx, ry) > 60`` decided from the squared length where it is clearly on one side of 3600
            # (its rounding errors are ~1e-13 here, libm's hypot is within an ulp); np.hypot itself near the edge
            # and for NaN (which passes, as before)
            sq = rx * rx + ry * ry
            if sq > 3601.0 or (not sq < 3599.0 and float(np.hypot(rx, ry)) > 60.0):
                continue
            if ahead is None:
                ahead, starts, siblings = _path_ahead(self.town, tuple(car.path[:4]))
                h = car.direction
                hx, hy = h.tolist()
            half = (car.LENGTH + other.LENGTH) / 2
            k = ahead.get(other.path[0])
            if k is None and other.s < 15.0:
                k = siblings.get(other.path[0])
            gap = np.inf
            if k is not None:
                along = starts[k] + other.s - car.s
                if along > 0:
                    gap = along - half
            # lon = ``np.dot(rel, h)`` only matters in (0, 35); the plain sum of products is within 1e-12 of it
            # here (|rel| <= 60 m, |h| = 1), so a car clearly outside that range is passed over without it
            # (NaN compares false both ways, as lon would)
            if -1e-9 < rx * hx + ry * hy < 35.0 + 1e-9:
                lon = float(np.dot(other.position - car.position, h))
                if 0 < lon < 35.0:  # the lateral offset and the other's heading only matter in this range
                    lat = abs(rx * hy - ry * hx)
                    # the corridor catches crossing and same-way cars; an oncoming car (waiting at the stop
                    # line of the arm a turning car leaves by) is in the other lane, not in the way
                    oncoming = float(np.dot(other.direction, h)) < -0.5
                    if lat < (car.WIDTH + other.WIDTH) / 2 + 0.4 and not oncoming:
                        gap = min(gap, lon - half)
            if gap < best_gap:
                best, best_gap = other, gap
        return best, best_gap

    def stop_line(self, car: PathCar) -> float | None:
        """Distance to a stop line the car must respect (junction held by another arm, or ring
        traffic at a roundabout entry), or None."""
        first, lengths, entry = _stop_plan(self.town, tuple(car.path[:4]))
        if entry is None:  # no junction entered within the next lanes
            return None
        d = first - car.s
        for length in lengths:  # the same sum, lane by lane, as walking the path
            d += length
        jid, node, lane = entry
        if d > 35.0:
            return None
        j = self.town.junctions[jid]
        arm = node.split(":i")[1]
        if j.kind == "roundabout":
            entry_len = self.town.lane(lane).length
            if not self.right_of_way.ring_clear(car, jid, arm):
                return max(d + entry_len - 3.0, 0.1)
            return None
        if not j.is_decision:
            return None
        if not self.right_of_way.may_enter_cross(car, jid, arm):
            return max(d - 1.0, 0.1)
        return None

    # ----- simulation -------------------------------------------------------------------------
    _act_positions: list | None = None  # (car, x, y) of every car while frame() runs their act()

    def frame(self) -> None:
        """One simulation frame: decisions, dynamics, collisions and curb strikes."""
        self.right_of_way.world_cars = self.cars
        self.right_of_way.release_stale(self.cars)
        # acting changes no car's position and adds or removes no car (that happens in step() and
        # maintain_traffic()), so leader_of() may read the positions taken here for the whole loop
        self._act_positions = [(car, *car.position.tolist()) for car in self.cars]
        try:
            for car in self.cars:
                car.act()
        finally:
            self._act_positions = None
        for car in self.cars:
            car.step(self.dt)
        self.time += self.dt
        self._collisions()
        self._curb()

    def _collisions(self) -> None:
        cars = self.cars
        ego = self.ego
        # pairs i < j in row-major order whose centres are under 6.5 m apart. The test is numpy's
        # ``np.sqrt(((pos[:, None] - pos[None]) ** 2).sum(-1)) < 6.5`` on Python floats: the same difference,
        # squares (``** 2`` is a multiplication) and one sum of two terms, then np.sqrt; a pair more than 7 m
        # apart on either axis (abs(dx) > 7.0, written without abs) is skipped first: its square alone is >= 49,
        # so the root is >= 7 > 6.5
        xy = [c.position.tolist() for c in cars]
        for i, (xi, yi) in enumerate(xy):
            for j in range(i + 1, len(xy)):
                xj, yj = xy[j]
                dx, dy = xi - xj, yi - yj
                if dx > 7.0 or dx < -7.0 or dy > 7.0 or dy < -7.0 or not np.sqrt(dx * dx + dy * dy) < 6.5:
                    continue
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
        if grid.within(car.position, inside):  # distance_to_road(car.position) <= inside
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
