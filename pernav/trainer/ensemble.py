"""An ensemble of dynamics models trained side by side on one data stream (the planner's uncertainty).

Each member is a :class:`~pernav.model.DynamicsModel` of the same architecture with its own initialization
and its own :class:`~pernav.trainer.ftml.FTMLTrainer` (Adam state); all share one
:class:`~pernav.trainer.buffers.RoundBuffers` and, per update, one sampled batch (members differ by their
initialization, as in a deep ensemble), so that the members train as one batched model over their stacked
parameters. The planner imagines every candidate with every member (adapted or not) and leaves explore only
where all members agree on the gain and on the candidate's effect
(:class:`~pernav.planner.retiming.RetimingPlanner`'s ``agree`` and ``max_spread``), so where the members
disagree, a poor model costs little. With ``size=1`` this is exactly one FTML trainer.

Example:
    >>> import torch
    >>> from tensordict import TensorDict
    >>> buffers = RoundBuffers(L=3, seed=0)
    >>> T = 20
    >>> buffers.add(0, TensorDict({"observation": torch.randn(T, 14), "action": torch.randint(7, (T,)),
    ...     "history": torch.randn(T, 5, 21), ("next", "observation"): torch.randn(T, 14)}, [T]), tau=True)
    >>> ens = EnsembleTrainer(lambda: DynamicsModel(hidden=(16,)), buffers, TrainConfig(batch=8, L=3, hidden=[16]),
    ...                       size=2)
    >>> ens.fit_normalization()
    >>> len(ens.train(2, meta=False)), len(ens.parameters(buffers.tau(0), adapted=True, alpha=0.01))
    (2, 2)
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import torch
from tensordict import TensorDictBase

from pernav.model.adapt import LossFn, adapt, meta_parameters
from pernav.model.dynamics import DynamicsModel
from pernav.model.losses import multistep_loss
from pernav.trainer.buffers import RoundBuffers
from pernav.trainer.ftml import FTMLTrainer, TrainConfig, keyed_loss

__all__ = ["EnsembleTrainer"]


class EnsembleTrainer:
    """``size`` FTML trainers on one data stream; the first member's module is ``model``.

    Args:
        make_model: builds one member (called under a member-specific torch seed, so members differ).
        buffers: the shared data stream.
        config: the members' hyperparameters.
        size: members.
        seed: base seed (member ``i`` uses ``seed + i`` for its initialization and its sampling).
        loss_fn: the loss of the updates, of ``U`` and of the round loss, as :class:`FTMLTrainer`'s (the paper's
            L-step loss by default). With several members it gets their stacked parameters (``params`` with a
            batch dimension ``[E]``, it returns ``[E]``) and, when trajectories are weighted, ``weights=``.
    """

    def __init__(self, make_model: Callable[[], DynamicsModel], buffers: RoundBuffers, config: TrainConfig,
                 size: int = 1, seed: int = 0, loss_fn: LossFn | None = None) -> None:
        if size < 1:
            raise ValueError(f"ensemble size must be >= 1, got {size}")
        self.members: list[FTMLTrainer] = []
        for i in range(size):
            with torch.random.fork_rng():
                torch.manual_seed(seed + i)
                model = make_model()
            self.members.append(FTMLTrainer(model, buffers, config, seed=seed + i, loss_fn=loss_fn))
        self.config, self._loss_fn = self.members[0].config, loss_fn  # the model's and buffers' fields read once
        # [E, trajectories]: each member's weight of each trajectory of ``buffers`` (bootstrap counts, set by
        # fine_tuned(..., bootstrap=True)); None: every window weighs the same for every member
        self.trajectory_weights: torch.Tensor | None = None

    @property
    def loss_fn(self) -> LossFn:
        """The loss given, or (None) this module's ``multistep_loss`` on the buffers' entry names, looked up at each
        use so that a patched module function (the reliability tests' NaN loss) is the one called."""
        return self._loss_fn if self._loss_fn is not None else keyed_loss(multistep_loss, self.buffers)

    @classmethod
    def from_states(cls, config: dict[str, Any], states: list[dict[str, Any]], train: TrainConfig,
                    buffers: RoundBuffers | None = None, seed: int = 0,
                    loss_fn: LossFn | None = None) -> EnsembleTrainer:
        """An ensemble of ``DynamicsModel(**config)`` members starting from ``states`` (their state dicts,
        normalization included), e.g. a finished study's (:func:`pernav.study.checkpoints.final_models`)."""
        out = cls(lambda: DynamicsModel(**config), buffers if buffers is not None else RoundBuffers(L=train.L),
                  train, size=len(states), seed=seed, loss_fn=loss_fn)
        for member, state in zip(out.members, states, strict=True):
            member.model.load_state_dict(state)
        return out

    @property
    def model(self) -> DynamicsModel:
        return self.members[0].model

    @property
    def buffers(self) -> RoundBuffers:
        return self.members[0].buffers

    @buffers.setter
    def buffers(self, buffers: RoundBuffers) -> None:
        for m in self.members:
            m.buffers = buffers

    @property
    def skipped(self) -> int:
        return sum(m.skipped for m in self.members)

    @property
    def clipped(self) -> int:
        return sum(m.clipped for m in self.members)

    @property
    def fallbacks(self) -> int:
        """Members' test-time ``U`` steps that fell back to the unadapted parameters (:attr:`FTMLTrainer.fallbacks`)."""
        return sum(m.fallbacks for m in self.members)

    @property
    def fallback_rounds(self) -> list[int]:
        """The rounds in which some member's ``U`` fell back, each once, in order."""
        return sorted({r for m in self.members for r in m.fallback_rounds})

    def fit_normalization(self) -> None:
        for m in self.members:
            m.fit_normalization()

    def train(self, updates: int, meta: bool) -> list[float]:
        """``updates`` steps of every member on the same batches (drawn once per step by the first member);
        the members' mean loss per step. All members' losses and gradients come from one batched pass over
        their stacked parameters (:meth:`update`); each member then steps its own Adam."""
        if len(self.members) == 1:
            return self.members[0].train(updates, meta)
        losses = []
        for _ in range(updates):
            first = self.members[0]
            losses.append(self.update(first.meta_batches() if meta else first.plain_batches(), meta))
        return losses

    def update(self, batches: list[tuple[int, int, Any]], meta: bool) -> float:
        """One step of every member on ``batches`` (from :meth:`FTMLTrainer.meta_batches` or ``plain_batches``):
        the same as each member's ``meta_update(batches)`` / ``plain_update(batches)`` in turn, but the members
        run as one batched model (their losses sum; each gets its own gradient), ~E times fewer small ops."""
        cfg, model = self.config, self.model
        params = torch.stack([meta_parameters(m.model) for m in self.members])  # [E], differentiable
        like = next(v for v in params.values(True, True) if v.is_floating_point())  # the members' dtype and device
        total = torch.zeros(len(self.members), dtype=like.dtype, device=like.device)
        for r, n, batch in batches:
            used = (adapt(model, self.buffers.tau(r), alpha=cfg.alpha, L=cfg.L, first_order=cfg.first_order,
                          params=params, max_norm=cfg.max_grad_norm, loss_fn=self.loss_fn,
                          action_key=self.buffers.action_key) if meta else params)
            batch = self.members[0].on_model(batch)
            # weights only when set (bootstrap): a loss without a weights argument works everywhere else
            weights = {} if self.trajectory_weights is None else {
                "weights": self.trajectory_weights[:, batch["traj"][:, 0].cpu()].to(like)}
            total = total + self.loss_fn(model, batch, params=used, **weights) * (n / cfg.batch)
        values = total.detach()
        for m in self.members:
            m.optimizer.zero_grad(set_to_none=True)
        finite = torch.isfinite(values)
        if bool(finite.any()):  # a member with a non-finite loss gets no step (FTMLTrainer.step skips it)
            total[finite].sum().backward()
        steps = [m.step(float(v)) for m, v in zip(self.members, values, strict=True)]
        return sum(steps) / len(steps)

    def parameters(self, tau: TensorDictBase | None, adapted: bool, alpha: float,
                   fixed_step: bool = False) -> list[TensorDictBase]:
        """Every member's parameters (detached), each adapted on ``tau`` with ``U`` when ``adapted`` (its step
        backtracked as ``config.backtrack`` says; ``fixed_step``: the paper's fixed ``alpha`` regardless; not
        ``adapted``: the members' own, ``tau`` unread)."""
        out = []
        backtrack = None if fixed_step else self.config.backtrack
        for m in self.members:
            if adapted:  # counted where U falls back (FTMLTrainer.fallbacks)
                out.append(m.adapted(tau, backtrack, alpha))
            else:
                out.append(meta_parameters(m.model).detach().clone())
        return out

    def adapted_parameters(self, tau: TensorDictBase | None, drives: Sequence[TensorDictBase] = (), meta: bool = True,
                           seed: int = 0) -> list[TensorDictBase]:
        """Every member's parameters for planning with one user, by the test-time rule ``config`` sets (the
        study's rounds and a person's session alike): ``personal_updates`` updates on the user's ``drives``
        (``tau`` among them; default ``[tau]``) with ``personal_replay``, else ``U(P, tau)`` with ``alpha``.
        ``meta=False`` (a learner that does not adapt) or no ``tau``: the members' own parameters."""
        if not meta or tau is None:
            return self.parameters(tau, adapted=False, alpha=self.config.alpha)
        if self.config.personal_updates:
            return self.fine_tuned(list(drives) or [tau], self.config.personal_updates, seed,
                                   replay=self.config.personal_replay)
        return self.parameters(tau, adapted=True, alpha=self.config.alpha)

    def fine_tuned(self, trajectories: list[TensorDictBase], updates: int, seed: int = 0,
                   bootstrap: bool = False, replay: float = 0.0) -> list[TensorDictBase]:
        """Every member's parameters (detached) after ``updates`` plain maximum-likelihood updates on
        ``trajectories`` alone, starting from the current (meta) parameters with a fresh Adam; the ensemble
        itself is unchanged. The many-step, many-trajectory alternative to ``U`` (``personal_updates``).

        ``bootstrap``: each member fits its own bootstrap resample of the trajectories (as weights: how often
        the resample holds each), so the members disagree where a few drives of the driver do not pin the
        model down, and the planner's agreement gate reads that as uncertainty (with every member on the same
        data they agree by construction).

        ``replay``: the share of every update's windows drawn from this trainer's own buffers (the data the
        meta parameters were trained on) instead of ``trajectories``; the buffers' sampling state is restored
        afterwards, so the study's own training draws as it would have without it."""
        if updates < 1 or not trajectories:
            raise ValueError(f"fine-tuning needs updates >= 1 and trajectories; got {updates} and {len(trajectories)}")
        if not 0.0 <= replay < 1.0 or (replay and bootstrap):
            raise ValueError(f"replay must be in [0, 1) and cannot be combined with bootstrap; got {replay}")
        twin = EnsembleTrainer.from_states(self.model.config(), [m.model.state_dict() for m in self.members],
                                           self.config, RoundBuffers.of(trajectories, self.config.L, seed), seed,
                                           self.loss_fn)
        if bootstrap:
            n, generator = len(trajectories), torch.Generator().manual_seed(seed)
            draws = torch.randint(n, (len(self.members), n), generator=generator)
            twin.trajectory_weights = torch.zeros(len(self.members), n).scatter_add_(1, draws, torch.ones(draws.shape))
        n_replay = round(self.config.batch * replay)
        if n_replay and self.buffers.rounds:
            source = self.members[0]
            states = source.generator.get_state(), self.buffers.generator.get_state()
            for _ in range(updates):
                twin.update(twin.members[0].plain_batches(self.config.batch - n_replay)
                            + source.plain_batches(n_replay), meta=False)
            source.generator.set_state(states[0])
            self.buffers.generator.set_state(states[1])
        else:
            twin.train(updates, meta=False)
        return [meta_parameters(m.model).detach().clone() for m in twin.members]

    def round_loss(self, round_: int, adapted: bool, params: list[TensorDictBase] | None = None) -> float:
        """The members' mean held-out L-step loss on a round (:meth:`FTMLTrainer.round_loss`); ``params``:
        every member's adapted parameters (e.g. from :meth:`fine_tuned`) instead of ``U`` on tau."""
        params = params if params is not None else [None] * len(self.members)
        return float(sum(m.round_loss(round_, adapted, p) for m, p in zip(self.members, params, strict=True))
                     / len(self.members))

    def state_dict(self) -> dict[str, Any]:
        return {"members": [m.state_dict() for m in self.members]}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        members = state["members"]
        if len(members) != len(self.members):
            raise ValueError(f"checkpoint has {len(members)} ensemble members, this config {len(self.members)}")
        for m, s in zip(self.members, members, strict=True):
            m.load_state_dict(s)
