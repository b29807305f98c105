"""A study's navigation personalized to a person: Algorithm 1 with a person in the loop.

The study's policies come from :class:`pernav.study.finished.FinishedStudy` (its meta model ensemble for a town,
adapted to a person on their drive tau exactly as the study adapts to a round's user at test time, with the study's
own planner: a :class:`~pernav.study.finished.StudyPolicy`, callable as a :class:`~pernav.play.loop.PlaySession`
policy, that carries the env settings the study planned on, which the session takes); :func:`study_policy` and
:func:`study_history` say the same for a study's folder, in play's words (:class:`~pernav.play.options.PlayError`).

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
    >>> policy, info = study_policy("runs/smoke", "Town1")                                        # doctest: +SKIP
    >>> PlaySession("Town1", 3, policy=policy, options=PlayOptions(n_traffic=2)).run().metrics["policy"]  # doctest: +SKIP
    'study'
    >>> options = SessionOptions(record_dir="me/")                                   # doctest: +SKIP
    >>> result = PersonalSession("runs/smoke", "Town1", [0, 3, 5], options=options).run()  # doctest: +SKIP
    >>> sorted(result.summary["policies"])                                             # doctest: +SKIP
    ['adapted', 'explore']
    >>> study_history("/nonexistent", "Town1")
    Traceback (most recent call last):
    ...
    pernav.play.options.PlayError: no study folder '/nonexistent'
"""

from __future__ import annotations

import json
import logging
import pickle
import random
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import torch
from tensordict import TensorDictBase
from tqdm.auto import tqdm

from pernav.play.framelog import PlayResult
from pernav.play.options import PlayError, PlayOptions
from pernav.play.sessions import PersonalResult, Session, check_session, policy_row, study_errors, summary_markdown
from pernav.study.finished import FinishedStudy, StudyPolicy, adapted_parameters
from pernav.trainer.buffers import RoundBuffers
from pernav.trainer.collect import derive_seed, in_action_space
from pernav.trainer.drives import atomic_write, load_drive, save_drive
from pernav.world.constants import N_INSTRUCTIONS

__all__ = ["PersonalResult", "PersonalSession", "study_history", "study_policy", "summarize_drives",
           "summary_markdown"]

POLICY_NAMES = ("adapted", "explore")  # the two policies a personalization session compares
# the settings a resumed session must share with the interrupted one
RESUME_KEYS = ("study", "town", "routes", "seed", "learner", "user", "context", "n_traffic", "updates")
# meta updates after a round by default (fewer if the study took fewer): a few, as the person waits for the next
# drive; the study's own (50 in the default preset) take minutes on a laptop with second-order updates
UPDATES = 10
# what the window says one meta update takes before a session has measured its own (a lab laptop: ~41 s for 10)
UPDATE_S = 4.0


def study_history(study_dir: str | Path, town: str) -> int:
    """The history window (steps) a finished study's model reads in ``town`` (:meth:`FinishedStudy.history`), its
    refusals as :class:`PlayError`."""
    with study_errors():
        return FinishedStudy.open(study_dir).history(town)


def study_policy(study_dir: str | Path, town: str, tau_trajectories: TensorDictBase | Sequence[TensorDictBase] | None
                 = None, learner: str = "adapt", seed: int = 0) -> tuple[Any, dict[str, Any]]:
    """The policy of ``learner`` in ``town`` adapted to a person on ``tau_trajectories`` and what it is
    (:meth:`FinishedStudy.policy`), its refusals as :class:`PlayError`."""
    with study_errors():
        return FinishedStudy.open(study_dir).policy(learner, town, tau_trajectories, seed=seed)


def summarize_drives(drives: list[dict[str, Any]]) -> dict[str, Any]:
    """Per policy over the paired rounds' whole drives (a quit drive is recorded but not counted): drives, mean
    tracking cost, vehicle collisions, kerb strikes, missed turns, completed; and the mean paired difference
    (adapted - explore) of the tracking cost over the routes driven whole with both.

    >>> print(summary_markdown(summarize_drives([])).splitlines()[2])
    | adapted | 0 | - | 0 | 0 | 0 | 0/0 |
    """
    whole = [d for d in drives if d["round"] > 0 and not d["interrupted"]]
    policies = {name: policy_row([d for d in whole if d["policy"] == name]) for name in POLICY_NAMES}
    by_round: dict[int, dict[str, float]] = {}
    for d in whole:
        by_round.setdefault(d["round"], {})[d["policy"]] = d["tracking_cost"]
    pairs = [r["adapted"] - r["explore"] for r in by_round.values() if len(r) == 2]
    return {"policies": policies, "paired_routes": len(pairs),
            "paired_cost_difference_mean": round(sum(pairs) / len(pairs), 2) if pairs else None}


class PersonalSession(Session):
    """Algorithm 1 with a person: tau on ``routes[0]`` with explore, then every next route driven with the adapted
    MPC policy and with explore in a hidden random order, FTML updates and re-adaptation after every round.

    The arguments are :class:`~pernav.play.sessions.Session`'s. Its options
    (:class:`~pernav.play.sessions.SessionOptions`): ``learner`` the study's model learner (default ``adapt``);
    ``updates`` the meta updates after each round (default: the study's ``train.updates``, at most
    :data:`UPDATES`); ``record_dir`` must not hold another session, unless ``resume`` (then it must hold one, run
    with the same settings).

    >>> session = PersonalSession("runs/smoke", "Town1", [0, 3, 5], options=SessionOptions(seed=1))  # doctest: +SKIP
    >>> session.order                                                                               # doctest: +SKIP
    [('explore', 'adapted'), ('adapted', 'explore')]
    """

    def _open(self, study_dir: str | Path) -> None:
        """Check the options, open the record folder and the study's model, and resume an interrupted session."""
        options, town = self.options, self.town
        updates, seed = options.updates, options.seed
        if updates is not None and updates < 0:
            raise PlayError(f"updates must be >= 0, got {updates}")
        self.record_dir = check_session(town, self.routes, seed, options.record_dir, options.resume)
        with study_errors():
            self.study = FinishedStudy.open(study_dir).model(town, options.learner or "adapt")
        self.updates = min(self.study.train.updates, UPDATES) if updates is None else int(updates)
        # the person's rounds: round 0 holds tau; round t its two drives, the explore one as its tau
        self.buffers = RoundBuffers(L=self.study.train.L, seed=derive_seed(seed, town, "personal", "buffers"))
        self.trainer = self.study.trainer(self.buffers, seed=derive_seed(seed, town, "personal", "trainer"))
        self.policy = StudyPolicy(self.study)
        self.params: list[TensorDictBase] | None = None  # adapted on the latest tau (set after round 0)
        self.adapted_on: int | None = None  # the round whose tau self.params are adapted on
        self.meta_losses: list[float] = []
        self._first_drive = True  # the calibration screen comes before it
        self._trajectories: dict[tuple[int, str], TensorDictBase] = {}  # (round, label) -> whole drive of this run
        self.resumed = options.resume
        if options.resume:
            self._restore()

    @property
    def order(self) -> list[tuple[str, str]]:
        """The hidden order of the two policies on each compared route (``routes[1:]``), drawn from the seed."""
        out = []
        for r in range(1, len(self.routes)):
            first_adapted = random.Random(derive_seed(self.seed, self.town, "order", r)).random() < 0.5
            out.append(POLICY_NAMES if first_adapted else POLICY_NAMES[::-1])
        return out

    def _drive(self, round_: int, route: int, policy_name: str, label: str, number: int, total: int
               ) -> PlayResult:
        """One drive, recorded at once; both drives of a round share the world's seed (same traffic, same luck)."""
        title = f"Drive {number} of {total}: {self.town} route {route}"
        policy = self.policy if policy_name == "adapted" else "explore"
        # adapt_speed's drives choose the playback speed too (each instruction at each speed); explore's do not
        options = PlayOptions(seed=derive_seed(self.seed, self.town, "drive", round_), K=self.study.K,
                              env_config=self.study.env_config(None if policy_name == "adapted" else N_INSTRUCTIONS),
                              calibrate=self.calibrate and self._first_drive, progress=f"Drive {number} of {total}")
        self._first_drive = False
        result = self._play(route, policy, title, options)
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
        self._tell(m, (("vehicle collisions", "vehicle_collisions"), ("kerb strikes", "edge_strikes"),
                       ("missed turns", "missed_turns")))
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
        logging.getLogger("torchrl").setLevel(logging.WARNING)  # no note of every round's new storage
        # a round's data in the learner's action space (explore's instructions re-encoded for adapt_speed's, each
        # instruction at each playback speed)
        self.buffers.add(round_, in_action_space(tau, self.study.n_actions), tau=True)
        if other is not None:
            self.buffers.add(round_, in_action_space(other, self.study.n_actions))
        started, last = time.perf_counter(), round_ == len(self.routes) - 1
        estimate = UPDATE_S * self.updates if self.learn_s is None else self.learn_s
        for _ in tqdm(range(self.updates), desc="learning from your drives", leave=False, disable=not self.progress):
            self.screens.learning("the navigation is learning from your drives", started, estimate, last)
            self.meta_losses.extend(self.trainer.train(1, meta=self.study.meta))  # sysid: plain updates, as in its study
        self.screens.learning("the navigation is learning from your drives", started, estimate, last)
        with study_errors():
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
            with study_errors():
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

    def _drive_all(self) -> bool:
        """Drive the rounds (a resumed session: from its first drive not yet whole), learning after each; True when
        the person stopped a drive (or Ctrl-C)."""
        total = 1 + 2 * (len(self.routes) - 1)
        self._first_drive = True
        for round_ in range(len(self.routes)):
            for r, route, name, label, number in self._slots():
                if r != round_ or self._whole(r, label) is not None:
                    continue
                result = self._drive(r, route, name, label, number, total)
                self.ctrl_c = self.ctrl_c or result.ctrl_c
                if result.metrics["interrupted"] or result.ctrl_c:
                    return True
            if round_ not in self.learned:  # (after the last round too: model.pt keeps what all drives taught)
                self._learn(round_, self._whole_trajectory(round_, "explore"), self._whole_trajectory(round_, "adapted"))
        return False

    def _finish(self, interrupted: bool) -> PersonalResult:
        """The summary of what was driven, written; the end screen (not after Ctrl-C)."""
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
            self._write_summary(summary, "Personalization")
        self._end(sum(not d["interrupted"] for d in self.drives), len(self._slots()), interrupted)
        return PersonalResult(list(self.drives), summary, self.record_dir, interrupted, self.ctrl_c)

