"""TreeSearchPlanner: the paper's planner (§4.2), a configuration of the generic
:class:`~pernav.planner.discrete.DiscreteTreeSearchPlanner`.

The return of an action sequence ``a_1..a_H`` is the navigation model env's own reward plus two task terms:

    sum_h -|| pos(s_hat_{h+1}) - g_{h+1} ||^2  +  bonus * [a matches the explore plan shifted by k, |k| <= S]
                                               -  penalty * #(turn/roundabout prompts the mask forbids)

where ``s_hat`` is imagined by the world model (:class:`~pernav.model.navigation.ImaginedNavigationEnv`, whose
reward is minus the env's :func:`~pernav.world.cost.tracking_cost`), ``g`` are the goal waypoints. The search is
the generic one: exhaustive, level by level (shared prefixes computed once), or with a beam (``beam=W``, for the
21-action space). With ``mask=True`` (default) the actions the situation forbids are not expanded at all; with
``mask=False`` they are expanded and penalized (a per-step reward term).

The planner reads ``"observation"``, ``"history"`` (the :class:`~pernav.transforms.HistoryWindow`),
``"plan_goals"`` ``[H, 2]``, ``"explore_plan"`` ``[H + 2S]`` and ``"action_mask"`` ``[H, A]``, which the navigation
env provides (:mod:`pernav.env.planning`); it writes ``"action"``. Any batch shape.

Example:
    >>> import torch
    >>> from tensordict import TensorDict
    >>> from pernav.model import DynamicsModel
    >>> from pernav.model.navigation import ImaginedNavigationEnv, make_world_model
    >>> env = ImaginedNavigationEnv(make_world_model(DynamicsModel(hidden=(16,))))
    >>> planner = TreeSearchPlanner(env, horizon=3, shift=1)
    >>> td = TensorDict({"observation": torch.zeros(14), "history": torch.zeros(5, 21),
    ...                  "plan_goals": torch.ones(3, 2), "explore_plan": torch.zeros(5, dtype=torch.long),
    ...                  "action_mask": torch.ones(3, 7, dtype=torch.bool)}, [])
    >>> planner(td)["action"].shape
    torch.Size([])
"""

from __future__ import annotations

import time
from contextlib import nullcontext

import torch
from tensordict import TensorDictBase

from pernav.model.egocentric import GX, GY, X, Y
from pernav.model.losses import using
from pernav.planner.discrete import DiscreteTreeSearchPlanner, SearchResult, planning_roots
from pernav.world.constants import N_ADAPTIVE_ACTIONS, N_PLAYBACKS, TURN_INSTRUCTIONS
from pernav.world.cost import tracking_cost

__all__ = ["TreeSearchPlanner"]



class TreeSearchPlanner(DiscreteTreeSearchPlanner):
    """The paper's planner: the generic tree search with the explore bonus and the turn penalty as reward terms.

    Args:
        env: an :class:`~pernav.model.navigation.ImaginedNavigationEnv` (its world model is the dynamics), or an
            env with ``imagine`` only (the true simulator, :class:`~pernav.diagnostics.TrueDynamicsEnv`).
        horizon: H, the number of imagined steps (5 in the paper).
        shift: S, the time shifts of the explore plan that earn the bonus (``explore_plan`` has H + 2S entries).
        bonus: return added to a sequence equal to a shifted explore plan (squared metres).
        penalty: return taken from each turn/roundabout prompt the action mask forbids (only when ``mask=False``).
        mask: prune forbidden actions from the tree instead of penalizing them.
        beam: keep only this many best nodes per level (``None``: exhaustive).
        playbacks: 3 for the 21-action space (instruction * 3 + playback), else 1.
        shift_decay: the bonus of a plan shifted by ``k`` steps is ``bonus * (1 - shift_decay * |k|)``, so a
            time shift is chosen only when the model predicts it pays (ties go to the explore timing).
        goal_source: ``"state"`` (default): the env's reward, each imagined position scored against the goal
            waypoint of the previous imagined state (the env's cost ``||pos_{t+1} - g_t||^2``); ``"route"``:
            against ``plan_goals`` (route points at the current speed, biased against slowing down for a turn).
    """

    def __init__(self, env, horizon: int = 5, shift: int = 2, bonus: float = 20.0, penalty: float = 1e3,
                 mask: bool = True, beam: int | None = None, playbacks: int | None = None,
                 goal_source: str = "state", shift_decay: float = 0.25) -> None:
        if horizon < 1:
            raise ValueError(f"horizon must be >= 1, got {horizon}")
        if goal_source not in ("state", "route"):
            raise ValueError(f"goal_source must be 'state' or 'route', got {goal_source!r}")
        if beam is not None and beam < 1:
            raise ValueError(f"beam must be >= 1 or None, got {beam}")
        super().__init__(env, planning_horizon=horizon, beam_width=beam, mask_key="action_mask" if mask else None)
        self.goal_source = goal_source
        self.shift_decay = float(shift_decay)
        self.model = getattr(env, "dynamics", None)  # None: an env that only imagines (the true simulator)
        self.playbacks = playbacks or (N_PLAYBACKS if self.n_actions == N_ADAPTIVE_ACTIONS else 1)
        self.horizon, self.shift = int(horizon), int(shift)
        self.bonus, self.penalty, self.mask, self.beam = float(bonus), float(penalty), bool(mask), beam
        # adapted parameters to plan with (None: the model's own); of an ensemble's list, the paper's planner
        # uses the first member (the paper plans with one model)
        self.params: list[TensorDictBase] | TensorDictBase | None = None
        self.in_keys = ["observation", "history", "plan_goals", "explore_plan", "action_mask"]
        if self.model is not None and self.model.road:  # it reads the road ahead of every imagined car
            if beam is not None:  # imagine() rolls the whole tree out; a beam would need the road in each step
                raise ValueError("beam search needs a model without the road (TrainConfig.road = 0); "
                                 f"this model reads {self.model.road} road points")
            self.in_keys.append("route_ahead")

    # ----- the navigation's terms as hooks of the generic search ------------------------------------------
    def levels(self, roots: TensorDictBase) -> int:
        return min(self.planning_horizon, roots["plan_goals"].shape[1])

    def step_reward(self, roots: TensorDictBase, children: dict, actions: torch.Tensor, level: int) -> torch.Tensor:
        if self.goal_source == "state":
            reward = super().step_reward(roots, children, actions, level)
        else:
            position = children["observation"][..., [X, Y]]
            reward = -tracking_cost(position, roots["plan_goals"][:, level].float().unsqueeze(1))
        if not self.mask:
            reward = reward - self._penalties(actions, roots["action_mask"][:, level].bool())
        return reward

    def sequence_reward(self, roots: TensorDictBase, sequences: torch.Tensor) -> torch.Tensor:
        """The explore-match bonus of complete sequences ``[B, N, H]``."""
        H = sequences.shape[-1]
        shifted = roots["explore_plan"].long()[:, : H + 2 * self.shift].unfold(-1, H, 1)  # [B, 2S + 1, H]
        instruction = sequences.div(self.playbacks, rounding_mode="floor")
        match = (instruction.unsqueeze(2) == shifted.unsqueeze(1)).all(-1)  # [B, N, 2S + 1]
        k = torch.arange(shifted.shape[1], dtype=torch.get_default_dtype(), device=sequences.device) \
            - (shifted.shape[1] - 1) / 2
        weight = 1.0 - self.shift_decay * k.abs()  # a shift must buy its cost: explore itself wins ties
        return self.bonus * (match.to(weight.dtype) * weight).amax(-1)

    def _penalties(self, actions: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        """``penalty`` for each turn/roundabout prompt in ``actions`` ``[B, N]`` that ``mask`` ``[B, A]`` forbids."""
        instruction = actions.div(self.playbacks, rounding_mode="floor")
        is_prompt = torch.isin(instruction, torch.tensor(TURN_INSTRUCTIONS, device=instruction.device))
        return self.penalty * (is_prompt & ~mask.gather(-1, actions)).to(torch.get_default_dtype())

    def _explore(self, roots: TensorDictBase, H: int) -> torch.Tensor:
        """``[B, H]``: the explore plan in the action space (the fallback when no sequence has a finite return)."""
        plan = roots["explore_plan"].long()[:, self.shift: self.shift + H]
        return plan * self.playbacks + (1 if self.playbacks == N_PLAYBACKS else 0)

    # ----- the search ---------------------------------------------------------------------------------------
    @torch.no_grad()
    def imagined_search(self, root: TensorDictBase) -> SearchResult:
        """The same tree from one root, imagined by the env's ``imagine`` (the true simulator, or a model that
        reads the road) and averaged over its samples: every sequence of the (masked) tree rolled out whole."""
        roots = root.unsqueeze(0)
        H = self.levels(roots)
        seqs = torch.cartesian_prod(*[self.allowed(roots, h)[0].nonzero().squeeze(-1) for h in range(H)]).reshape(-1, H)
        pos, goal = self.env.imagine(root, seqs)  # [M, N, H, 2]
        start = root["history"][-1, [GX, GY]].float().expand(*goal.shape[:2], 1, 2)
        prev = torch.cat([start, goal[:, :, :-1]], dim=2) if self.goal_source == "state" else root["plan_goals"][:H]
        ret = -tracking_cost(pos, prev).sum(-1).mean(0)
        if not self.mask:
            ret = ret - sum(self._penalties(seqs[:, h].unsqueeze(0), root["action_mask"][h].bool().unsqueeze(0))[0]
                            for h in range(H))
        ret = (ret + self.sequence_reward(roots, seqs.unsqueeze(0))[0]).unsqueeze(0)
        best = int(torch.nan_to_num(ret, nan=float("-inf")).argmax())
        return SearchResult(seqs[best].unsqueeze(0), ret[:, best], seqs.numel())

    def planning(self, td: TensorDictBase) -> torch.Tensor:
        flat = planning_roots(self, td, "the navigation env writes plan_goals/explore_plan/action_mask; wrap it "
                                        "with HistoryWindow for history")
        t0 = time.perf_counter()
        params = self.params[0] if isinstance(self.params, list) else self.params
        with using(self.model, params) if self.model is not None else nullcontext():
            imagined = self.model is None or bool(self.model.road)
            if imagined:
                results = [self.imagined_search(flat[i]) for i in range(flat.shape[0])]
                result = SearchResult(torch.cat([r.actions for r in results]), torch.cat([r.returns for r in results]),
                                      sum(r.evaluations for r in results))
            else:  # the generic search counts its non-finite decisions itself
                result = self.search(flat)
        # a model predicting NaN/Inf everywhere: no sequence has a finite return; play the explore plan
        lost = ~torch.isfinite(result.returns)
        if bool(lost.any()):
            self.nonfinite += int(lost.sum()) if imagined else 0
            result.actions[lost] = self._explore(flat[lost], result.actions.shape[1])
        self.last = result
        self.planning_s += time.perf_counter() - t0
        return result.actions[:, 0].reshape(td.shape)
