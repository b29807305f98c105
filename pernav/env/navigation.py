"""NavigationEnv: the gymnasium environment of docs/simulator.md.

One step = one simulated second: the navigation plays (or not) one voice instruction, then the world
runs ``frequency`` frames. Observation: the paper's 14-number state. Reward: minus the tracking cost.

Example:
    >>> import gymnasium as gym
    >>> import pernav
    >>> env = gym.make("pernav/Town2-v0")
    >>> obs, info = env.reset(seed=1, options={"route": 3, "user": "user4"})
    >>> obs.shape
    (14,)
    >>> obs, reward, terminated, truncated, info = env.step(0)
    >>> sorted(k for k in ("collisions", "missed_turns", "completed") if k in info)
    ['collisions', 'completed', 'missed_turns']
"""

from __future__ import annotations

import copy
from collections.abc import Callable
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from pernav.env.layout import EXPLORE_POINTS, EXPLORE_SPEEDS, STATE_DIM
from pernav.env.planning import action_mask, explore_plan, explore_table, plan_goals, route_ahead, route_boxes
from pernav.env.policies import (
    BeliefSource,
    NavView,
    PromptPolicy,
    belief_policy,
    explore_policy,
    oracle_policy,
)
from pernav.env.render import Renderer
from pernav.world.constants import N_PLAYBACKS, PLAYBACK, TOWN_NAMES, Instruction, audio_duration, n_actions
from pernav.world.cost import tracking_cost
from pernav.world.drivers import (
    CONTEXT_CHOICES,
    NAMED_USERS,
    PROFILE_RANGES,
    Context,
    DriverProfile,
    ProfileError,
    named_user,
    resolve,
)
from pernav.world.files import DataFileError, is_file, read_data_file
from pernav.world.routing import Route, RouteError, plan_route
from pernav.world.simulation import World
from pernav.world.towns import TownError, get_town

#: what the navigation senses of the car at each of the world's frames between two decisions (the ``"frames"`` entry,
#: ``[frequency, len(FRAME_KEYS)]``): speed (m/s), acceleration (m/s^2), brake pedal (0-1), steering (-1..1 of the
#: vehicle's lock), signed offset from the centre of the lane the car is in (m; it jumps by a lane's width
#: when the car changes lane). A car's own sensors give these; nothing of the driver's profile or intent.
FRAME_KEYS = ("speed", "acceleration", "brake", "steering", "lane_offset")
REPLAY_AFTER = 15  # an unchanged instruction is replayed after this many steps (paper §5.1)
DEFAULT_CONFIG: dict[str, Any] = {
    "frequency": 10,  # simulation frames per policy step (one step = one second)
    "n_traffic": 8,  # traffic cars kept around the driver
    "adaptive_speed": False,  # 21 actions (instruction x playback speed) instead of 7
    "time_limit_factor": 2.0,  # episode truncated at factor x nominal route time + 30 s
    "nominal_speed": 10.0,  # m/s used for a route's nominal time
    "arrival_radius": 8.0,  # m from the destination that counts as arrived
    # when the navigation re-plans: "branch", in the step the car enters a lane the route does not continue on (the
    # car matched to the lane graph, as a car navigation does); "distance", the rule before: once the car is
    # ``reroute_distance`` m off the route, or 3x that while on a road the route uses (a wrong turn then cost
    # seconds of driving away before the re-plan)
    "reroute": "branch",
    "reroute_distance": 8.0,  # m off the route before the navigation re-plans (also "branch"'s lost-car fallback, x3)
    "plan_horizon": 5,  # steps of the planning context in info (goals, explore plan, action mask)
    "plan_shift": 2,  # explore-plan time shifts the planner may match (steps each way)
    "future_steps": 18,  # steps of the explore policy's future plan in info (the re-timing planner's input)
    "route_points": 96,  # points of the planned route ahead in info (every 3 m from 15 m behind the car)
    # info also carries "explore_table": what explore's rule says at each of the layout's EXPLORE_SPEEDS and
    # EXPLORE_POINTS ahead (a planner that imagines explore closed loop reads it; zeros where explore's plan holds no
    # prompt); off by default: it costs a few ms a step
    "explore_table": False,
    # info also carries "route_boxes": the metres to the next crossing's box on the route and since the route entered
    # the last (pernav.env.planning.route_boxes: map data, as the route is; the hybrid driver model reads it)
    "route_boxes": True,
    # what the navigation believes of its user (a mapping of Driver fields over the average driver's, e.g. a
    # learner's estimate of its reaction and decision times): info then carries "belief_action", the explore
    # rule re-timed for that belief, as "oracle_action" is the rule re-timed for the truth. A BeliefSource (e.g.
    # pernav.learners.belief.BeliefTracker) is a belief updated within the drive from each prompt's answer: a copy of it
    # follows the drive (``env.tracker``) and info also carries "belief_reaction", its reaction time now. None: off
    "belief": None,
}


def load_user(spec: Any) -> tuple[DriverProfile, Context | None]:
    """A user from a name (``user3``), a mapping or a JSON/YAML file path.

    A mapping holds profile fields and/or context keys, and optionally ``user`` (a named user the
    other fields override).

    >>> p, c = load_user({"user": "user1", "reaction_time": 2.0, "visual": "foggy"})
    >>> p.reaction_time, c.visual
    (2.0, 'foggy')
    """
    if isinstance(spec, DriverProfile):
        return spec, None
    if isinstance(spec, (str, Path)) and str(spec) in NAMED_USERS:
        return named_user(str(spec)), None
    if isinstance(spec, (str, Path)):
        path = Path(spec)
        try:  # a name too long for a path, or with a NUL byte, is no file either
            exists = path.exists()
        except (OSError, ValueError):
            exists = False
        if not path.suffix and not exists:
            raise ProfileError(f"unknown user {str(spec)!r}; choose one of {', '.join(NAMED_USERS)} or a profile file")
        if not is_file(path):
            raise ProfileError(f"user file {str(path)!r} does not exist or is not a file")
        try:
            spec = read_data_file(path)
        except DataFileError as exc:
            raise ProfileError(f"cannot read user file {str(path)!r}: {exc}") from None
    if not isinstance(spec, dict):
        raise ProfileError(f"a user must be a name, a mapping or a file, not {type(spec).__name__}")
    spec = dict(spec)
    base = spec.pop("user", None)
    profile = named_user(base).to_dict() if base is not None else DriverProfile().to_dict()
    context = {k: spec.pop(k) for k in list(spec) if k in CONTEXT_CHOICES}
    unknown = sorted(set(spec) - set(PROFILE_RANGES), key=str)  # keys of any type (YAML: 1, null)
    if unknown:
        allowed = ", ".join(["user", *PROFILE_RANGES, *CONTEXT_CHOICES])
        raise ProfileError(f"unknown profile field {unknown[0]!r}; allowed: {allowed}")
    profile.update(spec)
    return DriverProfile(**profile), (Context(**context) if context else None)


class NavigationEnv(gym.Env):
    """Voice navigation of a simulated driver through a town (docs/simulator.md).

    ``reset(options=...)``: ``route`` (index 0-9, or a :class:`Route` of this town), ``user`` (name, mapping, file or
    :class:`DriverProfile`), ``context`` (:class:`Context` or mapping). Actions: 0-6 (or 0-20 with
    ``adaptive_speed``: ``instruction * 3 + playback``, playback 0 slower / 1 normal / 2 faster).
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 10}

    def __init__(self, town: str = "Town1", config: dict | None = None, render_mode: str | None = None) -> None:
        if town not in TOWN_NAMES:
            raise TownError(f"unknown town {town!r}; choose one of {', '.join(TOWN_NAMES)}")
        unknown = sorted(set(config or {}) - set(DEFAULT_CONFIG))
        if unknown:
            raise ValueError(f"unknown config key {unknown[0]!r}; allowed: {', '.join(DEFAULT_CONFIG)}")
        belief = (config or {}).get("belief")
        if belief is not None and not isinstance(belief, (dict, BeliefSource)):
            raise ValueError(f"config 'belief' must be a mapping of driver fields or a BeliefSource, not "
                             f"{type(belief).__name__}")
        if (config or {}).get("reroute", "branch") not in ("branch", "distance"):
            raise ValueError(f"config 'reroute' must be 'branch' or 'distance', not {config['reroute']!r}")
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"render_mode {render_mode!r} not supported; use 'rgb_array'")
        self.config = {**DEFAULT_CONFIG, **(config or {})}
        self.town = get_town(town)
        self.render_mode = render_mode
        self.n_actions = n_actions(self.config["adaptive_speed"])
        self.action_space = gym.spaces.Discrete(self.n_actions)
        high = np.full(STATE_DIM, 1e4, dtype=np.float32)
        self.observation_space = gym.spaces.Box(-high, high, dtype=np.float32)
        self.profile = named_user("user1")
        self.context = Context()
        self.route_index = 0
        self.world: World | None = None
        self._explore = explore_policy()
        self._viewer = None
        # observers of a step as it happens (pernav.play: speak the prompt, draw and pace every frame); None in
        # the simulated drives: a step then runs exactly as without them
        self.on_prompt: Callable[[int, str], None] | None = None  # (instruction, playback) played
        self.on_frame: Callable[[], None] | None = None  # after each world frame

    # ----- helpers ------------------------------------------------------------------------------
    def decode(self, action: int) -> tuple[int, str]:
        """(instruction 0-6, playback) of an action of this env's action space."""
        if not 0 <= int(action) < self.n_actions:
            raise ValueError(f"action {action} out of range [0, {self.n_actions - 1}]")
        if self.config["adaptive_speed"]:
            return int(action) // N_PLAYBACKS, PLAYBACK[int(action) % N_PLAYBACKS]
        return int(action), "normal"

    def encode(self, instruction: int, playback: str = "normal") -> int:
        return instruction * N_PLAYBACKS + PLAYBACK.index(playback) if self.config["adaptive_speed"] else instruction

    def nav_view(self) -> NavView:
        log = [(i, s) for i, s, r in self._played if r == self.reroutes]
        return NavView(self.route, self.progress, float(self.world.ego.speed), self.last_instruction, log)

    def policy_action(self, policy: PromptPolicy) -> int:
        """The action a prompt policy takes now, in this env's action space."""
        return self.encode(policy(self.nav_view()))

    def explore_action(self) -> int:
        return self.policy_action(self._explore)

    def oracle_action(self) -> int:
        return self.policy_action(self._oracle)

    # ----- gymnasium API ------------------------------------------------------------------------
    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        options = dict(options or {})
        unknown = sorted(set(options) - {"route", "user", "context"})
        if unknown:
            raise ValueError(f"unknown reset option {unknown[0]!r}; allowed: route, user, context")
        custom = options.get("route") if isinstance(options.get("route"), Route) else None
        if "route" in options and custom is None:
            idx = options["route"]
            if isinstance(idx, bool) or not isinstance(idx, (int, np.integer)) or not 0 <= idx < len(self.town.routes):
                raise TownError(f"route index {idx!r} out of range [0, {len(self.town.routes) - 1}] for {self.town.name}")
            self.route_index = int(idx)
        if "user" in options:
            self.profile, ctx = load_user(options["user"])
            if ctx is not None:
                self.context = ctx
        if "context" in options:
            ctx = options["context"]
            if not isinstance(ctx, (Context, dict)):
                raise ProfileError(f"reset option 'context' must be a Context or a mapping, not {type(ctx).__name__}")
            unknown = sorted(set(ctx) - set(CONTEXT_CHOICES), key=str) if isinstance(ctx, dict) else []
            if unknown:
                raise ProfileError(f"unknown context field {unknown[0]!r}; allowed: {', '.join(CONTEXT_CHOICES)}")
            self.context = ctx if isinstance(ctx, Context) else Context(**ctx)
        self.driver = resolve(self.profile, self.context)
        self._oracle = oracle_policy(self.driver)
        belief = self.config["belief"]
        self.tracker = belief.copy() if isinstance(belief, BeliefSource) else None
        fields = self.tracker.fields() if self.tracker is not None else belief
        self._belief = None if fields is None else belief_policy(fields)
        self.route = custom or self.town.routes[self.route_index]
        self.goal_lane, self.goal_s = self.route.lanes[-1], self.route.end_s
        world_seed = int(self.np_random.integers(2**31 - 1))
        self.world = World(self.town, self.driver, self.route, seed=world_seed,
                           n_traffic=self.config["n_traffic"], frequency=self.config["frequency"])
        self.progress, self.off_route = 0.0, 0.0
        self.time = 0.0
        self.time_limit = self.config["time_limit_factor"] * self.route.length / self.config["nominal_speed"] + 30.0
        self.last_instruction, self.repeat = 0, 0
        self._played: list[tuple[int, float, int]] = []  # (instruction, route progress, reroutes)
        self.tracking_cost = 0.0
        self.frames = np.zeros((self.config["frequency"], len(FRAME_KEYS)), dtype=np.float32)
        self.last_frame: tuple[float, ...] = (0.0,) * len(FRAME_KEYS)  # the frame sensed last (FRAME_KEYS)
        self.prompt_start = self.prompt_end = -1.0  # simulated time a prompt played this step began / its audio ended
        self.missed_turns = self.wrong_turns = self.reroutes = 0
        self._rerouted_in: str | None = None  # the cross junction of the last re-plan (None: none, or elsewhere)
        self.completed = False
        self._explore_past: list[int] = []  # explore instructions of the past steps (planning context)
        self.goal = self.route.goal_waypoint(self.progress, 0.0)
        self.planned_length, self.odometer = self.route.length, 0.0
        return self._observation(), self._info(0.0, False)

    def step(self, action):
        if self.world is None:
            raise RuntimeError("call reset() before step()")
        cost, played, arrived, truncated = self.advance(action)
        return self._observation(), -cost, arrived, truncated, self._info(cost, played)

    def advance(self, action) -> tuple[float, bool, bool, bool]:
        """One step without the observation and info (what a planner's branch needs):
        ``(step cost, played, arrived, truncated)``."""
        instruction, playback = self.decode(action)
        self._explore_past = [*self._explore_past, self._explore(self.nav_view())][-max(self.config["plan_shift"], 1):]
        played = instruction != Instruction.NONE and (instruction != self.last_instruction or self.repeat >= REPLAY_AFTER)
        self.prompt_start = self.prompt_end = -1.0
        if played:
            self.prompt_start = float(self.world.time)
            self.prompt_end = self.prompt_start + audio_duration(instruction, playback)
            self.world.ego.hear(instruction, playback, self.world.time)
            self._played.append((instruction, self.progress, self.reroutes))
            if self.on_prompt is not None:
                self.on_prompt(instruction, playback)
            self.repeat = 0
        else:
            self.repeat += 1
        self.last_instruction = instruction
        before = self.world.ego.position.copy()
        frames = np.empty_like(self.frames)
        for k in range(self.config["frequency"]):
            self.world.frame()
            frames[k] = self.last_frame = self._sense()  # last_frame: what a frame's callback may read
            if self.on_frame is not None:
                self.on_frame()
        self.frames = frames
        self.odometer += float(np.linalg.norm(self.world.ego.position - before))
        self.time += 1.0
        self.world.maintain_traffic()
        ego = self.world.ego
        cost = float(tracking_cost(ego.position, self.goal))
        self.tracking_cost += cost
        self._follow_route()
        arrived = (self.route.length - self.progress < self.config["arrival_radius"]
                   and np.linalg.norm(ego.position - self.route.destination) < self.config["arrival_radius"] + 4)
        self.completed = bool(arrived)
        truncated = not arrived and self.time >= self.time_limit
        self.goal = self.route.goal_waypoint(self.progress, float(ego.speed))
        if self.tracker is not None:  # the belief reads this step's answer, and the rest once the drive ends
            moved = self.tracker.observe(instruction, played, self.prompt_end, self.frames, self.time,
                                         self.junction_info()["distance_to_junction"], self.missed_turns)
            if arrived or truncated:
                moved = self.tracker.finish() or moved
            if moved:
                self._belief = belief_policy(self.tracker.fields())
        return cost, played, bool(arrived), bool(truncated)

    def branch(self, seed: int | None = None) -> NavigationEnv:
        """A copy of this env in its current state that steps on independently (0.7 ms).

        With ``seed`` the copy draws fresh randomness (mishearing, compliance, guesses, traffic), so
        planning on it does not know the original's future; without, it replays the original exactly.

        >>> env = NavigationEnv("Town1", config={"n_traffic": 2})
        >>> _ = env.reset(seed=0, options={"route": 0})
        >>> twin = env.branch()
        >>> [env.step(2)[1] for _ in range(3)] == [twin.step(2)[1] for _ in range(3)]
        True
        """
        if self.world is None:
            raise RuntimeError("call reset() before branch()")
        memo = self.world.shared()
        memo.update({id(self.route): self.route, id(self.driver): self.driver, id(self.profile): self.profile,
                     id(self._explore): self._explore, id(self._oracle): self._oracle,
                     id(self._belief): self._belief})
        if self.tracker is not None and hasattr(self.tracker, "detector"):  # fixed weights: shared, not copied
            memo[id(self.tracker.detector)] = self.tracker.detector
        # the viewer, the observers and a person's controls stay with this env: the copy is drawn by no one and
        # driven by the simulated driver (a planner's branch imagines the driver it models)
        detached = (self._viewer, self.on_prompt, self.on_frame, self.world.ego.external)
        self._viewer = self.on_prompt = self.on_frame = self.world.ego.external = None
        try:
            twin = copy.deepcopy(self, memo)
        finally:
            self._viewer, self.on_prompt, self.on_frame, self.world.ego.external = detached
        twin.world.after_copy(memo, seed)
        return twin

    def _follow_route(self) -> None:
        """Track progress; re-plan from where the car is when it has left the route."""
        ego = self.world.ego
        self.progress, dist = self.route.project(ego.position, hint=self.progress)
        if not self._left_route(dist):
            return
        box = self.town.lane_junction.get(ego.lane_index)
        box = box if box is not None and self.town.junctions[box].kind == "cross" else None  # a ring's exits: each its own
        # a swerve back in the cross junction of the last re-plan is the same wrong branch, not a second one
        if self.config["reroute"] == "distance" or box is None or box != self._rerouted_in:
            self._count_wrong_branch()
        if self.config["reroute"] == "branch":
            start, start_s = ego.lane_index, float(ego.s)  # the new route starts on the lane the car is on
        else:  # the rule before: from the first lane after the box the car is in
            start = next((lane for lane in ego.path if self.town.lane_junction.get(lane) is None), ego.path[-1])
            start_s = ego.s if start == ego.path[0] else 0.0
        try:
            self.route = plan_route(self.town, start, start_s, [(self.goal_lane, self.goal_s)],
                                    name=self.route.name)
        except RouteError:  # nothing reaches the goal from here (cannot happen in the built-in towns)
            return
        self.reroutes += 1
        self._rerouted_in = box
        # the new route starts where the car is: a detour may pass back along this road on its other
        # side, and an unhinted projection would latch onto that (progress then runs backwards)
        self.progress, _ = self.route.project(ego.position, hint=0.0)

    def _left_route(self, dist: float) -> bool:
        """Has the car left the route? ``dist``: metres from the route's nearest waypoint."""
        ego, limit = self.world.ego, self.config["reroute_distance"]
        if self.config["reroute"] == "distance":
            # on a road of the route near the car's progress (a route may pass the same place twice:
            # a road of the route far from the projected point is not "on route")
            on_route = ego.path[0][:2] in self.route.roads and dist < 3 * limit
            return not (on_route or dist < limit)
        return dist >= 3 * limit or not self.on_route_road(ego.lane_index)

    def on_route_road(self, lane: tuple) -> bool:
        """Is ``lane`` (the lane the car is on) on a road the route takes at the car's progress? A lane beside the
        route's on the same road counts (the car changes lane on the way); a road the route takes far before or
        after this point does not (a route may pass the same place twice)."""
        route, margin = self.route, 2 * self.config["reroute_distance"]
        return any(lane[:2] == road[:2] and route.lane_start[i] - margin <= self.progress
                   <= route.lane_start[i] + self.town.lane(road).length + margin
                   for i, road in enumerate(route.lanes))

    def _count_wrong_branch(self) -> None:
        """A missed turn or a wrong turn: classified against the route's manoeuvre the driver decided differently
        on (the world's record of the branch taken), else a wrong turn."""
        ego = self.world.ego
        taken = {"stay": "pass"}
        for m in self.route.manoeuvres:
            choice = ego.last_choice.get(m.node)
            if m.decision and choice is not None and taken.get(choice, choice) != m.kind and m.s >= self.progress - 80:
                missed = (m.kind in ("left", "right") and choice == "straight") or (m.kind == "exit" and choice == "stay")
                self.missed_turns += int(missed)
                self.wrong_turns += int(not missed)
                return
        self.wrong_turns += 1

    def _sense(self) -> tuple[float, ...]:
        """One frame of :data:`FRAME_KEYS`: what the car's sensors show."""
        ego = self.world.ego
        offset = float(ego.lane.local_coordinates(ego.position)[1])
        return (float(ego.speed), float(ego.accel), float(ego.brake_input),
                float(ego.steer / ego.driver.vehicle.max_steering), offset)

    def extra_distance(self) -> float:
        """Metres driven beyond the planned route: distance driven plus what is left to the destination,
        minus the route planned at reset (a missed turn's detour shows here, not only in the tracking
        cost, which a re-route that skips waypoints can make cheaper)."""
        return max(self.odometer + self.route.length - self.progress - self.planned_length, 0.0)

    def _observation(self) -> np.ndarray:
        ego = self.world.ego
        ahead = self.route.upcoming(self.progress)
        d = ahead[0].s - self.progress if ahead else 1e3
        at_ring = float(ego.box is not None and self.town.junctions[ego.box].kind == "roundabout")
        v = ego.velocity
        obs = np.array([ego.position[0], ego.position[1], 0.0, v[0], v[1], 0.0, ego.heading, np.exp(-max(d, 0.0)),
                        at_ring, self.goal[0], self.goal[1], ego.steer / ego.driver.vehicle.max_steering, 0.0,
                        ego.brake_input], dtype=np.float32)
        return obs

    def junction_info(self) -> dict[str, Any]:
        """What an action mask needs: distance to the next decision junction and roundabout flags."""
        ahead = self.route.upcoming(self.progress)
        m = ahead[0] if ahead else None
        ego = self.world.ego
        in_ring = ego.box is not None and self.town.junctions[ego.box].kind == "roundabout"
        return {
            "distance_to_junction": float(m.s - self.progress) if m else 1e3,
            "next_manoeuvre": m.kind if m else "none",
            "in_roundabout": bool(in_ring),
            "near_roundabout": bool(in_ring or (m is not None and m.kind in ("enter", "exit", "pass")
                                                and m.s - self.progress < 150.0)),
        }

    def _info(self, cost: float, played: bool) -> dict[str, Any]:
        ev = self.world.events
        info = {
            "step_cost": cost,
            "tracking_cost": self.tracking_cost,
            "vehicle_collisions": ev.vehicle_collisions,
            "edge_strikes": ev.edge_strikes,
            "collisions": ev.vehicle_collisions + ev.edge_strikes,
            "traffic_collisions": ev.traffic_collisions,
            "missed_turns": self.missed_turns,
            "wrong_turns": self.wrong_turns,
            "reroutes": self.reroutes,
            "extra_distance": self.extra_distance(),
            "completed": self.completed,
            "time": self.time,
            "progress": self.progress / max(self.route.length, 1.0),
            "played": played,
            "prompt_start": self.prompt_start,
            "prompt_end": self.prompt_end,
            "frames": self.frames.copy(),
            "explore_action": self.explore_action(),
            "oracle_action": self.oracle_action(),
        }
        if self._belief is not None:
            info["belief_action"] = self.policy_action(self._belief)
        if self.tracker is not None:
            info["belief_reaction"] = self._belief.driver.reaction_time  # what the prompts are timed for now
        info.update(self.junction_info())
        info.update(self.planning_info(info["in_roundabout"]))
        return info

    def planning_info(self, in_roundabout: bool) -> dict[str, np.ndarray]:
        """The planner's context (see :mod:`pernav.env.planning`): goals, explore plan, action mask."""
        H, S = int(self.config["plan_horizon"]), int(self.config["plan_shift"])
        view = self.nav_view()
        speed = float(self.world.ego.speed)
        F = int(self.config["future_steps"])
        # one imagined explore future serves both the paper planner's shifted plan and the re-timing planner
        full = explore_plan(self._explore, view, self._explore_past, max(H, F - S), S)
        plan, future = full[: H + 2 * S], full[S: S + F]
        playbacks = N_PLAYBACKS if self.config["adaptive_speed"] else 1
        table = {}
        if self.config["explore_table"]:  # only where a prompt is ahead in the plan: elsewhere no planner searches
            table["explore_table"] = explore_table(self._explore, view) if bool(future.any()) else \
                np.zeros((len(EXPLORE_SPEEDS), EXPLORE_POINTS), dtype=np.int64)
        if self.config["route_boxes"]:
            table["route_boxes"] = route_boxes(self.town, self.route, self.progress)
        return {
            "plan_goals": plan_goals(self.route, self.progress, speed, H),
            "explore_plan": plan,
            "action_mask": action_mask(self.route, self.progress, speed, in_roundabout, plan, H, S, playbacks),
            "explore_future": future,
            "route_ahead": route_ahead(self.route, self.progress, int(self.config["route_points"])),
            **table,
        }

    def render(self):
        if self.render_mode != "rgb_array":
            return None
        if self._viewer is None:
            self._viewer = Renderer()
        return self._viewer.frame(self)

    def close(self) -> None:
        if self._viewer is not None:
            self._viewer.close()
            self._viewer = None
