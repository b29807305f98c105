"""A lab session's file (:mod:`pernav.play.lab`): its fields parsed and checked (every bad one refused by name,
before any window opens), the counterbalanced order of its blocks (a Williams Latin square, or a seeded shuffle) and
each participant's steps (consent, the SSQ, the drives, the questionnaires, what the navigation learned).

Example:
    >>> plan = parse_plan({"participants": ["P1", "P2"], "blocks": [{"name": "a", "routes": [0]},
    ...                                                              {"name": "b", "routes": [1]}]})
    >>> [block_order(plan, p) for p in plan.participants]
    [[0, 1], [1, 0]]
"""

from __future__ import annotations

import math
import random
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from pernav.play.audio import voice_missing
from pernav.play.options import POLICIES
from pernav.world.constants import PLAYBACK, TOWN_NAMES
from pernav.world.drivers import CONTEXT_CHOICES, named_user
from pernav.world.towns import get_town

__all__ = ["AudioSettings", "Block", "Condition", "PlannedDrive", "Question", "SessionFileError", "SessionPlan",
           "Step", "block_order", "drive_list", "load_plan", "parse_plan", "session_steps", "square_warning",
           "williams_square"]

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

    >>> square_warning(parse_plan({"participants": ["A", "B", "C"], "blocks": [
    ...     {"name": "a", "routes": [0]}, {"name": "b", "routes": [0]}, {"name": "c", "routes": [0]}]}))[:56]
    'warning: 3 participants use 3 of the 6 orders of the cou'
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


def session_steps(plan: SessionPlan, participant: str) -> list[tuple[str, Any]]:
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
