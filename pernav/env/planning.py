"""What a planner needs from the navigation at a step: goal waypoints, the explore plan, an action mask.

The MPC of docs/study.md scores imagined action sequences of ``horizon`` steps against the route's goal
waypoints, rewards sequences equal to the explore policy's sequence up to a time shift, and never issues
a turn where no junction is ahead. The navigation knows its route, so it provides, per step:

* ``plan_goals`` ``[H, 2]``: where the car should be after 1..H more steps at its current speed;
* ``explore_plan`` ``[H + 2S]`` (instructions 0-6): the explore policy's instructions for the ``S`` past
  steps, now, and the ``H - 1 + S`` next steps (the future imagined along the route at constant speed), so
  that ``explore_plan[S + k : S + k + H]`` is the explore sequence shifted by ``k`` steps, ``|k| <= S``;
* ``route_boxes`` ``[2]``: the metres to the next crossing the route enters and since it entered the last (a
  driver drops the sided prompts it heard before a crossing; the hybrid driver model reads it);
* ``action_mask`` ``[H, n_actions]``: which actions make sense at each level of the tree: silence always;
  "prepare"/"turn" only in the direction of the next turn and only when it is within ``TURN_REACH``;
  roundabout prompts only near or in a roundabout; and whatever the explore plan says at that level.

Example:
    >>> import gymnasium as gym
    >>> import pernav
    >>> env = gym.make("pernav/Town1-v0")
    >>> _, info = env.reset(seed=0, options={"route": 0})
    >>> info["plan_goals"].shape, info["explore_plan"].shape, info["action_mask"].shape
    ((5, 2), (9,), (5, 7))
    >>> bool(info["action_mask"][:, 0].all())
    True
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from pernav.env.layout import EXPLORE_POINTS, EXPLORE_SPEEDS, ROUTE_BEHIND, ROUTE_SPACING
from pernav.env.policies import ENTER, EXIT, KEEP_LEFT, PREPARE, TURN, NavView, PromptPolicy
from pernav.world.constants import GOAL_LOOKAHEAD_S, N_INSTRUCTIONS, WAYPOINT_SPACING, Instruction
from pernav.world.network import Town
from pernav.world.routing import Route

__all__ = ["RING_REACH", "TURN_REACH", "allowed_instructions", "explore_plan", "explore_table", "plan_goals",
           "route_ahead"]

TURN_REACH = 200.0  # m: a junction further than this is not "ahead within reach" (covers explore's "prepare")
RING_REACH = 150.0  # m: "near a roundabout"


def plan_goals(route: Route, progress: float, speed: float, horizon: int) -> np.ndarray:
    """``[horizon, 2]`` goal waypoints: the route point ``h`` steps ahead at the current speed, h = 1..H."""
    step = max(speed * GOAL_LOOKAHEAD_S, WAYPOINT_SPACING)
    return np.stack([route.point_at(progress + step * h) for h in range(1, horizon + 1)]).astype(np.float32)


def route_ahead(route: Route, progress: float, points: int) -> np.ndarray:
    """``[points, 2]`` route points every ``ROUTE_SPACING`` m from ``ROUTE_BEHIND`` m behind the car (the
    planned route a long-horizon planner measures an imagined car's distance and progress against)."""
    s = progress - ROUTE_BEHIND + ROUTE_SPACING * np.arange(points)
    idx = np.clip(np.searchsorted(route.s, s), 0, len(route.s) - 1)
    return route.waypoints[idx].astype(np.float32)


def route_boxes(town: Town, route: Route, progress: float) -> np.ndarray:
    """``[2]``: the metres to the next crossing's box the route enters and since the car's route entered the last one
    (1e3: none): map data (the env's ``route_boxes`` option). A driver drops the sided prompts it heard before it
    entered a crossing (they were for that one), so a model of the driver needs where the route enters them.

    >>> import gymnasium as gym
    >>> import pernav
    >>> env = gym.make("pernav/Town1-v0")
    >>> _, info = env.reset(seed=0, options={"route": 0})
    >>> [round(float(x)) for x in info["route_boxes"]], round(info["distance_to_junction"])  # the first decision's
    ([111, 1000], 111)
    """
    # a box is entered where the route's lane enters a crossing from outside it (a roundabout is not a box here: its
    # exits are announced before it and on it)
    boxes = [town.lane_junction.get(lane) for lane in route.lanes]
    boxes = [b if b is not None and town.junctions[b].kind == "cross" else None for b in boxes]
    starts = np.array([route.lane_start[i] for i, box in enumerate(boxes) if box is not None
                       and (i == 0 or boxes[i - 1] != box)])
    ahead, behind = starts[starts > progress], starts[starts <= progress]
    return np.array([ahead.min() - progress if len(ahead) else 1e3, progress - behind.max() if len(behind) else 1e3],
                    dtype=np.float32)


def explore_plan(policy: PromptPolicy, view: NavView, past: list[int], horizon: int, shift: int) -> np.ndarray:
    """The explore instructions for steps ``-shift .. horizon - 1 + shift`` (``past`` holds earlier ones).

    The future is imagined by advancing the car along the route at its current speed and recording
    what the policy would play, so repeated prompts are handled as in the env.
    """
    past = ([Instruction.NONE] * shift + list(past))[-shift:] if shift else []
    plan = list(past)
    log = list(view.log)
    last = view.last_action
    step = max(view.speed, 0.0)
    for h in range(horizon + shift):
        v = replace(view, progress=view.progress + step * h, last_action=last, log=log)
        action = policy(v)
        if action != Instruction.NONE and action != last:
            log = [*log, (action, v.progress)]
        last = action
        plan.append(action)
    return np.asarray(plan, dtype=np.int64)


def explore_table(policy: PromptPolicy, view: NavView, speeds: tuple[float, ...] = EXPLORE_SPEEDS,
                  points: int = EXPLORE_POINTS, spacing: float = ROUTE_SPACING) -> np.ndarray:
    """``[len(speeds), points]``: what ``policy`` says with the car ``j * spacing`` m further along its route at each
    speed, with what it has said so far (``view``'s log and last action). A planner reads explore's rule off it for a
    car it imagines, at that car's speed and place (explore's plan, :func:`explore_plan`, assumes the speed now).

    >>> import gymnasium as gym
    >>> import pernav
    >>> from pernav.env.policies import explore_policy
    >>> env = gym.make("pernav/Town1-v0")
    >>> _ = env.reset(seed=0, options={"route": 0})
    >>> explore_table(explore_policy(), env.unwrapped.nav_view()).shape
    (10, 81)
    """
    return np.asarray([[policy(replace(view, progress=view.progress + j * spacing, speed=float(v)))
                        for j in range(points)] for v in speeds], dtype=np.int64)


def allowed_instructions(route: Route, progress: float, in_roundabout: bool) -> np.ndarray:
    """``[7]`` bool: the instructions that make sense at route distance ``progress``."""
    allowed = np.zeros(N_INSTRUCTIONS, dtype=bool)
    allowed[Instruction.NONE] = True
    ahead = route.upcoming(progress, horizon=max(TURN_REACH, RING_REACH))
    if ahead:
        m = ahead[0]
        dist = m.s - progress
        if m.kind in TURN and dist <= TURN_REACH:
            allowed[[TURN[m.kind], PREPARE[m.kind]]] = True
        ring = [x.kind for x in ahead if x.kind in ("enter", "exit", "pass") and x.s - progress <= RING_REACH]
        if "enter" in ring:
            allowed[ENTER] = True
        if "exit" in ring:
            allowed[EXIT] = True
        if "pass" in ring:
            allowed[KEEP_LEFT] = True
    if in_roundabout:
        allowed[[EXIT, KEEP_LEFT]] = True
    return allowed


def action_mask(route: Route, progress: float, speed: float, in_roundabout: bool, plan: np.ndarray,
                horizon: int, shift: int, playbacks: int = 1) -> np.ndarray:
    """``[horizon, 7 * playbacks]`` bool mask of the actions allowed at each level of the tree."""
    step = max(speed * GOAL_LOOKAHEAD_S, 0.0)
    rows = []
    for h in range(horizon):
        allowed = allowed_instructions(route, progress + step * h, in_roundabout and h == 0)
        allowed[plan[shift + h]] = True  # the explore plan is always in the tree
        rows.append(np.repeat(allowed, playbacks))
    return np.stack(rows)
