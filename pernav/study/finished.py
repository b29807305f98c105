"""A finished study, opened once: its settings, and for any learner it trained the policy that navigates a new
driver of one of its towns.

:meth:`FinishedStudy.open` reads and checks the study's folder (``study.json``, and ``results.json``: the study is
finished); :meth:`FinishedStudy.policy` hands out a learner's policy in a town, adapted to a driver on their drive(s)
tau as the study adapts to a round's user at test time:

- a dynamics model's learner (``adapt``, ``adapt_speed``, ``sysid``): the final meta ensemble
  (:func:`pernav.study.checkpoints.final_models`), every member adapted on tau (``U``: one gradient step of ``alpha``
  on tau's L-step loss, backtracked and clipped as the study's ``TrainConfig`` says; or ``personal_updates``
  maximum-likelihood updates where the study used them; ``sysid`` does not adapt), planning with the study's own
  planner (its ``planner`` options, ``retime`` by default) on
  :class:`~pernav.model.navigation.ImaginedNavigationEnv`: a :class:`StudyPolicy`, which carries the env settings the
  study planned on (history ``K``, planning context lengths);
- ``belief``: explore's rule re-timed for the posterior about the driver (the study's answer detector and population
  prior, :func:`pernav.study.checkpoints.final_belief`, having read tau's answers), updated within each drive from
  the answers to its prompts; ``timing``: explore's rule re-timed for what the study's timing model reads from tau.
  Both a :class:`RetimedPolicy`, whose ``env_config`` is what the env needs to re-time the rule.

Each policy is callable on a step's TensorDict, as :class:`pernav.play.loop.PlaySession` and the study's episodes
call a policy. A folder that holds no finished study, a town it did not run, a learner it did not train or a drive it
cannot read is a :class:`StudyError` (a ValueError, said in one line).

Example (a finished study in ``runs/smoke``):
    >>> study = FinishedStudy.open("runs/smoke")                                          # doctest: +SKIP
    >>> policy, info = study.policy("adapt", "Town1", load_drive("me/tau.pt"))          # doctest: +SKIP
    >>> info["adapted"], info["planner"]["kind"], policy.env_config["future_steps"]     # doctest: +SKIP
    (True, 'retime', 18)
    >>> FinishedStudy.open("/nonexistent")
    Traceback (most recent call last):
    ...
    pernav.study.finished.StudyError: no study folder '/nonexistent'
"""

from __future__ import annotations

import json
import pickle
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

from tensordict import TensorDictBase

from pernav.env.torchrl_env import info_action_module
from pernav.learners.belief import BeliefTracker
from pernav.learners.timing import TimingModel
from pernav.model.dynamics import DynamicsModel
from pernav.model.navigation import ImaginedNavigationEnv, make_world_model
from pernav.planner.factory import build_planner, env_planning_config
from pernav.study.checkpoints import final_belief, final_models, load_checkpoint
from pernav.study.config import BELIEF_DEFAULTS, LEARNERS
from pernav.study.driver_rounds import DriverState
from pernav.study.errors import CheckpointError
from pernav.study.study import ADDED_OPTIONS
from pernav.trainer.buffers import RoundBuffers
from pernav.trainer.collect import in_action_space
from pernav.trainer.ensemble import EnsembleTrainer
from pernav.trainer.ftml import TrainConfig
from pernav.world.constants import N_ADAPTIVE_ACTIONS

__all__ = ["RETIMED", "TRAIN_ADDED", "FinishedStudy", "RetimedPolicy", "StudyError", "StudyModel", "StudyPolicy",
           "adapted_parameters"]

#: the learners that re-time explore's rule for what they believe of the driver (no dynamics model)
RETIMED = ("timing", "belief")
#: train options added after studies had been saved, with the value an older study.json without them ran with
#: (the ``train.`` entries of :data:`pernav.study.study.ADDED_OPTIONS`)
TRAIN_ADDED = {name.removeprefix("train."): value for name, value in ADDED_OPTIONS.items()
               if name.startswith("train.")}
#: what reading a checkpoint may raise besides a checksum's refusal: a file cut short, unpickled wrong, or of
#: another layout
_UNREADABLE = (CheckpointError, OSError, KeyError, RuntimeError, EOFError, pickle.UnpicklingError, json.JSONDecodeError)


class StudyError(ValueError):
    """What a finished study cannot give: a folder that holds none, a town it did not run, a learner it did not
    train, a drive it cannot read (one line)."""


@dataclass
class StudyModel:
    """What a finished study gives for one town and learner: its settings and the final meta ensemble."""

    folder: Path
    town: str
    learner: str
    n_actions: int
    train: TrainConfig
    planner: dict[str, Any]  # the study's planner options (kind retime by default)
    model_config: dict[str, Any]
    members: list[dict[str, Any]]  # every ensemble member's state dict
    config: dict[str, Any] = field(repr=False, default_factory=dict)  # the whole study.json

    @property
    def K(self) -> int:
        """The history window the model reads (the env's ``HistoryWindow`` must match)."""
        return int(self.model_config["K"])

    @property
    def meta(self) -> bool:
        """Whether the learner adapts to a user (``sysid`` does not)."""
        return self.learner != "sysid"

    def env_config(self, n_actions: int | None = None) -> dict[str, Any]:
        """The navigation env's config entries of the study's drives in an ``n_actions`` env (default: the
        learner's): the planning context lengths its planner needs and the playback actions (as ``runner._env``)."""
        n = self.n_actions if n_actions is None else n_actions
        return {"adaptive_speed": n == N_ADAPTIVE_ACTIONS, **env_planning_config(self.planner)}

    def trainer(self, buffers: RoundBuffers | None = None, seed: int = 0) -> EnsembleTrainer:
        """An ensemble trainer starting from the study's final members (fresh Adam with the study's ``lr``: the
        checkpoint's moments belong to the study's stream of drivers, not to this one)."""
        return EnsembleTrainer.from_states(self.model_config, self.members, self.train, buffers, seed)


def adapted_parameters(study: StudyModel, trainer: EnsembleTrainer, drives: Sequence[TensorDictBase],
                       seed: int = 0) -> list[TensorDictBase]:
    """Every member's parameters for planning with a driver whose latest drives are ``drives`` (the last one is
    their tau), by the study's own test-time rule (:meth:`~pernav.trainer.EnsembleTrainer.adapted_parameters`):
    ``U(P, tau)``, or ``personal_updates`` updates on the drives. No drives (or ``sysid``): the meta parameters.

    >>> study = FinishedStudy.open("runs/smoke").model("Town1")                        # doctest: +SKIP
    >>> len(adapted_parameters(study, study.trainer(), [tau])) == study.train.ensemble  # doctest: +SKIP
    True
    """
    if not drives or not study.meta:
        return trainer.adapted_parameters(None, meta=False)
    for d in drives:
        if d["history"].shape[-2] != study.K:
            raise StudyError(f"a drive with a history of {d['history'].shape[-2]} steps: the study's model reads "
                             f"{study.K} (record it with this study's policy or session, or pernav play --history "
                             f"{study.K})")
    drives = [in_action_space(d, study.n_actions) for d in drives]
    return trainer.adapted_parameters(drives[-1], drives, seed=seed)


class StudyPolicy:
    """A study's MPC planner with given (adapted) parameters, callable as a drive's policy.

    ``env_config`` and ``K`` are the env settings the study planned on; a drive with this policy takes them (so the
    history window and the planning context match the planner)."""

    __name__ = "study"

    def __init__(self, study: StudyModel, params: list[TensorDictBase] | None = None) -> None:
        model = DynamicsModel(**study.model_config)
        model.load_state_dict(study.members[0])
        self.study = study
        self.planner = build_planner(ImaginedNavigationEnv(make_world_model(model)), study.planner, study.n_actions)
        self.env_config, self.K, self.n_actions = study.env_config(), study.K, study.n_actions
        self.set_parameters(params)

    def set_parameters(self, params: list[TensorDictBase] | None) -> None:
        """Plan with ``params`` (every member's; ``None``: the first member's own weights)."""
        self.planner.params = params

    def __call__(self, td: TensorDictBase) -> TensorDictBase:
        return self.planner(td)


class RetimedPolicy:
    """Explore's rule re-timed for what ``learner`` believes of the driver, callable as a drive's policy (it plays the
    env's ``belief_action``). ``belief``: driver fields (``timing``'s reading of tau; ``{}``: explore's timing) or a
    :class:`~pernav.learners.belief.BeliefTracker` (``belief``: the env follows a copy of it through each drive,
    reading each prompt's answer); ``env_config`` gives it to the env."""

    def __init__(self, learner: str, belief: Mapping[str, Any] | BeliefTracker) -> None:
        self.__name__, self.belief = learner, belief
        self._module = info_action_module("belief_action")

    @property
    def env_config(self) -> dict[str, Any]:
        """The navigation env's config entries this policy needs: the belief it re-times the rule for."""
        return {"belief": self.belief}

    def __call__(self, td: TensorDictBase) -> TensorDictBase:
        return self._module(td)


def _drives(tau: TensorDictBase | Sequence[TensorDictBase] | None) -> list[TensorDictBase]:
    return [] if tau is None else [tau] if isinstance(tau, TensorDictBase) else list(tau)


class FinishedStudy:
    """A finished study's folder, its settings read once (:meth:`open`); each town's final learners read from its
    checkpoint when asked (:meth:`model`, :meth:`belief_tracker`, :meth:`timing_model`), and any learner's policy
    handed out (:meth:`policy`)."""

    def __init__(self, folder: str | Path, config: Mapping[str, Any]) -> None:
        self.folder, self.config = Path(folder), dict(config)

    @classmethod
    def open(cls, study_dir: str | Path) -> FinishedStudy:
        """The study in ``study_dir``, its ``study.json`` read; a folder holding no finished pernav study is a
        :class:`StudyError`. Reads no checkpoint (fast: the checks before a window opens)."""
        folder = Path(study_dir)
        if not folder.is_dir():
            raise StudyError(f"no study folder {str(folder)!r}")
        marker = folder / "study.json"
        if not marker.is_file():
            raise StudyError(f"{str(folder)!r} holds no pernav study (no study.json)")
        try:
            config = json.loads(marker.read_text())
        except (json.JSONDecodeError, UnicodeDecodeError):
            raise StudyError(f"{str(marker)!r} is corrupted") from None
        if not isinstance(config, dict):
            raise StudyError(f"{str(marker)!r} is not a study configuration")
        if not (folder / "results.json").is_file():
            raise StudyError(f"the study in {str(folder)!r} is not finished (no results.json): finish it with "
                             "pernav study --resume")
        return cls(folder, config)

    # ----- its settings ------------------------------------------------------------------------------------
    @property
    def towns(self) -> list[str]:
        """The towns the study ran."""
        return list(self.config.get("towns") or [])

    @property
    def methods(self) -> list[str]:
        """The methods the study compared."""
        return list(self.config.get("methods") or [])

    @property
    def model_learners(self) -> list[str]:
        """The dynamics models' learners the study trained (``hindsight`` trains ``adapt``'s too)."""
        return [m for m in LEARNERS if m in self.methods or (m == "adapt" and "hindsight" in self.methods)]

    @property
    def train(self) -> TrainConfig:
        """The study's training options (an option added after it was saved: the value it ran with)."""
        known = {f.name for f in fields(TrainConfig)}
        return TrainConfig(**{**TRAIN_ADDED, **{k: v for k, v in (self.config.get("train") or {}).items() if k in known}})

    @property
    def planner(self) -> dict[str, Any]:
        """The study's planner options (``retime`` where it named none)."""
        return dict(self.config.get("planner") or {"kind": "retime"})

    @property
    def belief_options(self) -> dict[str, Any]:
        """The belief learner's options the study ran with."""
        return {**BELIEF_DEFAULTS, **(self.config.get("belief") or {})}

    def check_town(self, town: str) -> None:
        """A :class:`StudyError` unless the study ran ``town``."""
        if town not in self.towns:
            raise StudyError(f"the study in {str(self.folder)!r} did not run {town}; it ran "
                             f"{', '.join(self.towns) or 'no town'}")

    def history(self, town: str) -> int:
        """The history window (steps) the study's models read in ``town``: what a drive recorded for it must have."""
        self.check_town(town)
        return int((self.config.get("train") or {}).get("K", TrainConfig().K))

    # ----- its learners --------------------------------------------------------------------------------------
    def model(self, town: str, learner: str = "adapt") -> StudyModel:
        """The settings and final ensemble of the model ``learner`` in ``town``."""
        self.check_town(town)
        if learner not in LEARNERS or learner not in self.model_learners:
            raise StudyError(f"learner {learner!r} not in the study; it trained "
                             f"{', '.join(self.model_learners) or 'none'}")
        train = self.train
        try:
            model, members = final_models(self.folder, town, learner)
        except _UNREADABLE as exc:
            raise StudyError(f"cannot read the study's {town} checkpoint: {' '.join(str(exc).split())}") from None
        return StudyModel(self.folder, town, learner, LEARNERS[learner], train, self.planner, model.config(), members,
                          self.config)

    def belief_tracker(self, town: str) -> BeliefTracker:
        """The belief learner of ``town``: its answer detector and its population prior, as a tracker that has read
        nothing yet."""
        self.check_town(town)
        try:
            model = final_belief(self.folder, town)
        except CheckpointError as exc:
            raise StudyError(str(exc)) from None
        return BeliefTracker.from_model(model, guard=bool(self.belief_options["guard"]))

    def _run_state(self, town: str, field: str, learner: str) -> Any:
        """The field ``field`` of ``town``'s last checkpoint (a :class:`StudyError` where ``learner`` did not run)."""
        self.check_town(town)
        try:
            state = load_checkpoint(self.folder / "checkpoints" / town, {})
        except _UNREADABLE as exc:
            raise StudyError(f"cannot read the study's {town} checkpoint: {' '.join(str(exc).split())}") from None
        if state is None:
            raise StudyError(f"no {town} checkpoint in {str(self.folder)!r} (run the study first)")
        if getattr(state, field) is None:
            raise StudyError(f"the study in {str(self.folder)!r} did not run {learner} (add it to its methods)")
        return getattr(state, field)

    def timing_model(self, town: str) -> TimingModel:
        """The timing learner of ``town``, as fitted offline."""
        return TimingModel().load_state_dict(self._run_state(town, "timing_model", "the timing learner"))

    def driver_state(self, town: str) -> DriverState:
        """adapt_driver's state in ``town`` at the study's end: its meta model, detectors and estimates."""
        return DriverState(self._run_state(town, "driver", "adapt_driver"))

    def policy(self, learner: str, town: str, tau: TensorDictBase | Sequence[TensorDictBase] | None = None,
               seed: int = 0) -> tuple[StudyPolicy | RetimedPolicy, dict[str, Any]]:
        """``learner``'s policy in ``town`` for a driver whose drive(s) ``tau`` are (e.g.
        :func:`~pernav.trainer.drives.load_drive`; ``None``: the policy for the population, unadapted), and what it
        is: a :class:`StudyPolicy` for a dynamics model's learner (``seed``: its adaptation's), a
        :class:`RetimedPolicy` for ``timing`` (its reading of the last tau) and ``belief`` (having read every tau's
        answers)."""
        drives = _drives(tau)
        if learner in RETIMED:
            return self._retimed(learner, town, drives)
        study = self.model(town, learner)
        trainer = study.trainer(seed=seed)
        params = adapted_parameters(study, trainer, drives, seed)
        policy = StudyPolicy(study, params)
        adapted = bool(drives) and study.meta
        info = {"study": str(study.folder), "town": town, "learner": learner, "members": len(study.members),
                "adapted": adapted,
                "adaptation": ("personal_updates" if study.train.personal_updates else "U") if adapted else None,
                "tau_steps": [int(d.shape[0]) for d in drives], "planner": {"kind": "retime", **study.planner},
                "env_config": dict(policy.env_config), "K": policy.K}
        return policy, info

    def _retimed(self, learner: str, town: str, drives: list[TensorDictBase]) -> tuple[RetimedPolicy, dict[str, Any]]:
        if learner == "belief":
            tracker = self.belief_tracker(town)
            for d in drives:
                tracker.observe_drive(d)
            belief: Any = tracker
            fields_now = tracker.fields()
        else:
            model = self.timing_model(town)  # (refused for a study that did not run it, with or without tau)
            belief = fields_now = model.belief(drives[-1]) if drives else {}
        info = {"study": str(self.folder), "town": town, "learner": learner, "adapted": bool(drives),
                "tau_steps": [int(d.shape[0]) for d in drives], "belief": dict(fields_now)}
        return RetimedPolicy(learner, belief), info
