"""A lab's study session: one participant drives the blocks of a session file in a counterbalanced order, every
drive logged at the world's frame rate into one tidy CSV, with per-drive and per-answer tables and a data dictionary
beside it; a session killed at any point resumes where it stopped, and nothing recorded is ever truncated or
replaced.

The session file (YAML; ``docs/human.md`` has the protocol and a full example)::

    name: pilot-2026-11                 # the study's name (free text)
    participants: [P01, P02, P03, P04]  # ids; a participant's place in this list picks their row of the order
    counterbalance: latin               # latin: a Williams Latin square over the blocks; shuffle: seeded per participant
    seed: 0                             # the worlds' seeds (the same route meets the same traffic in every block)
    traffic: 8                          # traffic cars (default 8)
    study: runs/default                 # optional: a finished study whose learners a block's policy may name
    consent: "I agree to take part ..."  # optional: shown first; Enter agrees, Esc declines (the session ends)
    instructions: "You will drive ..."  # optional: shown at the start (and on resume)
    break_s: 60                         # optional: a break screen between blocks, at least this long (s)
    ssq: [before, after_block]          # optional: the simulator-sickness questionnaire (true: before and after)
    show_learned: true                  # optional: after a learner's block, what it learned of the participant
    audio: {volume: 0.8, voice: default, playback: normal}   # optional: the prompts' sound
    defaults: {town: Town1, vehicle: camaro, visual: normal, camera: third_person, equipment: keyboard}
    practice: {route: 0, policy: explore}   # optional: one drive before the blocks, logged with practice = true
    blocks:                             # each: a name, its routes (driven in this order) and its conditions
      - {name: rule, policy: explore, routes: [1, 2]}
      - {name: fog, policy: belief, visual: foggy, routes: [1, 2], counters: false}
    questionnaire:                      # optional, after each block: questions shown in the window (or the terminal)
      questions:
        - {id: workload, text: "How hard was it to follow the prompts?", scale: [1, 7]}
      # or: command: "python ask.py"    # run after each block; stdout lines "id=answer" are the answers

Conditions: ``town``, ``vehicle``, ``visual`` (the weather: normal, rgb, foggy), ``camera``, ``equipment``,
``policy`` (explore, oracle, or a learner of the ``study``: :mod:`pernav.play.labpersonal`), ``user`` (who the oracle
times its prompts for; default user1) and ``counters`` (the live counters of collisions, missed turns and re-routes;
default true). A block's name is never shown to the participant: the screens say "Part 2 of 3".

What a participant's folder holds (``OUT/<participant>/``, made by the session; :mod:`pernav.play.labfolder`), each
file written once or only appended to: ``plan.yaml`` (the session file as run), ``session.json`` (participant,
order, start), ``events.jsonl`` (every start, kill, resume, end, file and consent), ``progress.jsonl`` (one line per
finished step: the commit point of each), ``drives/`` (each drive in the study's format, a recorded tau, its
metrics and its rows of the CSV), ``session.csv`` (:mod:`pernav.play.framelog`: one row per frame, prompt, drive and
answer), ``drives.csv`` and ``answers.csv`` (:mod:`pernav.play.labdata`: the tidy per-drive and per-answer tables),
``dictionary.csv`` (every column: type, unit, meaning), ``belief.pt`` (a belief block's posterior) and, once the last
step is done, ``summary.json``.

Example (headless: the scripted bot drives, the questionnaire answered by a function):
    >>> plan = parse_plan({"participants": ["P1", "P2"], "traffic": 0,
    ...                    "blocks": [{"name": "a", "routes": [0]}, {"name": "b", "policy": "oracle", "routes": [0]}]})
    >>> [d.block for d in drive_list(plan, "P1")], [d.block for d in drive_list(plan, "P2")]
    (['a', 'b'], ['b', 'a'])
"""

from __future__ import annotations

import json
import math
import os
import random
import subprocess
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from pernav.play import ssq
from pernav.play.audio import voice_missing
from pernav.play.framelog import COLUMNS, answer_rows, csv_text, drive_rows
from pernav.play.labdata import ANSWER_TABLE, DRIVE_TABLE, answer_table_rows, dictionary_text, drive_table_row
from pernav.play.labfolder import FolderError, ParticipantFolder, now
from pernav.play.options import POLICIES, PlayOptions
from pernav.play.questionnaire import ask_question
from pernav.play.screens import FINISHED, STOPPED, show_finished, show_panel, show_waiting, wait_for_go
from pernav.play.view import PlayView
from pernav.world.constants import PLAYBACK, TOWN_NAMES
from pernav.world.drivers import CONTEXT_CHOICES, named_user
from pernav.world.towns import get_town

__all__ = ["Block", "Condition", "LabOptions", "LabSession", "MissingAnswer", "PlannedDrive", "SessionFileError",
           "SessionPlan", "block_order", "drive_list", "load_plan", "parse_plan", "square_warning", "williams_square"]

SESSION_FIELDS = ("name", "participants", "counterbalance", "seed", "traffic", "countdown", "hide_cost", "defaults",
                  "practice", "blocks", "questionnaire", "study", "consent", "instructions", "break_s", "ssq",
                  "show_learned", "audio")
CONDITION_FIELDS = ("town", "vehicle", "visual", "camera", "equipment", "policy", "user", "counters")
COUNTERBALANCE = ("latin", "shuffle")
LAB_POLICIES = POLICIES  # the rules a condition's policy may name without a study (explore, the oracle)
SSQ_MOMENTS = ("before", "after_block", "after")
AUDIO_FIELDS = ("volume", "voice", "playback")


class SessionFileError(ValueError):
    """A bad session file or participant folder (reported by ``pernav session`` in one line, exit 2)."""


class MissingAnswer(ValueError):
    """A question with no answer to read (headless, stdin ended): one line, exit 2."""


@dataclass(frozen=True)
class Condition:
    """What one drive is: a route of a town, the prompts' policy, the user the oracle times for, the context."""

    town: str
    route: int
    policy: str = "explore"
    user: str = "user1"
    context: tuple[tuple[str, str], ...] = ()  # (name, value) of the context fields given
    counters: bool = True  # the live counters shown

    def columns(self) -> dict[str, Any]:
        """The condition's columns of the session's CSV."""
        return {"town": self.town, "route": self.route, "policy": self.policy, "user": self.user, **dict(self.context)}


@dataclass(frozen=True)
class Block:
    name: str
    drives: tuple[Condition, ...]


@dataclass(frozen=True)
class Question:
    id: str
    text: str
    scale: tuple[int, int] | None = None  # inclusive; None: a free-text answer


@dataclass(frozen=True)
class AudioSettings:
    """The prompts' sound in every drive of the session: volume 0..1, a voice folder (None: the built-in voice) and
    the rules' playback speed."""

    volume: float = 1.0
    voice: str | None = None
    playback: str = "normal"


@dataclass(frozen=True)
class SessionPlan:
    """A parsed session file (:func:`load_plan`)."""

    participants: tuple[str, ...]
    blocks: tuple[Block, ...]
    name: str = "session"
    counterbalance: str = "latin"
    seed: int = 0
    traffic: int = 8
    countdown: float = 3.0
    hide_cost: bool = True
    practice: Condition | None = None
    questions: tuple[Question, ...] = ()
    command: str | None = None
    text: str = field(default="", compare=False)  # the file as written (kept in the participant's folder)
    study: str | None = None  # a finished study's folder (its learners are conditions)
    consent: tuple[str, ...] = ()
    instructions: tuple[str, ...] = ()
    break_s: float | None = None  # None: no break screen
    ssq: tuple[str, ...] = ()
    show_learned: bool = False
    audio: AudioSettings = AudioSettings()


@dataclass(frozen=True)
class PlannedDrive:
    """One drive of a participant's session: its number (0: the practice drive), block and world seed."""

    number: int
    block: str
    condition: Condition
    seed: int
    practice: bool = False
    position: int = 0  # the block's place in the participant's order (0: the practice drive)

    @property
    def key(self) -> str:
        return f"drive:{self.number}"


# ----- the session file --------------------------------------------------------------------------------------
def _fail(where: str, message: str) -> SessionFileError:
    return SessionFileError(f"{where}: {message}")


def _check_fields(where: str, entry: Any, allowed: Sequence[str]) -> Mapping[str, Any]:
    if not isinstance(entry, Mapping):
        raise _fail(where, f"expected a mapping of fields, got {type(entry).__name__}")
    for name in entry:
        if name not in allowed:
            hint = " (the weather is `visual`: normal, rgb, foggy)" if name == "weather" else ""
            raise _fail(where, f"unknown field {name!r}; allowed: {', '.join(allowed)}{hint}")
    return entry


def _bool(where: str, value: Any) -> bool:
    if not isinstance(value, bool):
        raise _fail(where, f"expected true or false, got {value!r}")
    return value


def _text(where: str, value: Any) -> tuple[str, ...]:
    """A screen's text: a string (its lines) or a list of lines."""
    if value is None:
        return ()
    if isinstance(value, str):
        value = value.strip().splitlines()
    if not isinstance(value, list) or not value or not all(isinstance(v, str) for v in value):
        raise _fail(where, "expected a text (a string, or a list of lines)")
    return tuple(value)


def _condition(where: str, fields: Mapping[str, Any], route: Any, learners: Sequence[str], study: Any) -> Condition:
    town = fields.get("town", "Town1")
    if town not in TOWN_NAMES:
        raise _fail(where, f"unknown town {town!r}; choose one of {', '.join(TOWN_NAMES)}")
    n_routes = len(get_town(town).routes)
    if isinstance(route, bool) or not isinstance(route, int) or not 0 <= route < n_routes:
        raise _fail(where, f"route {route!r} out of range [0, {n_routes - 1}] for {town}")
    policy = fields.get("policy", "explore")
    if policy not in (*LAB_POLICIES, *learners):
        extra = (f" or a learner of the study ({', '.join(learners)})" if study is not None
                 else " (a learner, e.g. belief or adapt, needs a finished study: give its folder in `study:`)")
        raise _fail(where, f"unknown policy {policy!r}; choose one of {', '.join(LAB_POLICIES)}{extra}")
    if policy in learners and town not in study.towns:
        raise _fail(where, f"policy {policy!r} in {town}: the study ran {', '.join(study.towns)} only")
    user = fields.get("user", "user1")
    try:
        named_user(user)
    except Exception:  # noqa: BLE001 - any failure to name a user is the file's fault, said in one line
        raise _fail(where, f"unknown user {user!r}; choose one of user1..user7") from None
    context = []
    for name, allowed in CONTEXT_CHOICES.items():
        if name in fields:
            if fields[name] not in allowed:
                raise _fail(where, f"unknown {name} {fields[name]!r}; allowed: {', '.join(allowed)}")
            context.append((name, str(fields[name])))
    counters = _bool(f"{where}: counters", fields.get("counters", True))
    return Condition(town, route, policy, user, tuple(context), counters)


def _questions(entry: Any) -> tuple[tuple[Question, ...], str | None]:
    if entry is None:
        return (), None
    entry = _check_fields("questionnaire", entry, ("questions", "command"))
    command = entry.get("command")
    if command is not None and not isinstance(command, str):
        raise _fail("questionnaire.command", "expected a shell command (a string)")
    out, seen = [], set()
    raw = entry.get("questions") or []
    if not isinstance(raw, list):
        raise _fail("questionnaire.questions", "expected a list of {id, text, scale}")
    for k, q in enumerate(raw):
        where = f"questionnaire.questions[{k}]"
        q = _check_fields(where, q, ("id", "text", "scale"))
        if not q.get("id") or not q.get("text"):
            raise _fail(where, "each question needs an id and a text")
        if q["id"] in seen:
            raise _fail(where, f"question id {q['id']!r} used twice")
        if str(q["id"]).startswith("ssq_"):
            raise _fail(where, f"question id {q['id']!r}: ids starting ssq_ are the built-in SSQ's (`ssq:`)")
        seen.add(q["id"])
        scale = q.get("scale")
        if scale is not None and not (isinstance(scale, list) and len(scale) == 2
                                      and all(isinstance(v, int) for v in scale) and 0 <= scale[0] < scale[1] <= 9):
            raise _fail(where, f"scale must be [low, high], whole numbers 0-9 with low < high; got {scale!r}")
        out.append(Question(str(q["id"]), str(q["text"]), None if scale is None else (scale[0], scale[1])))
    if not out and command is None:
        raise _fail("questionnaire", "give questions or a command (or leave the questionnaire out)")
    return tuple(out), command


def _ssq(value: Any) -> tuple[str, ...]:
    if value is None or value is False:
        return ()
    if value is True:
        return ("before", "after")
    if not isinstance(value, list) or not all(v in SSQ_MOMENTS for v in value) or len(set(value)) != len(value):
        raise _fail("ssq", f"expected true, false or a list of moments from {', '.join(SSQ_MOMENTS)}; got {value!r}")
    return tuple(value)


def _audio(entry: Any, base: Path) -> AudioSettings:
    if entry is None:
        return AudioSettings()
    entry = _check_fields("audio", entry, AUDIO_FIELDS)
    volume = entry.get("volume", 1.0)
    if isinstance(volume, bool) or not isinstance(volume, (int, float)) or not 0 <= volume <= 1:
        raise _fail("audio.volume", f"expected a number from 0 (silent) to 1 (full), got {volume!r}")
    playback = entry.get("playback", "normal")
    if playback not in PLAYBACK:
        raise _fail("audio.playback", f"unknown playback {playback!r}; choose one of {', '.join(PLAYBACK)}")
    voice = entry.get("voice", "default")
    if not isinstance(voice, str):
        raise _fail("audio.voice", f"expected default or a folder of WAV files, got {voice!r}")
    folder = None
    if voice != "default":
        path = Path(voice) if Path(voice).is_absolute() else base / voice
        missing = voice_missing(path) if path.is_dir() else ["the folder"]
        if missing:
            raise _fail("audio.voice", f"{voice!r} lacks {missing[0]}: a voice is a folder of 1_normal.wav ... "
                        "6_faster.wav (every instruction at every playback speed), or default")
        folder = str(path)
    return AudioSettings(float(volume), folder, playback)


def _study(value: Any, base: Path) -> tuple[Any, str | None, list[str]]:
    """The finished study a session names (opened: a fast read of its settings), its folder and its learners."""
    if value is None:
        return None, None, []
    from pernav.play.labpersonal import study_learners  # lazy: it loads torch; a file without a study needs none
    from pernav.study.finished import FinishedStudy, StudyError

    if not isinstance(value, str):
        raise _fail("study", f"expected a finished study's folder, got {value!r}")
    path = Path(value) if Path(value).is_absolute() else base / value
    try:
        study = FinishedStudy.open(path)
    except StudyError as exc:
        raise _fail("study", str(exc)) from None
    return study, str(path), study_learners(study)


def parse_plan(data: Any, text: str = "", base: str | Path = ".") -> SessionPlan:
    """A :class:`SessionPlan` from a session file's contents (a mapping); every bad field is refused by name.
    ``base``: the folder that relative paths (``study``, ``audio.voice``) are read from (the file's)."""
    base = Path(base)
    data = _check_fields("session file", data, SESSION_FIELDS)
    participants = data.get("participants")
    if (not isinstance(participants, list) or not participants
            or not all(isinstance(p, str) and p and p.replace("-", "").replace("_", "").isalnum() for p in participants)):
        raise _fail("participants", "expected a list of ids (letters, digits, - and _), e.g. [P01, P02]")
    if len(set(participants)) != len(participants):
        raise _fail("participants", "an id is listed twice")
    counterbalance = data.get("counterbalance", "latin")
    if counterbalance not in COUNTERBALANCE:
        raise _fail("counterbalance", f"{counterbalance!r}; choose one of {', '.join(COUNTERBALANCE)}")
    for name, low in (("seed", 0), ("traffic", 0), ("countdown", 0), ("break_s", 0)):
        value = data.get(name, 0)
        if isinstance(value, bool) or not isinstance(value, (int, float)) or value < low:
            raise _fail(name, f"expected a number >= {low}, got {value!r}")
    hide_cost = _bool("hide_cost", data.get("hide_cost", True))
    show_learned = _bool("show_learned", data.get("show_learned", False))
    study, study_path, learners = _study(data.get("study"), base)
    defaults = _check_fields("defaults", data.get("defaults") or {}, CONDITION_FIELDS)
    blocks_raw = data.get("blocks")
    if not isinstance(blocks_raw, list) or not blocks_raw:
        raise _fail("blocks", "expected a list of blocks, each {name, routes, conditions...}")
    blocks, names = [], set()
    for k, entry in enumerate(blocks_raw):
        where = f"blocks[{k}]"
        entry = _check_fields(where, entry, ("name", "routes", *CONDITION_FIELDS))
        name = str(entry.get("name") or f"block{k + 1}")
        if name in names:
            raise _fail(where, f"block name {name!r} used twice")
        names.add(name)
        routes = entry.get("routes")
        if not isinstance(routes, list) or not routes:
            raise _fail(where, "routes: expected a list of route indices, e.g. [1, 2]")
        fields = {**defaults, **{k2: v for k2, v in entry.items() if k2 in CONDITION_FIELDS}}
        blocks.append(Block(name, tuple(_condition(f"{where} ({name})", fields, r, learners, study) for r in routes)))
    practice = None
    if data.get("practice") is not None:
        entry = _check_fields("practice", data["practice"], ("route", *CONDITION_FIELDS))
        practice = _condition("practice", {**defaults, **entry}, entry.get("route", 0), learners, study)
    questions, command = _questions(data.get("questionnaire"))
    return SessionPlan(tuple(participants), tuple(blocks), str(data.get("name", "session")), counterbalance,
                       int(data.get("seed", 0)), int(data.get("traffic", 8)), float(data.get("countdown", 3.0)),
                       hide_cost, practice, questions, command, text, study_path,
                       _text("consent", data.get("consent")), _text("instructions", data.get("instructions")),
                       None if data.get("break_s") is None else float(data["break_s"]), _ssq(data.get("ssq")),
                       show_learned, _audio(data.get("audio"), base))


def load_plan(path: str | Path) -> SessionPlan:
    """Read and check a session file (YAML); relative paths in it are read from its folder."""
    path = Path(path)
    if not path.is_file():
        raise SessionFileError(f"session file {str(path)!r} does not exist")
    text = path.read_text()
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise SessionFileError(f"{path}: not valid YAML ({' '.join(str(exc).split())})") from None
    return parse_plan(data, text, path.resolve().parent)


# ----- the order of the blocks ---------------------------------------------------------------------------------
def williams_square(n: int) -> list[list[int]]:
    """A Williams design over ``n`` conditions: each row an order in which every condition comes once in every
    place and (for even ``n``; over the ``2n`` rows for odd ``n``) directly after every other once.

    >>> williams_square(4)
    [[0, 1, 3, 2], [1, 2, 0, 3], [2, 3, 1, 0], [3, 0, 2, 1]]
    """
    if n < 1:
        raise ValueError(f"need at least one condition, got {n}")
    first, low, high = [0], 1, n - 1
    while len(first) < n:
        first.append(low)
        low += 1
        if len(first) < n:
            first.append(high)
            high -= 1
    rows = [[(c + i) % n for c in first] for i in range(n)]
    return rows if n % 2 == 0 else rows + [row[::-1] for row in rows]


def square_warning(plan: SessionPlan) -> str | None:
    """A warning when the participants do not complete the Williams square's rows (``latin`` only), else None.

    >>> square_warning(parse_plan({"participants": ["A", "B", "C"], "blocks": [{"routes": [0]}] * 0 + [
    ...     {"name": "a", "routes": [0]}, {"name": "b", "routes": [0]}, {"name": "c", "routes": [0]}]}))[:60]
    'warning: 3 participants use 3 of the 6 orders of the counterbal'
    """
    if plan.counterbalance != "latin":
        return None
    rows = len(williams_square(len(plan.blocks)))
    n = len(plan.participants)
    if n % rows == 0:
        return None
    used = min(n, rows)
    return (f"warning: {n} participants use {used} of the {rows} orders of the counterbalancing square (Williams, "
            f"{len(plan.blocks)} blocks){'' if n < rows else ' unevenly'}: every order occurs equally often with a "
            f"multiple of {rows} participants (next: {rows * math.ceil(n / rows)})")


def block_order(plan: SessionPlan, participant: str) -> list[int]:
    """The indices of ``plan``'s blocks in the order ``participant`` drives them."""
    if participant not in plan.participants:
        raise SessionFileError(f"participant {participant!r} is not in the session file's participants "
                               f"({', '.join(plan.participants)})")
    n = len(plan.blocks)
    if plan.counterbalance == "latin":
        rows = williams_square(n)
        return rows[plan.participants.index(participant) % len(rows)]
    order = list(range(n))
    random.Random(f"{plan.seed}:{participant}").shuffle(order)  # a string seed: the same in every process
    return order


def drive_list(plan: SessionPlan, participant: str) -> list[PlannedDrive]:
    """Every drive of ``participant``'s session in order: the practice drive (number 0), then the blocks'.
    The world's seed depends on the route only, so each route meets the same traffic in every block."""
    from pernav.trainer.collect import derive_seed  # lazy: it loads torch and torchrl; a session file is checked without

    drives = []
    if plan.practice is not None:
        c = plan.practice
        drives.append(PlannedDrive(0, "practice", c, derive_seed(plan.seed, "practice", c.town, c.route), True))
    for position, index in enumerate(block_order(plan, participant), start=1):
        block = plan.blocks[index]
        for c in block.drives:
            drives.append(PlannedDrive(len(drives) + (plan.practice is None), block.name, c,
                                       derive_seed(plan.seed, c.town, c.route), position=position))
    return drives


@dataclass(frozen=True)
class Step:
    """One step of a session that is committed once done: a drive, a questionnaire, the SSQ, consent, or what the
    navigation learned shown."""

    key: str
    kind: str  # drive, questions, ssq, consent, learned
    drive: PlannedDrive | None = None
    block: str = ""
    position: int = 0
    when: str = ""  # the SSQ's: before, after_block, after
    last: PlannedDrive | None = None  # the last drive before the step


def _items(plan: SessionPlan, participant: str) -> list[tuple[str, Any]]:
    """The session's steps in order, each ``(key, Step)``."""
    steps: list[Step] = []
    if plan.consent:
        steps.append(Step("consent", "consent"))
    if "before" in plan.ssq:
        steps.append(Step("ssq:before", "ssq", when="before"))
    drives = drive_list(plan, participant)
    learners = {c.policy for b in plan.blocks for c in b.drives if c.policy not in LAB_POLICIES}
    for k, drive in enumerate(drives):
        steps.append(Step(drive.key, "drive", drive, drive.block, drive.position, last=drive))
        last = k + 1 == len(drives) or drives[k + 1].block != drive.block
        if not last or drive.practice:
            continue
        common = {"block": drive.block, "position": drive.position, "last": drive}
        if plan.questions or plan.command:
            steps.append(Step(f"questions:{drive.block}", "questions", **common))
        if "after_block" in plan.ssq:
            steps.append(Step(f"ssq:{drive.block}", "ssq", when="after_block", **common))
        block = next(b for b in plan.blocks if b.name == drive.block)
        if plan.show_learned and any(c.policy in learners for c in block.drives):
            steps.append(Step(f"learned:{drive.block}", "learned", **common))
    if "after" in plan.ssq:
        steps.append(Step("ssq:after", "ssq", when="after", last=drives[-1] if drives else None))
    return [(s.key, s) for s in steps]


# ----- the session -------------------------------------------------------------------------------------------
Answerer = Callable[[Question, str], Any]


@dataclass
class LabResult:
    folder: Path
    done: int  # items (drives and questionnaires) finished, this run and before
    total: int
    stopped: bool = False  # a drive was stopped (Esc then Y) or Ctrl-C: the session can be resumed
    ctrl_c: bool = False

    @property
    def finished(self) -> bool:
        return self.done == self.total


@dataclass(frozen=True)
class LabOptions:
    """How a lab session runs beside its plan and people: ``realtime`` (None: a window is paced to real time; False:
    as fast as it computes, a test's windowed run) and ``notice`` (a line on each ready screen, e.g. no sound)."""

    realtime: bool | None = None
    notice: str | None = None


class LabSession:
    """``participant``'s session of ``plan``, in ``out/<participant>``: drives each item not yet done, in order.

    ``window``: a person drives in one window kept open for the whole session (``controls``: their controls, or a
    class made per drive once the window is open); headless, the scripted bot drives. ``answer``: a function
    ``(question, block) -> answer`` for the questionnaires (scripted tests; default: the window, else the terminal).
    ``resume``: continue a session whose folder exists (with the same session file); without it such a folder is
    refused, and so is a folder holding anything the session did not write (:mod:`pernav.play.labfolder`).
    """

    def __init__(self, plan: SessionPlan, participant: str, out: str | Path, window: bool = False,
                 controls: Any = None, speaker: Any = None, answer: Answerer | None = None, resume: bool = False,
                 announce: Callable[[str], None] = print, options: LabOptions | None = None) -> None:
        self.plan, self.participant = plan, participant
        self.items = _items(plan, participant)  # refuses a participant the file does not list
        self.options = options or LabOptions()
        self.window, self.controls, self.speaker, self.notice = window, controls, speaker, self.options.notice
        self.answer, self.announce = answer, announce
        self.drives = [s.drive for _, s in self.items if s.kind == "drive"]
        self.total_drives = sum(not d.practice for d in self.drives)
        self.parts = len(plan.blocks)
        self.view: Any = None
        self.store = ParticipantFolder(out, participant, plan.text, resume)
        try:
            self.store.check()
        except FolderError as exc:
            raise SessionFileError(str(exc)) from None
        self.folder = self.store.path
        self.learned: Any = None  # the study's learners for this participant (opened by run)

    @property
    def records(self) -> list[dict[str, Any]]:
        """The committed steps' records (``progress.jsonl``)."""
        return self.store.records

    def done_items(self) -> set[str]:
        """The items whose record is committed (a stopped drive is not done: it is driven again)."""
        return {r["item"] for r in self.records if not r.get("interrupted")}

    def answers_needed(self) -> list[str]:
        """What the steps not yet done will ask the participant (one entry per answer), for a headless run."""
        done, out = self.done_items(), []
        for key, step in self.items:
            if key in done:
                continue
            if step.kind == "questions":
                out += [f"{q.id} after part {step.position}" for q in self.plan.questions]
            elif step.kind == "ssq":
                out += [f"{item.id} ({step.when})" for item in ssq.ITEMS]
        return out

    def questions_in_order(self) -> list[Question]:
        """Every question the steps not yet done ask, in order (what stdin answers, one a line)."""
        done, out = self.done_items(), []
        for key, step in self.items:
            if key not in done:
                out += self._step_questions(step)
        return out

    def _step_questions(self, step: Step) -> list[Question]:
        if step.kind == "questions":
            return list(self.plan.questions)
        if step.kind == "ssq":
            return [Question(i.id, f"{i.text}: 0 none, 1 slight, 2 moderate, 3 severe", ssq.SCALE) for i in ssq.ITEMS]
        return []

    # ----- the steps ---------------------------------------------------------------------------------------
    def _begin(self) -> None:
        order = [self.plan.blocks[i].name for i in block_order(self.plan, self.participant)]
        info = {"participant": self.participant, "session": self.plan.name, "order": order,
                "counterbalance": self.plan.counterbalance, "started": now(), "study": self.plan.study}
        headers = {"session.csv": csv_text([], COLUMNS, header=True),
                   "drives.csv": csv_text([], [c[0] for c in DRIVE_TABLE], header=True),
                   "answers.csv": csv_text([], [c[0] for c in ANSWER_TABLE], header=True),
                   "dictionary.csv": dictionary_text()}
        self.store.begin(info, headers)
        if self.plan.study is not None:
            from pernav.play.labpersonal import LearnedPolicies, whole_files  # lazy: torch

            self.learned = LearnedPolicies(self.plan.study, self.folder)
            self.learned.restore()
            for town, file in whole_files(self.records):
                self.learned.add(town, file)

    def run(self) -> LabResult:
        """Drive (and ask) every item not yet done; stop at a stopped drive, declined consent or Ctrl-C."""
        self._begin()
        done = self.done_items()
        todo = [(key, item) for key, item in self.items if key not in done]
        if done:
            self.announce(f"resuming {self.folder}: {len(done)} of {len(self.items)} step(s) done")
        result = LabResult(self.folder, len(done), len(self.items))
        end = "stopped"
        try:
            self._open_window()
            self._instructions()
            for key, step in todo:
                if step.kind == "drive":
                    self._break(step.drive)
                    stopped, ctrl_c = self._drive(step.drive)
                    if stopped:
                        result.stopped, result.ctrl_c = True, ctrl_c
                        break
                elif step.kind == "consent":
                    if not self._consent():
                        result.stopped = True
                        break
                elif step.kind == "learned":
                    self._show_learned(step)
                else:
                    self._ask(key, step)
                result.done += 1
            if result.finished:
                self._finish()
                end = "finished"
            self._show_end(result)
        except KeyboardInterrupt:
            result.stopped = result.ctrl_c = True
        finally:
            self.store.event("end", state="ctrl-c" if result.ctrl_c else end, done=result.done, total=result.total)
            if self.view is not None:
                self.view.close()
                self.view = None
        return result

    def _open_window(self) -> None:
        if not self.window:
            return
        first = self.drives[0]
        self.view = PlayView(get_town(first.condition.town), window=True)

    def _screen(self, lines: Sequence[str], heading: str | None = None, title: str | None = None) -> bool:
        """A text screen until the participant's go (True; False: they asked to leave). Headless: nothing."""
        if self.view is None:
            return True

        def draw() -> None:
            self.view.surface.fill((8, 10, 14))
            show_panel(self.view, [*([heading] if heading else []), *lines], title=title)

        draw()
        controls = self._make_controls()
        return True if controls is None else wait_for_go(controls, draw)

    def _instructions(self) -> None:
        if self.plan.instructions:
            self._screen([*self.plan.instructions, "Press Enter to begin"], heading="Instructions")
            self.store.event("instructions", shown=self.view is not None)

    def _consent(self) -> bool:
        """The consent screen: Enter agrees, Esc declines (the session ends, nothing driven). Headless: given."""
        agreed = self._screen([*self.plan.consent, "Enter: I agree   Esc: I do not agree"], heading="Consent")
        self.store.event("consent", given=agreed, how="window" if self.view is not None else "headless")
        if agreed:
            self.store.commit({"item": "consent", "participant": self.participant, "given": True, "ended": now(),
                               "how": "window" if self.view is not None else "headless"}, {})
        return agreed

    def _break(self, drive: PlannedDrive) -> None:
        """Between two blocks: a break screen, at least ``break_s`` long, until the participant's go."""
        k = self.drives.index(drive)
        first_of_block = k > 0 and self.drives[k - 1].block != drive.block and not self.drives[k - 1].practice
        if self.plan.break_s is None or not first_of_block:
            return
        self.store.event("break", before_drive=drive.number, shown=self.view is not None)
        if self.view is None:
            return
        until = time.monotonic() + self.plan.break_s
        while time.monotonic() < until:
            show_waiting(self.view, "Please rest", until - time.monotonic(), heading=f"Part {drive.position - 1} of "
                         f"{self.parts} done: a break")
            time.sleep(1 / 30)
        self._screen([f"Part {drive.position} of {self.parts} comes next.", "Press Enter when you are ready"],
                     heading="Break")

    def _meta(self, drive: PlannedDrive) -> dict[str, Any]:
        return {"session": self.plan.name, "participant": self.participant, "block": drive.block,
                "position": drive.position, "drive": drive.number, "practice": drive.practice,
                **drive.condition.columns()}

    def _title(self, drive: PlannedDrive) -> str:
        c = drive.condition
        head = "Practice drive" if drive.practice else f"Drive {drive.number} of {self.total_drives}"
        return f"{head}: {c.town} route {c.route}"

    def _policy(self, drive: PlannedDrive) -> Any:
        """The drive's policy: a rule's name, or a learner's policy personalized by the drives so far."""
        c = drive.condition
        if c.policy in LAB_POLICIES:
            return c.policy
        from pernav.trainer.collect import derive_seed  # lazy: torch

        return self.learned.policy(c.policy, c.town, seed=derive_seed(self.plan.seed, self.participant, drive.number))

    def _drive(self, drive: PlannedDrive) -> tuple[bool, bool]:
        """One drive, recorded; returns (stopped, ctrl_c)."""
        # lazy: the play loop and the drives' files load torch and torchrl; a session file is checked without them
        from pernav.play.labpersonal import prompt_reactions
        from pernav.play.loop import PlaySession
        from pernav.trainer.drives import save_drive

        c = drive.condition
        title = self._title(drive)
        self.announce(title)
        if self.view is not None:
            show_waiting(self.view, f"{title} (a few seconds)", None, heading="Preparing the next drive")
        started = _now()
        policy = self._policy(drive)
        learned = self.learned
        rules = isinstance(policy, str)
        options = PlayOptions(seed=drive.seed, n_traffic=self.plan.traffic, window=self.window,
                              realtime=self.options.realtime, countdown=self.plan.countdown, title=title,
                              hide_cost=self.plan.hide_cost, counters=c.counters, notice=self.notice,
                              progress=title.split(":")[0], playback=self.plan.audio.playback if rules else "normal",
                              K=None if learned is None else learned.history_window(c.town))
        session = PlaySession(c.town, c.route, c.user, dict(c.context), policy, speaker=self.speaker, view=self.view,
                              options=options)
        if self.controls is not None:
            session.controls = self._make_controls()
        try:
            result = session.run()
        finally:
            session.close()  # leaves the session's window open: it is this session's
        m = result.metrics
        attempt = 1 + sum(r["item"] == drive.key for r in self.records)
        base = f"{drive.number:02d}-{drive.block}-{c.town}-r{c.route}" + ("-stopped" if m["interrupted"] else "")
        name = self.store.free_name(base, (".pt", ".json", ".csv"))
        meta = {**self._meta(drive), "attempt": attempt}
        steps = [instruction for _, instruction, _ in (result.log.steps if result.log is not None else [])]
        detector = None if learned is None else learned.detector(c.town)
        reactions = prompt_reactions(result.trajectory, steps, detector)
        rows = drive_rows(result, meta)
        for row in rows:
            if row["row"] == "prompt" and row["step"] in reactions:
                row["reaction_s"] = reactions[row["step"]][1]
        record = {"item": drive.key, **meta, "counters": c.counters, "seed": drive.seed, "started": started,
                  "ended": _now(), "interrupted": bool(m["interrupted"]), "file": None, "files": [],
                  "wall_start": rows[-1].get("wall_start"), "wall_end": rows[-1].get("wall_end"),
                  **{k: m[k] for k in ("completed", "time", "tracking_cost", "vehicle_collisions", "edge_strikes",
                                       "missed_turns", "reroutes") if k in m}}
        if result.trajectory is not None:
            for suffix in (".pt", ".json"):
                self.store.announce(name + suffix)
            record["file"] = save_drive(result.trajectory, {**m, **record}, self.folder / "drives", name).name
            record["files"] += [f"drives/{name}.pt", f"drives/{name}.json"]
        rows_file = self.folder / "drives" / f"{name}.csv"
        self.store.announce(rows_file.name)
        _write_new(rows_file, csv_text(rows, COLUMNS))
        record["files"].append(f"drives/{name}.csv")
        played = [s for s, (_, instruction, _) in enumerate(result.log.steps) if s in result.log.prompts] \
            if result.log is not None else []
        table = drive_table_row(record, list(reactions.values()), [steps[s] for s in played])
        self.store.commit(record, {"session.csv": rows_file,
                                   "drives.csv": csv_text([table], [col[0] for col in DRIVE_TABLE])})
        if learned is not None and record["file"] and not m["interrupted"]:
            learned.add(c.town, record["file"], result.trajectory)
        state = "stopped" if m["interrupted"] else ("arrived" if m.get("completed") else "did not arrive")
        self.announce(f"  {state} after {m.get('time', 0):.0f} s")
        return bool(m["interrupted"]), bool(result.ctrl_c)

    def _ask(self, key: str, step: Step) -> None:
        """A questionnaire (the file's after a block, or the SSQ): each question, then the command; the answers as
        rows of session.csv and answers.csv."""
        answers: dict[str, Any] = {}
        title = self._part_title(step)
        for question in self._step_questions(step):
            answers[question.id] = self._answer(question, step.block, title)
        if step.kind == "ssq":
            answers.update(ssq.scores(answers))
        elif self.plan.command is not None:
            answers.update(self._run_command(step.block))
        last = step.last
        meta = {"session": self.plan.name, "participant": self.participant, "block": step.block,
                "position": step.position, "drive": 0 if last is None else last.number, "practice": False}
        condition = {} if last is None or step.kind == "ssq" and step.when == "before" else \
            {"town": last.condition.town, "policy": last.condition.policy, "user": last.condition.user}
        if step.when == "before":
            meta["drive"] = 0
        table_meta = {**meta, **condition, "questionnaire": "ssq" if step.kind == "ssq" else "block",
                      "when": step.when or "after_block", "asked": _now()}
        rows = answer_table_rows(table_meta, answers)
        if step.kind != "ssq" and self.plan.command is not None:
            for row in rows:
                if row["question"] not in {q.id for q in self.plan.questions}:
                    row["questionnaire"] = "command"
        self.store.commit({"item": key, "participant": self.participant, "block": step.block,
                           "position": step.position, "answers": answers, "ended": table_meta["asked"]},
                          {"session.csv": csv_text(answer_rows({**meta, **condition}, answers), COLUMNS),
                           "answers.csv": csv_text(rows, [c[0] for c in ANSWER_TABLE])})

    def _part_title(self, step: Step) -> str:
        if step.when == "before":
            return "Before the first drive"
        if step.when == "after":
            return "After the last drive"
        return f"Part {step.position} of {self.parts}"

    def _answer(self, question: Question, block: str, title: str) -> Any:
        if self.answer is not None:
            return self.answer(question, block)
        if self.view is not None:
            return ask_question(self.view, question.text, question.scale, title=title)
        while True:  # headless without a function: the terminal asks
            try:
                reply = input(f"{question.text} " + (f"[{question.scale[0]}-{question.scale[1]}] " if question.scale
                                                      else "") + "> ").strip()
            except EOFError:
                raise MissingAnswer(f"no answer to question {question.id!r} on stdin (it ended): give one answer a "
                                    "line, or run with a window; the session keeps what was done (--resume)") from None
            if question.scale is None:
                return reply
            if reply.isdigit() and question.scale[0] <= int(reply) <= question.scale[1]:
                return int(reply)

    def _show_learned(self, step: Step) -> None:
        """What the navigation learned of the participant in the block, in plain words (window and terminal)."""
        block = next(b for b in self.plan.blocks if b.name == step.block)
        c = next(c for c in block.drives if c.policy not in LAB_POLICIES)
        lines = self.learned.learned_words(c.policy, c.town)
        for line in lines:
            self.announce(f"  {line}")
        self._screen([*lines, "Press Enter to go on"], heading="What the navigation learned about you",
                     title=self._part_title(step))
        self.store.commit({"item": step.key, "participant": self.participant, "block": step.block,
                           "position": step.position, "shown": lines, "ended": _now()}, {})

    def _run_command(self, block: str) -> dict[str, Any]:
        """The questionnaire command, with the participant, block and folder in its environment; its stdout lines
        ``id=answer`` are answers, its exit code is kept as ``command_exit``."""
        env = {**os.environ, "PERNAV_PARTICIPANT": self.participant, "PERNAV_BLOCK": block,
               "PERNAV_SESSION_DIR": str(self.folder)}
        done = subprocess.run(self.plan.command, shell=True, env=env, capture_output=True, text=True)  # noqa: S602
        answers: dict[str, Any] = {"command_exit": done.returncode}
        for line in done.stdout.splitlines():
            if "=" in line:
                k, v = line.split("=", 1)
                answers[k.strip()] = _number(v.strip())
        return answers

    def _finish(self) -> None:
        """summary.json: the drives whole, in order (written once, when the last item is done)."""
        drives = [{k: v for k, v in r.items() if k != "appends"} for r in self.records
                  if r["item"].startswith("drive:") and not r.get("interrupted")]
        answers = {r["item"]: r["answers"] for r in self.records if "answers" in r}
        summary = {"participant": self.participant, "session": self.plan.name, "finished": _now(),
                   "drives": drives, "answers": answers}
        path = self.folder / "summary.json"
        if not path.exists():
            path.write_text(json.dumps(summary, indent=2) + "\n")

    def _show_end(self, result: LabResult) -> None:
        if self.view is None:
            return
        if not result.ctrl_c:  # after Ctrl-C the person at the terminal wants out
            show_finished(self.view, ["Please tell the experimenter."], controls=self._make_controls(),
                          heading=FINISHED if result.finished else STOPPED)

    def _make_controls(self) -> Any:
        """The person's controls (keyboard controls are a class, made once the window is open), or None."""
        if self.controls is None:
            return None
        return self.controls() if isinstance(self.controls, type) else self.controls


def _number(text: str) -> Any:
    """A command's answer as a number where it is one."""
    try:
        value = float(text)
    except ValueError:
        return text
    return int(value) if value.is_integer() and "." not in text else value


def _write_new(path: Path, text: str) -> None:
    """Write a file the session has just announced (never one that exists)."""
    with open(path, "x") as f:
        f.write(text)
        f.flush()
        os.fsync(f.fileno())


def _now() -> str:
    return now()
