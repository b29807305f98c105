"""TreeSearchPlanner: exact discrete tree-search MPC over a learned world model (paper §4.2, docs/study.md).

The cost of an action sequence ``a_1..a_H`` is

    sum_h || pos(s_hat_{h+1}) - g_{h+1} ||^2  -  bonus * [a matches the explore plan shifted by k, |k| <= S]
                                               +  penalty * #(turn/roundabout prompts the mask forbids)

where ``s_hat`` is imagined by the world model (:class:`~pernav.model.world_model.ImaginedNavigationEnv`),
``g`` are the route's goal waypoints and the tracking term is the env's own
:func:`~pernav.world.cost.tracking_cost`. The search is exhaustive and level by level: the ``N`` nodes of
level ``h`` are expanded with the actions allowed at that level in one batched model call, so shared
prefixes are computed once (``sum_h A^h`` model evaluations instead of ``H * A^H`` for a flat enumeration).
With ``mask=True`` (default) the actions the situation forbids are not expanded at all, which shrinks the
tree; with ``mask=False`` they are expanded and penalized. ``beam=W`` keeps only the ``W`` cheapest nodes of
each level (for the 21-action space); a beam as wide as the tree is the exhaustive search.

The planner reads from the tensordict: ``"history"`` (the :class:`~pernav.transforms.HistoryWindow`),
``"plan_goals"`` ``[H, 2]``, ``"explore_plan"`` ``[H + 2S]`` and ``"action_mask"`` ``[H, A]``, which the
navigation env provides (:mod:`pernav.env.planning`); it writes ``"action"``. Any batch shape.

Example:
    >>> import torch
    >>> from tensordict import TensorDict
    >>> from pernav.model import DynamicsModel
    >>> from pernav.model.world_model import ImaginedNavigationEnv, make_world_model
    >>> env = ImaginedNavigationEnv(make_world_model(DynamicsModel(hidden=(16,))))
    >>> planner = TreeSearchPlanner(env, horizon=3, shift=1)
    >>> td = TensorDict({"observation": torch.zeros(14), "history": torch.zeros(5, 21),
    ...                  "plan_goals": torch.ones(3, 2), "explore_plan": torch.zeros(5, dtype=torch.long),
    ...                  "action_mask": torch.ones(3, 7, dtype=torch.bool)}, [])
    >>> planner(td)["action"].shape
    torch.Size([])
"""

from __future__ import annotations

import logging
import time
from contextlib import nullcontext
from dataclasses import dataclass

import torch
from tensordict import TensorDictBase
from torchrl.modules.planners import MPCPlannerBase

from pernav.model.dynamics import GX, GY, X, Y
from pernav.model.losses import using
from pernav.world.cost import tracking_cost

__all__ = ["PlanResult", "TreeSearchPlanner"]

TURN_INSTRUCTIONS = (1, 2, 3, 4, 5, 6)
log = logging.getLogger("pernav.planner")


@dataclass
class PlanResult:
    """The best sequence of one search, its cost, and how many model evaluations it took."""

    actions: torch.Tensor  # [H] int64
    cost: float
    evaluations: int


class TreeSearchPlanner(MPCPlannerBase):
    """Exhaustive (or beam) level-by-level tree search; see the module docstring for the cost.

    Args:
        env: an :class:`~pernav.model.world_model.ImaginedNavigationEnv` (its world model is the dynamics).
        horizon: H, the number of imagined steps (5 in the paper).
        shift: S, the time shifts of the explore plan that earn the bonus (``explore_plan`` has H + 2S entries).
        bonus: cost reduction for a sequence equal to a shifted explore plan (squared metres).
        penalty: cost of each turn/roundabout prompt the action mask forbids (only when ``mask=False``).
        mask: prune forbidden actions from the tree instead of penalizing them.
        beam: keep only this many cheapest nodes per level (``None``: exhaustive).
        playbacks: 3 for the 21-action space (instruction * 3 + playback), else 1.
        shift_decay: the bonus of a plan shifted by ``k`` steps is ``bonus * (1 - shift_decay * |k|)``, so a
            time shift is chosen only when the model predicts it pays (ties go to the explore timing).
        goal_source: ``"state"`` (default): each imagined position is scored against the goal waypoint of
            the previous imagined state, which the model predicts like every state entry — exactly the env's
            cost ``||pos_{t+1} - g_t||^2`` with the env's speed-dependent goal selection; ``"route"``: against
            ``plan_goals`` (route points at the current speed — biased against slowing down for a turn).
    """

    def __init__(self, env, horizon: int = 5, shift: int = 2, bonus: float = 20.0, penalty: float = 1e3,
                 mask: bool = True, beam: int | None = None, playbacks: int | None = None,
                 goal_source: str = "state", shift_decay: float = 0.25) -> None:
        super().__init__(env, action_key="action")
        if horizon < 1:
            raise ValueError(f"horizon must be >= 1, got {horizon}")
        if goal_source not in ("state", "route"):
            raise ValueError(f"goal_source must be 'state' or 'route', got {goal_source!r}")
        self.goal_source = goal_source
        self.shift_decay = float(shift_decay)
        if beam is not None and beam < 1:
            raise ValueError(f"beam must be >= 1 or None, got {beam}")
        self.model = getattr(env, "dynamics", None)  # None: an env that only imagines (the true simulator)
        self.n_actions = self.model.n_actions if self.model is not None else int(env.action_spec.space.n)
        self.playbacks = playbacks or (3 if self.n_actions == 21 else 1)
        self.horizon, self.shift = int(horizon), int(shift)
        self.bonus, self.penalty, self.mask, self.beam = float(bonus), float(penalty), bool(mask), beam
        # adapted parameters to plan with (None: the model's own); of an ensemble's list, the paper's planner
        # uses the first member (the paper plans with one model)
        self.params: list[TensorDictBase] | TensorDictBase | None = None
        self.in_keys = ["observation", "history", "plan_goals", "explore_plan", "action_mask"]
        if self.model is not None and self.model.road:  # it reads the road ahead of every imagined car
            if beam is not None:  # imagine() rolls the whole tree out; a beam would need the road in _step
                raise ValueError("beam search needs a model without the road (TrainConfig.road = 0); "
                                 f"this model reads {self.model.road} road points")
            self.in_keys.append("route_ahead")
        self.last: list[PlanResult] = []
        self.nonfinite = 0  # decisions where some imagined cost was NaN/Inf
        self.planning_s = 0.0  # wall time spent planning (profiling)

    # ----- one imagined step for a batch of nodes ---------------------------------------------------
    def _step(self, history: torch.Tensor, action: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        # The env's transition (model, then next_window) called directly: env.step would add TensorDict
        # copies, done/spec bookkeeping and a reward the search does not use (~40 % of a masked decision).
        next_state = self.model(history, action)
        return next_state, self.model.next_window(history, action, next_state)

    def _goal(self, state_goal: torch.Tensor, route_goals: torch.Tensor, h: int) -> torch.Tensor:
        """The goal the position after step ``h`` is scored against (see ``goal_source``)."""
        return state_goal if self.goal_source == "state" else route_goals[h]

    def _allowed(self, mask: torch.Tensor, h: int) -> torch.Tensor:
        return mask[h].nonzero().squeeze(-1) if self.mask else torch.arange(self.n_actions)

    def _final_cost(self, seqs: torch.Tensor, cost: torch.Tensor, plan: torch.Tensor) -> torch.Tensor:
        """Add the explore-match bonus to complete sequences ``[N, H]``."""
        H = seqs.shape[1]
        shifted = plan.unfold(0, H, 1)  # [2S + 1, H]: the explore plan shifted by -S..S
        match = (seqs.div(self.playbacks, rounding_mode="floor").unsqueeze(1) == shifted.unsqueeze(0)).all(-1)
        k = torch.arange(shifted.shape[0], dtype=cost.dtype) - (shifted.shape[0] - 1) / 2
        weight = 1.0 - self.shift_decay * k.abs()  # a shift must buy its cost: explore itself wins ties
        return cost - self.bonus * (match.to(cost.dtype) * weight).amax(-1)

    def _best(self, seqs: torch.Tensor, total: torch.Tensor, plan: torch.Tensor, evaluations: int) -> PlanResult:
        """The cheapest sequence. Non-finite costs (a model predicting NaN/Inf) never win; if no sequence has
        a finite cost the planner falls back to the explore plan and counts it in ``nonfinite``."""
        finite = torch.isfinite(total)
        if not bool(finite.all()):
            self.nonfinite += 1
            log.warning("TreeSearchPlanner: %d non-finite sequence costs", int((~finite).sum()))
            if not bool(finite.any()):
                H = seqs.shape[1]
                explore = plan[self.shift: self.shift + H] * self.playbacks + (1 if self.playbacks == 3 else 0)
                return PlanResult(explore, float("inf"), evaluations)
            total = torch.where(finite, total, torch.full_like(total, float("inf")))
        best = int(torch.argmin(total))
        return PlanResult(seqs[best], float(total[best]), evaluations)

    def _penalties(self, actions: torch.Tensor, mask: torch.Tensor, h: int) -> torch.Tensor:
        instruction = actions.div(self.playbacks, rounding_mode="floor")
        is_prompt = torch.isin(instruction, torch.tensor(TURN_INSTRUCTIONS))
        return self.penalty * (is_prompt & ~mask[h, actions]).to(torch.float32)

    # ----- searches ---------------------------------------------------------------------------------
    @torch.no_grad()
    def search(self, observation: torch.Tensor, history: torch.Tensor, goals: torch.Tensor, plan: torch.Tensor,
               mask: torch.Tensor) -> PlanResult:
        """Level-by-level search from one root (unbatched tensors)."""
        H = min(self.horizon, goals.shape[0])
        hist = history.unsqueeze(0)  # the model reads the state from the window's newest row
        goal = hist[:, -1, [GX, GY]]  # the goal waypoint of each node's state
        seqs = torch.zeros(1, 0, dtype=torch.long)
        cost = torch.zeros(1)
        evaluations = 0
        for h in range(H):
            allowed = self._allowed(mask, h)
            n, a = seqs.shape[0], allowed.shape[0]
            parent = torch.arange(n).repeat_interleave(a)
            actions = allowed.repeat(n)
            obs, hist = self._step(hist[parent], actions)
            evaluations += actions.shape[0]
            cost = cost[parent] + tracking_cost(obs[:, [X, Y]], self._goal(goal[parent], goals, h))
            goal = obs[:, [GX, GY]]
            if not self.mask:
                cost = cost + self._penalties(actions, mask, h)
            seqs = torch.cat([seqs[parent], actions.unsqueeze(1)], dim=1)
            if self.beam is not None and seqs.shape[0] > self.beam and h + 1 < H:
                keep = torch.topk(cost, self.beam, largest=False, sorted=False).indices.sort().values
                hist, cost, seqs, goal = hist[keep], cost[keep], seqs[keep], goal[keep]
        total = self._final_cost(seqs, cost, plan[: H + 2 * self.shift])
        return self._best(seqs, total, plan, evaluations)

    @torch.no_grad()
    def imagined_search(self, root: TensorDictBase, goals: torch.Tensor, plan: torch.Tensor,
                        mask: torch.Tensor) -> PlanResult:
        """The same tree, imagined by the env's ``imagine`` (the true simulator, or a model that reads the road)
        and averaged over its samples: every sequence of the masked tree rolled out whole (the true simulator
        shares their common prefixes; a model does not)."""
        H = min(self.horizon, goals.shape[0])
        seqs = torch.cartesian_prod(*[self._allowed(mask, h) for h in range(H)]).reshape(-1, H)
        pos, goal = self.env.imagine(root, seqs)  # [M, N, H, 2]
        start = root["history"][-1, [GX, GY]].float().expand(*goal.shape[:2], 1, 2)
        prev = torch.cat([start, goal[:, :, :-1]], dim=2) if self.goal_source == "state" else goals[:H]
        cost = tracking_cost(pos, prev).sum(-1).mean(0)
        if not self.mask:
            cost = cost + sum(self._penalties(seqs[:, h], mask, h) for h in range(H))
        total = self._final_cost(seqs, cost, plan[: H + 2 * self.shift])
        return self._best(seqs, total, plan, seqs.numel())

    @torch.no_grad()
    def flat_search(self, observation: torch.Tensor, history: torch.Tensor, goals: torch.Tensor,
                    plan: torch.Tensor, mask: torch.Tensor) -> PlanResult:
        """Reference: enumerate every sequence of the same tree and roll each out H steps (no sharing)."""
        H = min(self.horizon, goals.shape[0])
        sets = [self._allowed(mask, h) for h in range(H)]
        seqs = torch.cartesian_prod(*sets).reshape(-1, H)
        N = seqs.shape[0]
        hist = history.expand(N, *history.shape)
        goal = hist[:, -1, [GX, GY]]
        cost = torch.zeros(N)
        for h in range(H):
            obs, hist = self._step(hist, seqs[:, h])
            cost = cost + tracking_cost(obs[:, [X, Y]], self._goal(goal, goals, h))
            goal = obs[:, [GX, GY]]
            if not self.mask:
                cost = cost + self._penalties(seqs[:, h], mask, h)
        total = self._final_cost(seqs, cost, plan[: H + 2 * self.shift])
        return self._best(seqs, total, plan, N * H)

    # ----- MPCPlannerBase ---------------------------------------------------------------------------
    def planning(self, td: TensorDictBase) -> torch.Tensor:
        missing = [k for k in self.in_keys if k not in td.keys()]
        if missing:
            raise KeyError(f"TreeSearchPlanner needs {missing} in the tensordict (the navigation env writes "
                           "plan_goals/explore_plan/action_mask; wrap it with HistoryWindow for history)")
        t0 = time.perf_counter()
        flat = td.reshape(-1)
        actions, self.last = [], []
        params = self.params[0] if isinstance(self.params, list) else self.params
        with using(self.model, params) if self.model is not None else nullcontext():
            for i in range(flat.shape[0]):
                row = flat[i]
                # the true simulator, or a model that reads the road (the env's imagine tracks each imagined
                # car's road; every sequence rolled out whole, as flat_search does)
                if self.model is None or self.model.road:
                    result = self.imagined_search(row, row["plan_goals"].float(), row["explore_plan"].long(),
                                                  row["action_mask"].bool())
                    self.last.append(result)
                    actions.append(result.actions[0])
                    continue
                result = self.search(row["observation"].float(), row["history"].float(), row["plan_goals"].float(),
                                     row["explore_plan"].long(), row["action_mask"].bool())
                self.last.append(result)
                actions.append(result.actions[0])
        self.planning_s += time.perf_counter() - t0
        return torch.stack(actions).reshape(td.shape)
