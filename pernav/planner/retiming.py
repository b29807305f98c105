"""RetimingPlanner: a long-horizon discrete tree search over re-timings of the explore plan (pernav's default).

The paper's planner (:class:`~pernav.planner.tree_search.TreeSearchPlanner`, horizon 5) cannot see a prompt's
consequence for a slow driver: audio, reaction, commit and the turn take 8-12 s. This planner searches a
small tree whose branches are the explore policy's *own* upcoming prompts re-timed (the MPC policy is a
residual of explore, as the paper intends), over a horizon long enough to see the turn (12 s by default):

* ``advance k`` (k = 1..A): the explore plan ``k`` steps early (its next prompt said now, if it is within k;
  never skipping an instruction explore would say before it);
* ``delay k`` (k = 1..D): silence (or the held prompt) for ``k`` more steps, then the explore plan (with
  ``Departure(kept_delays=True)``, only where explore still says the delayed prompt ``k`` steps on);
* ``say a now``: every instruction the situation allows at this step (the fine choice near a junction),
  held for the horizon (a held instruction is not replayed);
* with 21 actions, each of these at the three playback speeds.

Each candidate is imagined from the current state by the env's ``imagine`` (a learned
:class:`~pernav.model.navigation.ImaginedNavigationEnv`, one row per ensemble member, or the true simulator,
:class:`~pernav.diagnostics.TrueDynamicsEnv`, one row per re-seeded sample) and scored by

    sum_h tracking_cost(pos_h, goal_{h-1})  +  route_weight * sum_h dist(pos_h, planned route)^2
                                            -  progress_weight * (route distance of pos_H)

The first term is the env's own step cost; the second makes a missed turn or a circled roundabout cost
inside the horizon (the env re-routes after a miss, so its goals alone would forgive it); the third keeps
stopping from looking cheap. The planner leaves explore only where the imagined gain is clear: the best
candidate must beat explore's plan by ``margin`` (absolute) plus ``rel_margin`` (relative) on average *and*
in at least ``agree`` of the rows (ensemble members or samples; with ``agree=1`` the worst member's gain must
clear it: a lower confidence bound), and the rows must agree on what the re-timing does to the car's path (the
spread of its effect, at most ``max_spread`` metres plus ``rel_spread`` times the effect's size); otherwise it
plays explore's action. So a poor or uncertain model costs little.

Reads ``"history"``, ``"explore_future"`` ``[F]``, ``"route_ahead"`` ``[P, 2]`` and ``"action_mask"`` (the
navigation env provides them, :mod:`pernav.env.planning`); writes ``"action"``.

Example:
    >>> import torch
    >>> from tensordict import TensorDict
    >>> from pernav.model import DynamicsModel
    >>> from pernav.model.navigation import ImaginedNavigationEnv, make_world_model
    >>> planner = RetimingPlanner(ImaginedNavigationEnv(make_world_model(DynamicsModel(hidden=(16,)))), horizon=4)
    >>> td = TensorDict({"history": torch.zeros(5, 21), "explore_future": torch.tensor([0, 0, 4, 4, 2, 2, 0, 0]),
    ...                  "route_ahead": torch.zeros(10, 2), "action_mask": torch.ones(5, 7, dtype=torch.bool)}, [])
    >>> int(planner(td)["action"]) in range(7)
    True
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModuleBase
from torchrl.modules.planners import MPCPlannerBase

from pernav.env.layout import EXPLORE_SPEEDS, ROUTE_SPACING, STATE_DIM
from pernav.model.egocentric import GX, GY, VX, VY, X, Y
from pernav.planner.discrete import planning_roots
from pernav.world.constants import N_ADAPTIVE_ACTIONS, N_INSTRUCTIONS, N_PLAYBACKS, PREPARES, Instruction
from pernav.world.cost import tracking_cost

__all__ = ["Departure", "RetimedExplore", "RetimingPlanner", "RetimingResult", "ShiftedExplore", "candidate_plans"]


@dataclass
class RetimingResult:
    """One decision: the candidates, their mean costs, which one is explore's and which was chosen."""

    candidates: torch.Tensor  # [N, H] actions
    costs: torch.Tensor  # [N] mean over rows
    explore: int
    chosen: int
    gain: float  # explore's cost minus the chosen one's (0 when explore is kept)
    spread: torch.Tensor | None = None  # [N] the rows' disagreement (m) on each candidate's effect


def candidate_plans(future: torch.Tensor, last: int, allowed: torch.Tensor, horizon: int, advance: int,
                    delay: int, in_order: bool = False, kept_delays: bool = False) -> tuple[torch.Tensor, int]:
    """The candidate instruction sequences ``[N, horizon]`` (unique) and the index of explore's own plan.

    ``future`` holds explore's instructions for the next steps (at least ``horizon + advance``), ``last``
    the instruction played last step, ``allowed`` the instructions the situation allows now. With ``in_order``
    the fine choices keep explore's order as the advances do: an instruction said now is a candidate only if it
    skips none that explore would say before it within reach (a "turn" now is none while explore's "prepare" is
    still to come). With ``kept_delays`` a delay of ``k`` is a candidate only where explore still says its next
    prompt ``k`` steps after it is due: explore says a "prepare" over a window of distance, and a "prepare" held back
    past it is never said (explore's plan then goes straight to the "turn"), so the delayed plan could not be played.

    >>> seqs, e = candidate_plans(torch.tensor([0, 0, 4, 4, 2, 2, 0, 0]), 0, torch.tensor([0, 2, 4]), 4, 2, 1)
    >>> seqs[e].tolist()
    [0, 0, 4, 4]
    >>> [4, 4, 2, 2] in seqs.tolist() and [2, 2, 2, 2] in seqs.tolist()
    True
    >>> seqs, e = candidate_plans(torch.tensor([1, 1, 0, 4, 4, 0, 0, 0]), 0, torch.tensor([0, 1]), 4, 3, 0)
    >>> seqs.tolist()  # advancing past the "turn left" due now would drop it: not a candidate
    [[1, 0, 4, 4], [1, 1, 0, 4], [1, 1, 1, 1]]
    >>> seqs, e = candidate_plans(torch.tensor([0, 4, 4, 2, 2, 0, 0, 0]), 0, torch.tensor([0, 2, 4]), 4, 3, 0, True)
    >>> [2, 2, 2, 2] in seqs.tolist(), [4, 4, 4, 4] in seqs.tolist()  # "turn" now would skip the "prepare"
    (False, True)
    >>> seqs, e = candidate_plans(torch.tensor([4, 4, 2, 2, 2, 2, 0, 0]), 0, torch.tensor([0]), 4, 0, 2, kept_delays=True)
    >>> seqs.tolist()  # delayed 2 steps the "prepare" is past explore's window: no such candidate
    [[0, 4, 4, 2], [4, 4, 2, 2]]
    """
    H = horizon
    pad = future[-1:].expand(H + advance)  # past the known future the plan stays as it ends
    future = torch.cat([future, pad])
    held = int(future[0]) if int(future[0]) == last and last != Instruction.NONE else 0
    rows = [future[:H]]
    # advancing the plan by k must not drop an instruction it would say within those k steps (one not held
    # now): "turn left" due now, advanced past, would leave the driver with the *next* manoeuvre's prompt
    skipped = [{int(a) for a in future[:k].tolist()} - {Instruction.NONE, last, int(future[k])} for k in range(advance + 1)]
    rows += [future[k:k + H] for k in range(1, advance + 1) if not skipped[k]]
    due = next((j for j, a in enumerate(future[:H].tolist()) if a not in (Instruction.NONE, last)), None) \
        if kept_delays else None

    def kept(k: int) -> bool:  # explore still says its next prompt k steps after it is due
        return due is None or int(future[due + k]) == int(future[due])

    rows += [torch.cat([torch.full((k,), held, dtype=future.dtype), future[: H - k]]) for k in range(1, delay + 1)
             if kept(k)]
    if bool(future[: advance + 1].any()):  # a prompt is due within reach: the fine choices now as well
        reach = future[: advance + 1].tolist()

        def keeps_order(a: int) -> bool:  # says nothing explore would say before ``a`` (within reach) out of turn
            before = reach[: reach.index(a)] if a in reach else reach
            return not set(before) - {Instruction.NONE, last, a}

        rows += [torch.full((H,), int(a), dtype=future.dtype) for a in allowed.tolist()
                 if a != Instruction.NONE and (not in_order or keeps_order(a))]
    seqs, inverse = torch.unique(torch.stack(rows), dim=0, return_inverse=True)
    return seqs, int(inverse[0])


@dataclass(frozen=True)
class Departure:
    """When the :class:`RetimingPlanner` leaves explore's plan for a cheaper candidate.

    Args:
        margin, rel_margin: the gain over explore's plan needed to leave it (absolute, fraction of its cost).
        agree: fraction of the rows (ensemble members, samples) that must each see a gain above the margin.
        max_spread, rel_spread: leave explore only for a candidate whose effect (its positions minus explore's
            plan's) the rows agree on within ``max_spread + rel_spread * size`` metres (the planner's
            ``effect_spread``; the size is the effect's largest mean distance over the horizon; ``max_spread=None``:
            no such test). ``rel_spread`` > 0 lets members that agree a re-timing moves the car tens of metres (an exit
            taken or missed) but not to the metre leave explore; in the default study 0.5 did that and lost more
            than it gained (docs/research/findings.md, "End to end with the paper's one-step adaptation"), so it is
            0 by default. With one row (one model, or one true-model sample) the spread is 0.
        wait: compare a candidate that plays another action now with the cheapest one that plays explore's action now
            (explore's plan or one of its re-timings), not with explore's plan alone: only the first action is played
            and the next decision may still leave explore, so what the planner must beat is waiting a step. Where
            the car's speed changes, explore's plan (imagined at the speed now) says its prompts at times explore
            itself would not, and against it alone a prompt now can look far cheaper than it is.
        kept_delays: leave explore for a delay only where explore's plan still says the delayed prompt at its later
            time (:func:`candidate_plans`), so that the plan imagined can be played: a "prepare" delayed step after
            step past explore's window is otherwise never said.

    >>> Departure(margin=-1e12, agree=1e-9).rel_margin
    0.05
    """

    margin: float = 20.0
    rel_margin: float = 0.05
    agree: float = 1.0
    max_spread: float | None = 2.0
    rel_spread: float = 0.0
    wait: bool = False
    kept_delays: bool = False

    def __post_init__(self) -> None:
        if not 0.0 < self.agree <= 1.0:
            raise ValueError(f"agree must be in (0, 1], got {self.agree}")
        if self.rel_spread < 0:
            raise ValueError(f"rel_spread must be >= 0, got {self.rel_spread}")
        for name in ("margin", "rel_margin", "agree", "rel_spread"):  # as the planner read them: floats
            object.__setattr__(self, name, float(getattr(self, name)))
        if self.max_spread is not None:
            object.__setattr__(self, "max_spread", float(self.max_spread))


class RetimingPlanner(MPCPlannerBase):
    """Tree search over re-timings of the explore plan with a route-aware cost; see the module docstring.

    Args:
        env: an env with ``imagine(root, sequences) -> (positions, goals)``, ``[M, N, H, 2]`` each.
        horizon: imagined steps (12: prompt, audio, reaction, commit and the turn of the slowest driver).
        advance, delay: how many steps earlier / later explore's plan may be re-timed (``delay`` 0 by default:
            only earlier, see :data:`~pernav.planner.factory.PLANNER_DEFAULTS`).
        route_weight: weight of the squared distance to the planned route.
        progress_weight: reward per metre of route progress at the horizon.
        departure: when a candidate may leave explore's plan (:class:`Departure`: margins, agreement, spread).
        playbacks: 3 for the 21-action space (instruction * 3 + playback), else 1.
        in_order: the fine choices keep explore's order (:func:`candidate_plans`): no "turn" said now while
            explore's "prepare" is still to come; and where the env counts the prompts its driver drops
            (``env.dropped(root, sequences) -> [N]``: said before a junction's box the route goes straight through),
            no candidate drops more of them than explore's plan (a prompt said where it is dropped is one skipped).
        prepare_early: a "prepare" may be said before explore says it. ``False``: a candidate that says a "prepare"
            now where explore's plan does not is refused, so only the "turn" (and silences) are re-timed.

    Attributes:
        by_distance: read each candidate's steps as distances (set it on a planner: off by default, not kept;
            nineteenth session).
            Explore's plan is imagined at the car's speed now, so where the car speeds up or slows explore says its
            prompts steps earlier or later than its plan (docs/adapt_driver.md). With this option, step ``h`` of every
            candidate plays the plan's step that the car, driving explore's plan in the imagination (the rows' mean),
            has reached by then at the plan's speed: a prompt said where the plan says it, in metres, not in steps.
            The first step (the action played) is unchanged.
        closed_loop: imagine explore's plan and its advances closed loop (set it on a planner: off by default;
            twentieth session). Candidate "explore ``k`` steps early" plays its first action, then at each step what
            explore's rule says (the env's ``"explore_table"``) ``k`` steps ahead of the imagined car at its imagined
            speed, as :class:`ShiftedExplore` does on the real car; so the base the planner must beat is explore as it
            plays, not its plan at the speed now. Iterated: each row's imagined car gives its prompts, and they the car.
        step_cap: cap each imagined step's charge (tracking plus route term) at this many squared metres (``None``,
            the default: uncapped; twenty-second session, not kept). A missed turn then costs at most the cap a step,
            about what it costs an episode (the env re-routes), instead of thousands of squared metres off the route.
    """

    by_distance: bool = False
    step_cap: float | None = None
    closed_loop: bool = False
    closed_passes: int = 2  # re-imaginations with the prompts read off the car imagined the pass before

    def __init__(self, env, horizon: int = 12, advance: int = 6, delay: int = 0, route_weight: float = 1.0,
                 progress_weight: float = 1.0, departure: Departure | None = None, playbacks: int | None = None,
                 in_order: bool = False, prepare_early: bool = True) -> None:
        super().__init__(env, action_key="action")
        if horizon < 1 or advance < 0 or delay < 0:
            raise ValueError(f"need horizon >= 1 and advance, delay >= 0; got {horizon}, {advance}, {delay}")
        self.horizon, self.advance, self.delay, self.in_order = int(horizon), int(advance), int(delay), bool(in_order)
        self.prepare_early = bool(prepare_early)
        self.route_weight, self.progress_weight = float(route_weight), float(progress_weight)
        self.departure = departure = departure if departure is not None else Departure()
        self.margin, self.rel_margin, self.agree = departure.margin, departure.rel_margin, departure.agree
        self.max_spread, self.rel_spread = departure.max_spread, departure.rel_spread
        n_actions = int(env.action_spec.space.n)
        self.playbacks = playbacks or (N_PLAYBACKS if n_actions == N_ADAPTIVE_ACTIONS else 1)
        self.params: list[TensorDictBase | None] | TensorDictBase | None = None  # plan with these (an ensemble)
        self.in_keys = ["history", "explore_future", "route_ahead", "action_mask"]
        self.last: list[RetimingResult] = []
        self.planning_s = 0.0
        self.decisions = self.departures = 0  # decisions searched, and those that left explore

    def _actions(self, seqs: torch.Tensor) -> tuple[torch.Tensor, int]:
        """Instruction sequences in the action space (with 21 actions: each at the three speeds)."""
        if self.playbacks == 1:
            return seqs, 1
        # normal first: explore's is row 0 of its block
        return torch.cat([seqs * N_PLAYBACKS + p for p in (1, 0, 2)]), N_PLAYBACKS

    def costs(self, root: TensorDictBase, seqs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """``[M, N]`` cost of each sequence for each row of the env's imagination, and the imagined positions
        ``[M, N, H, 2]``."""
        pos, goal = self._imagine(root, seqs)  # [M, N, H, 2]
        return self.score(root, pos, goal), pos

    def _imagine(self, root: TensorDictBase, seqs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """The env's imagination of ``seqs`` from ``root`` with the planner's parameters (an ensemble), if any."""
        params = self.params if isinstance(self.params, list) or self.params is None else [self.params]
        return self.env.imagine(root, seqs, **({} if params is None else {"params": params}))

    def score(self, root: TensorDictBase, pos: torch.Tensor, goal: torch.Tensor) -> torch.Tensor:
        """``[M, N]``: the planner's cost of positions and goals ``[M, N, H, 2]`` from ``root`` (imagined or driven)."""
        start_goal = root["history"][-1, [GX, GY]].float()
        prev = torch.cat([start_goal.expand(*goal.shape[:2], 1, 2), goal[:, :, :-1]], dim=2)
        route = root["route_ahead"].float()  # [P, 2]
        d = torch.cdist(pos.reshape(-1, 2), route).reshape(*pos.shape[:-1], route.shape[0])  # [M, N, H, P]
        dist, nearest = d.min(-1)
        if self.step_cap is None:  # the two sums kept apart, as before the cap: the default's figures stay bit-identical
            cost = tracking_cost(pos, prev).sum(-1) + self.route_weight * (dist ** 2).sum(-1)
        else:  # each step's charge capped: a missed turn costs about what it costs an episode, not its squared metres
            step = tracking_cost(pos, prev) + self.route_weight * dist ** 2  # [M, N, H]
            cost = step.clamp(max=self.step_cap).sum(-1)
        progress = self.progress_weight * ROUTE_SPACING * nearest[..., -1].to(cost.dtype)
        return cost - progress

    def distance_steps(self, root: TensorDictBase, seqs: torch.Tensor, explore: int) -> torch.Tensor:
        """``seqs`` ``[N, H]`` read by distance (``by_distance``): step ``h`` plays step ``j(h)`` of each sequence, where
        ``j(h)`` is how many of the plan's steps (at the car's speed now) the car has driven when step ``h`` starts,
        imagining explore's plan (the rows' mean). Unchanged where the car is (nearly) stopped: the plan then does
        not move on."""
        hist = root["history"]
        v0 = float(torch.hypot(hist[-1, VX], hist[-1, VY]))
        if v0 < 0.5:
            return seqs
        pos, _ = self._imagine(root, seqs[explore:explore + 1])
        path = pos[:, 0].mean(0).double()  # [H, 2]
        start = hist[-1, [X, Y]].double()
        moved = self._steps(start, path).cumsum(0)  # by each step's end
        at_start = torch.cat([moved.new_zeros(1), moved[:-1]])  # driven when each step starts
        H = seqs.shape[1]
        j = torch.floor(at_start / v0 + 1e-6).long().clamp(0, H - 1)  # 0 at the first step: the action played
        return seqs[:, j]

    @staticmethod
    def _steps(start: torch.Tensor, pos: torch.Tensor) -> torch.Tensor:
        """``[..., H]``: the metres each step of positions ``[..., H, 2]`` moves the car, the first from ``start``."""
        return torch.cat([(pos[..., :1, :] - start).norm(dim=-1), (pos[..., 1:, :] - pos[..., :-1, :]).norm(dim=-1)], -1)

    def shifts(self, root: TensorDictBase, seqs: torch.Tensor) -> torch.Tensor:
        """``[N]``: for each candidate (action space), the ``k`` (0..advance) for which it is explore's plan ``k`` steps
        early, or -1 (a fine choice held, or a delay: imagined as it is)."""
        future = root["explore_future"].long()
        H = seqs.shape[1]
        future = torch.cat([future, future[-1:].expand(H + self.advance)])
        instr = seqs // self.playbacks
        out = torch.full((seqs.shape[0],), -1, dtype=torch.long)
        for k in range(self.advance, -1, -1):  # the smallest k wins
            out = torch.where((instr == future[k:k + H]).all(-1), k, out)
        return out

    def closed_sequences(self, root: TensorDictBase, seqs: torch.Tensor, pos: torch.Tensor, shifts: torch.Tensor
                         ) -> torch.Tensor:
        """``[M, N, H]``: each row's prompts when the candidates with a shift ``k`` >= 0 play explore's rule ``k`` steps
        ahead of the car imagined at ``pos`` ``[M, N, H, 2]`` (after its first action, which stays the candidate's), at
        its imagined speed: explore's table at the car's place plus ``k`` steps at that speed, the nearest of its
        speeds. As explore's rule does, a prompt said in the imagination is not said again once another was said after
        it, until the car passes the junction ahead; the others are ``seqs`` as they are."""
        table = root["explore_table"].long()  # [V, P]
        speeds = torch.tensor(EXPLORE_SPEEDS, dtype=torch.float64)
        hist = root["history"]
        start = hist[-1, [X, Y]].double()
        v0 = float(torch.hypot(hist[-1, VX], hist[-1, VY]))
        p = pos.double()
        M, N, H = p.shape[:3]
        step = self._steps(start, p)
        at = torch.cat([step.new_zeros(M, N, 1), step[..., :-1].cumsum(-1)], -1)  # m driven when each step starts
        # its speed then: the mean of the steps either side (each step's length is its mean speed, at its middle)
        v = torch.cat([step.new_full((M, N, 1), v0), (step[..., :-1] + step[..., 1:]) / 2], -1)
        k = shifts.clamp(min=0).to(torch.float64)[None, :, None]
        ahead = torch.round((at + k * v) / ROUTE_SPACING).long()
        vi = (v.unsqueeze(-1) - speeds).abs().argmin(-1)
        desired = torch.where(ahead < table.shape[1], table[vi, ahead.clamp(max=table.shape[1] - 1)], 0)
        junction = float(root["distance_to_junction"]) if "distance_to_junction" in root.keys() else math.inf
        instr = (seqs // self.playbacks).expand(M, N, H).clone()
        playback = seqs[:, :1] % self.playbacks
        said = torch.zeros(M, N, N_INSTRUCTIONS, dtype=torch.bool)  # (silence marked too: it is never "again")
        said.scatter_(-1, instr[..., :1], True)
        for h in range(1, H):
            said &= ~(at[..., h] > junction).unsqueeze(-1)  # past the junction: its prompts are forgotten
            a = desired[..., h]
            again = said.gather(-1, a.unsqueeze(-1))[..., 0] & (a != instr[..., h - 1])
            a = torch.where(again, 0, a)
            instr[..., h] = a
            said.scatter_(-1, a.unsqueeze(-1), True)
        closed = instr * self.playbacks + (playback if self.playbacks > 1 else 0)
        return torch.where((shifts >= 0)[None, :, None], closed, seqs.expand(M, N, H))

    def imagine_closed(self, root: TensorDictBase, seqs: torch.Tensor
                       ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Positions and goals ``[M, N, H, 2]`` of the candidates ``seqs`` ``[N, H]`` with explore's rule played
        closed loop (:attr:`closed_loop`), and the prompts each row played ``[M, N, H]``."""
        if "explore_table" not in root.keys():
            raise KeyError("closed_loop reads \"explore_table\": make the navigation env with "
                           "config={\"explore_table\": True}")
        shifts = self.shifts(root, seqs)
        pos, goal = self._imagine(root, seqs)
        played = seqs.expand(pos.shape[0], *seqs.shape)
        for _ in range(self.closed_passes):
            played = self.closed_sequences(root, seqs, pos, shifts)
            pos, goal = self._imagine(root, played)
        return pos, goal, played

    @staticmethod
    def effect_spread(pos: torch.Tensor, explore: int) -> torch.Tensor:
        """``[N]``: how much the rows disagree on each candidate's *effect*, its positions minus explore's
        plan's: the largest (over the horizon) mean distance of the rows' effects from their mean. Errors the
        rows share for every candidate (e.g. the car's speed in traffic) cancel; 0 for explore and one row."""
        effect = pos - pos[:, explore:explore + 1]  # [M, N, H, 2]
        return (effect - effect.mean(0)).norm(dim=-1).mean(0).amax(-1)

    def candidates(self, root: TensorDictBase) -> tuple[torch.Tensor, int]:
        """The candidate action sequences ``[N, horizon]`` at ``root`` and the index of explore's plan."""
        future = root["explore_future"].long()
        hist = root["history"]
        last_onehot = hist[-2, STATE_DIM:] if hist.shape[0] > 1 else hist[-1, STATE_DIM:]
        last = int(last_onehot.argmax()) // self.playbacks if bool(last_onehot.any()) else 0
        mask = root["action_mask"][0].bool()
        allowed = mask.reshape(-1, self.playbacks).any(-1).nonzero().squeeze(-1)
        seqs, explore = candidate_plans(future, last, allowed, self.horizon, self.advance, self.delay, self.in_order,
                                        self.departure.kept_delays)
        return self._actions(seqs)[0], explore

    def searches(self, root: TensorDictBase) -> bool:
        """Would :meth:`decide` search at ``root`` (do the candidates differ in their first action)?"""
        seqs, explore = self.candidates(root)
        return not bool((seqs[:, 0] == seqs[explore, 0]).all())

    @torch.no_grad()
    def decide(self, root: TensorDictBase) -> tuple[int, RetimingResult | None]:
        """The action for one root (unbatched tensordict) and the search behind it (``None``: no choice)."""
        seqs, explore = self.candidates(root)
        explore_action = int(seqs[explore, 0])
        if bool((seqs[:, 0] == explore_action).all()):  # receding horizon: only the first action is played
            return explore_action, None
        imagined = self.distance_steps(root, seqs, explore) if self.by_distance else seqs
        if self.closed_loop:
            pos, goal, _ = self.imagine_closed(root, seqs)
            cost = self.score(root, pos, goal)
        else:
            cost, pos = self.costs(root, imagined)  # [M, N], [M, N, H, 2]
        spread = self.effect_spread(pos, explore)
        mean = cost.mean(0)
        base = explore
        if self.departure.wait:  # the cheapest candidate that plays explore's action now: waiting a step
            same = seqs[:, 0] == explore_action
            base = int(torch.where(same, mean, torch.full_like(mean, float("inf"))).argmin())
        gain = cost[:, base:base + 1] - cost  # [M, N]: > 0 where a candidate beats the base
        need = self.margin + self.rel_margin * mean[base].abs()
        ok = (gain.mean(0) > need) & ((gain > need).to(cost.dtype).mean(0) >= self.agree)
        ok &= torch.isfinite(mean)
        if self.in_order and hasattr(self.env, "dropped"):  # a prompt said where the driver drops it is one skipped
            dropped = self.env.dropped(root, imagined // self.playbacks)  # [N]
            ok &= dropped <= dropped[explore]
        if not self.prepare_early:  # a "prepare" no earlier than explore's: only the "turn" is re-timed
            first = seqs[:, 0] // self.playbacks
            ok &= ~(torch.isin(first, torch.tensor(PREPARES)) & (first != explore_action // self.playbacks))
        if self.max_spread is not None:  # the rows must agree on what the re-timing does, not only on the gain
            size = (pos - pos[:, explore:explore + 1]).mean(0).norm(dim=-1).amax(-1)  # [N] the mean effect's size
            ok &= spread <= self.max_spread + self.rel_spread * size
        self.decisions += 1
        if bool(ok.any()):
            chosen = int(torch.where(ok, mean, torch.full_like(mean, float("inf"))).argmin())
            self.departures += int(int(seqs[chosen, 0]) != explore_action)
        else:
            chosen = explore
        result = RetimingResult(seqs, mean, explore, chosen, float(mean[explore] - mean[chosen]), spread)
        return int(seqs[chosen, 0]), result

    def planning(self, td: TensorDictBase) -> torch.Tensor:
        flat = planning_roots(self, td, "the navigation env writes explore_future/route_ahead/action_mask; wrap it "
                                        "with HistoryWindow for history")
        t0 = time.perf_counter()
        actions, self.last = [], []
        for i in range(flat.shape[0]):
            action, result = self.decide(flat[i])
            if result is not None:
                self.last.append(result)
            actions.append(action)
        self.planning_s += time.perf_counter() - t0
        return torch.tensor(actions, dtype=torch.long).reshape(td.shape)


class RetimedExplore(TensorDictModuleBase):
    """The explore policy with its prompts re-timed at random: a data-collection policy that shows the model
    what a prompt's *timing* does for this driver.

    Explore alone always speaks at the same lead, so its data cannot identify the effect of speaking earlier
    or later, which is exactly what :class:`RetimingPlanner` asks of the model. Where a re-timing would change
    this step's action, with probability ``p`` this policy plays one of the planner's own candidates (drawn
    uniformly from :func:`candidate_plans`, explore's excluded) for ``hold`` steps, then returns to explore.
    It never evaluates a method; it only collects data.

    Reads ``"history"``, ``"explore_future"`` and ``"action_mask"``; writes ``"action"``. Call :meth:`reset`
    (or make a new one) per episode.

    Example:
        >>> import torch
        >>> from tensordict import TensorDict
        >>> policy = RetimedExplore(p=1.0, seed=0)
        >>> td = TensorDict({"history": torch.zeros(5, 21), "explore_future": torch.tensor([0, 0, 4, 4, 2, 2, 0]),
        ...                  "action_mask": torch.ones(5, 7, dtype=torch.bool)}, [])
        >>> int(policy(td)["action"]) != 0  # explore would stay silent now; a re-timing speaks early
        True
    """

    def __init__(self, p: float = 0.5, advance: int = 6, delay: int = 3, hold: int = 6, seed: int = 0) -> None:
        super().__init__()
        if not 0.0 <= p <= 1.0 or hold < 1:
            raise ValueError(f"need p in [0, 1] and hold >= 1; got p={p}, hold={hold}")
        self.p, self.advance, self.delay, self.hold = float(p), int(advance), int(delay), int(hold)
        self.in_keys = ["history", "explore_future", "action_mask"]
        self.out_keys = ["action"]
        self.generator = torch.Generator().manual_seed(int(seed))
        self.reset()

    def reset(self) -> None:
        """Forget the re-timing in progress (a new episode)."""
        self._plan: list[int] = []

    def _uniform(self) -> float:
        return float(torch.rand((), generator=self.generator))

    def _act(self, root: TensorDictBase) -> int:
        n_actions = int(root["action_mask"].shape[-1])
        playbacks = N_PLAYBACKS if n_actions == N_ADAPTIVE_ACTIONS else 1
        future = root["explore_future"].long()
        if self._plan:
            instruction = self._plan.pop(0)
        else:
            hist = root["history"]
            last_onehot = hist[-2, STATE_DIM:] if hist.shape[0] > 1 else hist[-1, STATE_DIM:]
            last = int(last_onehot.argmax()) // playbacks if bool(last_onehot.any()) else 0
            allowed = root["action_mask"][0].bool().reshape(-1, playbacks).any(-1).nonzero().squeeze(-1)
            seqs, explore = candidate_plans(future, last, allowed, self.hold, self.advance, self.delay)
            others = [i for i in range(seqs.shape[0]) if int(seqs[i, 0]) != int(seqs[explore, 0])]
            if others and self._uniform() < self.p:
                pick = others[int(torch.randint(len(others), (), generator=self.generator))]
                self._plan = seqs[pick].tolist()
                instruction = self._plan.pop(0)
            else:
                instruction = int(future[0])
        return instruction * playbacks + (1 if playbacks == N_PLAYBACKS else 0)  # 21 actions: normal playback

    def forward(self, td: TensorDictBase) -> TensorDictBase:
        flat = td.reshape(-1)
        actions = [self._act(flat[i]) for i in range(flat.shape[0])]
        td.set("action", torch.tensor(actions, dtype=torch.long).reshape(td.shape))
        return td


class ShiftedExplore(TensorDictModuleBase):
    """Explore's rule shifted by a constant ``shift`` of whole steps: ``shift`` > 0 says each prompt that many steps
    earlier (explore's plan ahead, ``"explore_future"``), < 0 later (what explore said ``-shift`` steps ago, from
    ``"explore_plan"``, which reaches ``plan_shift`` steps back). The family ``best_shift`` picks from for each driver.

    >>> import torch
    >>> from tensordict import TensorDict
    >>> td = TensorDict({"explore_future": torch.tensor([0, 0, 4, 4]), "explore_plan": torch.tensor([1, 1, 0, 0, 4])}, [])
    >>> [int(ShiftedExplore(k, plan_shift=2)(td.clone())["action"]) for k in (-2, -1, 0, 2)]
    [1, 1, 0, 4]
    """

    def __init__(self, shift: int, plan_shift: int = 2) -> None:
        super().__init__()
        if shift < -plan_shift:
            raise ValueError(f"a later shift reaches at most plan_shift = {plan_shift} steps back; got {shift}")
        self.shift, self.plan_shift = int(shift), int(plan_shift)
        self.in_keys = ["explore_future", "explore_plan"]
        self.out_keys = ["action"]

    def forward(self, td: TensorDictBase) -> TensorDictBase:
        if self.shift >= 0:
            future = td["explore_future"]
            action = future[..., min(self.shift, future.shape[-1] - 1)]
        else:
            action = td["explore_plan"][..., self.plan_shift + self.shift]
        td.set("action", action.long())
        return td
