"""The driver's car, driven by a simulated driver who knows only what it has heard (or by a person)."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from highway_env.road.lane import CircularLane
from highway_env.vehicle.kinematics import Vehicle

from pernav.world.constants import OPPOSITE, PREPARES, SIDED, TURNS, Instruction, audio_duration
from pernav.world.controls import ExternalControls, PersonAtTheWheel
from pernav.world.drivers import Driver
from pernav.world.events import Heard
from pernav.world.network import LaneIndex, turn_direction
from pernav.world.scalars import clamp, wrap_angle
from pernav.world.towns import SPEED_RING
from pernav.world.vehicles import PathCar, braking_for, idm_acceleration

if TYPE_CHECKING:
    from pernav.world.simulation import World

class DriverCar(PersonAtTheWheel, PathCar, Vehicle):
    """The navigated car, driven by a simulated driver who knows only what it has heard."""

    # what the driver hears and decides
    MISHEARD_SWAP = 0.5  # [probability] a misheard left/right instruction is taken as the other side (else lost)
    FOLLOW_PREPARE = 0.5  # [probability] at a junction with only a "prepare" heard, the driver follows it
    DECISION_REACH = 4.0  # [m] the driver commits to a branch at the latest this far before its node
    PATH_HORIZON = 120.0  # [m] forced lanes (no choice) are added to the path this far ahead
    TRAIL_LANES = 8  # [lanes] the last lanes the car left that it remembers (a follower drives along them)
    # speed
    CONSTRAINT_SIGHT = 60.0  # [m] speed limits ahead are seen at least this far, however short the driver's sight
    CONSTRAINT_MARGIN = 1.0  # [m] the driver brakes to be at a limit's speed this far before it
    PREPARE_SPEED = 0.5  # [] a heard "prepare" aims at this weight of (turn speed + cruise): halfway between them
    PREPARE_CRUISE = 0.75  # [] share of the cruise speed kept while preparing for a turn on the approach
    PREPARE_HEADWAY = 1  # [s] IDM time headway of that slowing (no leader: it has no effect)
    STOP_HEADWAY = 1.0  # [s] IDM time headway towards a stop line
    BRAKE_SHARE = 0.55  # [] a deceleration need beyond this share of the comfort deceleration is braked for
    HARSH_SHARE = 1.5  # [] a need beyond this multiple of the comfort deceleration counts as a harsh brake
    ACCEL_SHARE = 1.5  # [] the most acceleration asked, as a multiple of the comfort acceleration
    RING_MARGIN = 1.0  # [m/s] speed on a roundabout's ring above the driver's turn speed (capped by SPEED_RING)
    TIGHT_RADIUS = 18  # [m] a curved lane tighter than this is driven at the driver's turn speed
    GAP_MARGIN = 2.0  # [m] free road wanted beside the cars' half lengths before a lane change
    GAP_BEHIND = 0.5  # [s] of a following car's own travel also kept free behind (beside 1 s of its closing speed)
    # a late turn: the swerve
    SWERVE_REACH = 0.35  # [] a late turn is still tried this fraction of the way through a junction box
    SWERVE_TIME = 3.0  # [s] a swerve lasts this long (harsh braking, sharp steering)
    SWERVE_BRAKE = 0.8  # [] share of the car's maximum deceleration braked while swerving above the turn speed
    PANIC_GAIN = 1.8  # [] the steering command is multiplied by this in the panicked yank ...
    PANIC_SETTLE = 1.5  # [s] ... until this long before the swerve ends
    SKID_RATIO = 1.5  # [] lateral acceleration asked / grip beyond which a swerving car slides
    SKID_TIME = 0.3  # [s] of sliding that carries the car over the kerb
    # hands and feet of the simulated driver (SIM_: the person's own are PersonAtTheWheel's, which this class inherits)
    SIM_WHEEL_LAG = 0.12  # [s] time constant of a wheel driver's steering following the command
    SIM_KEY_DEADBAND = 0.4  # [m/s2] a keyboard driver presses no pedal key for a smaller acceleration wanted
    SIM_KEY_THROTTLE = 1.3  # [] the throttle key's acceleration, as a multiple of the comfort acceleration
    SIM_KEY_BRAKE = 1.25  # [] the brake key overshoots the deceleration wanted by this factor ...
    SIM_KEY_BRAKE_MIN = 1.5  # [m/s2] ... and brakes at least this hard
    SIM_KEY_STEER_DEADBAND = 0.035  # [rad] a keyboard driver leaves a smaller steering error alone
    SIM_KEY_STEER_RATE = 1.6  # [rad/s] a steering key turns the wheel at this rate
    # the car: a kinematic bicycle with a friction circle
    CG_SHARE = 0.5  # [] rear axle to centre of gravity, as a share of the wheelbase (the slip angle's factor)
    GRIP_MARGIN = 0.5  # [m/s2] the friction circle's radius above the larger of the braking and lateral limits
    MIN_LATERAL_SQ = 1.0  # [m2/s4] the square of the least lateral grip left however hard the car brakes
    MIN_GRIP_SPEED = 0.1  # [m/s] speed floor of the yaw-rate limit (grip / speed)

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
        self.trail = [*self.trail[-(self.TRAIL_LANES - 1):], lane]

    # ----- hearing ----------------------------------------------------------------------------
    def hear(self, instruction: int, playback: str, now: float) -> None:
        """The instruction was played: understood (or misheard) and acted on after audio + reaction."""
        if instruction == Instruction.NONE:
            return
        d, ev = self.driver, self.world.events
        heard, swapped, complied = self.world.driver_rng.random(3)  # four draws per play, always
        reaction = d.reaction_draw(float(self.world.driver_rng.standard_normal()))  # this prompt's reaction
        if heard > d.understanding(playback):
            if instruction in SIDED and swapped < self.MISHEARD_SWAP:  # misheard left <-> right
                instruction = OPPOSITE[instruction]
                ev.misunderstood += 1
            else:
                ev.misunderstood += 1
                return
        if complied > d.compliance:
            ev.ignored += 1
            return
        active = now + audio_duration(instruction, playback) + reaction
        if instruction in TURNS:  # a new turn instruction replaces older ones
            self.heard = [h for h in self.heard if h.instruction not in (*TURNS, Instruction.KEEP_LEFT)]
        elif instruction in PREPARES:
            self.heard = [h for h in self.heard if h.instruction not in PREPARES]
        elif instruction == Instruction.KEEP_LEFT:
            self.heard = [h for h in self.heard if h.instruction not in TURNS]
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
    def extend_forced(self, horizon: float = PATH_HORIZON) -> None:
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
        turn = self.active(now, TURNS)
        prep = self.active(now, PREPARES)
        if ":r" in node:
            choice = "exit" if turn is not None and "exit" in options else "stay"
            if choice == "exit":
                self.consume(TURNS, now)
        else:
            choice = None
            if turn is not None and turn.direction in options:
                choice = turn.direction
                self.consume(SIDED, now)
            elif prep is not None and prep.direction in options and follow_prep < self.FOLLOW_PREPARE:
                choice = prep.direction
                self.consume(PREPARES, now)
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
            self.swerving_until = now + self.SWERVE_TIME
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
        now = self.world.time
        self.advance_path()
        self.forget(now)
        self.extend_forced()
        self._decide_branches(now)
        self._enter_box(now)
        self._steer_and_pedal(self._acceleration(now), now)

    def _decide_branches(self, now: float) -> None:
        """Commit to the branch ahead at the decision point; a turn heard after the commit is a swerve or a miss."""
        world, d, v = self.world, self.driver, max(self.speed, 0.0)
        town = world.town
        node_dist = self.decision_node()
        if node_dist is not None:
            node, dist = node_dist
            if dist <= max(d.decision_time * v, self.DECISION_REACH):
                self.commit(node, now)
                self.extend_forced()
        turn = self.active(now, TURNS)
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
                self.swerving_until = now + self.SWERVE_TIME
                world.events.swerves += 1
                self.advance_path()
                self.extend_forced()

    def _enter_box(self, now: float) -> None:
        """Entering a junction box: what was heard before it was meant for this junction."""
        world, town = self.world, self.world.town
        in_box = town.lane_junction.get(self.path[0])
        if in_box is not None and in_box != self.box and town.junctions[in_box].kind == "cross":
            dropped = [h for h in self.heard if h.instruction in SIDED and h.heard_at < now]
            world.events.discarded += len(dropped)
            self.heard = [h for h in self.heard if h not in dropped]
        self.box = in_box

    def _acceleration(self, now: float) -> float:
        """The acceleration the driver wants: cruise, slower lanes, planned turns, roundabouts, leader, right of way."""
        world, town, d = self.world, self.world.town, self.driver
        v = max(self.speed, 0.0)
        v_seen = v * d.speed_misjudgement
        limit = self.lane_speed(self.lane)
        cruise = limit * d.speed_factor
        acc = idm_acceleration(v, cruise, np.inf, 0.0, d.time_headway, d.comfort_accel, d.comfort_decel)
        needs = []
        for dist, vmax in self.speed_constraints(max(d.sight_distance, self.CONSTRAINT_SIGHT)):
            needs.append(braking_for(v_seen, vmax, dist - self.CONSTRAINT_MARGIN))
        nd = self.decision_node()
        if nd is not None and ":i" in nd[0]:
            node, dist = nd
            j = town.junction_of_node(node)
            expect = self.active(now, TURNS) or self.active(now, PREPARES)
            if j is not None and dist < d.sight_distance:
                if j.kind == "roundabout":
                    needs.append(braking_for(v_seen, self.ring_speed(), dist))
                elif expect is not None:
                    target = d.turn_speed if expect.instruction in TURNS else self.PREPARE_SPEED * (d.turn_speed + cruise)
                    needs.append(braking_for(v_seen, target, dist))
        if self.active(now, (Instruction.ENTER_ROUNDABOUT,)) is not None and nd is not None:
            j = town.junction_of_node(nd[0])
            if j is not None and j.kind == "roundabout":
                needs.append(braking_for(v_seen, self.ring_speed(), nd[1]))
        prep = self.active(now, PREPARES)
        if prep is not None and town.lane_junction.get(self.path[0]) is None:
            acc = min(acc, idm_acceleration(v, self.PREPARE_CRUISE * cruise, np.inf, 0, self.PREPARE_HEADWAY,
                                            d.comfort_accel, d.comfort_decel))
            self.lane_for(prep.direction)
        elif (heard_turn := self.active(now, TURNS)) is not None:  # a turn without its "prepare": its lane
            self.lane_for(heard_turn.direction)
        need = max(needs, default=0.0)
        harsh_limit = d.vehicle.max_decel
        if need > self.BRAKE_SHARE * d.comfort_decel:
            if need > self.HARSH_SHARE * d.comfort_decel and self.accel > -d.comfort_decel:
                world.events.harsh_brakes += 1
            acc = min(acc, -min(need, harsh_limit))
        leader, gap = world.leader_of(self)
        if leader is not None:
            closing = v - float(np.dot(leader.velocity, self.direction))
            acc = min(acc, idm_acceleration(v, cruise, gap, closing, d.time_headway, d.comfort_accel,
                                            d.comfort_decel))
        stop = world.stop_line(self)
        if stop is not None:
            acc = min(acc, idm_acceleration(v, cruise, stop, v, self.STOP_HEADWAY, d.comfort_accel, d.comfort_decel))
        if now < self.swerving_until:
            acc = min(acc, -self.SWERVE_BRAKE * harsh_limit) if v > d.turn_speed else acc
        acc = clamp(acc, -harsh_limit, d.comfort_accel * self.ACCEL_SHARE)
        return acc

    def _steer_and_pedal(self, acc: float, now: float) -> None:
        """The wheel follows the lane (a panicked yank when swerving); keyboard drivers press in steps."""
        world, d = self.world, self.driver
        harsh_limit = d.vehicle.max_decel
        steer_cmd = self.lane_steering(d.steering_tau)
        if now < self.swerving_until - self.PANIC_SETTLE:  # panic: a sharp, over-corrected yank of the wheel
            steer_cmd *= self.PANIC_GAIN
        if d.keyboard:  # on/off keys: pedals in steps, steering ramps at a fixed rate
            acc = 0.0 if abs(acc) < self.SIM_KEY_DEADBAND else (
                d.comfort_accel * self.SIM_KEY_THROTTLE if acc > 0
                else min(acc * self.SIM_KEY_BRAKE, -self.SIM_KEY_BRAKE_MIN))
            acc = max(acc, -harsh_limit)
            err = steer_cmd - self.steer
            if abs(err) > self.SIM_KEY_STEER_DEADBAND:
                self.steer += np.sign(err) * min(abs(err), self.SIM_KEY_STEER_RATE * world.dt)
        else:
            self.steer += (steer_cmd - self.steer) * min(1.0, world.dt / self.SIM_WHEEL_LAG)
        self.steer = clamp(self.steer, -d.vehicle.max_steering, d.vehicle.max_steering)
        self.accel = acc
        self.brake_input = clamp(-acc / harsh_limit, 0.0, 1.0)
        self.action = {"steering": self.steer, "acceleration": acc}

    def _options_at(self, k: int, node: str) -> dict[str, list[LaneIndex]]:
        saved = self.path[k:]
        del self.path[k:]
        try:
            return self._options(node)
        finally:
            self.path.extend(saved)

    def ring_speed(self) -> float:
        return min(SPEED_RING, self.driver.turn_speed + self.RING_MARGIN)

    def lane_speed(self, lane) -> float:
        limit = float(lane.speed_limit)
        if isinstance(lane, CircularLane):
            return min(limit, self.driver.turn_speed) if lane.radius < self.TIGHT_RADIUS else min(limit, self.ring_speed())
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
            room = half + other.LENGTH / 2 + self.GAP_MARGIN
            if -room - max(other.speed - self.speed, 0.0) - self.GAP_BEHIND * other.speed < ds < room:
                return False
        return True

    def step(self, dt: float) -> None:
        """Kinematic bicycle with a friction circle: braking hard leaves little grip for turning,
        and beyond the lateral grip the car runs wide."""
        v = self.speed
        veh = self.driver.vehicle
        beta = np.arctan(self.CG_SHARE * np.tan(self.steer))
        yaw_rate = v * np.sin(beta) / (self.LENGTH / 2)
        total = max(veh.max_decel, veh.max_lateral_accel) + self.GRIP_MARGIN
        lateral = min(veh.max_lateral_accel, np.sqrt(max(total**2 - self.accel**2, self.MIN_LATERAL_SQ)))
        grip = lateral / max(v, self.MIN_GRIP_SPEED)
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
        yaw_rate = clamp(yaw_rate, -grip, grip)
        self.position = self.position + v * np.array([np.cos(self.heading + beta), np.sin(self.heading + beta)]) * dt
        self.heading = wrap_angle(self.heading + yaw_rate * dt)
        self.speed = max(0.0, v + self.accel * dt)
