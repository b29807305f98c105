"""Follow-The-Meta-Leader (paper Eq. 3) and the plain maximum-likelihood updates (Eq. 1, SysID).

``meta_update``: sample up to ``rounds_per_update`` rounds that have an adaptation trajectory, adapt the
meta parameters on each round's ``tau_n`` with ``U`` (second order unless ``first_order``), take the L-step
loss of the adapted parameters on windows of that round's data, and step the meta parameters on the mean
(so, over updates, FTML minimizes ``sum_{n <= t} loss(U(P, tau_n), D_n)``). ``plain_update``: the L-step
loss of the parameters themselves on windows from all rounds (the warm start of Eq. 1 and SysID).

A non-finite loss (or gradient) is never applied: the update is skipped, counted in ``skipped`` and the
parameters stay the last good ones. Gradients above ``max_grad_norm`` (the update's and ``U``'s inner step)
are scaled down to it, counted in ``clipped``.

Example:
    >>> import torch
    >>> from tensordict import TensorDict
    >>> from pernav.model import DynamicsModel
    >>> from pernav.trainer.buffers import RoundBuffers
    >>> buffers = RoundBuffers(L=3, seed=0)
    >>> for r in (0, 1):
    ...     T = 20
    ...     buffers.add(r, TensorDict({"observation": torch.randn(T, 14), "action": torch.randint(7, (T,)),
    ...         "history": torch.randn(T, 5, 21), ("next", "observation"): torch.randn(T, 14)}, [T]), tau=True)
    >>> trainer = FTMLTrainer(DynamicsModel(hidden=(16,)), buffers, TrainConfig(batch=8, L=3, hidden=[16]), seed=0)
    >>> trainer.fit_normalization()
    >>> loss = trainer.meta_update()
    >>> bool(torch.isfinite(torch.tensor(loss)))
    True
"""

from __future__ import annotations

import copy
import functools
import logging
import math
from dataclasses import asdict, dataclass, field, fields, replace
from typing import Any

import torch
from tensordict import TensorDictBase

from pernav.model.adapt import MAX_NORM, AdaptInfo, LossFn, adapt, to_model, trajectory_windows
from pernav.model.dynamics import DynamicsModel
from pernav.model.egocentric import ROAD_MAX, road_of
from pernav.model.losses import multistep_loss
from pernav.trainer.buffers import RoundBuffers
from pernav.world.files import key_values

__all__ = ["FTMLTrainer", "TrainConfig", "check_consistent", "keyed_loss"]

log = logging.getLogger("pernav.trainer")


@dataclass
class TrainConfig:
    """Model-learning hyperparameters (docs/study.md defaults)."""

    lr: float = 1e-3
    updates: int = 50  # model updates per round
    batch: int = 128  # L-windows per update
    L: int = 5
    alpha: float = 0.01  # adaptation rate of U
    first_order: bool = False
    rounds_per_update: int = 4  # rounds sampled per meta update (the batch is split among them)
    warm_updates: int = 300  # plain updates of the offline warm start (Eq. 1)
    hidden: list[int] = field(default_factory=lambda: [256, 256, 256])
    K: int = 5  # history window (steps) the model reads
    # route points ahead (6 m apart) the model also reads, at most ROAD_MAX (16); 0: none, the paper's model.
    # The driver's next second depends on where the road turns, which the state alone does not tell
    road: int = 0
    # size of a learned context vector the model reads (DynamicsModel(context=n)); with one, U adapts only it
    # (CAVIA) and alpha is its step. 0: none, U steps every weight (the paper)
    context: int = 0
    ensemble: int = 1  # dynamics models trained side by side (the planner's uncertainty)
    # 0: adapt with U, one gradient step on tau (the paper). n > 0: adapt by n maximum-likelihood updates (fresh
    # Adam, lr) from the meta parameters on the round user's own drives, tau and calibration (EnsembleTrainer.fine_tuned)
    personal_updates: int = 0
    # share of each personal update's windows drawn from the meta-training data (every round so far, the other
    # drivers'), the rest from the user's drives: the fit to one drive stays anchored in the population's
    # dynamics (a fit to one drive alone predicts the user's other drives worse). 0: the user's drives alone
    personal_replay: float = 0.0
    # gradient-norm clip of every update and of U's adaptation step (None: none). Typical norms are 5-20; a
    # model whose rollouts diverge gives thousands, and unclipped one such step left an ensemble member whose
    # every later meta update overflowed (skipped, so frozen bad; docs/reliability.md)
    max_grad_norm: float | None = MAX_NORM  # adapt's own default max_norm: one value for both
    # test-time U (planning, the held-out check; not the meta updates): the Armijo constant of a step-halving
    # line search from alpha on tau (pernav.model.adapt); None: the paper's fixed step alpha. A fixed step
    # overshoots on a driver whose gradient is large (docs/research/findings.md, "One step, how long?")
    backtrack: float | None = 0.5

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    def for_model(self, model_config: dict[str, Any]) -> TrainConfig:
        """A copy with the model fields (``MODEL_FIELDS``) of ``model_config`` (a ``DynamicsModel.config()``, e.g.
        a study's saved model), so a trainer accepts that model."""
        return replace(self, **{k: _plain(model_config[k]) for k in MODEL_FIELDS if k in model_config})

    def with_options(self, pairs: list[str]) -> TrainConfig:
        """A copy with ``KEY=VALUE`` strings applied (JSON values of each field's type: an int, a number, null
        where the default is null or the field is optional, a list of ints for ``hidden``); ``ValueError``
        naming the bad pair and what is allowed.

        >>> TrainConfig().with_options(["updates=150", "backtrack=null"]).updates
        150
        """
        out = copy.deepcopy(self)
        names = [f.name for f in fields(self)]
        for key, value, pair in key_values(pairs, names, "the train options"):
            default = getattr(TrainConfig(), key)
            if key == "hidden":
                ok = isinstance(value, list) and value and all(isinstance(v, int) and v > 0 for v in value)
            elif key == "road":
                ok = isinstance(value, int) and not isinstance(value, bool) and 0 <= value <= ROAD_MAX
            elif isinstance(default, bool):
                ok = isinstance(value, bool)
            elif value is None:
                ok = key in _OPTIONAL
            elif isinstance(default, int):
                ok = isinstance(value, int) and not isinstance(value, bool) and value >= 0
            else:
                ok = isinstance(value, (int, float)) and not isinstance(value, bool)
            if not ok:
                kind = ("a list of positive ints" if key == "hidden" else f"an int from 0 to {ROAD_MAX}" if key == "road"
                        else "true or false" if isinstance(default, bool)
                        else "an int >= 0" if isinstance(default, int) else "a number")
                raise ValueError(f"{pair!r}: {key} must be {kind}{' or null' if key in _OPTIONAL else ''}")
            setattr(out, key, float(value) if isinstance(default, float) and value is not None else value)
        return out


_OPTIONAL = ("max_grad_norm", "backtrack")  # the train options that may be null (off)
_DEFAULT = TrainConfig()

#: The TrainConfig fields that describe the model (``DynamicsModel.config()`` keys of the same names). The trainer
#: reads them from its model; a config that names other values is refused (:func:`check_consistent`).
MODEL_FIELDS = ("K", "hidden", "road", "context")


def check_consistent(model: torch.nn.Module, buffers: RoundBuffers, config: TrainConfig) -> TrainConfig:
    """The config a trainer of ``model`` on ``buffers`` uses: ``config`` with the model's fields (``MODEL_FIELDS``,
    from its ``config()`` where it has one) and the buffers' ``L``, so that each is given once, where it is built.

    A field left at its ``TrainConfig`` default is read from the model or buffers; one set to another value than
    theirs is refused: ``ValueError`` naming every such field and the fix. ``config`` itself is returned when it
    already agrees."""
    built = model.config() if callable(getattr(model, "config", None)) else {}
    wrong, read = [], {}
    for name in MODEL_FIELDS:
        if name not in built or _plain(built[name]) == _plain(getattr(config, name)):
            continue
        if _plain(getattr(config, name)) == _plain(getattr(_DEFAULT, name)):  # not given: the model's
            read[name] = _plain(built[name])
        else:
            wrong.append(f"TrainConfig.{name}={getattr(config, name)!r} but the model's {name}={built[name]!r}")
    if buffers.L != config.L:  # adapt() uses the config's L while the buffers sample windows of theirs
        if config.L == _DEFAULT.L:
            read["L"] = buffers.L
        else:
            wrong.append(f"TrainConfig.L={config.L} but RoundBuffers.L={buffers.L}")
    if wrong:
        raise ValueError("the trainer's TrainConfig disagrees with its model or buffers: " + "; ".join(wrong)
                         + " (give each once: leave these TrainConfig fields at their defaults and the trainer reads "
                         "them from the model and buffers, or build all three from the same config)")
    return replace(config, **read) if read else config


def keyed_loss(loss: LossFn, buffers: RoundBuffers) -> LossFn:
    """``loss`` (a loss taking ``observation_key=``, ``action_key=``, ``history_key=``, as ``multistep_loss``) reading
    the entries ``buffers`` store; ``loss`` itself for the default names."""
    names = {"observation_key": buffers.observation_key, "action_key": buffers.action_key,
             "history_key": buffers.history_key}
    if names == {"observation_key": "observation", "action_key": "action", "history_key": "history"}:
        return loss
    return functools.partial(loss, **names)


def _plain(value: Any) -> Any:
    return [int(v) for v in value] if isinstance(value, (list, tuple)) else value


class FTMLTrainer:
    """Owns one model, its Adam optimizer and its data stream (``RoundBuffers``).

    Any :class:`~pernav.model.dynamics.DynamicsModel` (any state size and ``delta``); ``loss_fn`` is the loss
    of the updates, of ``U`` and of :meth:`round_loss` (the paper's L-step loss by default, reading the buffers'
    entry names: ``RoundBuffers(observation_key=...)`` needs nothing more). The model's ``K``, ``hidden``, ``road``
    and ``context`` and the buffers' ``L`` are read from them (``config`` may leave them at their defaults; a
    different value is refused, :func:`check_consistent`); ``self.config`` is the config in use. Batches and ``tau``
    go to the model's device and floating dtype (a float64 or CUDA model trains on the buffers' data as it is).

    Attributes:
        skipped, clipped: updates skipped (non-finite) and updates whose gradient was clipped.
        fallbacks: test-time ``U`` steps (backtracked) that fell back to the unadapted parameters because no step
            passed the sufficient-decrease test on ``tau``; ``fallback_rounds``: their rounds (tau's ``"round"``)."""

    def __init__(self, model: DynamicsModel, buffers: RoundBuffers, config: TrainConfig, seed: int = 0,
                 loss_fn: LossFn | None = None) -> None:
        config = check_consistent(model, buffers, config)
        self.model, self.buffers, self.config, self._loss_fn = model, buffers, config, loss_fn
        self.optimizer = torch.optim.Adam(model.parameters(), lr=config.lr)
        self.generator = torch.Generator().manual_seed(seed)
        self.skipped = self.clipped = self.fallbacks = 0
        self.fallback_rounds: list[int] = []
        self.losses: list[float] = []

    @property
    def loss_fn(self) -> LossFn:
        """The loss given, or (None) this module's ``multistep_loss`` on the buffers' entry names, looked up at each
        use so that a patched module function (the reliability tests' NaN loss) is the one called."""
        if self._loss_fn is not None:
            return self._loss_fn
        return keyed_loss(multistep_loss, self.buffers)

    def on_model(self, data: TensorDictBase) -> TensorDictBase:
        """``data`` on the model's device and floating dtype (``data`` itself when it already is)."""
        reference = next((t for t in (*self.model.parameters(), *self.model.buffers()) if t.is_floating_point()), None)
        return data if reference is None else to_model(data, reference.device, reference.dtype)

    def adapted(self, tau: TensorDictBase, backtrack: float | None, alpha: float | None = None) -> TensorDictBase:
        """Test-time ``U(P, tau)`` (first order, detached), counting a fallback (:attr:`fallbacks`)."""
        with torch.enable_grad():
            params, info = adapt(self.model, tau, alpha=self.config.alpha if alpha is None else alpha,
                                 L=self.config.L, first_order=True, max_norm=self.config.max_grad_norm,
                                 backtrack=backtrack, loss_fn=self.loss_fn, action_key=self.buffers.action_key,
                                 return_info=True)
        self.note(info, tau)
        return params.detach()

    def note(self, info: AdaptInfo, tau: TensorDictBase) -> None:
        """Count ``U``'s fallbacks (:class:`~pernav.model.adapt.AdaptInfo`) on ``tau`` (its round from ``"round"``)."""
        if info.fallbacks:
            self.fallbacks += info.fallbacks
            self.fallback_rounds.append(int(tau["round"].reshape(-1)[0]) if "round" in tau.keys() else -1)
            log.info("U fell back on tau (round %s): no step passed the sufficient-decrease test; the unadapted "
                     "parameters are used", self.fallback_rounds[-1])

    # ----- data ---------------------------------------------------------------------------------
    def fit_normalization(self) -> None:
        """Set the model's input/output statistics from all data so far (done once, at warm start)."""
        data, buffers = self.on_model(self.buffers.all_data()), self.buffers
        self.model.fit_normalization(data[buffers.history_key], data[buffers.action_key], data[buffers.keys[-1]],
                                     road_of(data))

    def _split(self, rounds: list[int]) -> list[tuple[int, int]]:
        """(round, windows) pairs: up to ``rounds_per_update`` rounds drawn without replacement."""
        pick = torch.randperm(len(rounds), generator=self.generator)[: self.config.rounds_per_update]
        chosen = [rounds[int(i)] for i in pick]
        base, extra = divmod(self.config.batch, len(chosen))
        return [(r, base + (i < extra)) for i, r in enumerate(chosen)]

    # ----- updates --------------------------------------------------------------------------------
    def _apply(self, loss: torch.Tensor) -> float:
        value = float(loss.detach())
        if math.isfinite(value):
            self.optimizer.zero_grad(set_to_none=True)
            loss.backward()
        return self.step(value)

    def step(self, value: float) -> float:
        """Apply the gradients now in the parameters' ``.grad`` for a loss of ``value``; skip the update (and
        count it) when the loss or a gradient is not finite. Returns ``value`` (NaN for a bad gradient)."""
        if not math.isfinite(value):
            self.skipped += 1
            self.optimizer.zero_grad(set_to_none=True)
            log.warning("non-finite model loss (%s): update skipped, parameters kept", value)
            return value
        params = [p for p in self.model.parameters() if p.grad is not None]
        if not all(torch.isfinite(p.grad).all() for p in params):
            self.skipped += 1
            self.optimizer.zero_grad(set_to_none=True)
            log.warning("non-finite gradient: update skipped, parameters kept")
            return float("nan")
        if self.config.max_grad_norm is not None:
            norm = torch.nn.utils.clip_grad_norm_(params, self.config.max_grad_norm)
            self.clipped += int(norm > self.config.max_grad_norm)
        self.optimizer.step()
        self.losses.append(value)
        return value

    def meta_batches(self) -> list[tuple[int, int, Any]]:
        """One meta update's data: (round, windows, ``[n, L]`` batch) for up to ``rounds_per_update`` rounds."""
        rounds = sorted(self.buffers.taus)
        if not rounds:
            raise ValueError("meta_update needs rounds with an adaptation trajectory")
        return [(r, n, self.buffers.sample(r, n)) for r, n in self._split(rounds)]

    def plain_batches(self, windows: int | None = None) -> list[tuple[int, int, Any]]:
        """One plain update's data: ``windows`` (default ``batch``) windows drawn over all rounds in proportion
        to their size."""
        rounds = self.buffers.rounds
        if not rounds:
            raise ValueError("plain_update needs data")
        sizes = torch.tensor([len(self.buffers.buffers[r]) for r in rounds], dtype=torch.float)
        draws = torch.multinomial(sizes, self.config.batch if windows is None else windows, replacement=True,
                                  generator=self.generator)
        counts = [(r, int((draws == i).sum())) for i, r in enumerate(rounds)]
        return [(r, n, self.buffers.sample(r, n)) for r, n in counts if n]

    def meta_update(self, batches: list[tuple[int, int, Any]] | None = None) -> float:
        """One FTML step over sampled rounds (each adapted on its own tau); ``batches`` from
        :meth:`meta_batches` (drawn here by default; an ensemble draws once for all its members)."""
        total = 0.0
        for r, n, batch in self.meta_batches() if batches is None else batches:
            adapted = adapt(self.model, self.buffers.tau(r), alpha=self.config.alpha, L=self.config.L,
                            first_order=self.config.first_order, max_norm=self.config.max_grad_norm,
                            loss_fn=self.loss_fn, action_key=self.buffers.action_key)
            total = total + self.loss_fn(self.model, self.on_model(batch), params=adapted) * (n / self.config.batch)
        return self._apply(total)

    def plain_update(self, batches: list[tuple[int, int, Any]] | None = None) -> float:
        """One maximum-likelihood step on windows from all rounds (no adaptation); ``batches`` as in
        :meth:`meta_update`, from :meth:`plain_batches`."""
        total = 0.0
        for _r, n, batch in self.plain_batches() if batches is None else batches:
            total = total + self.loss_fn(self.model, self.on_model(batch)) * (n / self.config.batch)
        return self._apply(total)

    def train(self, updates: int, meta: bool) -> list[float]:
        """``updates`` meta (FTML) or plain steps; their losses."""
        step = self.meta_update if meta else self.plain_update
        return [step() for _ in range(updates)]

    # ----- evaluation -----------------------------------------------------------------------------
    @torch.no_grad()
    def round_loss(self, round_: int, adapted: bool, params: TensorDictBase | None = None) -> float:
        """Held-out L-step loss on a round (for regret curves and the adaptation check), with or without
        adapting on its ``tau`` first (or with given adapted ``params``): every transition of the round's
        trajectories other than its user's drives (tau, calibration) predicted once (windows tiling each
        trajectory; no sampling, so the figure is exact). A round that holds only its ``tau`` is scored on
        ``tau`` itself (then it is not held out)."""
        tau = self.buffers.tau(round_)
        if adapted and params is None:
            params = self.adapted(tau, self.config.backtrack)
        elif not adapted:
            params = None
        data = self.buffers.data(round_)
        user = torch.tensor([int(t["traj"][0]) for t in self.buffers.user_trajectories(round_)])
        held_out = data[~torch.isin(data["traj"], user)]
        source = held_out if held_out.shape[0] else tau
        windows = [trajectory_windows(source[source["traj"] == t], self.config.L, self.config.L)
                   for t in torch.unique(source["traj"]).tolist()]
        by_length: dict[int, list] = {}  # a trajectory shorter than L gives one shorter window
        for w in windows:
            by_length.setdefault(w.shape[1], []).append(w)
        total, count = 0.0, 0
        for group in by_length.values():
            batch = self.on_model(torch.cat(group))
            total += float(self.loss_fn(self.model, batch, params=params)) * batch.shape[0]
            count += batch.shape[0]
        return total / count

    # ----- checkpoints ----------------------------------------------------------------------------
    def state_dict(self) -> dict[str, Any]:
        return {"model": self.model.state_dict(), "model_config": self.model.config(),
                "optimizer": self.optimizer.state_dict(), "generator": self.generator.get_state(),
                "skipped": self.skipped, "clipped": self.clipped, "fallbacks": self.fallbacks,
                "fallback_rounds": list(self.fallback_rounds)}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.model.load_state_dict(state["model"])
        # Optimizer.load_state_dict keeps the given moment tensors: copy them, or two trainers loaded from one
        # state (sysid and adapt after the shared warm start) would update the same Adam moments.
        self.optimizer.load_state_dict(copy.deepcopy(state["optimizer"]))
        self.generator.set_state(state["generator"])
        self.skipped = int(state["skipped"])
        self.clipped = int(state.get("clipped", 0))  # checkpoints before gradient clipping have none
        self.fallbacks = int(state.get("fallbacks", 0))  # nor before U's fallback
        self.fallback_rounds = list(state.get("fallback_rounds", []))
