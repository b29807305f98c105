"""``pernav personalize --learner belief``: the navigation learns when to speak for *you* from how you answer its
prompts (the belief learner of a finished study, docs/personal.md).

The first drive (``routes[0]``) is explore's; every next route is driven with explore's rules re-timed for what
the navigation believes of you so far, updated within the drive after each answered prompt. After every whole drive
the belief reads that drive's answers (when the car began to slow, to change lane, to turn; or no answer), and you
see your estimated reaction time with its 90 % interval and how your "turn" prompt moved. The posterior is kept in
the record folder (``belief.pt``) after each drive.

Example:
    >>> options = SessionOptions(record_dir="drives/me")                                     # doctest: +SKIP
    >>> session = BeliefSession("runs/default", "Town1", [0, 3, 5], options=options)          # doctest: +SKIP
    >>> result = session.run()                                                               # doctest: +SKIP
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any

import torch

from pernav.env.policies import belief_policy
from pernav.learners.belief import BeliefTracker
from pernav.play.options import PlayError, PlayOptions
from pernav.play.personal import PersonalSession
from pernav.play.sessions import PersonalResult, Session, belief_markdown, check_session, policy_row, study_errors
from pernav.study.finished import FinishedStudy
from pernav.trainer.collect import derive_seed
from pernav.trainer.drives import atomic_write, save_drive

__all__ = ["REFERENCE_SPEED", "BeliefSession", "belief_markdown", "prompt_lead", "session_class"]

#: the speed at which a person is shown how their "turn" prompt moved (50 km/h, in m/s)
REFERENCE_SPEED = 50 / 3.6
#: what the window says reading a drive's answers takes before a session has measured it (s; measured: well under 1 s)
READ_S = 2.0


def prompt_lead(fields: dict[str, Any], speed: float = REFERENCE_SPEED) -> float:
    """Seconds before the junction's commit point at which the "turn" prompt is said at ``speed`` for a belief's
    prompt fields (``{}``: explore's timing).

    >>> prompt_lead({}) < prompt_lead({"reaction_time": 2.5})
    True
    """
    return belief_policy(fields).turn_lead(speed) / speed


def session_class(learner: str) -> type:
    """The session ``pernav personalize --learner LEARNER`` runs: :class:`BeliefSession` for ``"belief"``, else
    :class:`pernav.play.personal.PersonalSession` (a model-based learner of the study)."""
    return BeliefSession if learner == "belief" else PersonalSession


class BeliefSession(Session):
    """A person's drives with prompts timed by the belief learner of the study in ``study_dir`` (its answer detector
    and population prior for ``town``: :meth:`pernav.study.finished.FinishedStudy.policy`). The arguments and options
    are :class:`~pernav.play.sessions.Session`'s, but for ``updates`` and ``resume`` (the belief takes no gradient
    steps; a stopped session is kept, not resumed) and ``learner`` (``"belief"`` only); ``window``: one window for
    the whole session, as there."""

    def _open(self, study_dir: str | Path) -> None:
        """Check the options, open the record folder and the study's belief learner."""
        options = self.options
        if (options.learner or "belief") != "belief":
            raise PlayError(f"BeliefSession runs the belief learner, not {options.learner!r} (use PersonalSession)")
        if options.updates is not None:
            raise PlayError("--updates goes with a model-based learner; the belief learner takes no gradient steps")
        if options.resume:
            raise PlayError("--resume goes with a model-based learner; a belief session's drives and belief.pt are "
                            "kept as they were driven: start a new session")
        self.record_dir = check_session(self.town, self.routes, options.seed, options.record_dir, resume=False,
                                        resumable=False)
        with study_errors():
            self.policy, _ = FinishedStudy.open(study_dir).policy("belief", self.town)
        self.study = str(study_dir)
        self.beliefs: list[dict[str, Any]] = [self._belief_record(None)]  # the prior, then after each whole drive

    @property
    def tracker(self) -> BeliefTracker:
        """The belief about the person now (it has read every whole drive's answers so far)."""
        return self.policy.belief

    @tracker.setter
    def tracker(self, tracker: BeliefTracker) -> None:
        self.policy.belief = tracker

    def _belief_record(self, drive: int | None) -> dict[str, Any]:
        """What the person is shown: the estimated reaction time, its 90 % interval, the answers read so far and
        the "turn" prompt's lead at :data:`REFERENCE_SPEED` for this belief."""
        b = self.tracker.belief
        low, high = b.interval(0.9)
        record = {"after_drive": drive, "reaction_time": round(b.mean_reaction(), 3),
                  "interval": [round(low, 3), round(high, 3)], "answers": int(b.answers),
                  "turn_lead_s": round(prompt_lead(self.tracker.fields()), 3)}
        if b.decision is not None:  # the decision time too: from the announced junctions' outcomes
            low, high = b.decision_interval(0.9)
            record.update({"decision_time": round(b.decision_mean, 3),
                           "decision_interval": [round(low, 3), round(high, 3)], "junctions": int(b.outcomes)})
        return record

    def _drive(self, number: int, route: int) -> Any:
        policy_name = "explore" if number == 1 else "belief"
        title = f"Drive {number} of {len(self.routes)}: {self.town} route {route}"
        # explore's drive runs with the belief too (the env reads its answers as it goes; the rule is explore's)
        options = PlayOptions(seed=derive_seed(self.seed, self.town, "drive", number), env_config=self.policy.env_config,
                              calibrate=self.calibrate and number == 1, progress=f"Drive {number} of {len(self.routes)}")
        result = self._play(route, "explore" if policy_name == "explore" else self.policy, title, options)
        m = result.metrics
        record = {**m, "policy": policy_name, "round": number - 1, "route": route, "label": f"drive{number}",
                  "frames": result.frame_stats(), "file": None}
        if result.trajectory is not None and self.record_dir is not None:
            name = f"drive{number:02d}-route{route}-{policy_name}" + ("-stopped" if m["interrupted"] else "")
            record["file"] = str(save_drive(result.trajectory, record, self.record_dir, name))
        self.drives.append(record)
        self._tell(m, (("missed turns", "missed_turns"),))
        if result.trajectory is not None and not m["interrupted"]:
            self._learn(number, result.trajectory)
        return result

    def _learn(self, number: int, trajectory: Any) -> None:
        """The belief reads the drive's answers; the person sees where it stands and how the prompt moved."""
        before = self.beliefs[-1]
        started = time.perf_counter()
        self.screens.learning("the navigation is reading your answers", started,
                              READ_S if self.learn_s is None else self.learn_s, last=number == len(self.routes))
        tracker = self.tracker.copy()
        tracker.observe_drive(trajectory)
        self.tracker = tracker
        self.learn_s = time.perf_counter() - started
        self.learned.append(number - 1)
        now = self._belief_record(number)
        self.beliefs.append(now)
        moved = now["turn_lead_s"] - before["turn_lead_s"]
        self.announce(f"  your reaction time, as the navigation reads it: {now['reaction_time']:.2f} s (90 % interval "
                      f"{now['interval'][0]:.2f}-{now['interval'][1]:.2f} s, from {now['answers']} answered prompts)")
        if "decision_time" in now:
            self.announce(f"  when you choose your branch, as it reads it: {now['decision_time']:.1f} s before the "
                          f"junction (90 % interval {now['decision_interval'][0]:.1f}-{now['decision_interval'][1]:.1f}"
                          f" s, from {now['junctions']} announced junctions)")
        self.announce(f"  your 'turn' prompt at 50 km/h: {now['turn_lead_s']:.1f} s before the junction "
                      f"({'unchanged' if abs(moved) < 0.05 else f'{moved:+.1f} s'}; explore's "
                      f"{prompt_lead({}):.1f} s)")
        self._save()

    def _save(self) -> None:
        if self.record_dir is None:
            return
        self.record_dir.mkdir(parents=True, exist_ok=True)
        atomic_write(self.record_dir / "belief.pt", lambda p: torch.save(
            {"study": self.study, "town": self.town, "belief": self.tracker.belief.state_dict(),
             "beliefs": self.beliefs}, p))
        data = {"study": self.study, "town": self.town, "routes": self.routes, "seed": self.seed, "learner": "belief",
                "drives": self.drives, "beliefs": self.beliefs}
        atomic_write(self.record_dir / "session.json", lambda p: p.write_text(json.dumps(data, indent=1)))

    def _drive_all(self) -> bool:
        """Drive the routes in order; True when the person stopped a drive (or Ctrl-C)."""
        for number, route in enumerate(self.routes, start=1):
            result = self._drive(number, route)
            self.ctrl_c = self.ctrl_c or result.ctrl_c
            if result.metrics["interrupted"] or result.ctrl_c:
                return True
        return False

    def _finish(self, interrupted: bool) -> PersonalResult:
        """The summary of what was driven, written; the end screen (not after Ctrl-C)."""
        whole = [d for d in self.drives if not d["interrupted"]]
        summary = {"study": self.study, "town": self.town, "routes": self.routes, "seed": self.seed,
                   "learner": "belief", "interrupted": interrupted,
                   "policies": {name: policy_row([d for d in whole if d["policy"] == name])
                                for name in ("belief", "explore")},
                   "beliefs": self.beliefs,
                   "drives": [{k: d[k] for k in ("round", "route", "label", "policy", "tracking_cost", "missed_turns",
                                                 "completed", "interrupted", "file") if k in d} for d in self.drives]}
        if self.record_dir is not None and self.drives:
            self._save()
            self._write_summary(summary, "Personal timing")
        self._end(len(whole), len(self.routes), interrupted)
        return PersonalResult(list(self.drives), summary, self.record_dir, interrupted, self.ctrl_c)

