"""What every personalization session shares (``pernav personalize``: with a model-based learner,
:class:`pernav.play.personal.PersonalSession`; with the belief learner, :class:`pernav.play.believe.BeliefSession`):
the checks before its first drive (the town and routes, the seed and the record folder, each refused by name), its
arguments (:class:`Session`, with :class:`SessionOptions`), how it drives, tells and ends, its result and its
summary table.

Example:
    >>> check_session("Town1", [0, 3], 0, None, resume=False) is None
    True
    >>> SessionOptions(seed=1, updates=2).countdown
    3.0
"""

from __future__ import annotations

import json
import os
from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from pernav.play.controls import ScriptedControls
from pernav.play.framelog import PlayResult
from pernav.play.loop import PlaySession
from pernav.play.options import PlayError, PlayOptions
from pernav.play.screens import SessionWindow
from pernav.study.finished import StudyError
from pernav.trainer.drives import atomic_write
from pernav.world.constants import TOWN_NAMES
from pernav.world.towns import get_town

__all__ = ["SESSION_FILES", "PersonalResult", "Session", "SessionOptions", "belief_markdown", "check_session",
           "check_writable", "policy_row", "study_errors", "summary_markdown"]

#: what a session writes beside its drives (a folder holding one of them holds a session)
SESSION_FILES = ("session.json", "summary.json", "summary.md", "model.pt", "belief.pt")


@contextmanager
def study_errors() -> Iterator[None]:
    """A finished study's refusal (:class:`~pernav.study.finished.StudyError`) as a session's :class:`PlayError`,
    its words unchanged."""
    try:
        yield
    except StudyError as exc:
        raise PlayError(str(exc)) from None


@dataclass(frozen=True)
class SessionOptions:
    """How a personalization session runs, beside its study, town, routes, people and objects (:class:`Session`)."""

    seed: int = 0
    """The session's seed: each drive's world (traffic, luck), the hidden order of the compared policies, the
    learning's draws; >= 0."""
    record_dir: str | Path | None = None
    """Where the drives and the session's files are written (None: nowhere); a folder holding another session is
    refused, unless ``resume``."""
    n_traffic: int = 8
    """Traffic cars in every drive."""
    updates: int | None = None
    """Meta updates after each round of a model-based learner (None: the study's ``train.updates``, at most
    :data:`pernav.play.personal.UPDATES`); the belief learner takes none (None only)."""
    learner: str | None = None
    """The study's learner that personalizes (None: the session's own, ``adapt`` or ``belief``)."""
    window: bool = False
    """One window for the whole session: "Drive n of N" on each drive, the learning's wait between drives, the
    end until Enter."""
    progress: bool = True
    """A progress bar in the terminal while the model learns."""
    resume: bool = False
    """Continue the interrupted session in ``record_dir`` (a model-based learner's; run with the same settings)."""
    countdown: float = 3.0
    """Seconds of each drive's countdown (:class:`~pernav.play.options.PlayOptions`)."""
    hide_cost: bool = False
    """Keep the tracking cost off the screen and out of what the person is told."""
    notice: str | None = None
    """A line on each ready screen (e.g. "no sound on this computer")."""
    calibrate: bool = False
    """A wheel's calibration screen before the first drive."""


@dataclass
class PersonalResult:
    """A session's drives (one record per drive: its metrics, round, policy, file) and the summary table."""

    drives: list[dict[str, Any]]
    summary: dict[str, Any]
    folder: Path | None
    interrupted: bool
    ctrl_c: bool = False  # the session was stopped by Ctrl-C (the command line exits 130)


class Session:
    """A person's drives on ``routes`` of ``town`` with a learner of the finished study in ``study_dir``: what the
    sessions share. A session of a kind opens its study and checks its options in :meth:`_open`.

    ``controls``: ``None`` (the scripted bot, a fresh one per drive), controls to reuse for every drive (a
    joystick), or a zero-argument factory called once per drive after its window is open (``KeyboardControls``).
    ``speaker`` says the prompts (None: text only). ``announce`` is called with a neutral line before each drive
    ("Drive 2 of 5: Town1 route 3") and after it (how it went, not with which policy), ``ready`` after the
    announcement (e.g. waits for the person to press Enter). ``options``: :class:`SessionOptions`; ``settings``:
    its fields by keyword, over ``options`` (the keyword form, for callers that give them one by one).
    ``speaker``, ``notice`` and ``controls`` may be set after the session is made (before :meth:`run`).
    """

    def __init__(self, study_dir: str | Path, town: str, routes: Sequence[int], user: Any = "user1",
                 context: dict | None = None, controls: Any = None, speaker: Any = None,
                 announce: Callable[[str], None] | None = None, ready: Callable[[], None] | None = None,
                 options: SessionOptions | None = None) -> None:
        options = options if options is not None else SessionOptions()
        self.options = options
        self.town, self.routes, self.seed = town, list(routes), int(options.seed)
        self.user, self.context, self.n_traffic = user, context, int(options.n_traffic)
        self.controls, self.window, self.speaker = controls, options.window, speaker
        self.announce = announce or (lambda line: None)
        self.ready = ready or (lambda: None)
        self.progress = options.progress
        self.countdown, self.hide_cost = options.countdown, options.hide_cost
        self.notice, self.calibrate = options.notice, options.calibrate
        self.drives: list[dict[str, Any]] = []
        self.learned: list[int] = []  # what the learner has learned from (rounds; the CLI's resume line counts them)
        self.learn_s: float | None = None  # how long the last learning took (the next wait's estimate)
        self.screens = SessionWindow(town, False)  # the session's window, opened by run()
        self.ctrl_c = False
        self.record_dir: Path | None = None
        self._open(study_dir)

    def _open(self, study_dir: str | Path) -> None:
        """Check the session's options, open its record folder and its study (a session of each kind)."""
        raise NotImplementedError

    def _drive_all(self) -> bool:
        """Drive the session's drives in its window; True when one was stopped (a session of each kind)."""
        raise NotImplementedError

    def _finish(self, interrupted: bool) -> PersonalResult:
        """The summary of what was driven, written; the end screen (a session of each kind)."""
        raise NotImplementedError

    def run(self) -> PersonalResult:
        """Drive the session; it stops early when the person quits or on Ctrl-C (what was driven is kept). Writes
        the summary with what was driven."""
        with SessionWindow(self.town, self.window) as self.screens:  # closed at the end, whatever happens
            try:
                interrupted = self._drive_all()
            except KeyboardInterrupt:
                interrupted = self.ctrl_c = True
            return self._finish(interrupted)

    def _controls(self) -> Any:
        """This drive's controls: a fresh bot, the controls given, or a new one from the factory given."""
        if self.controls is None:
            return ScriptedControls()
        if hasattr(self.controls, "read") and not isinstance(self.controls, type):
            return self.controls
        return self.controls()  # a factory: keyboard controls need the drive's window open

    def _play(self, route: int, policy: Any, title: str, options: PlayOptions) -> PlayResult:
        """One drive in the session's window: announced, the person ready, driven with this drive's controls.
        ``options``: the drive's own (its seed, title, ...); the session's traffic, window and screens go over
        them."""
        self.announce(title)
        self.ready()
        self.screens.waiting(title, None)
        options = replace(options, n_traffic=self.n_traffic, window=self.window, title=title,
                          countdown=self.countdown, hide_cost=self.hide_cost, notice=self.notice)
        session = PlaySession(self.town, route, self.user, self.context, policy, speaker=self.speaker,
                              view=self.screens.view, options=options)
        session.controls = self._controls()
        return session.run()

    def _tell(self, metrics: Mapping[str, Any], counts: Sequence[tuple[str, str]]) -> None:
        """How the drive went, not with which policy: arrived or not, its time, its cost (not with ``hide_cost``)
        and ``counts`` (words, metric)."""
        m = metrics
        state = "stopped" if m["interrupted"] else ("arrived" if m.get("completed") else "did not arrive")
        cost = "" if self.hide_cost else f"tracking cost {m.get('tracking_cost', 0):.0f}, "
        self.announce(f"  {state} after {m.get('time', 0):.0f} s: {cost}"
                      + ", ".join(f"{words} {m.get(key, 0)}" for words, key in counts))

    def _write_summary(self, summary: Mapping[str, Any], heading: str) -> None:
        """``summary.json`` and ``summary.md`` (``heading``, then the table) in the record folder."""
        assert self.record_dir is not None
        atomic_write(self.record_dir / "summary.json", lambda p: p.write_text(json.dumps(summary, indent=2)))
        atomic_write(self.record_dir / "summary.md", lambda p: p.write_text(
            f"# {heading}: {self.town}, routes {self.routes}, seed {self.seed}\n\n{summary_markdown(summary)}\n"))

    def _end(self, whole: int, total: int, interrupted: bool) -> None:
        """The end screen (not after Ctrl-C: no screen waits for the person), then the speaker closed."""
        if not self.ctrl_c:
            self.ctrl_c = self.screens.finish(self._controls, whole, total, interrupted)
        if self.speaker is not None and hasattr(self.speaker, "close"):
            self.speaker.close()


# ----- the summary table ---------------------------------------------------------------------------------------
def policy_row(drives: list[dict[str, Any]]) -> dict[str, Any]:
    """One policy's row of the summary over its whole ``drives``."""
    n = len(drives)
    return {"drives": n,
            "tracking_cost_mean": round(sum(d["tracking_cost"] for d in drives) / n, 2) if n else None,
            "vehicle_collisions": sum(d["vehicle_collisions"] for d in drives),
            "kerb_strikes": sum(d["edge_strikes"] for d in drives),
            "missed_turns": sum(d["missed_turns"] for d in drives),
            "completed": sum(bool(d["completed"]) for d in drives),
            "completion": round(sum(bool(d["completed"]) for d in drives) / n, 4) if n else None}


def summary_markdown(summary: dict[str, Any]) -> str:
    """The summary's table in Markdown (a belief session's: with the belief after each drive).

    >>> row = policy_row([])
    >>> print(summary_markdown({"policies": {"adapted": row}}).splitlines()[2])
    | adapted | 0 | - | 0 | 0 | 0 | 0/0 |
    """
    lines = ["| policy | drives | mean tracking cost | vehicle collisions | kerb strikes | missed turns | completed |",
             "|---|---|---|---|---|---|---|"]
    for name, row in summary["policies"].items():
        cost = "-" if row["tracking_cost_mean"] is None else f"{row['tracking_cost_mean']:.0f}"
        lines.append(f"| {name} | {row['drives']} | {cost} | {row['vehicle_collisions']} | {row['kerb_strikes']} | "
                     f"{row['missed_turns']} | {row['completed']}/{row['drives']} |")
    if summary.get("beliefs"):  # a belief session: where the belief stood after each drive
        lines += ["", belief_markdown(summary)]
    if summary.get("paired_routes"):
        lines.append("")
        lines.append(f"Paired routes: {summary['paired_routes']}; mean tracking cost difference (adapted - explore): "
                     f"{summary['paired_cost_difference_mean']:+.0f} (negative: the adapted policy did better).")
    return "\n".join(lines)


def belief_markdown(summary: dict[str, Any]) -> str:
    """The belief after each drive as a Markdown table.

    >>> print(belief_markdown({"beliefs": [{"after_drive": None, "reaction_time": 1.2, "interval": [0.8, 1.9],
    ...     "answers": 0, "turn_lead_s": 2.6}]}).splitlines()[2])
    | prior | 1.20 s | 0.80-1.90 s | 0 | 2.6 s |
    """
    lines = ["| after | reaction time | 90 % interval | answers read | 'turn' lead at 50 km/h |",
             "|---|---|---|---|---|"]
    for b in summary["beliefs"]:
        after = "prior" if b["after_drive"] is None else f"drive {b['after_drive']}"
        lines.append(f"| {after} | {b['reaction_time']:.2f} s | {b['interval'][0]:.2f}-{b['interval'][1]:.2f} s | "
                     f"{b['answers']} | {b['turn_lead_s']:.1f} s |")
    return "\n".join(lines)


# ----- the checks before the first drive ------------------------------------------------------------------------
def check_session(town: str, routes: Sequence[int], seed: int, record_dir: str | Path | None, resume: bool,
                  resumable: bool = True) -> Path | None:
    """The session's record folder (``None``: not recorded) once ``town``, ``routes`` (tau's, then at least one more),
    ``seed`` and the folder are valid: a folder holding another session is refused unless ``resume``, when it must
    hold one (the refusal suggests ``--resume`` only where the session can be ``resumable``).
    :class:`~pernav.play.options.PlayError` names the bad setting and what is allowed."""
    if town not in TOWN_NAMES:
        raise PlayError(f"unknown town {town!r}; choose one of {', '.join(TOWN_NAMES)}")
    n_routes = len(get_town(town).routes)
    if len(routes) < 2:
        raise PlayError(f"need at least two routes (tau's, then one or more to compare on), got {list(routes)}")
    bad = [r for r in routes if isinstance(r, bool) or not isinstance(r, int) or not 0 <= r < n_routes]
    if bad:
        raise PlayError(f"unknown route {bad[0]!r} in {town}; routes are 0-{n_routes - 1}")
    if seed < 0:
        raise PlayError(f"seed must be >= 0, got {seed}")
    folder = None if record_dir is None else Path(record_dir)
    if resume and folder is None:
        raise PlayError("resuming needs the interrupted session's record folder")
    if folder is not None:
        if folder.exists() and not folder.is_dir():
            raise PlayError(f"record folder {str(folder)!r} exists and is not a folder")
        held = any((folder / name).exists() for name in SESSION_FILES)
        if held and not resume:
            raise PlayError(f"record folder {str(folder)!r} already holds a personalization session; choose "
                            + ("another, or --resume to continue it" if resumable else "another (this learner's "
                               "sessions are not resumed)"))
        if resume and not (folder / "session.json").is_file():
            raise PlayError(f"--resume: record folder {str(folder)!r} holds no personalization session "
                            "to resume (no session.json)")
    return folder


def check_writable(option: str, folder: str | Path) -> None:
    """Write (and remove) a probe file in ``folder`` before anyone drives: a folder that cannot be written is found
    now, not after the drive. Folders made for the probe are removed again (they are made when a drive is saved)."""
    folder = Path(folder)
    made = [p for p in (folder, *folder.parents) if not p.exists()]
    probe = folder / f".pernav-write-test-{os.getpid()}"
    try:
        folder.mkdir(parents=True, exist_ok=True)
        probe.write_bytes(b"pernav")
    except OSError as exc:
        raise PlayError(f"{option} {str(folder)!r} cannot be written ({exc.strerror or exc}): nothing was driven"
                         ) from None
    finally:
        try:
            probe.unlink(missing_ok=True)
        except OSError:  # under a file: there is no probe to remove
            pass
        for p in made:  # deepest first
            try:
                p.rmdir()
            except OSError:
                break
