"""The learners of a finished study as a lab session's conditions (:mod:`pernav.play.lab`): a block's ``policy``
may be any learner the study ran (``belief``, ``timing``, ``adapt``, ...; :meth:`~pernav.study.finished.
FinishedStudy.policy` hands out each), personalized to the participant by every whole drive they drove before, in the
session, in the drive's town.

- ``belief`` carries its posterior across the participant's drives, as ``pernav personalize --learner belief``
  does (:class:`pernav.play.believe.BeliefSession`): it reads each whole drive's answers once, and the posterior is
  kept in the participant's folder (``belief.pt``, with the drives it has read) after each; a resumed session takes
  it up from there (and reads any committed drive it had not read yet).
- ``timing`` re-times the prompts for its reading of the participant's last whole drive; a dynamics model's learner
  (``adapt``, ``adapt_speed``, ``sysid``, ...) adapts to the drives as the study does at test time, the last one as
  its tau. Their estimate is a function of the drives, read again from ``drives/`` on resume.

What the navigation learned is told in plain words (:meth:`LearnedPolicies.learned_words`), naming neither the block
nor the learner.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import torch

from pernav.learners.belief import AnswerDetector, BeliefTracker, ReactionBelief, answers_of, frame_series
from pernav.play.believe import prompt_lead
from pernav.study.finished import RETIMED, FinishedStudy, StudyError
from pernav.trainer.drives import atomic_write, load_drive

__all__ = ["LearnedPolicies", "prompt_reactions", "study_learners", "whole_files"]


def study_learners(study: FinishedStudy) -> list[str]:
    """The learners of ``study`` a session's block may name as its policy."""
    return [m for m in study.methods if m in RETIMED or m in study.model_learners]


class LearnedPolicies:
    """A participant's personalized policies in their session folder ``folder``, from the study in ``study_dir``.

    ``drives`` (:meth:`add`) are the participant's whole drives so far: ``(town, file)``, in order."""

    def __init__(self, study_dir: str | Path, folder: Path) -> None:
        self.study = FinishedStudy.open(study_dir)
        self.folder = folder
        self.drives: list[tuple[str, str]] = []
        self.trackers: dict[str, BeliefTracker] = {}  # per town: the belief having read ``read[town]``
        self.read: dict[str, list[str]] = {}
        self.history: list[dict[str, Any]] = []  # the belief after each drive read (what belief.pt keeps)
        self._trajectories: dict[str, Any] = {}
        self._detectors: dict[str, Any] = {}

    # ----- the drives ------------------------------------------------------------------------------------------
    def add(self, town: str, file: str, trajectory: Any = None) -> None:
        """A whole drive of the participant (``file``: in the folder's ``drives/``)."""
        self.drives.append((town, file))
        if trajectory is not None:
            self._trajectories[file] = trajectory

    def _trajectory(self, file: str) -> Any:
        if file not in self._trajectories:
            self._trajectories[file] = load_drive(self.folder / "drives" / file)
        return self._trajectories[file]

    def _town_drives(self, town: str) -> list[Any]:
        return [self._trajectory(f) for t, f in self.drives if t == town]

    def history_window(self, town: str) -> int | None:
        """The history window (steps) every drive in ``town`` is recorded with (what the study's models read)."""
        return self.study.history(town) if town in self.study.towns else None

    def detector(self, town: str) -> Any:
        """The study's answer detector for ``town`` (None: the study did not fit the belief learner there)."""
        if town not in self._detectors:
            try:
                self._detectors[town] = self.study.belief_tracker(town).detector
            except StudyError:
                self._detectors[town] = None
        return self._detectors[town]

    # ----- the belief, kept ------------------------------------------------------------------------------------
    def _tracker(self, town: str) -> BeliefTracker:
        """The belief in ``town`` having read every whole drive there."""
        if town not in self.trackers:
            self.trackers[town] = self.study.belief_tracker(town)
            self.read[town] = []
        tracker = self.trackers[town]
        for t, file in self.drives:
            if t == town and file not in self.read[town]:
                tracker.observe_drive(self._trajectory(file))
                self.read[town].append(file)
                b = tracker.belief
                low, high = b.interval(0.9)
                self.history.append({"town": town, "after": file, "reaction_time": round(b.mean_reaction(), 3),
                                     "interval": [round(low, 3), round(high, 3)], "answers": int(b.answers)})
                self.save()
        return tracker

    def save(self) -> None:
        """``belief.pt``: each town's posterior and the drives it has read."""
        atomic_write(self.folder / "belief.pt", lambda p: torch.save(
            {"study": str(self.study.folder), "beliefs": {t: k.belief.state_dict() for t, k in self.trackers.items()},
             "read": self.read, "history": self.history}, p))

    def restore(self) -> None:
        """Take up the posteriors kept in ``belief.pt`` (a resumed session)."""
        path = self.folder / "belief.pt"
        if not path.exists():
            return
        saved = torch.load(path, weights_only=False)
        for town, state in saved["beliefs"].items():
            tracker = self.study.belief_tracker(town)
            tracker.belief = ReactionBelief.from_state_dict(state)
            self.trackers[town], self.read[town] = tracker, list(saved["read"][town])
        self.history = list(saved["history"])

    # ----- the policies ----------------------------------------------------------------------------------------
    def policy(self, learner: str, town: str, seed: int = 0) -> Any:
        """``learner``'s policy in ``town`` for the participant's next drive."""
        if learner == "belief":
            policy, _ = self.study.policy("belief", town)
            policy.belief = self._tracker(town)
            return policy
        drives = self._town_drives(town)
        if learner == "timing":
            return self.study.policy("timing", town, drives[-1:] or None)[0]
        return self.study.policy(learner, town, drives or None, seed=seed)[0]

    def learned_words(self, learner: str, town: str) -> list[str]:
        """What the navigation learned of the participant, in plain words (neither the block nor the learner is
        named)."""
        n = sum(t == town for t, _ in self.drives)
        if n == 0:
            return ["The navigation has not yet seen you drive here: it spoke as it would for anyone."]
        if learner == "belief":
            b = self._tracker(town).belief
            low, high = b.interval(0.9)
            lead = prompt_lead(self._tracker(town).fields())
            return [f"From your answers to {int(b.answers)} prompts, the navigation reads that you react about "
                    f"{b.mean_reaction():.1f} s after a prompt",
                    f"(most likely between {low:.1f} and {high:.1f} s).",
                    f"At 50 km/h it now says \"turn\" {lead:.1f} s before a junction (for anyone: "
                    f"{prompt_lead({}):.1f} s)."]
        if learner == "timing":
            fields = self.study.policy("timing", town, self._town_drives(town)[-1:])[1]["belief"]
            reaction = fields.get("reaction_time")
            lead = prompt_lead(fields)
            said = f"you react about {reaction:.1f} s after a prompt" if reaction else "how you answer its prompts"
            return [f"From your last drive, the navigation reads {said}.",
                    f"At 50 km/h it now says \"turn\" {lead:.1f} s before a junction (for anyone: "
                    f"{prompt_lead({}):.1f} s)."]
        return [f"The navigation has fitted its picture of how you drive to your {n} drive{'s' * (n != 1)} so far,",
                "and chose its prompts for the driver it now expects."]


def whole_files(records: Sequence[dict[str, Any]]) -> list[tuple[str, str]]:
    """The ``(town, file)`` of the whole drives among progress records, in order."""
    return [(r["town"], r["file"]) for r in records
            if r.get("item", "").startswith("drive:") and not r.get("interrupted") and r.get("file")]


def prompt_reactions(trajectory: Any, instructions: Sequence[int], detector: AnswerDetector | None
                     ) -> dict[int, tuple[int, float]]:
    """Per decision step whose prompt's reaction was read: (instruction, reaction s after its audio end).
    ``instructions``: each step's chosen instruction (the drive log's); ``detector``: the study's answer detector
    (None: nothing is read)."""
    if detector is None or trajectory is None or trajectory.shape[0] == 0:
        return {}
    step = trajectory["next"]
    T = min(trajectory.shape[0], len(instructions))
    played = [t for t in range(T) if bool(step["played"][t])]
    if not played:
        return {}
    ends = [float(step["prompt_end"][t]) for t in played]
    series, times = frame_series(step["frames"][:T], step["time"][:T])
    answers = {a.end: a for a in answers_of([instructions[t] for t in played], ends, series, times, complete=False)}
    out = {}
    with torch.no_grad():
        for t, end in zip(played, ends, strict=True):
            answer = answers.get(end)
            if answer is None:
                continue
            p = detector(answer.features, answer.prepare).exp()
            if float(p[-1]) > 0.5:  # the detector reads no answer to this prompt
                continue
            out[t] = (int(instructions[t]), round(float(answer.delays[int(p[:-1].argmax())]), 3))
    return out
