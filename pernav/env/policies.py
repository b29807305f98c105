"""Rule-based prompt policies: the explore policy π^e and the oracle.

Both apply the same A*-route-aware rules — "prepare" then "turn" before a turn, "enter the roundabout"
on the approach, "turn right" for the roundabout exit, "keep left" for exits to pass — timed for a
driver: the explore policy for the population-average driver, the oracle for the true user.

Example:
    >>> import gymnasium as gym
    >>> import pernav
    >>> env = gym.make("pernav/Town1-v0")
    >>> obs, info = env.reset(seed=0, options={"route": 0})
    >>> policy = explore_policy()
    >>> policy(env.unwrapped.nav_view()) in range(7)
    True
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any, Protocol, runtime_checkable

import numpy as np

from pernav.world.constants import SIDED, WAYPOINT_SPACING, Instruction, audio_duration
from pernav.world.drivers import AVERAGE_CONTEXT, POPULATION_AVERAGE, Driver, resolve
from pernav.world.routing import Manoeuvre, Route
from pernav.world.towns import SPEED_RING

TURN = {"left": Instruction.TURN_LEFT, "right": Instruction.TURN_RIGHT}
PREPARE = {"left": Instruction.PREPARE_LEFT, "right": Instruction.PREPARE_RIGHT}
ENTER, KEEP_LEFT = Instruction.ENTER_ROUNDABOUT, Instruction.KEEP_LEFT
EXIT = Instruction.TURN_RIGHT  # a roundabout's exit is said "turn right"
DROPPED = SIDED  # what a driver drops on entering a junction box when heard before it
GUARD_RING_SPEED = SPEED_RING  # the speed the exit guard assumes on a ring (the car slows to it)


@dataclass
class NavView:
    """What a navigation system knows at a step: its route and where the car is on it, and the
    instructions it has played for the next manoeuvre."""

    route: Route
    progress: float
    speed: float
    last_action: int
    log: list[tuple[int, float]] = field(default_factory=list)  # (instruction, progress) played on this route

    def previous_manoeuvre(self) -> Manoeuvre | None:
        passed = [m for m in self.route.manoeuvres if m.decision and m.s <= self.progress]
        return passed[-1] if passed else None

    def played_for(self, target: Manoeuvre) -> set[int]:
        """Instructions played since the last decision at another junction before ``target`` (a
        roundabout's entry and exits share one window: their prompts may come before the entry;
        the "turn right" said for a roundabout's exit is not the one for a right turn after it)."""
        start = 0.0
        for m in self.route.manoeuvres:
            if m.decision and m.s < target.s and m.junction != target.junction:
                start = m.s
        return {i for i, s in self.log if s >= start}


@dataclass
class PromptPolicy:
    """Prompt timing for one driver model (the lead distances follow from its parameters).

    ``driver`` is what the navigation believes about the user; ``margin`` seconds of slack. ``fastest``, when
    the navigation is unsure of its user, is the quickest driver it may be speaking to: the rules say a prompt as
    early as ``driver`` needs it, but never so early that ``fastest`` would act on it at a junction before the one
    meant (a roundabout exit to pass) or forget a "prepare" before committing; and never before the car is inside
    the last junction box before the one meant (a prompt heard before a box is taken for that junction and dropped:
    explore's short leads rarely meet this, a slow belief's often). ``None``: ``driver`` itself, and no such waits
    (explore and the oracle)."""

    driver: Driver
    margin: float = 0.8
    prepare_gap: float = 6.0
    step: float = 1.0  # s between two decisions of the policy (one env step)
    fastest: Driver | None = None

    def __post_init__(self) -> None:
        # the slack covers a driver's slower prompts too: at least the 95th percentile of its reaction time
        # above the mean (~1.65 SD); for the average driver 0.73 s < 0.8 s, so explore's timing is unchanged
        self.margin = max(self.margin, 1.65 * self.driver.reaction_sd)

    def prepare_lead(self, v: float, lead: float) -> float:
        """Metres before the stop line at which to say "prepare": ``prepare_gap`` seconds before the
        "turn", but late enough that the driver still remembers it when committing (the prepare is
        its fallback when the "turn" is lost)."""
        d = self.fastest or self.driver
        remembered = v * (audio_duration(Instruction.PREPARE_LEFT) + d.reaction_time + d.memory + d.decision_time
                          - self.margin)
        return min(lead + v * (audio_duration(Instruction.PREPARE_LEFT) + self.prepare_gap), remembered)

    def _brake_distance(self, v: float, v_target: float) -> float:
        b = 0.6 * self.driver.comfort_decel
        return max(v * v - v_target * v_target, 0.0) / (2 * b)

    def turn_lead(self, v: float) -> float:
        """Metres before the stop line at which to say "turn": heard, understood, reacted to and
        still in time to brake comfortably before the driver commits."""
        d = self.driver
        react = v * (audio_duration(Instruction.TURN_LEFT) + d.reaction_time + self.margin)
        return react + max(v * d.decision_time, self._brake_distance(v, d.turn_speed))

    def exit_lead(self, v: float) -> tuple[float, float]:
        """(commit distance, prompt distance) before a roundabout exit."""
        d = self.driver
        commit = v * d.decision_time
        return commit, commit + v * (audio_duration(EXIT) + d.reaction_time + 1.25 * self.margin)

    def _exit_due(self, view: NavView, exit_: Manoeuvre, before: Manoeuvre | None) -> bool:
        """Say "turn right" for ``exit_`` now? Not so early that the driver would take the exit
        before it (``before``, a ring exit it must pass)."""
        v = max(view.speed, 3.0)
        if exit_.s - view.progress - v * self.step > self.exit_lead(v)[1]:  # the next step is still in time
            return False
        if before is None or before.kind == "enter":
            return True
        fast = self.fastest or self.driver  # the quickest listener must have passed ``before`` when it acts
        if self.fastest is not None:  # unsure of the user: the car slows to the ring's speed meanwhile, so the
            v = min(v, GUARD_RING_SPEED)  # listener acts sooner and commits closer than at this speed
        active_at = view.progress + v * (audio_duration(EXIT) + fast.reaction_time)
        return active_at >= before.s - v * fast.decision_time + 1.0

    def _box_before(self, view: NavView, target: Manoeuvre) -> bool:
        """Is there a junction box before ``target`` that the car may not have entered yet? A driver takes a turn or
        "prepare" heard before entering a junction (a bend too) for that junction, and drops it there. ``progress``
        is the nearest waypoint's: a junction counts as passed up to half a spacing early, hence the margin."""
        return any(m.kind in (*TURN, "straight") and view.progress - 2 * WAYPOINT_SPACING < m.s < target.s
                   for m in view.route.manoeuvres)

    def __call__(self, view: NavView) -> int:
        d = self.driver
        ahead = view.route.upcoming(view.progress)
        if not ahead:
            return Instruction.NONE
        m = target = ahead[0]
        v = max(view.speed, 5.0)
        dist = m.s - view.progress
        desired = Instruction.NONE
        if m.kind in TURN:
            lead = self.turn_lead(v)
            if dist - v * self.step <= lead:  # at the next step it would be too late
                desired = TURN[m.kind]
            elif dist <= self.prepare_lead(v, lead):
                desired = PREPARE[m.kind]
        elif m.kind in ("enter", "pass"):
            exit_ = next((x for x in ahead[1:] if x.kind == "exit"), None)
            passes = [x for x in ahead[1:] if x.kind == "pass" and exit_ is not None and x.s < exit_.s]
            if exit_ is not None and not passes and self._exit_due(view, exit_, m):
                desired, target = EXIT, exit_
            elif m.kind == "enter":
                ring = min(SPEED_RING, d.turn_speed + 1.0)
                if dist <= v * (audio_duration(ENTER) + d.reaction_time + 1.5) + self._brake_distance(v, ring):
                    desired = ENTER
            elif dist <= self.exit_lead(max(view.speed, 3.0))[1]:
                desired = KEEP_LEFT
        elif m.kind == "exit" and self._exit_due(view, m, view.previous_manoeuvre()):
            desired = EXIT
        if desired == Instruction.NONE:
            return Instruction.NONE
        if desired in DROPPED and self.fastest is not None and self._box_before(view, target):  # else dropped
            return Instruction.NONE
        if desired in view.played_for(target):  # said already: hold it (no replay) or stay silent
            return desired if view.last_action == desired else Instruction.NONE
        if view.last_action == desired:  # same words for a new manoeuvre: pause once so it plays
            return Instruction.NONE
        return desired


#: the driver fields the prompt rules read (what a belief about a user may set)
BELIEF_FIELDS = ("reaction_time", "decision_time", "turn_speed", "comfort_decel", "memory")


@runtime_checkable
class BeliefSource(Protocol):
    """A belief about the user that the navigation updates as a drive goes on (``NavigationEnv``'s
    ``config["belief"]``; :class:`pernav.learners.belief.BeliefTracker` is one). It reads what the navigation played and
    what it sensed of the car, never the driver's profile."""

    def copy(self) -> BeliefSource:
        """A copy for a new drive of the same user: the belief so far, no frames of this drive."""

    def observe(self, instruction: int, played: bool, prompt_end: float, frames: Any, step_end: float,
                junction: float | None = None, missed: int | None = None) -> bool:
        """One step's prompt, the car's frames, the distance to the next decision junction and the missed-turn count
        (what the navigation itself knows); True when the belief moved."""

    def finish(self) -> bool:
        """The drive ended; True when the belief moved."""

    def fields(self) -> dict[str, Any]:
        """What :func:`belief_policy` re-times the rules for now."""


def explore_policy() -> PromptPolicy:
    """π^e: prompts timed for the population-average driver in the average context."""
    return PromptPolicy(resolve(POPULATION_AVERAGE, AVERAGE_CONTEXT))


def oracle_policy(driver: Driver) -> PromptPolicy:
    """The same rules re-timed with the true user's profile and context."""
    return PromptPolicy(driver)


def belief_policy(belief: dict[str, Any]) -> PromptPolicy:
    """The same rules re-timed for what the navigation believes of its user: ``belief`` holds effective
    :class:`~pernav.world.drivers.Driver` fields (e.g. ``reaction_time``, ``decision_time``) that replace the
    average driver's; an empty belief is explore. An optional ``"fastest"`` entry holds the same fields for the
    quickest driver it may be (:class:`PromptPolicy`'s ``fastest``: the guards against a too-early prompt).

    >>> belief_policy({}).turn_lead(10.0) == explore_policy().turn_lead(10.0)
    True
    >>> belief_policy({"reaction_time": 2.5}).turn_lead(10.0) > explore_policy().turn_lead(10.0)
    True
    >>> belief_policy({"reaction_time": 2.5, "fastest": {"reaction_time": 0.9}}).fastest.reaction_time
    0.9
    """
    average = explore_policy().driver

    def driver(fields: dict[str, Any], where: str) -> Driver:
        unknown = sorted(set(fields) - set(BELIEF_FIELDS))
        if unknown:
            raise ValueError(f"unknown {where} field {unknown[0]!r}; allowed: {', '.join(BELIEF_FIELDS)}")
        return dataclasses.replace(average, **{k: float(v) for k, v in fields.items()})

    point = {k: v for k, v in belief.items() if k != "fastest"}
    fastest = belief.get("fastest")
    return PromptPolicy(driver(point, "belief"), fastest=None if fastest is None else driver(fastest, "fastest"))


def late_share(driver: Driver, lead_s: float, before: float, step: float = 1.0, n: int = 101) -> float:
    """Share of "turn" prompts said ``lead_s`` (+ up to one ``step``) seconds before the stop line that become
    active less than ``before`` seconds before it (``audio + reaction > lead - before``), from the driver's
    per-prompt reaction time (lognormal, :meth:`~pernav.world.drivers.Driver.reaction_draw`). Analytic: no
    simulation.

    >>> d = resolve(POPULATION_AVERAGE, AVERAGE_CONTEXT)
    >>> late_share(d, 20.0, 0.0) < 1e-6 < late_share(d, 3.0, 0.0)
    True
    """
    sigma = math.sqrt(math.log1p((driver.reaction_sd / driver.reaction_time) ** 2))
    mu = math.log(driver.reaction_time) - sigma**2 / 2
    cap = 3.0 * driver.reaction_time
    shares = []
    for u in np.linspace(0.0, step, n):  # where within the step the lead ran out: uniform
        x = lead_s + u - before - audio_duration(TURN["left"])  # the reaction time that just makes it
        if x <= 0:
            shares.append(1.0)
        elif x >= cap:
            shares.append(0.0)
        else:
            shares.append(0.5 * math.erfc((math.log(x) - mu) / (sigma * math.sqrt(2))))
    return float(np.mean(shares))


def lateness(driver: Driver, speed: float = 10.0) -> dict[str, float]:
    """How often explore's and the oracle's "turn" prompts reach ``driver`` after its commit point at ``speed``
    m/s (the driver chooses its branch ``max(decision_time, 4 m / speed)`` before the line), and the excess of
    explore's share over the oracle's: where personal timing has late prompts to fix.

    >>> from pernav.world.drivers import Context, named_user
    >>> round(lateness(resolve(named_user("user3"), Context()))["excess"], 2)
    0.8
    """
    commit = max(driver.decision_time, 4.0 / speed)
    out = {}
    for name, policy in (("explore", explore_policy()), ("oracle", oracle_policy(driver))):
        out[name] = late_share(driver, policy.turn_lead(speed) / speed, commit)
    out["excess"] = out["explore"] - out["oracle"]
    return out
