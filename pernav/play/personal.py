"""A study's navigation personalized to a person: the adapted-model policy and Algorithm 1 with a person in the loop.

:func:`study_policy` loads a finished study's meta model ensemble for a town
(:func:`pernav.study.checkpoints.final_models`), adapts every member to a person on their drive tau exactly as the
study adapts to a round's user at test time (``U``: one gradient step of ``alpha`` on tau's L-step loss, backtracked
and clipped as the study's ``TrainConfig`` says; or ``personal_updates`` maximum-likelihood updates where the study
used them) and returns the study's own planner (its
``planner`` options, ``retime`` by default) on :class:`~pernav.model.navigation.ImaginedNavigationEnv` planning with
those parameters: a :class:`StudyPolicy`, callable as a :class:`~pernav.play.loop.PlaySession` policy, that also
carries the env settings the study planned on (history ``K``, planning context lengths), which the session takes.

:class:`PersonalSession` is the paper's Algorithm 1 with one person as the stream of users: round 0, the person
drives ``routes[0]`` with explore (tau); the meta model takes FTML updates on it and adapts to it. Each next route
is driven twice, once with the adapted MPC policy and once with explore, in an order drawn per route from the
seed and never shown (each drive is announced as "drive n of N: town, route"); the round's explore drive is its tau.
After each round: FTML meta updates (the study's ``TrainConfig``, ``updates`` of them) on all the person's rounds so
far, then re-adaptation on the latest tau. The MPC drive of round ``t`` plans with the parameters adapted on round
``t - 1``'s tau, so both drives of a round face the same policies whatever their order (the paper adapts on the
round's own tau, driven first; here that would tell the person which drive comes next).

Every drive is recorded at once (:func:`~pernav.trainer.drives.save_drive`), with the session's progress
(``session.json``) after each drive and the personalized model (``model.pt``) after each round's learning; quitting
(Esc then Y, or Ctrl+C) ends the session with what was driven (a drive cut short is kept as ``...-stopped``), and
``summary.json``/``summary.md`` compare the two policies on the paired routes. ``resume=True`` continues an
interrupted session in its folder: the drives already whole are kept (tau among them), the model is the one saved
after the last round learned, and the session goes on with the first drive not yet whole.

Example (the scripted bot drives; a finished study in ``runs/smoke``):
    >>> policy, info = study_policy("runs/smoke", "Town1")                             # doctest: +SKIP
    >>> PlaySession("Town1", 3, policy=policy, n_traffic=2).run().metrics["policy"]   # doctest: +SKIP
    'study'
    >>> result = PersonalSession("runs/smoke", "Town1", [0, 3, 5], record_dir="me/").run()  # doctest: +SKIP
    >>> sorted(result.summary["policies"])                                             # doctest: +SKIP
    ['adapted', 'explore']
"""

from __future__ import annotations

import json
import pickle
import random
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

import torch
from tensordict import TensorDictBase

from pernav.model.dynamics import DynamicsModel
from pernav.model.navigation import ImaginedNavigationEnv, make_world_model
from pernav.planner.factory import build_planner, env_planning_config
from pernav.play.controls import ScriptedControls
from pernav.play.loop import PlayError, PlayResult, PlaySession
from pernav.play.screens import SessionWindow
from pernav.play.sessions import check_session
from pernav.study.checkpoints import final_models
from pernav.study.config import LEARNERS
from pernav.study.errors import CheckpointError
from pernav.trainer.buffers import RoundBuffers
from pernav.trainer.collect import derive_seed, in_action_space
from pernav.trainer.drives import atomic_write, load_drive, save_drive
from pernav.trainer.ensemble import EnsembleTrainer
from pernav.trainer.ftml import TrainConfig

__all__ = ["PersonalResult", "PersonalSession", "StudyModel", "StudyPolicy", "adapted_parameters", "load_study",
           "study_policy", "summary_markdown"]

POLICY_NAMES = ("adapted", "explore")  # the two policies a personalization session compares
# the settings a resumed session must share with the interrupted one
RESUME_KEYS = ("study", "town", "routes", "seed", "learner", "user", "context", "n_traffic", "updates")
# meta updates after a round by default (fewer if the study took fewer): a few, as the person waits for the next
# drive; the study's own (50 in the default preset) take minutes on a laptop with second-order updates
UPDATES = 10
# what the window says one meta update takes before a session has measured its own (a lab laptop: ~41 s for 10)
UPDATE_S = 4.0

# train options added after studies had been saved, with the value an older study.json without them ran with
# (pernav.study.study.ADDED_OPTIONS; not imported: it loads the whole study package)
_TRAIN_ADDED = {"ensemble": 1, "personal_updates": 0, "personal_replay": 0.0, "road": 0, "context": 0}


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
        return {"adaptive_speed": n == 21, **env_planning_config(self.planner)}

    def trainer(self, buffers: RoundBuffers | None = None, seed: int = 0) -> EnsembleTrainer:
        """An ensemble trainer starting from the study's final members (fresh Adam with the study's ``lr``: the
        checkpoint's moments belong to the study's stream of drivers, not to this one)."""
        return EnsembleTrainer.from_states(self.model_config, self.members, self.train, buffers, seed)


def study_settings(study_dir: str | Path, town: str) -> dict[str, Any]:
    """A finished study's ``study.json`` (its settings), checked: a folder holding a finished study that ran ``town``;
    :class:`PlayError` (one line) otherwise. Reads no checkpoint (fast: the checks before a window opens)."""
    folder = Path(study_dir)
    if not folder.is_dir():
        raise PlayError(f"no study folder {str(folder)!r}")
    marker = folder / "study.json"
    if not marker.is_file():
        raise PlayError(f"{str(folder)!r} holds no pernav study (no study.json)")
    try:
        config = json.loads(marker.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError):
        raise PlayError(f"{str(marker)!r} is corrupted") from None
    if not isinstance(config, dict):
        raise PlayError(f"{str(marker)!r} is not a study configuration")
    if not (folder / "results.json").is_file():
        raise PlayError(f"the study in {str(folder)!r} is not finished (no results.json): finish it with "
                        "pernav study --resume")
    towns = list(config.get("towns") or [])
    if town not in towns:
        raise PlayError(f"the study in {str(folder)!r} did not run {town}; it ran {', '.join(towns) or 'no town'}")
    return config


def study_history(study_dir: str | Path, town: str) -> int:
    """The history window (steps) a finished study's model reads: what a drive recorded for it must have."""
    train = study_settings(study_dir, town).get("train") or {}
    return int(train.get("K", TrainConfig().K))


def load_study(study_dir: str | Path, town: str, learner: str = "adapt") -> StudyModel:
    """Read a finished study's settings and final ensemble of ``learner`` in ``town``; :class:`PlayError` (one line)
    for a missing or unfinished study folder, a town it did not run, a learner it did not train.

    >>> load_study("/nonexistent", "Town1")
    Traceback (most recent call last):
    ...
    pernav.play.loop.PlayError: no study folder '/nonexistent'
    """
    folder = Path(study_dir)
    config = study_settings(folder, town)
    methods = list(config.get("methods") or [])
    if learner not in LEARNERS or not (learner in methods or (learner == "adapt" and "hindsight" in methods)):
        trained = [m for m in LEARNERS if m in methods or (m == "adapt" and "hindsight" in methods)]
        raise PlayError(f"learner {learner!r} not in the study; it trained {', '.join(trained) or 'none'}")
    known = {f.name for f in fields(TrainConfig)}
    train = TrainConfig(**{**_TRAIN_ADDED, **{k: v for k, v in (config.get("train") or {}).items() if k in known}})
    try:
        model, members = final_models(folder, town, learner)
    except (CheckpointError, OSError, KeyError, RuntimeError, EOFError, pickle.UnpicklingError, json.JSONDecodeError) as exc:
        raise PlayError(f"cannot read the study's {town} checkpoint: {' '.join(str(exc).split())}") from None
    return StudyModel(folder, town, learner, LEARNERS[learner], train, dict(config.get("planner") or {"kind": "retime"}),
                      model.config(), members, config)


def adapted_parameters(study: StudyModel, trainer: EnsembleTrainer, drives: Sequence[TensorDictBase],
                       seed: int = 0) -> list[TensorDictBase]:
    """Every member's parameters for planning with a person whose latest drives are ``drives`` (the last one is
    their tau), by the study's own test-time rule (:meth:`~pernav.trainer.EnsembleTrainer.adapted_parameters`):
    ``U(P, tau)``, or ``personal_updates`` updates on the drives. No drives (or ``sysid``): the meta parameters.

    >>> study = load_study("runs/smoke", "Town1")                                      # doctest: +SKIP
    >>> len(adapted_parameters(study, study.trainer(), [tau])) == study.train.ensemble  # doctest: +SKIP
    True
    """
    if not drives or not study.meta:
        return trainer.adapted_parameters(None, meta=False)
    for d in drives:
        if d["history"].shape[-2] != study.K:
            raise PlayError(f"a drive with a history of {d['history'].shape[-2]} steps: the study's model reads "
                            f"{study.K} (record it with this study's policy or session, or pernav play --history "
                            f"{study.K})")
    drives = [in_action_space(d, study.n_actions) for d in drives]
    return trainer.adapted_parameters(drives[-1], drives, seed=seed)


class StudyPolicy:
    """A study's MPC planner with given (adapted) parameters, callable as a :class:`PlaySession` policy.

    ``env_config`` and ``K`` are the env settings the study planned on; a :class:`PlaySession` with this policy
    takes them (so the history window and the planning context match the planner)."""

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


def study_policy(study_dir: str | Path, town: str, tau_trajectories: TensorDictBase | Sequence[TensorDictBase] | None
                 = None, learner: str = "adapt", seed: int = 0) -> tuple[StudyPolicy, dict[str, Any]]:
    """The study's MPC policy for ``town`` adapted to a person on ``tau_trajectories`` (their explore drive(s),
    e.g. :func:`~pernav.trainer.drives.load_drive`; ``None``: the meta model unadapted), and what it is.

    >>> policy, info = study_policy("runs/smoke", "Town1", load_drive("me/tau.pt"))      # doctest: +SKIP
    >>> info["adapted"], info["planner"]["kind"], policy.env_config["future_steps"]     # doctest: +SKIP
    (True, 'retime', 18)
    """
    study = load_study(study_dir, town, learner)
    drives = [] if tau_trajectories is None else (
        [tau_trajectories] if isinstance(tau_trajectories, TensorDictBase) else list(tau_trajectories))
    trainer = study.trainer(seed=seed)
    params = adapted_parameters(study, trainer, drives, seed)
    policy = StudyPolicy(study, params)
    info = {"study": str(study.folder), "town": town, "learner": learner, "members": len(study.members),
            "adapted": bool(drives) and study.meta,
            "adaptation": ("personal_updates" if study.train.personal_updates else "U") if drives and study.meta else None,
            "tau_steps": [int(d.shape[0]) for d in drives], "planner": {"kind": "retime", **study.planner},
            "env_config": dict(policy.env_config), "K": policy.K}
    return policy, info


# ----- Algorithm 1 with a person -------------------------------------------------------------------------------
@dataclass
class PersonalResult:
    """A session's drives (one record per drive: its metrics, round, policy, file) and the summary table."""

    drives: list[dict[str, Any]]
    summary: dict[str, Any]
    folder: Path | None
    interrupted: bool
    ctrl_c: bool = False  # the session was stopped by Ctrl-C (the command line exits 130)


def _policy_row(drives: list[dict[str, Any]]) -> dict[str, Any]:
    n = len(drives)
    return {"drives": n,
            "tracking_cost_mean": round(sum(d["tracking_cost"] for d in drives) / n, 2) if n else None,
            "vehicle_collisions": sum(d["vehicle_collisions"] for d in drives),
            "kerb_strikes": sum(d["edge_strikes"] for d in drives),
            "missed_turns": sum(d["missed_turns"] for d in drives),
            "completed": sum(bool(d["completed"]) for d in drives),
            "completion": round(sum(bool(d["completed"]) for d in drives) / n, 4) if n else None}


def summarize_drives(drives: list[dict[str, Any]]) -> dict[str, Any]:
    """Per policy over the paired rounds' whole drives (a quit drive is recorded but not counted): drives, mean
    tracking cost, vehicle collisions, kerb strikes, missed turns, completed; and the mean paired difference
    (adapted - explore) of the tracking cost over the routes driven whole with both."""
    whole = [d for d in drives if d["round"] > 0 and not d["interrupted"]]
    policies = {name: _policy_row([d for d in whole if d["policy"] == name]) for name in POLICY_NAMES}
    by_round: dict[int, dict[str, float]] = {}
    for d in whole:
        by_round.setdefault(d["round"], {})[d["policy"]] = d["tracking_cost"]
    pairs = [r["adapted"] - r["explore"] for r in by_round.values() if len(r) == 2]
    return {"policies": policies, "paired_routes": len(pairs),
            "paired_cost_difference_mean": round(sum(pairs) / len(pairs), 2) if pairs else None}


def summary_markdown(summary: dict[str, Any]) -> str:
    """The summary's table in Markdown.

    >>> print(summary_markdown(summarize_drives([])).splitlines()[2])
    | adapted | 0 | - | 0 | 0 | 0 | 0/0 |
    """
    lines = ["| policy | drives | mean tracking cost | vehicle collisions | kerb strikes | missed turns | completed |",
             "|---|---|---|---|---|---|---|"]
    for name, row in summary["policies"].items():
        cost = "-" if row["tracking_cost_mean"] is None else f"{row['tracking_cost_mean']:.0f}"
        lines.append(f"| {name} | {row['drives']} | {cost} | {row['vehicle_collisions']} | {row['kerb_strikes']} | "
                     f"{row['missed_turns']} | {row['completed']}/{row['drives']} |")
    if summary.get("beliefs"):  # a belief session: where the belief stood after each drive
        from pernav.play.believe import belief_markdown

        lines += ["", belief_markdown(summary)]
    if summary.get("paired_routes"):
        lines.append("")
        lines.append(f"Paired routes: {summary['paired_routes']}; mean tracking cost difference (adapted - explore): "
                     f"{summary['paired_cost_difference_mean']:+.0f} (negative: the adapted policy did better).")
    return "\n".join(lines)


class PersonalSession:
    """Algorithm 1 with a person: tau on ``routes[0]`` with explore, then every next route driven with the adapted
    MPC policy and with explore in a hidden random order, FTML updates and re-adaptation after every round.

    ``controls``: ``None`` (the scripted bot, a fresh one per drive), controls to reuse for every drive (a
    joystick), or a zero-argument factory called once per drive after its window is open (``KeyboardControls``).
    ``updates``: meta updates after each round (default: the study's ``train.updates``, at most :data:`UPDATES`).
    ``announce`` is called with a neutral line before each drive ("Drive 2 of 5: Town1 route 3") and after it (how
    it went, not with which policy), ``ready`` after the announcement (e.g. waits for the person to press Enter);
    ``window``, ``speaker``, ``countdown``, ``hide_cost`` and ``notice`` as :class:`PlaySession` (one window for
    the session: "Drive n of N" on each drive, the learning's wait between drives, the end until Enter;
    ``calibrate``: a wheel's calibration screen before the first drive). ``record_dir``
    must not hold another session, unless ``resume`` (then it must hold one, run with the same settings).

    >>> session = PersonalSession("runs/smoke", "Town1", [0, 3, 5], seed=1)   # doctest: +SKIP
    >>> session.order                                                          # doctest: +SKIP
    [('explore', 'adapted'), ('adapted', 'explore')]
    """

    def __init__(self, study_dir: str | Path, town: str, routes: Sequence[int], user: Any = "user1",
                 context: dict | None = None, controls: Any = None, seed: int = 0, record_dir: str | Path | None = None,
                 n_traffic: int = 8, updates: int | None = None, learner: str = "adapt", window: bool = False,
                 speaker: Any = None, announce: Callable[[str], None] | None = None,
                 ready: Callable[[], None] | None = None, progress: bool = True, resume: bool = False,
                 countdown: float = 3.0, hide_cost: bool = False, notice: str | None = None,
                 calibrate: bool = False) -> None:
        routes = list(routes)
        if updates is not None and updates < 0:
            raise PlayError(f"updates must be >= 0, got {updates}")
        self.record_dir = check_session(town, routes, seed, record_dir, resume)
        self.study = load_study(study_dir, town, learner)
        self.town, self.routes, self.seed = town, routes, int(seed)
        self.user, self.context, self.n_traffic = user, context, int(n_traffic)
        self.controls, self.window, self.speaker = controls, window, speaker
        self.announce = announce or (lambda line: None)
        self.ready = ready or (lambda: None)
        self.progress = progress
        self.updates = min(self.study.train.updates, UPDATES) if updates is None else int(updates)
        # the person's rounds: round 0 holds tau; round t its two drives, the explore one as its tau
        self.buffers = RoundBuffers(L=self.study.train.L, seed=derive_seed(seed, town, "personal", "buffers"))
        self.trainer = self.study.trainer(self.buffers, seed=derive_seed(seed, town, "personal", "trainer"))
        self.policy = StudyPolicy(self.study)
        self.params: list[TensorDictBase] | None = None  # adapted on the latest tau (set after round 0)
        self.adapted_on: int | None = None  # the round whose tau self.params are adapted on
        self.drives: list[dict[str, Any]] = []
        self.meta_losses: list[float] = []
        self.countdown, self.hide_cost, self.notice, self.calibrate = countdown, hide_cost, notice, calibrate
        self.learned: list[int] = []  # rounds whose drives the model has learned from
        self.learn_s: float | None = None  # how long the last round's learning took (the next wait's estimate)
        self.screens = SessionWindow(town, False)  # the session's window, opened by run()
        self.ctrl_c = False
        self._first_drive = True  # the calibration screen comes before it
        self._trajectories: dict[tuple[int, str], TensorDictBase] = {}  # (round, label) -> whole drive of this run
        self.resumed = resume
        if resume:
            self._restore()

    @property
    def order(self) -> list[tuple[str, str]]:
        """The hidden order of the two policies on each compared route (``routes[1:]``), drawn from the seed."""
        out = []
        for r in range(1, len(self.routes)):
            first_adapted = random.Random(derive_seed(self.seed, self.town, "order", r)).random() < 0.5
            out.append(POLICY_NAMES if first_adapted else POLICY_NAMES[::-1])
        return out

    def _controls(self) -> Any:
        """This drive's controls: a fresh bot, the controls given, or a new one from the factory given."""
        if self.controls is None:
            return ScriptedControls()
        if hasattr(self.controls, "read") and not isinstance(self.controls, type):
            return self.controls
        return self.controls()  # a factory: keyboard controls need the drive's window open

    def _drive(self, round_: int, route: int, policy_name: str, label: str, number: int, total: int
               ) -> PlayResult:
        """One drive, recorded at once; both drives of a round share the world's seed (same traffic, same luck)."""
        title = f"Drive {number} of {total}: {self.town} route {route}"
        self.announce(title)
        self.ready()
        policy = self.policy if policy_name == "adapted" else "explore"
        self.screens.waiting(title, None)
        session = PlaySession(self.town, route, self.user, context=self.context, policy=policy,
                              seed=derive_seed(self.seed, self.town, "drive", round_), n_traffic=self.n_traffic,
                              window=self.window, speaker=self.speaker, K=self.study.K,
                              # adapt_speed's drives choose the playback speed too (21 actions); explore's do not
                              env_config=self.study.env_config(None if policy_name == "adapted" else 7),
                              title=title, countdown=self.countdown, hide_cost=self.hide_cost, notice=self.notice,
                              calibrate=self.calibrate and self._first_drive, progress=f"Drive {number} of {total}",
                              view=self.screens.view)
        self._first_drive = False
        session.controls = self._controls()
        result = session.run()
        m = result.metrics
        record = {**m, "policy": policy_name, "round": round_, "label": label, "tau": round_ == 0 or policy_name
                  == "explore", "adapted_on_round": self.adapted_on if policy_name == "adapted" else None,
                  "frames": result.frame_stats(), "file": None}
        if result.trajectory is not None and self.record_dir is not None:
            record["file"] = str(save_drive(result.trajectory, record, self.record_dir, self._file_name(
                round_, route, label, m["interrupted"])))
        if result.trajectory is not None and not m["interrupted"]:
            self._trajectories[round_, label] = result.trajectory
        self.drives.append(record)
        self._save_progress()
        state = "stopped" if m["interrupted"] else ("arrived" if m.get("completed") else "did not arrive")
        cost = "" if self.hide_cost else f"tracking cost {m.get('tracking_cost', 0):.0f}, "  # not with --hide-cost
        self.announce(f"  {state} after {m.get('time', 0):.0f} s: {cost}"
                      f"vehicle collisions {m.get('vehicle_collisions', 0)}, kerb strikes {m.get('edge_strikes', 0)}, "
                      f"missed turns {m.get('missed_turns', 0)}")
        return result

    def _file_name(self, round_: int, route: int, label: str, stopped: bool) -> str:
        """A whole drive's name, or for one cut short a ``-stopped`` name not yet taken (a resumed session drives
        that slot again under the whole name)."""
        name = f"round{round_:02d}-route{route}-{label}"
        if not stopped:
            return name
        k = 1
        while (self.record_dir / f"{name}-stopped{'' if k == 1 else k}.pt").exists():
            k += 1
        return f"{name}-stopped{'' if k == 1 else k}"

    def _learn(self, round_: int, tau: TensorDictBase, other: TensorDictBase | None = None) -> None:
        """Add the round's drives (``tau`` as its adaptation trajectory), take the meta updates on all rounds so
        far, and adapt the planner's parameters on this tau."""
        import logging

        from tqdm.auto import tqdm

        logging.getLogger("torchrl").setLevel(logging.WARNING)  # no note of every round's new storage
        # a round's data in the learner's action space (explore's 7 actions re-encoded for adapt_speed's 21)
        self.buffers.add(round_, in_action_space(tau, self.study.n_actions), tau=True)
        if other is not None:
            self.buffers.add(round_, in_action_space(other, self.study.n_actions))
        started, last = time.perf_counter(), round_ == len(self.routes) - 1
        estimate = UPDATE_S * self.updates if self.learn_s is None else self.learn_s
        for _ in tqdm(range(self.updates), desc="learning from your drives", leave=False, disable=not self.progress):
            self.screens.learning("the navigation is learning from your drives", started, estimate, last)
            self.meta_losses.extend(self.trainer.train(1, meta=self.study.meta))  # sysid: plain updates, as in its study
        self.screens.learning("the navigation is learning from your drives", started, estimate, last)
        self.params = adapted_parameters(self.study, self.trainer, [tau],
                                         derive_seed(self.seed, self.town, "personal", round_))
        self.policy.set_parameters(self.params)
        self.adapted_on = round_
        self.learned.append(round_)
        self._save_model()
        self.learn_s = time.perf_counter() - started

    # ----- progress on disk, and resuming ------------------------------------------------------------
    def settings(self) -> dict[str, Any]:
        """What a resumed session must share with the interrupted one (:data:`RESUME_KEYS`)."""
        return {"study": str(self.study.folder.resolve()), "town": self.town, "routes": self.routes, "seed": self.seed,
                "learner": self.study.learner, "user": self.user if isinstance(self.user, str) else "custom",
                "context": dict(self.context or {}), "n_traffic": self.n_traffic, "updates": self.updates}

    def _save_progress(self) -> None:
        """``session.json``: the settings and every drive so far (written after each drive)."""
        if self.record_dir is None:
            return
        self.record_dir.mkdir(parents=True, exist_ok=True)
        data = {**self.settings(), "K": self.study.K, "drives": self.drives, "learned": self.learned}
        atomic_write(self.record_dir / "session.json", lambda p: p.write_text(json.dumps(data, indent=1)))

    def _save_model(self) -> None:
        """``model.pt``: the personalized ensemble after the rounds learned so far (what a resumed session starts
        from), with the replay's sampling state."""
        if self.record_dir is None:
            return
        self.record_dir.mkdir(parents=True, exist_ok=True)
        atomic_write(self.record_dir / "model.pt", lambda p: torch.save(
            {"study": str(self.study.folder), "town": self.town, "learner": self.study.learner,
             "saved": time.strftime("%Y-%m-%d %H:%M:%S"), "trainer": self.trainer.state_dict(),
             "learned": list(self.learned), "meta_losses": list(self.meta_losses),
             "buffers_generator": self.buffers.generator.get_state()}, p))
        self._save_progress()

    def _restore(self) -> None:
        """Take up an interrupted session from its folder: its drives, and the model after its last learned round
        (its buffers rebuilt from the recorded drives of those rounds, as they were added)."""
        folder = self.record_dir
        try:
            saved = json.loads((folder / "session.json").read_text())
        except (OSError, json.JSONDecodeError, UnicodeDecodeError) as exc:
            raise PlayError(f"--resume: {str(folder / 'session.json')!r} cannot be read ({exc})") from None
        mine = self.settings()
        for key in RESUME_KEYS:
            if saved.get(key) != mine[key]:
                raise PlayError(f"--resume: the session in {str(folder)!r} was run with {key} {saved.get(key)!r}, "
                                f"not {mine[key]!r}")
        self.drives = list(saved.get("drives") or [])
        learned = list(saved.get("learned") or [])
        if learned:
            try:
                state = torch.load(folder / "model.pt", weights_only=False)
                self.trainer.load_state_dict(state["trainer"])
            except (OSError, KeyError, RuntimeError, EOFError, pickle.UnpicklingError, ValueError) as exc:
                raise PlayError(f"--resume: the session's model {str(folder / 'model.pt')!r} cannot be read "
                                f"({' '.join(str(exc).split())})") from None
            learned = list(state["learned"])
            self.meta_losses = list(state["meta_losses"])
            for r in learned:
                tau, other = self._whole_trajectory(r, "explore"), self._whole_trajectory(r, "adapted")
                self.buffers.add(r, in_action_space(tau, self.study.n_actions), tau=True)
                if other is not None:
                    self.buffers.add(r, in_action_space(other, self.study.n_actions))
            self.buffers.generator.set_state(state["buffers_generator"])
            last = learned[-1]
            self.params = adapted_parameters(self.study, self.trainer, [self._whole_trajectory(last, "explore")],
                                             derive_seed(self.seed, self.town, "personal", last))
            self.policy.set_parameters(self.params)
            self.adapted_on = last
        self.learned = learned
        if len(self.learned) == len(self.routes) and all(self._whole(r, label) for r, _, _, label, _ in self._slots()):
            raise PlayError(f"--resume: the session in {str(folder)!r} is complete; nothing to resume")

    def _slots(self) -> list[tuple[int, int, str, str, int]]:
        """Every drive of the session: (round, route, policy, label, number)."""
        slots = [(0, self.routes[0], "explore", "tau", 1)]
        for r, route in enumerate(self.routes[1:], start=1):
            slots += [(r, route, name, f"drive{j + 1}", 2 * r + j) for j, name in enumerate(self.order[r - 1])]
        return slots

    def _whole(self, round_: int, label: str) -> dict[str, Any] | None:
        """The record of the whole (not stopped) drive of a round's slot, if there is one."""
        return next((d for d in self.drives if d["round"] == round_ and d["label"] == label
                     and not d["interrupted"]), None)

    def _whole_trajectory(self, round_: int, policy_name: str) -> TensorDictBase | None:
        """The trajectory of a round's whole drive with a policy (``explore``: tau in round 0), from this run or its
        file."""
        record = next((d for d in self.drives if d["round"] == round_ and d["policy"] == policy_name
                       and not d["interrupted"]), None)
        if record is None:
            return None
        if (round_, record["label"]) in self._trajectories:
            return self._trajectories[round_, record["label"]]
        if not record.get("file"):
            raise PlayError(f"--resume: the drive {record['label']} of round {round_} has no file")
        try:
            return load_drive(record["file"])
        except (OSError, ValueError) as exc:
            raise PlayError(f"--resume: {' '.join(str(exc).split())}") from None

    def run(self) -> PersonalResult:
        """Drive the rounds (a resumed session: from its first drive not yet whole); stops early when the person
        quits or on Ctrl-C. Writes the summary with what was driven."""
        total = 1 + 2 * (len(self.routes) - 1)
        interrupted = False
        self._first_drive = True
        with SessionWindow(self.town, self.window) as self.screens:  # closed at the end, whatever happens
            try:
                for round_ in range(len(self.routes)):
                    for r, route, name, label, number in self._slots():
                        if r != round_ or self._whole(r, label) is not None:
                            continue
                        result = self._drive(r, route, name, label, number, total)
                        self.ctrl_c = self.ctrl_c or result.ctrl_c
                        if result.metrics["interrupted"] or result.ctrl_c:
                            interrupted = True
                            break
                    if interrupted:
                        break
                    if round_ not in self.learned:  # (after the last round too: model.pt keeps what all drives taught)
                        self._learn(round_, self._whole_trajectory(round_, "explore"),
                                    self._whole_trajectory(round_, "adapted"))
            except KeyboardInterrupt:
                interrupted = self.ctrl_c = True
            return self._finish(interrupted)

    def _finish(self, interrupted: bool) -> PersonalResult:
        summary = {"study": str(self.study.folder), "town": self.town, "routes": self.routes, "seed": self.seed,
                   "user": self.user if isinstance(self.user, str) else "custom", "learner": self.study.learner,
                   "updates_per_round": self.updates, "interrupted": interrupted,
                   "order": [list(o) for o in self.order[: max((d["round"] for d in self.drives), default=0)]],
                   **summarize_drives(self.drives),
                   "resumed": self.resumed,
                   "drives": [{k: d[k] for k in ("round", "route", "label", "policy", "tracking_cost",
                                                 "vehicle_collisions", "edge_strikes", "missed_turns", "completed",
                                                 "interrupted", "file") if k in d}
                              for d in self.drives]}
        if self.record_dir is not None and any(d["file"] for d in self.drives):
            atomic_write(self.record_dir / "summary.json", lambda p: p.write_text(json.dumps(summary, indent=2)))
            atomic_write(self.record_dir / "summary.md", lambda p: p.write_text(
                f"# Personalization: {self.town}, routes {self.routes}, seed {self.seed}\n\n"
                f"{summary_markdown(summary)}\n"))
        if not self.ctrl_c:  # stopped at the terminal (Ctrl-C): no screen waits for the person
            whole = sum(not d["interrupted"] for d in self.drives)
            self.ctrl_c = self.screens.finish(self._controls, whole, len(self._slots()), interrupted)
        if self.speaker is not None and hasattr(self.speaker, "close"):
            self.speaker.close()
        return PersonalResult(list(self.drives), summary, self.record_dir, interrupted, self.ctrl_c)

