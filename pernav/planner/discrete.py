"""DiscreteTreeSearchPlanner: model-predictive control by tree search over discrete actions, for any TorchRL env.

TorchRL's MPC planners (``CEMPlanner``, ``MPPIPlanner``) sample continuous actions; this one searches a tree
of discrete actions. From the current state it expands every action at every level (or, with a beam, the
``beam_width`` best nodes of each level) for ``planning_horizon`` levels, steps each level's nodes through
the env in one batched call, so shared prefixes are computed once (``sum_h A^h`` steps instead of
``H * A^H`` for a flat enumeration), and scores a sequence by the env's own summed reward (rewards after the
first ``done`` are ignored, as in TorchRL's planners), plus an optional terminal ``value_module``. It plays
the first action of the best sequence (receding horizon).

Any env whose action spec is ``Categorical`` or ``OneHot`` and that steps batches of any size: a
``ModelBasedEnvBase`` (a learned model) or any stateless ``EnvBase``. Nodes are stepped with ``env.step``, so a
sequence scores exactly as ``env.rollout`` would play it (the env's own ``_step``, reward, done and
``world_model_params``); a plain world model (:class:`~pernav.model.PlainWorldModel`) in an env whose step is
its world model alone is stepped on plain tensors instead, the same computation without TensorDicts
(:attr:`DiscreteTreeSearchPlanner.fast_path`). An action mask (``mask_key``: ``[..., A]`` for every level, or
``[..., H, A]`` one per level) prunes forbidden actions from the tree. The input tensordict may have any
batch shape; each root is searched on its own, all in the same batched env calls. An env built with a
``batch_size`` (whose ``step`` takes exactly that shape) is stepped one node per root and slot, root ``b`` in slot
``b mod batch_size.numel()``, as ``env.rollout`` on those roots plays it.

Example:
    >>> import torch
    >>> from tensordict import TensorDict
    >>> from tensordict.nn import TensorDictModule
    >>> from torch import nn
    >>> from torchrl.data import Categorical, Composite, Unbounded
    >>> from torchrl.envs import ModelBasedEnvBase
    >>> from torchrl.modules import WorldModelWrapper
    >>> class Walk(nn.Module):  # a walker on a line: action 0 steps left, 1 stays, 2 steps right
    ...     def forward(self, x, a):
    ...         return x + (a.unsqueeze(-1) - 1).float()
    >>> class Near(nn.Module):  # reward: minus the distance to 3
    ...     def forward(self, x):
    ...         return -(x - 3).abs()
    >>> class Line(ModelBasedEnvBase):
    ...     def __init__(self):
    ...         super().__init__(WorldModelWrapper(TensorDictModule(Walk(), ["x", "action"], ["x"]),
    ...                                            TensorDictModule(Near(), ["x"], ["reward"])))
    ...         self.observation_spec = Composite(x=Unbounded((1,)))
    ...         self.action_spec = Categorical(3)
    ...         self.reward_spec = Unbounded((1,))
    ...     def _reset(self, td=None, **kwargs):
    ...         return td
    >>> planner = DiscreteTreeSearchPlanner(Line(), planning_horizon=3)
    >>> planner(TensorDict({"x": torch.tensor([[0.0], [5.0]])}, [2]))["action"].tolist()
    [2, 0]
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass

import torch
from tensordict import TensorDict, TensorDictBase
from tensordict.nn import TensorDictModuleBase
from tensordict.utils import NestedKey
from torchrl.data import Categorical, Composite, OneHot, TensorSpec
from torchrl.envs import ModelBasedEnvBase
from torchrl.modules.planners import MPCPlannerBase

__all__ = ["DiscreteTreeSearchPlanner", "SearchResult", "planning_roots"]

log = logging.getLogger("pernav.planner")


def planning_roots(planner: MPCPlannerBase, td: TensorDictBase, source: str = "") -> TensorDictBase:
    """The opening of every planner's ``planning``: the roots to search, ``td`` flattened to ``[B]``, once it holds
    each of the ``planner``'s ``in_keys``; else a ``KeyError`` that names the missing keys (and, in ``source``,
    where they come from).

    Example:
        >>> from tensordict import TensorDict
        >>> class Needs:
        ...     in_keys = ["observation"]
        >>> planning_roots(Needs(), TensorDict({"observation": torch.zeros(2, 3, 4)}, [2, 3])).shape
        torch.Size([6])
        >>> planning_roots(Needs(), TensorDict({}, [2]), "an env writes it")
        Traceback (most recent call last):
        ...
        KeyError: "Needs needs ['observation'] in the tensordict (an env writes it)"
    """
    missing = [k for k in planner.in_keys if k not in td.keys(True, True)]
    if missing:
        raise KeyError(f"{type(planner).__name__} needs {missing} in the tensordict" + (f" ({source})" if source else ""))
    return td.reshape(-1)


@dataclass
class SearchResult:
    """One search per root: the best sequence ``[B, H]``, its return ``[B]`` and the env steps it took."""

    actions: torch.Tensor
    returns: torch.Tensor
    evaluations: int


def _key(key: NestedKey) -> tuple[str, ...]:
    return (key,) if isinstance(key, str) else tuple(key)


def _device(roots: TensorDictBase, keys: list) -> torch.device:
    """Where the roots' state lives (a TensorDict without a device of its own: its first state entry's)."""
    return roots.device if roots.device is not None else roots.get(keys[0]).device


def _action_layout(spec: TensorSpec, batch_size: torch.Size) -> tuple[bool, int, torch.dtype, tuple[int, ...]]:
    """Whether ``spec`` is one-hot, its number of actions, dtype and per-root shape; ``TypeError`` for a spec that
    is not one ``Categorical`` or ``OneHot`` action (its subclasses ``MultiCategorical``, ``Binary``,
    ``MultiOneHot`` encode several actions at once)."""
    if type(spec) not in (Categorical, OneHot):
        hint = ("for continuous actions use torchrl's CEMPlanner or MPPIPlanner" if spec.domain == "continuous" else
                "it plans one discrete action per step: MultiCategorical, MultiOneHot and Binary are not supported")
        raise TypeError(f"DiscreteTreeSearchPlanner needs a Categorical or OneHot action spec, got "
                        f"{type(spec).__name__} ({hint})")
    shape = tuple(spec.shape[len(batch_size):]) if tuple(spec.shape[: len(batch_size)]) == tuple(batch_size) \
        else tuple(spec.shape)
    n = int(spec.space.n)
    if shape not in (((n,),) if isinstance(spec, OneHot) else ((), (1,))):
        expected = (n,) if isinstance(spec, OneHot) else "() or (1,)"
        raise TypeError(f"DiscreteTreeSearchPlanner plans one action per step, got a {type(spec).__name__} spec of "
                        f"per-step shape {shape}: several actions are not supported (expected {expected})")
    return isinstance(spec, OneHot), n, spec.dtype, shape


class DiscreteTreeSearchPlanner(MPCPlannerBase):
    """Exhaustive or beam tree search over a discrete action space, scored by the env's reward.

    Args:
        env: a batched, stateless env with a ``Categorical`` or ``OneHot`` action spec (e.g. a
            ``ModelBasedEnvBase`` around a learned model).
        planning_horizon: H, the levels of the tree (imagined steps).
        beam_width: keep only this many best nodes per level and root (``None``: exhaustive). A beam at least as
            wide as the tree is the exhaustive search.
        reward_key: where the env's step writes its reward (``("next", "reward")`` for TorchRL envs).
        mask_key: an input entry of booleans, ``[..., A]`` or ``[..., H', A]`` with ``H' >= H`` (level ``h``
            reads row ``h``): actions it forbids are not expanded (a root with none allowed at a level, or a mask
            of another width than A: ``ValueError``). ``None``: every action is allowed.
        value_module: optional ``TensorDictModule`` reading a leaf's state and writing ``value_key``, added to
            the return of each complete sequence (a terminal value; not applied after ``done``).
        value_key: where ``value_module`` writes.
        action_key: the action entry (read by the env, written by the planner).

    The search is exact: it returns the sequence with the highest return (ties go to the sequence that comes
    first in the order of the action indices), as a brute-force enumeration of the same tree would. A sequence
    whose return is NaN never wins; :attr:`nonfinite` counts decisions where some return was not finite.

    Actions are written (to the env's step and as the output) in the spec's own dtype and shape: a bool one-hot for
    ``OneHot(n)``, ``[..., 1]`` for ``Categorical(n, shape=(1,))``; so ``MPCPlannerBase.forward`` keeps the output as
    it is (it would project an action outside the spec with ``torch.multinomial``, a draw from the global
    generator). Specs of several actions (``MultiCategorical``, ``MultiOneHot``, ``Binary``) are refused.
    """

    def __init__(self, env, planning_horizon: int, beam_width: int | None = None,
                 reward_key: NestedKey = ("next", "reward"), mask_key: NestedKey | None = None,
                 value_module: TensorDictModuleBase | None = None, value_key: NestedKey = "state_value",
                 action_key: NestedKey = "action") -> None:
        super().__init__(env, action_key=action_key)
        if int(planning_horizon) < 1:
            raise ValueError(f"planning_horizon must be >= 1, got {planning_horizon}")
        if beam_width is not None and int(beam_width) < 1:
            raise ValueError(f"beam_width must be >= 1 or None, got {beam_width}")
        spec = env.full_action_spec[action_key] if isinstance(env.action_spec, Composite) else env.action_spec
        self.action_spec = spec  # the leaf (TorchRL's env.action_spec is a Composite for an action not at "action")
        self.one_hot, self.n_actions, self.action_dtype, self.action_shape = _action_layout(spec, env.batch_size)
        self.planning_horizon = int(planning_horizon)
        self.beam_width = None if beam_width is None else int(beam_width)
        self.reward_key, self.mask_key, self.action_key = _key(reward_key), mask_key, action_key
        self.value_module, self.value_key = value_module, value_key
        self.model_based = isinstance(env, ModelBasedEnvBase)
        self.state_keys = sorted({*env.observation_spec.keys(True, True), *env.state_spec.keys(True, True)}, key=str)
        self.in_keys = self.state_keys + ([mask_key] if mask_key is not None else [])
        # the step's entries the hooks read besides the state (reward, done), kept as the env wrote them
        self._extra_keys = [self._reward_key, "done", "terminated"]
        self.nonfinite = 0  # decisions where some sequence's return was not finite
        self.planning_s = 0.0  # wall time spent planning
        self.last: SearchResult | None = None

    # ----- hooks (a subclass adds task terms here) ----------------------------------------------------
    def levels(self, roots: TensorDictBase) -> int:
        """The number of levels searched from ``roots`` (``planning_horizon``)."""
        return self.planning_horizon

    def allowed(self, roots: TensorDictBase, level: int, mask: torch.Tensor | None = None) -> torch.Tensor:
        """``[B, A]`` booleans: the actions each root's tree may take at ``level`` (from ``mask_key``; ``mask``:
        that entry already read, as :meth:`search` does once per search)."""
        if self.mask_key is None:
            return torch.ones(roots.shape[0], self.n_actions, dtype=torch.bool, device=_device(roots, self.state_keys))
        mask = self._mask(roots, level + 1) if mask is None else mask
        return mask[:, level] if mask.ndim == 3 else mask

    def _mask(self, roots: TensorDictBase, levels: int) -> torch.Tensor:
        """The ``mask_key`` entry of flat roots as booleans, ``ValueError`` unless it is ``[B, A]`` or ``[B, H', A]``
        with at least ``levels`` rows (a bare ``IndexError`` otherwise, or a silently wrong action set)."""
        mask = roots.get(self.mask_key)
        shape, name = tuple(mask.shape), f"{type(self).__name__}: the mask {self.mask_key!r}"
        if mask.ndim - roots.batch_dims not in (1, 2):
            raise ValueError(f"{name} must be [..., A] or [..., H, A] for roots of batch shape {tuple(roots.shape)}, "
                             f"got shape {shape}")
        if shape[-1] != self.n_actions:
            raise ValueError(f"{name} has width {shape[-1]} (shape {shape}) but the env has {self.n_actions} actions "
                             "(its action spec): one column per action")
        if mask.ndim - roots.batch_dims == 2 and shape[-2] < levels:
            raise ValueError(f"{name} has {shape[-2]} level row(s) (shape {shape}) for a search of {levels} levels: "
                             "one row per level")
        return mask.bool()

    def step_reward(self, roots: TensorDictBase, children: dict, actions: torch.Tensor, level: int) -> torch.Tensor:
        """``[B, N]``: the reward of the step that led to each node (the env's, at ``reward_key``). ``children``
        maps the env's output keys (state, reward, done) to ``[B, N, ...]`` tensors."""
        reward = children.get(self._reward_key)
        if reward is None:
            raise KeyError(f"the env's step wrote no reward at {self.reward_key!r} (reward_key)")
        return reward.reshape(actions.shape)

    def sequence_reward(self, roots: TensorDictBase, sequences: torch.Tensor) -> torch.Tensor | float:
        """A term added to the return of each complete sequence ``[B, N, H]`` (0 here)."""
        return 0.0

    # ----- one batched step ---------------------------------------------------------------------------
    @property
    def _reward_key(self) -> NestedKey:
        # the children are the step's "next" entries (a world model writes them at its root)
        key = self.reward_key[1:] if self.reward_key[0] == "next" and len(self.reward_key) > 1 else self.reward_key
        return key[0] if len(key) == 1 else key

    @property
    def fast_path(self) -> bool:
        """Whether a level is stepped by the world model's ``tensor_step`` on plain tensors (no TensorDict per
        call: a third of a decision's time at the navigation's size). Only where that is provably the env's
        step: a ``ModelBasedEnvBase`` whose ``_step`` is TorchRL's own (the world model and nothing else), with
        no ``world_model_params``/``world_model_buffers``, and a world model that offers ``tensor_step``
        (:class:`~pernav.model.PlainWorldModel`). Elsewhere the env's own ``step``."""
        env = self.env
        return (self.model_based and type(env)._step is ModelBasedEnvBase._step
                and env.world_model_params is None and env.world_model_buffers is None
                and callable(getattr(env.world_model, "tensor_step", None)))

    def _step(self, nodes: dict, actions: torch.Tensor) -> dict:
        """The children of flat nodes (``{key: [B * k, ...]}``) after ``actions`` ``[B, k]`` (``k`` per root):
        every entry the env's step writes (next state, reward, done), as ``env.step`` computes them (its
        ``_step``, reward and done)."""
        data = dict(nodes)
        data[self.action_key] = self._encoded(actions.reshape(-1))
        if self.fast_path:
            return self.env.world_model.tensor_step(data)
        if self.env.batch_size:
            return self._step_in_slots(data, *actions.shape)
        td = TensorDict(batch_size=[actions.numel()], device=actions.device)
        for key, value in data.items():
            td.set(key, value)
        out = self.env.step(td).get("next")
        return {key: out.get(key) for key in out.keys(True, True)}

    def _step_in_slots(self, data: dict, roots: int, k: int) -> dict:
        """``env.step`` for an env with a batch size, which steps exactly that shape: ``k`` calls, each with one
        node per root in the root's own slot (root ``b`` in slot ``b mod P``), as ``env.rollout`` plays the roots."""
        shape = self.env.batch_size
        slots = shape.numel()
        if roots % slots:
            raise ValueError(f"{type(self).__name__}: the env steps batches of exactly {tuple(shape)}, one root per "
                             f"slot; got {roots} roots, not a multiple of {slots} (give roots of shape "
                             f"[..., {', '.join(map(str, shape))}])")
        groups = roots // slots

        def to_slots(v: torch.Tensor) -> torch.Tensor:  # [groups * slots * k, ...] -> [groups * k, *shape, ...]
            v = v.reshape(groups, slots, k, *v.shape[1:]).transpose(1, 2)
            return v.reshape(groups * k, *shape, *v.shape[3:])

        def from_slots(v: torch.Tensor) -> torch.Tensor:
            v = v.reshape(groups, k, slots, *v.shape[1 + len(shape):]).transpose(1, 2)
            return v.reshape(groups * slots * k, *v.shape[3:])

        td = TensorDict(batch_size=[groups * k, *shape], device=data[self.action_key].device)
        for key, value in data.items():
            td.set(key, to_slots(value))
        out = torch.stack([self.env.step(td[i]).get("next") for i in range(groups * k)])
        return {key: from_slots(out.get(key)) for key in out.keys(True, True)}

    @staticmethod
    def _done(children: dict, shape: tuple[int, int]) -> torch.Tensor | None:
        done = children.get("done")
        done = children.get("terminated") if done is None else done
        return None if done is None else done.reshape(shape).bool()

    # ----- the search ---------------------------------------------------------------------------------
    @torch.no_grad()
    def search(self, roots: TensorDictBase) -> SearchResult:
        """The best sequence from each root of a flat ``[B]`` tensordict (see the class docstring)."""
        B = roots.shape[0]
        H = self.levels(roots)
        device = _device(roots, self.state_keys)  # every tensor made here lives with the roots' state
        if device.type == "meta":  # a search reads values (its choices are data-dependent): refuse before it starts
            raise ValueError(f"{type(self).__name__}: the roots are on the 'meta' device, which holds shapes but no "
                             "values to search from; move them to a real device (e.g. roots.to('cpu'))")
        mask = None if self.mask_key is None else self._mask(roots, H)  # once per search, not per level
        nodes = {k: roots.get(k) for k in self.state_keys}  # flat [B * N, ...]: N nodes per root
        parent_count = 1
        seqs = torch.zeros(B, 1, 0, dtype=torch.long, device=device)
        ret = torch.zeros(B, 1, device=device)  # promoted to the reward's dtype (float64 stays float64)
        alive = None  # [B, N] not done yet (later rewards count); None: no node done so far
        valid = torch.ones(B, 1, dtype=torch.bool, device=device)  # a real node (not padding of a root with fewer nodes)
        rows = torch.arange(B, device=device).unsqueeze(-1)
        evaluations = 0
        for level in range(H):
            # every (node, action) pair the mask allows, packed per root in order (root-major, action-minor)
            level_allowed = self.allowed(roots, level, mask)  # [B, A]
            k, index, parent, action, keep = self._expand(level_allowed, valid, parent_count, rows, level)
            out = self._step({key: v[index] for key, v in nodes.items()}, action)
            children = {key: out[key].reshape(B, k, *out[key].shape[1:]) for key in self.state_keys}
            children.update({key: out[key] for key in self._extra_keys if key in out})
            evaluations += B * k
            reward = self.step_reward(roots, children, action, level)
            ret = ret.gather(-1, parent)
            if alive is None:  # no node has finished: every reward counts
                ret = ret + reward
            else:
                alive = alive.gather(-1, parent)
                ret = ret + torch.where(alive, reward, 0.0)
            done = self._done(children, (B, k))
            if done is not None:
                alive = ~done if alive is None else alive & ~done
            seqs = torch.cat([seqs.reshape(B * seqs.shape[1], level)[index].reshape(B, k, level), action.unsqueeze(-1)], -1)
            nodes = {key: out[key] for key in self.state_keys}  # flat [B * k, ...]
            parent_count = k
            valid = keep if keep is not None else torch.ones(B, k, dtype=torch.bool, device=device)
            if keep is not None:
                ret = torch.where(valid, ret, torch.full_like(ret, float("-inf")))
            if self.beam_width is not None and k > self.beam_width and level + 1 < H:
                scores = torch.nan_to_num(ret, nan=float("-inf"))
                top = torch.topk(scores, self.beam_width, dim=-1, sorted=False).indices.sort(-1).values
                flat_top = (top + rows * k).reshape(-1)
                nodes = {key: v[flat_top] for key, v in nodes.items()}
                seqs, ret, valid = seqs[rows, top], ret.gather(-1, top), valid.gather(-1, top)
                alive = None if alive is None else alive.gather(-1, top)
                parent_count = self.beam_width
        nodes = {key: v.reshape(B, parent_count, *v.shape[1:]) for key, v in nodes.items()}
        return self._best(roots, nodes, seqs, ret, alive, valid, rows, evaluations)

    def _expand(self, level_allowed: torch.Tensor, valid: torch.Tensor, parent_count: int, rows: torch.Tensor,
                level: int) -> tuple[int, torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor | None]:
        """Every (node, action) pair the mask allows at ``level``, packed per root in order (root-major,
        action-minor): the children per root ``k``, the flat parent ``index``, the ``[B, k]`` parent and action,
        and which children are real (``None``: all of them)."""
        B, A, device = level_allowed.shape[0], self.n_actions, rows.device
        if B == 1:  # one root (a deployed planner): every node is real, each expands the same actions
            actions = level_allowed[0].nonzero().squeeze(-1)
            if not actions.numel():
                self._refuse_unplannable(level_allowed, level)
            index = torch.arange(parent_count, device=device).repeat_interleave(actions.numel())
            return parent_count * actions.numel(), index, index.unsqueeze(0), actions.repeat(parent_count).unsqueeze(0), None
        if not bool(level_allowed.any(-1).all()):
            self._refuse_unplannable(level_allowed, level)
        allowed = (valid.unsqueeze(-1) & level_allowed.unsqueeze(1)).reshape(B, -1)  # [B, N*A]
        k = max(int(allowed.sum(-1).max()), 1)
        pick = torch.argsort((~allowed).to(torch.int8), dim=-1, stable=True)[:, :k]  # allowed first, in order
        parent, action = pick.div(A, rounding_mode="floor"), pick.remainder(A)
        return k, (parent + rows * parent_count).reshape(-1), parent, action, allowed.gather(-1, pick)

    def _best(self, roots: TensorDictBase, nodes: dict[str, torch.Tensor], seqs: torch.Tensor, ret: torch.Tensor,
              alive: torch.Tensor | None, valid: torch.Tensor, rows: torch.Tensor, evaluations: int) -> SearchResult:
        """The leaves' values and the sequence rewards added, the best sequence per root."""
        if self.value_module is not None:
            leaves = TensorDict(batch_size=[ret.numel()])
            for key, v in nodes.items():
                leaves.set(key, v.reshape(ret.numel(), *v.shape[2:]))
            value = self.value_module(leaves).get(self.value_key).reshape(ret.shape)
            ret = ret + (value.to(ret.dtype) if alive is None else torch.where(alive, value.to(ret.dtype), 0.0))
        ret = ret + self.sequence_reward(roots, seqs)
        ret = torch.where(valid, ret, torch.full_like(ret, float("-inf")))
        finite = torch.isfinite(ret) | ~valid
        if not bool(finite.all()):
            self.nonfinite += 1
            log.warning("DiscreteTreeSearchPlanner: %d non-finite sequence returns", int((~finite).sum()))
        best = torch.nan_to_num(ret, nan=float("-inf")).argmax(-1)  # the first best: ties go to the lower sequence
        return SearchResult(seqs[rows[:, 0], best], ret[rows[:, 0], best], evaluations)


    def _refuse_unplannable(self, allowed: torch.Tensor, level: int) -> None:
        """Raise for roots whose ``allowed`` ``[B, A]`` row is all false: no sequence exists there, and the search
        would return action 0 with a return of -inf as if it were a plan."""
        roots = (~allowed.any(-1)).nonzero().squeeze(-1).tolist()
        raise ValueError(f"{type(self).__name__}: no allowed action at level {level} for root(s) {roots} (flat "
                         f"index into the input's batch) of {allowed.shape[0]}; the mask ({self.mask_key!r}) must "
                         "allow at least one action per root and level")

    def planning(self, td: TensorDictBase) -> torch.Tensor:
        roots = planning_roots(self, td)
        t0 = time.perf_counter()
        self.last = self.search(roots)
        first = self.last.actions[:, 0]
        self.planning_s += time.perf_counter() - t0
        # in the spec's own dtype and shape: MPCPlannerBase.forward then keeps it as it is (an action outside the
        # spec, e.g. an int64 one-hot for a bool spec, it would "project" with torch.multinomial)
        return self._encoded(first).reshape(tuple(td.shape) + self.action_shape)

    def _encoded(self, actions: torch.Tensor) -> torch.Tensor:
        """Action indices ``[M]`` as the spec writes them: ``[M, A]`` one-hot or ``[M]`` (``[M, 1]``) indices, in
        the spec's dtype (the indices themselves, untouched, for a default ``Categorical``)."""
        if self.one_hot:
            return torch.nn.functional.one_hot(actions, self.n_actions).to(self.action_dtype)
        if actions.dtype != self.action_dtype:
            actions = actions.to(self.action_dtype)
        return actions.reshape(-1, *self.action_shape) if self.action_shape else actions

