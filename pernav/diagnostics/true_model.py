"""A world model backed by copies of the live simulator: plan on the true dynamics, in expectation.

:class:`TrueDynamicsEnv` is a TorchRL env (any batch size, like a model-based env) whose transitions are the
simulator's own: reset from the live :class:`~pernav.env.navigation.NavigationEnv` branches it
(:meth:`~pernav.env.navigation.NavigationEnv.branch`), and each row steps its own copy. Every copy is
re-seeded, so it does not know the live episode's future random draws (mishearing, compliance, the driver's
guesses, traffic); :meth:`TrueDynamicsEnv.imagine` averages ``samples`` such futures. A planner given this
env in place of the learned one has no model error: its loss to the oracle is *planning error*, and the
learned planner's loss to it is *model error* (:mod:`pernav.diagnostics.planning_error`).

Example:
    >>> import torch
    >>> from pernav.env.navigation import NavigationEnv
    >>> live = NavigationEnv("Town1", config={"n_traffic": 2})
    >>> _ = live.reset(seed=0, options={"route": 0})
    >>> true = TrueDynamicsEnv(live, samples=2)
    >>> pos, goal = true.imagine(None, torch.zeros(3, 4, dtype=torch.long))
    >>> pos.shape
    torch.Size([2, 3, 4, 2])
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch
from tensordict import TensorDict, TensorDictBase
from torchrl.data import Categorical, Composite, Unbounded
from torchrl.envs import EnvBase

from pernav.env.layout import STATE_DIM
from pernav.env.navigation import NavigationEnv

__all__ = ["TrueDynamicsEnv"]


class TrueDynamicsEnv(EnvBase):
    """The live simulator as a (perfect, in expectation) world model; see the module docstring.

    Args:
        source: the live env the planner decides for (its current state is the root of every imagination).
        samples: re-seeded copies averaged per imagination (rows ``M`` of :meth:`imagine`).
        seed: base of the copies' seeds (each imagination draws new ones).
    """

    def __init__(self, source: NavigationEnv, samples: int = 2, seed: int = 0) -> None:
        super().__init__(batch_size=torch.Size([]))
        self._batch_locked = False
        if samples < 1:
            raise ValueError(f"samples must be >= 1, got {samples}")
        self.source, self.samples = source, int(samples)
        self._rng = np.random.default_rng(seed)
        self._copies: list[NavigationEnv] = []
        self.observation_spec = Composite(observation=Unbounded((STATE_DIM,)))
        self.action_spec = Categorical(source.n_actions)
        self.reward_spec = Unbounded((1,))

    def _seed(self) -> int:
        return int(self._rng.integers(2**31 - 1))

    # ----- EnvBase: each row of the batch steps its own re-seeded copy of the live env ------------
    def _reset(self, tensordict: TensorDictBase | None = None, **kwargs: Any) -> TensorDictBase:
        shape = tensordict.shape if tensordict is not None else torch.Size([])
        n = int(np.prod(shape)) if len(shape) else 1
        self._copies = [self.source.branch(self._seed()) for _ in range(n)]
        obs = torch.stack([torch.as_tensor(c._observation()) for c in self._copies]).reshape(*shape, STATE_DIM)
        done = torch.zeros(*shape, 1, dtype=torch.bool)
        return TensorDict({"observation": obs, "done": done, "terminated": done.clone()}, shape)

    def _step(self, tensordict: TensorDictBase) -> TensorDictBase:
        shape = tensordict.shape
        actions = tensordict["action"].reshape(-1).tolist()
        out = [c.advance(a) for c, a in zip(self._copies, actions, strict=True)]
        obs = torch.stack([torch.as_tensor(c._observation()) for c in self._copies]).reshape(*shape, STATE_DIM)
        reward = torch.tensor([-o[0] for o in out], dtype=torch.float32).reshape(*shape, 1)
        done = torch.tensor([o[2] or o[3] for o in out]).reshape(*shape, 1)
        return TensorDict({"observation": obs, "reward": reward, "done": done, "terminated": done.clone()}, shape)

    def _set_seed(self, seed: int | None) -> None:
        self._rng = np.random.default_rng(seed)

    # ----- what a planner calls -------------------------------------------------------------------
    def imagine(self, root: Any, sequences: torch.Tensor, params: Any = None) -> tuple[torch.Tensor, torch.Tensor]:
        """Positions and goals ``[samples, N, H, 2]`` of action ``sequences`` ``[N, H]`` from the live env.

        Sequences sharing a prefix share its simulation (a copy is branched where they part, with the same
        random state: common random numbers across candidates); ``root`` and ``params`` are ignored (the root
        is the live env's state, and the simulator has no parameters)."""
        N, H = sequences.shape
        pos = np.zeros((self.samples, N, H, 2), dtype=np.float32)
        goal = np.zeros_like(pos)
        seqs = sequences.tolist()
        for m in range(self.samples):
            self._expand(self.source.branch(self._seed()), list(range(N)), seqs, 0, pos[m], goal[m])
        return torch.from_numpy(pos), torch.from_numpy(goal)

    def _expand(self, env: NavigationEnv, rows: list[int], seqs: list[list[int]], h: int, pos: np.ndarray,
                goal: np.ndarray, done: bool = False) -> None:
        H = len(seqs[0])
        while h < H:
            groups: dict[int, list[int]] = {}
            for r in rows:
                groups.setdefault(seqs[r][h], []).append(r)
            if len(groups) > 1 and not done:
                *others, (action, rows) = groups.items()
                for a, sub in others:  # every branch but the last steps a copy; the last goes on with env
                    twin = env.branch()
                    self._expand(twin, sub, seqs, h + 1, pos, goal, self._advance(twin, a, sub, h, pos, goal, done))
            else:
                action = next(iter(groups)) if len(groups) == 1 else 0
            done = self._advance(env, action, rows, h, pos, goal, done)
            h += 1

    @staticmethod
    def _advance(env: NavigationEnv, action: int, rows: list[int], h: int, pos: np.ndarray, goal: np.ndarray,
                 done: bool) -> bool:
        """Step ``env`` (unless its episode ended: then the car stays, at zero cost) and record the rows."""
        if not done:
            _, _, arrived, truncated = env.advance(action)
            done = arrived or truncated
        pos[rows, h] = env.world.ego.position
        goal[rows, h] = env.world.ego.position if done else env.goal
        return done
