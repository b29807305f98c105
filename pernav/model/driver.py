"""A world model that can represent a driver: what the navigation knows (its route, its prompts and their audio, the
car's speed) is not learned; a driver-response part with per-driver parameters (:class:`DriverParams`) says when a
prompt takes effect and what the car does then. The planner imagines each candidate prompt sequence with *this*
driver (:class:`DriverImaginedEnv`, an env with ``imagine`` for :class:`~pernav.planner.retiming.RetimingPlanner`).

The structure it assumes is the model's own, not the simulator's (it never calls :mod:`pernav.world`'s drivers or
traffic):

* a "turn" or "prepare" said before the car enters a crossing is dropped there (it was for that crossing): one of the
  history said before the car entered the last crossing, and one said before the car reaches a crossing that lies
  before the next decision junction (the env's ``route_boxes``: where the route enters crossings, map data); where the
  root does not hold them, a prompt of the history said over 160 m before the junction ahead is the last junction's
  (the model before the twenty-first session, which ignored explore's "prepare" said farther out to a fast car);
* a prompt played at the start of a step is heard by the end of its audio and takes effect a reaction time later,
  lognormal around the driver's mean reaction time ``R`` with a log-SD ``sigma`` (one draw per row of the
  imagination: rows are quantiles of that draw and samples of the driver's parameters);
* once a "turn" took effect the driver means to reach the junction at its turn speed (after a "prepare" alone,
  halfway between that and its cruise, which it also slows to a share ``prepared`` of): it brakes for it no earlier
  than its comfortable deceleration ``brake`` needs (harder if it learns of the turn too late), so a prompt that
  takes effect before that point changes nothing of the car's speed; it drives the turn at its turn speed;
* a "turn" is in effect from its effect until the next "turn", "prepare" or "keep left" is said (the driver acts on
  the latest instruction, from the moment it is said: a "prepare" after a "turn" says the turn is still to come);
* a "turn" or "prepare" names a side: one of the side the route does not turn to at the junction (read from the
  route's shape; not on a ring, whose exits are all "turn right") names the other branch, so it neither chooses nor
  prepares the route's, and such a "turn" supersedes the route's as any newer "turn" does;
* the driver commits to a branch ``D`` seconds (its decision time, at least 4 m) before the next decision junction, at
  its speed then (the moment interpolated between the imagination's steps): if no "turn" is in effect then, the car
  goes straight through the junction (a missed turn), else it follows the route; a "turn" that takes effect after the
  commit but before the car reaches the junction is swerved into, the car braking hard for it from then on (however
  fast it is: a late "turn" is yanked into, not given up; seventeenth session); a "prepare" heard without its
  "turn" chooses the branch in half of the rows (a driver may not trust it alone); where the route goes straight
  through the junction ahead (read from its shape), the prompts are for the next point where it turns, a "turn" in
  effect at (or swerved into before) the junction it goes straight through is taken there (a wrong turn), and a "turn"
  or "prepare" said before the car enters that junction is dropped there; whether it goes straight is read from the
  direction the route leaves by past the junction's box;
* on the way into a roundabout (the navigation's ``near_roundabout`` flag) nothing chooses a branch and the driver
  slows for the ring whatever it heard ("enter the roundabout" and "keep left" name no branch); on the ring
  (``in_roundabout``) a "turn" in effect when the driver commits takes the exit ahead, else it stays on the ring;
  the route takes that exit where its shape leaves the ring there, else it passes it (a "turn" in effect there is a
  wrong exit): a route that stays on the ring keeps bending the ring's way past the exit (the navigation's own plan
  cannot tell: it says the "turn" for the exit after this one before the car passes this one); the car drives the
  ring at its turn speed (it may have entered it from a stop);
* the car follows the planned route (the env's ``route_ahead``) at its current speed otherwise, back to its cruise
  after the junction; the goal is the navigation's own: where the car would be a step on at its speed.

The parameters are what :mod:`pernav.learners.driver` adapts to a driver from what the navigation senses.

Example:
    >>> import torch
    >>> from tensordict import TensorDict
    >>> route = torch.stack([torch.arange(96.0) * 3 - 15, torch.zeros(96)], -1)     # straight ahead along x
    >>> route[25:, 1] = (torch.arange(71.0) + 1) * 3; route[25:, 0] = route[24, 0]     # a right turn 57 m ahead
    >>> history = torch.zeros(5, 21); history[:, 3] = 10.0                          # 10 m/s, no prompt yet
    >>> root = TensorDict({"history": history, "route_ahead": route, "distance_to_junction": torch.tensor(57.0)}, [])
    >>> env = DriverImaginedEnv()
    >>> now, late = torch.full((12,), 2), torch.cat([torch.zeros(10, dtype=torch.long), torch.full((2,), 2)])
    >>> pos, goal = env.imagine(root, torch.stack([now, late]), [DriverParams(reaction_time=1.0)])
    >>> bool(pos[0, 0, -1, 1] > 5.0), bool(pos[0, 1, -1, 1].abs() < 1.0)    # said now: turned; said late: missed
    (True, True)
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from tensordict import TensorDictBase
from torchrl.data import Categorical, Composite, Unbounded
from torchrl.envs import EnvBase

from pernav.env.layout import ROUTE_BEHIND, ROUTE_SPACING, STATE_DIM
from pernav.model.egocentric import VX, VY
from pernav.world.constants import (
    AUDIO_DURATION,
    GOAL_LOOKAHEAD_S,
    N_INSTRUCTIONS,
    PREPARES,
    TURNS,
    WAYPOINT_SPACING,
    Instruction,
)

__all__ = ["DriverImaginedEnv", "DriverParams", "dropped_prompts", "imagine_drive"]

HERE = round(ROUTE_BEHIND / ROUTE_SPACING)  # the car's projection in ``route_ahead``
SUBSTEPS = 2  # the imagination's steps per one-second decision (0.5 s: a decision within its time budget)
MIN_COMMIT = 4.0  # m: a driver commits no closer to the junction than this
BOX_MARGIN = 2.0  # m: a junction box that starts this close before the decision junction is that junction's
PROMPT_REACH = 160.0  # m: no prompt is said further than this before its junction (a "prepare" at the latest speeds)
FAR = 1e3  # the env's distance_to_junction when no decision junction lies ahead
HARD_BRAKE = 2.5  # a driver's braking for a turn it learns of too late, in multiples of its comfortable deceleration
TURN_LENGTH = 12.0  # m past the junction's entry still driven at turn speed when turning
STRAIGHT_DEG = 30.0  # degrees: a route that turns less than this at a junction goes straight through it
JUNCTION_SPAN = 9.0  # m either side of a point over which the route's turn there is measured
# m past a junction's entry (``distance_to_junction``) where the route has left it: a turn's arc through a junction
# box is 15-25 m long, so the direction the route leaves by is measured past it, not at the entry
JUNCTION_ARC = 24.0
RING_REACH = 50.0  # m: the farthest a ring's exit ahead lies from a car on the ring
# the ring bends clockwise in the route's (x, y) coordinates (right-hand traffic in the world's y-down frame): a route
# that bends at least this much that way over RING_SPAN m past an exit stays on the ring (it passes that exit); one
# that leaves it bends the other way (Town3's and Town4's rings: -39.5 to -45.1 degrees against +12.9 to +21.9, by
# docs/research/scripts/ring_exits.py)
RING_BEND_DEG = -20.0
RING_SPAN = (5.0, 20.0)


@dataclass(frozen=True)
class DriverParams:
    """One driver as the model sees it (all in seconds, m/s, m/s^2).

    >>> DriverParams(reaction_time=2.0).reaction_time
    2.0
    """

    reaction_time: float = 1.2  # mean time from a prompt's audio end to its effect
    decision_time: float = 2.0  # s before the junction at which the driver commits to a branch
    sigma: float = 0.3  # log-SD of one prompt's reaction time around the mean
    turn_speed: float = 5.0  # the speed the driver brakes to for a turn
    brake: float = 2.0  # its deceleration
    cruise: float = 10.0  # the speed it drives at between junctions
    prepared: float = 0.75  # the share of its cruise it slows to on a "prepare"
    accel: float = 1.5  # its acceleration back to cruise

    def tensor(self) -> torch.Tensor:
        return torch.tensor([self.reaction_time, self.decision_time, self.sigma, self.turn_speed, self.brake,
                             self.cruise, self.prepared, self.accel], dtype=torch.float64)


QUANTILES = (-1.2816, -0.5244, 0.0, 0.5244, 1.2816)  # standard-normal quantiles of one prompt's reaction draw


def _audio(actions: torch.Tensor) -> torch.Tensor:
    table = torch.tensor(AUDIO_DURATION, dtype=torch.float64)
    return table[actions.long().clamp(0, N_INSTRUCTIONS - 1)]


def _arc(route: torch.Tensor) -> torch.Tensor:
    """``[P]``: the arc length of each point of ``route`` from its first. The env's points are the route's waypoints
    nearest to every ``ROUTE_SPACING`` m, so they lie 2 or 4 m apart, not 3: positions are read along the polyline
    itself, not from a uniform spacing (which made an imagined car at a constant speed move 8 and 10 m in turn)."""
    return torch.cat([route.new_zeros(1), (route[1:] - route[:-1]).norm(dim=-1).cumsum(0)])


def _route_at(route: torch.Tensor, s: torch.Tensor) -> torch.Tensor:
    """Points ``[..., 2]`` at arc length ``s`` ``[...]`` (m from the car's projection, the point ``HERE``) along a
    ``[P, 2]`` polyline (linear between its points; past the end it goes on straight, and stays where the route's
    last points repeat).

    >>> route = torch.tensor([[0.0, 0.0], [2.0, 0.0], [6.0, 0.0], [8.0, 0.0], [12.0, 0.0], [14.0, 0.0], [18.0, 0.0]])
    >>> _route_at(route, torch.tensor([0.0, 3.0, 6.0]))[:, 0].tolist()   # HERE is the sixth point, at 14 m
    [14.0, 17.0, 20.0]
    """
    P = route.shape[0]
    arc = _arc(route)
    a = (arc[min(HERE, P - 1)] + s).clamp(min=0.0)
    i = (torch.searchsorted(arc, a.contiguous(), right=True) - 1).clamp(0, P - 2)
    length = arc[i + 1] - arc[i]
    frac = torch.where(length > 0, (a - arc[i]) / length.clamp(min=1e-9), torch.zeros_like(a)).unsqueeze(-1)
    return route[i] + frac * (route[i + 1] - route[i])


def _end(route: torch.Tensor) -> float:
    """The arc length (m from the car's projection) of the route's last point."""
    arc = _arc(route)
    return float(arc[-1] - arc[min(HERE, route.shape[0] - 1)])


def _effects(hist: torch.Tensor, sequences: torch.Tensor, reaction: torch.Tensor, s_junction: float, v0: float,
             dropped_before: float = -math.inf, other_side: tuple[int, ...] = (), entered: float | None = None
             ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """``(first_turn, first_prepare, turn_from, turn_until)``: when the first "turn" and the first "prepare" for the
    junction ahead take effect (``[M, N]``, s from now; ``inf``: none), for each row's reaction time ``reaction``
    ``[M, 1]`` and each sequence (``[N, H]``, or ``[M, N, H]``: each row's own); and each played "turn"'s window in
    effect ``[M, N, T]``: from its effect until the next "turn", "prepare" or "keep left" is said (a newer instruction
    supersedes it as soon as it is said; ``inf`` if none).
    A "turn" or "prepare" said before ``dropped_before`` (s) does not count: the driver drops what it heard when it
    enters a junction (it was meant for that one). One of ``other_side`` (the side the route does not turn to) names
    the other branch: it neither chooses nor prepares the route's, and a "turn" of that side supersedes the route's."""
    seqs = sequences if sequences.dim() == 3 else sequences.unsqueeze(0)  # [S, N, H]: S = 1 or one per row
    S, N = seqs.shape[:2]
    # the prompts played: the history's (steps -K+1..-1) then the sequence's (steps 0..H-1); a repeat is held
    past = hist[:-1, STATE_DIM:STATE_DIM + N_INSTRUCTIONS]
    past_actions = torch.where(past.any(-1), past.argmax(-1), torch.zeros(len(past), dtype=torch.long))
    actions = torch.cat([past_actions.expand(S, N, -1), seqs.long()], -1)  # [S, N, K-1+H]
    starts = torch.arange(actions.shape[-1], dtype=torch.float64) - len(past_actions)  # step start times
    previous = torch.cat([torch.zeros(S, N, 1, dtype=torch.long), actions[..., :-1]], -1)
    played = (actions != Instruction.NONE) & (actions != previous)
    effect = starts + _audio(actions)  # [S, N, T] heard at the audio's end...
    effect = effect + reaction.unsqueeze(-1)  # [M, N, T] ...and acted on a reaction later
    # a prompt of the history is for the junction ahead only if it was said within reach of it (else it was the last
    # junction's): the navigation said it ``-start`` s ago, about ``v0 * -start`` m further back; where the navigation
    # gives its route's junction boxes, only if said after the car entered the last (the driver dropped the others)
    reach = (s_junction - v0 * starts.clamp(max=0.0)) <= PROMPT_REACH if entered is None else \
        starts >= -entered / max(v0, 0.1)
    ours = ~torch.isin(actions, torch.tensor(other_side, dtype=torch.long))  # [S, N, T] not the other side's
    prepare = torch.isin(actions, torch.tensor(PREPARES)) & ours
    # only a "turn" names a branch: "enter the roundabout" and "keep left" leave the driver on its way
    turn = torch.isin(actions, torch.tensor(TURNS)) & ours
    dropped = (turn | prepare) & (starts < dropped_before)
    effect = torch.where(played & reach & ~dropped, effect, torch.full_like(effect, math.inf))
    turn_from = torch.where(turn, effect, torch.full_like(effect, math.inf))  # [M, N, T]
    first_turn = turn_from.min(-1).values  # [M, N]
    first_prepare = torch.where(prepare, effect, torch.full_like(effect, math.inf)).min(-1).values
    # a "turn" holds until the next "turn", "prepare" or "keep left" is said: the driver acts on the latest it heard (a
    # "prepare" after a "turn" says the turn is still to come)
    supersedes = played & torch.isin(actions, torch.tensor((*TURNS, *PREPARES, Instruction.KEEP_LEFT)))  # [S, N, T]
    said = torch.where(supersedes, starts.expand_as(supersedes), torch.full(supersedes.shape, math.inf,
                                                                            dtype=torch.float64))
    # the first superseding start after each prompt's own: a reversed running minimum over the later ones
    later = torch.cat([said[..., 1:], torch.full_like(said[..., :1], math.inf)], -1)
    turn_until = later.flip(-1).cummin(-1).values.flip(-1)  # [S, N, T]
    return first_turn, first_prepare, turn_from, turn_until.expand_as(turn_from)


def _directions(route: torch.Tensor, s_junction: float) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """The junction's point on the route, and the unit directions the route comes in by and leaves by."""
    s_j = min(s_junction, 1e4)
    # the four points in one read of the route (each read measures the polyline's arc length)
    junction, behind, leaving, left = _route_at(route, torch.tensor(
        [s_j, max(s_j - JUNCTION_SPAN, -ROUTE_BEHIND), s_j + JUNCTION_ARC, s_j + JUNCTION_ARC + JUNCTION_SPAN],
        dtype=route.dtype))
    into, out = junction - behind, left - leaving
    return junction, into / into.norm().clamp(min=1e-6), out / out.norm().clamp(min=1e-6)


def _other_side(route: torch.Tensor, s_junction: float) -> tuple[int, int]:
    """The "turn" and "prepare" of the side the route does *not* turn to at the junction ``s_junction`` m ahead. The
    route's (x, y) are the world's, y down: a turn to the right is counter-clockwise there (explore's 724 sided
    prompts in five towns all agree, docs/research/scripts/prompt_sides.py)."""
    _, into, out = _directions(route, s_junction)
    right = float(into[0] * out[1] - into[1] * out[0]) > 0.0
    return (Instruction.TURN_LEFT, Instruction.PREPARE_LEFT) if right else \
        (Instruction.TURN_RIGHT, Instruction.PREPARE_RIGHT)


def _goes_straight(route: torch.Tensor, s_junction: float) -> bool:
    """Whether the route goes straight through the junction ahead (turns by under :data:`STRAIGHT_DEG`)."""
    if s_junction >= FAR:
        return False
    _, into, out = _directions(route, s_junction)
    return float((into * out).sum()) > math.cos(math.radians(STRAIGHT_DEG))


def _next_turn(route: torch.Tensor, s_from: float) -> float:
    """The arc length of the first point past ``s_from`` where the route turns (by :data:`STRAIGHT_DEG` or more over
    a junction's length), or :data:`FAR` if it goes straight to the end of ``route``."""
    s_end = _end(route) - JUNCTION_SPAN
    if s_from + ROUTE_SPACING >= s_end:  # the junction ahead is at the end of what the route shows
        return FAR
    s = torch.arange(s_from + ROUTE_SPACING, s_end, ROUTE_SPACING, dtype=torch.float64)
    here = _route_at(route, s)
    into, out = here - _route_at(route, s - JUNCTION_SPAN), _route_at(route, s + JUNCTION_SPAN) - here
    cos = (into * out).sum(-1) / (into.norm(dim=-1) * out.norm(dim=-1)).clamp(min=1e-6)
    turns = (cos < math.cos(math.radians(STRAIGHT_DEG))).nonzero()
    return float(s[turns[0, 0]]) if len(turns) else FAR


def _bend(route: torch.Tensor, a: float, b: float) -> float:
    """The route's heading change from arc length ``a`` to ``b`` (degrees, counter-clockwise positive in its (x, y))."""
    p = _route_at(route, torch.tensor([a - 1.0, a + 1.0, b - 1.0, b + 1.0], dtype=route.dtype))
    h1, h2 = p[1] - p[0], p[3] - p[2]
    return math.degrees(math.atan2(float(h1[0] * h2[1] - h1[1] * h2[0]), float((h1 * h2).sum())))


def _stays_on_ring(route: torch.Tensor, s_exit: float) -> bool:
    """Whether the route passes the ring's exit ``s_exit`` m ahead (keeps bending the ring's way past it)."""
    return _bend(route, s_exit + RING_SPAN[0], s_exit + RING_SPAN[1]) <= RING_BEND_DEG


def _junction_ahead(root: TensorDictBase, route: torch.Tensor) -> tuple[float, float, bool, bool, bool]:
    """``(s_first, s_junction, through, ring, in_ring)``: the next manoeuvre's arc length (the env's
    ``distance_to_junction``), the one the prompts are for (where the route goes straight through the first, the next
    point it turns at), whether it goes straight through the first, and the navigation's own roundabout flags."""
    keys = root.keys()
    s_first = float(root["distance_to_junction"]) if "distance_to_junction" in keys else FAR
    # in a ring's box with the next manoeuvre beyond the ring's reach, the car is leaving it: the next is a junction
    in_ring = "in_roundabout" in keys and bool(root["in_roundabout"]) and s_first < RING_REACH
    ring = in_ring or ("near_roundabout" in keys and bool(root["near_roundabout"]))
    through = not ring and _goes_straight(route, s_first)
    return s_first, (_next_turn(route, s_first) if through else s_first), through, ring, in_ring


def _positions(route: torch.Tensor, s_junction: float, s_all: torch.Tensor, taken: torch.Tensor, wrong: torch.Tensor,
               s_wrong: float) -> torch.Tensor:
    """``[M, N, H, 2]`` positions at arc lengths ``s_all``: along the route, but straight on past the junction
    ``s_junction`` whose turn was missed (``taken`` ``[M, N, H]`` false) and off to the side past the junction
    ``s_wrong`` the route goes straight through, where a turn was taken (``wrong`` ``[M, N]``)."""
    junction, into, _ = _directions(route, s_junction)
    past = (s_all - s_junction).clamp(min=0.0).unsqueeze(-1)
    pos = torch.where(~taken.unsqueeze(-1) & (s_all > s_junction).unsqueeze(-1), junction + past * into,
                      _route_at(route, s_all))
    if not bool(wrong.any()):
        return pos
    junction, into, _ = _directions(route, s_wrong)
    side = torch.stack([-into[1], into[0]])
    off = junction + (s_all - s_wrong).clamp(min=0.0).unsqueeze(-1) * side
    return torch.where(wrong[..., None, None] & (s_all > s_wrong).unsqueeze(-1), off, pos)


def imagine_drive(root: TensorDictBase, sequences: torch.Tensor, drivers: torch.Tensor
                  ) -> tuple[torch.Tensor, torch.Tensor]:
    """Positions and goals ``([M, N, H, 2], [M, N, H, 2])`` of the car after each step of each action sequence
    ``[N, H]`` (7 instructions; or ``[M, N, H]``, each row's own, as a policy played closed loop gives) from ``root``,
    for ``M`` rows of ``drivers`` ``[M, 10]``: the eight :class:`DriverParams` fields, whether a "prepare" alone chooses
    the branch (0 or 1) and the row's reaction-time quantile ``z``.

    ``root`` holds ``"history"`` ``[K, 14 + 7]`` (the prompts of the last ``K - 1`` steps and the car now),
    ``"route_ahead"`` ``[P, 2]`` and ``"distance_to_junction"`` (what the navigation env provides)."""
    hist = root["history"].double()
    route = root["route_ahead"].double()
    s_first, s_junction, through, ring, in_ring = _junction_ahead(root, route)
    # on the ring, the exit ahead is the route's where the route leaves the ring there; where it passes the exit, a
    # turn in effect when the driver commits leaves the route (a wrong exit), none keeps to it
    passing = in_ring and _stays_on_ring(route, s_first)
    N, H = sequences.shape[-2:]
    M = drivers.shape[0]
    if sequences.dim() == 3 and sequences.shape[0] != M:
        raise ValueError(f"sequences: one per row needs [{M}, N, H] for {M} rows, got {list(sequences.shape)}")
    drivers = drivers.double()
    R, D, sigma = (drivers[:, k].reshape(M, 1) for k in range(3))
    follow, z = drivers[:, 8].reshape(M, 1), drivers[:, 9].reshape(M, 1)
    reaction = R * torch.exp(sigma * z - sigma**2 / 2)  # [M, 1] this row's draw (mean R over draws)
    state = hist[-1]
    v0 = float(torch.hypot(state[VX], state[VY]))
    # the prompts heard by the next junction; where the route goes straight through it, those said before the car
    # enters it are dropped there, and the ones after are for the junction it turns at
    # at a junction (not a ring, whose exits are all "turn right"), a prompt of the side the route does not turn to
    # names the other branch: the car does not follow the route there
    other = () if ring or s_junction >= FAR else _other_side(route, s_junction)
    # the navigation's junction boxes on its route: a prompt said before the car enters one ahead of the junction is
    # dropped there (it was for that one), as one said before the car entered the last
    box_ahead, entered = (float(root["route_boxes"][0]), float(root["route_boxes"][1])) if "route_boxes" in root.keys() \
        else (math.inf, None)
    moving = max(v0, 0.1)  # the speed the moments of reaching a box or a junction are read at
    drop = box_ahead / moving if box_ahead < s_first - BOX_MARGIN else -math.inf
    heard = _effects(hist, sequences, reaction, s_first, v0, drop, () if through else other, entered)
    if through:
        heard, heard_first = _effects(hist, sequences, reaction, s_first, v0, max(drop, s_first / moving), other,
                                      entered), heard
    first_turn, first_prepare = heard[:2]
    start = float(torch.clamp(D * v0, min=MIN_COMMIT).min())  # a junction this close was decided before the root (unknown)
    # the junction the route goes straight through: a turn in effect there is taken there (a wrong turn); the one it
    # turns at: followed if a turn is in effect (on a ring where the route passes the exit, left if one is)
    first = _Decision(s_first, (M, N), s_first <= start, heard_first, follow, swerve=True, chosen=False) \
        if through else None
    junction = _Decision(s_junction, (M, N), s_junction <= start, heard, follow, swerve=not ring, chosen=True,
                         invert=passing)
    if ring and not in_ring:  # on the way in no branch is chosen; the driver sees the ring and slows for it
        first_turn = junction.prepared_by = torch.full_like(first_turn, -math.inf)
    elif in_ring:  # on the ring only a "turn" chooses: it takes the exit ahead
        junction.prepared_by = torch.full_like(first_turn, math.inf)
    s = torch.zeros(M, N, dtype=torch.float64)
    v = torch.full((M, N), v0, dtype=torch.float64)
    dt = 1.0 / SUBSTEPS
    out_s, out_taken, out_v = [], [], []
    for h in range(H):
        for k in range(SUBSTEPS):
            t = h + (k + 1) * dt
            # the driver commits D seconds before the junction at its speed then (a braking car commits later)
            commit_distance = torch.clamp(D * v, min=MIN_COMMIT)  # [M, N]
            for decision in (first, junction):
                if decision is not None:
                    decision.step(s, v, commit_distance, t - dt, dt)
            taken = junction.chosen
            d = s_junction - s
            turning = (first_turn <= t) & taken
            preparing = (first_prepare <= t) & (d > 0)
            # on the ring the car drives at its turn speed up to the exit ahead, and past it if it stays on the ring
            ring_speed = ((d > -TURN_LENGTH) | ~(taken ^ passing)) if in_ring else None
            v = _next_speed(v, d, turning, preparing, ring_speed, drivers, dt)
            s = s + v * dt
        out_s.append(s.clone())
        out_taken.append(taken.clone())
        out_v.append(v.clone())
    s_all = torch.stack(out_s, -1)  # [M, N, H]
    taken_all = torch.stack(out_taken, -1)
    wrong = first.chosen if first is not None else torch.zeros(M, N, dtype=torch.bool)
    pos = _positions(route, s_junction, s_all, taken_all, wrong, s_first)
    # the navigation's goal: where the car would be one step on at its speed, along the route
    v_all = torch.stack(out_v, -1)
    goal = _route_at(route, s_all + torch.clamp(v_all * GOAL_LOOKAHEAD_S, min=WAYPOINT_SPACING))
    return pos.float(), goal.float()


def dropped_prompts(root: TensorDictBase, sequences: torch.Tensor) -> torch.Tensor:
    """``[N]``: the "turn" and "prepare" prompts each sequence ``[N, H]`` plays (not held) before the car enters a
    junction the route goes straight through: the driver drops what it heard there (it was meant for that junction),
    so they are for no junction. The entry is imagined at the car's speed now.

    >>> import torch
    >>> from tensordict import TensorDict
    >>> route = torch.stack([torch.arange(96.0) * 3 - 15, torch.zeros(96)], -1)  # straight on through a junction 20 m
    >>> route[60:, 1] = (torch.arange(36.0) + 1) * 3; route[60:, 0] = route[59, 0]  # ahead, then a right turn
    >>> history = torch.zeros(5, 21); history[:, 3] = 10.0
    >>> root = TensorDict({"history": history, "route_ahead": route, "distance_to_junction": torch.tensor(20.0)}, [])
    >>> dropped_prompts(root, torch.tensor([[4, 4, 4, 0], [0, 0, 4, 4]])).tolist()  # said at 0 s: dropped; at 2 s: not
    [1, 0]
    """
    route = root["route_ahead"].double()
    s_first, _, through, _, _ = _junction_ahead(root, route)
    N, H = sequences.shape
    if not through:
        return torch.zeros(N, dtype=torch.long)
    state = root["history"][-1].double()
    v0 = float(torch.hypot(state[VX], state[VY]))
    past = root["history"][-2, STATE_DIM:STATE_DIM + N_INSTRUCTIONS] if root["history"].shape[0] > 1 else None
    last = int(past.argmax()) if past is not None and bool(past.any()) else Instruction.NONE
    previous = torch.cat([torch.full((N, 1), last, dtype=torch.long), sequences[:, :-1].long()], 1)
    played = (sequences != previous) & torch.isin(sequences, torch.tensor((*TURNS, *PREPARES)))
    before = torch.arange(H, dtype=torch.float64) < s_first / max(v0, 0.1)
    return (played & before).sum(-1)


class _Decision:
    """One junction's branch, as the driver chooses it: at its commit ``D`` s (at its speed then) before the junction
    ``at`` (m), from the "turn" (or followed "prepare") in effect then; with ``swerve``, a "turn" that takes effect
    after the commit and before the car reaches the junction is swerved into (the car then brakes hard for it,
    :func:`_next_speed`). ``heard``:
    :func:`_effects` of the prompts for it; ``follow`` ``[M, 1]``: the rows where a "prepare" alone chooses.
    ``chosen`` ``[M, N]``: turned (with ``invert``: did not); its initial value where the junction was decided before
    the root (``decided``)."""

    def __init__(self, at: float, shape: tuple[int, int], decided: bool, heard: tuple, follow: torch.Tensor,
                 swerve: bool, chosen: bool, invert: bool = False) -> None:
        self.at, self.swerve, self.invert = at, swerve, invert
        _, first_prepare, self.turn_from, self.turn_until = heard
        self.prepared_by = torch.where(follow > 0, first_prepare, torch.full_like(first_prepare, math.inf))
        self.committed = torch.full(shape, decided)
        self.reached = torch.full(shape, at <= 0)
        self.chosen = torch.full(shape, chosen)

    def turns_at(self, point: torch.Tensor | float, s: torch.Tensor, v: torch.Tensor, t: float, dt: float,
                 prepare: bool = True) -> torch.Tensor:
        """``[M, N]``: whether the latest "turn" the driver heard (or, with ``prepare``, a followed "prepare") is in
        effect when it passes ``point`` (m); it was at ``s`` at ``t``: the moment is interpolated within the last
        step ``dt`` (a "keep left" said a moment after the commit no longer counts)."""
        at = (t - (s - point) / v.clamp(min=0.1)).clamp(min=t - dt).unsqueeze(-1)
        turn = ((self.turn_from <= at) & (at < self.turn_until)).any(-1)
        return turn | (self.prepared_by <= at[..., 0]) if prepare else turn

    def step(self, s: torch.Tensor, v: torch.Tensor, commit_distance: torch.Tensor, t: float, dt: float) -> None:
        """The car, at ``s`` at time ``t`` at speed ``v``, moves on."""
        inside = (~self.committed) & (self.at - s <= commit_distance)
        if bool(inside.any()):
            chosen = self.turns_at(self.at - commit_distance, s, v, t, dt) ^ self.invert
            self.chosen = torch.where(inside, chosen, self.chosen)
        self.committed = self.committed | inside
        if self.swerve:
            late = self.committed & ~self.reached & ~self.chosen  # committed to going on, not yet at the junction
            if bool(late.any()):  # a "turn" in effect now, or when it reached the junction: swerved into
                now = self.turns_at(s.clamp(max=self.at), s, v, t, dt, prepare=False)
                self.chosen = self.chosen | (late & now)
            self.reached = self.reached | (self.at - s <= 0)


def _next_speed(v: torch.Tensor, d: torch.Tensor, turning: torch.Tensor, preparing: torch.Tensor,
                ring: torch.Tensor | None, drivers: torch.Tensor, dt: float) -> torch.Tensor:
    """``[M, N]``: the speed ``dt`` on from ``v``, ``d`` m before the junction: the driver means to reach it at its
    turn speed once it knows it turns, halfway to its cruise on a "prepare" alone, and brakes for it only as late as
    its comfortable deceleration allows (harder for a turn it learns of too late); where ``ring``, it drives at its
    turn speed (a ring is a long turn)."""
    M = drivers.shape[0]
    v_turn, brake, cruise, prepared, accel = (drivers[:, k].reshape(M, 1) for k in range(3, 8))
    cruise = cruise.expand_as(v)
    before = d > 0
    inf = torch.full_like(v, math.inf)
    arrive = torch.where(turning & before, v_turn.expand_as(v), inf)
    arrive = torch.where(preparing & ~turning, (v_turn + cruise) / 2, arrive)
    reach = torch.sqrt(arrive.clamp(max=FAR) ** 2 + 2 * brake * d.clamp(min=0.0))
    reach = torch.where(torch.isinf(arrive), inf, reach)
    target = torch.where(preparing, torch.minimum(cruise, prepared * cruise), cruise)
    target = torch.where(turning & ~before & (d > -TURN_LENGTH), torch.minimum(target, v_turn), target)
    target = torch.minimum(target, reach)
    if ring is not None:
        target = torch.where(ring, v_turn.expand_as(target), target)
    down = torch.where(reach < v, HARD_BRAKE * brake, brake).expand_as(v)
    return torch.where(v > target, torch.maximum(v - down * dt, target), torch.minimum(v + accel * dt, target))


class DriverImaginedEnv(EnvBase):
    """The hybrid world model as a planner's env: ``imagine(root, sequences, params)`` with ``params`` a list of
    driver rows (:class:`DriverParams` or ``[8]`` tensors; each imagined at the reaction quantiles ``quantiles``),
    or ``None``: :attr:`drivers`, set by whoever adapts the model (the planner reads it at every decision).

    >>> env = DriverImaginedEnv()
    >>> env.rows().shape
    torch.Size([10, 10])
    """

    def __init__(self, drivers: list[DriverParams] | None = None, quantiles: tuple[float, ...] = QUANTILES) -> None:
        super().__init__(batch_size=torch.Size([]))
        self._batch_locked = False
        self.drivers = list(drivers) if drivers else [DriverParams()]
        self.quantiles = tuple(quantiles)
        self.action_spec = Categorical(N_INSTRUCTIONS)
        self.observation_spec = Composite(observation=Unbounded((STATE_DIM,)))
        self.reward_spec = Unbounded((1,))

    # the model imagines whole sequences from a real root (what a planner asks); it is not stepped one action at a time
    def _reset(self, tensordict: TensorDictBase | None = None, **kwargs) -> TensorDictBase:
        raise NotImplementedError("DriverImaginedEnv only imagines sequences from a real root: call imagine()")

    def _step(self, tensordict: TensorDictBase) -> TensorDictBase:
        raise NotImplementedError("DriverImaginedEnv only imagines sequences from a real root: call imagine()")

    def _set_seed(self, seed: int | None) -> None:
        pass

    def rows(self, params: list | None = None) -> torch.Tensor:
        """``[M, 10]``: every driver row at every reaction quantile, with and without following a "prepare" alone."""
        drivers = params if params is not None else self.drivers
        base = torch.stack([d.tensor() if isinstance(d, DriverParams) else torch.as_tensor(d, dtype=torch.float64)
                            for d in drivers])
        z = torch.tensor(self.quantiles, dtype=torch.float64)
        follow = torch.tensor([0.0, 1.0], dtype=torch.float64)  # whether a "prepare" alone chooses the branch
        n = len(base) * len(follow) * len(z)
        return torch.cat([base.repeat_interleave(len(follow) * len(z), 0),
                          follow.repeat_interleave(len(z)).repeat(len(base)).unsqueeze(-1),
                          z.repeat(len(base) * len(follow)).unsqueeze(-1)], 1).reshape(n, -1)

    @torch.no_grad()
    def imagine(self, root: TensorDictBase, sequences: torch.Tensor, params: list | None = None
                ) -> tuple[torch.Tensor, torch.Tensor]:
        """``([M, N, H, 2], [M, N, H, 2])`` positions and goals (:func:`imagine_drive`)."""
        return imagine_drive(root, sequences, self.rows(params))

    @torch.no_grad()
    def dropped(self, root: TensorDictBase, sequences: torch.Tensor) -> torch.Tensor:
        """``[N]``: how many "turn" and "prepare" prompts each sequence says where this model's driver drops them
        (:func:`dropped_prompts`): a prompt said where it is dropped is a prompt not said."""
        return dropped_prompts(root, sequences)
