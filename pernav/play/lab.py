"""A lab's study session: one participant drives the blocks of a session file in a counterbalanced order, every
drive logged at the world's frame rate into one tidy CSV; a session killed at any point resumes where it stopped.

The session file (YAML; ``docs/human.md`` has the protocol and a full example)::

    name: pilot-2026-11                 # the study's name (free text)
    participants: [P01, P02, P03, P04]  # ids; a participant's place in this list picks their row of the order
    counterbalance: latin               # latin: a Williams Latin square over the blocks; shuffle: seeded per participant
    seed: 0                             # the worlds' seeds (the same route meets the same traffic in every block)
    traffic: 8                          # traffic cars (default 8)
    defaults: {town: Town1, vehicle: camaro, visual: normal, camera: third_person, equipment: keyboard}
    practice: {route: 0, policy: explore}   # optional: one drive before the blocks, logged with practice = true
    blocks:                             # each: a name, its routes (driven in this order) and its conditions
      - {name: rule, policy: explore, routes: [1, 2]}
      - {name: fog, policy: explore, visual: foggy, routes: [1, 2]}
    questionnaire:                      # optional, after each block: questions shown in the window (or the terminal)
      questions:
        - {id: workload, text: "How hard was it to follow the prompts?", scale: [1, 7]}
      # or: command: "python ask.py"    # run after each block; stdout lines "id=answer" are the answers

Conditions: ``town``, ``vehicle``, ``visual`` (the weather: normal, rgb, foggy), ``camera``, ``equipment``,
``policy`` (explore or oracle) and ``user`` (who the oracle times its prompts for; default user1).

What a participant's folder holds (``OUT/<participant>/``), each file written once or only appended to:
``plan.yaml`` (the session file as run), ``session.json`` (participant, order, start), ``progress.jsonl`` (one line
per finished drive or questionnaire: the commit point of each), ``drives/`` (each drive in the study's format, a
recorded tau, and its metrics), ``session.csv`` (:mod:`pernav.play.framelog`: one row per frame, prompt, drive and
answer) and, once the last item is done, ``summary.json``.

Example (headless: the scripted bot drives, the questionnaire answered by a function):
    >>> plan = parse_plan({"participants": ["P1", "P2"], "traffic": 0,
    ...                    "blocks": [{"name": "a", "routes": [0]}, {"name": "b", "policy": "oracle", "routes": [0]}]})
    >>> [d.block for d in drive_list(plan, "P1")], [d.block for d in drive_list(plan, "P2")]
    (['a', 'b'], ['b', 'a'])
"""

from __future__ import annotations

import json
import os
import random
import subprocess
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from pernav.play.framelog import answer_rows, append_csv, drive_rows
from pernav.play.options import POLICIES, PlayOptions
from pernav.play.questionnaire import ask_question
from pernav.play.screens import FINISHED, STOPPED, show_finished, show_waiting
from pernav.play.view import PlayView
from pernav.world.constants import TOWN_NAMES
from pernav.world.drivers import CONTEXT_CHOICES, named_user
from pernav.world.towns import get_town

__all__ = ["Block", "Condition", "LabSession", "PlannedDrive", "SessionFileError", "SessionPlan", "block_order",
           "drive_list", "load_plan", "parse_plan", "williams_square"]

SESSION_FIELDS = ("name", "participants", "counterbalance", "seed", "traffic", "countdown", "hide_cost", "defaults",
                  "practice", "blocks", "questionnaire")
CONDITION_FIELDS = ("town", "vehicle", "visual", "camera", "equipment", "policy", "user")
COUNTERBALANCE = ("latin", "shuffle")
LAB_POLICIES = POLICIES  # a condition's policy: one of the rules (explore, or the oracle timed for its user)


class SessionFileError(ValueError):
    """A bad session file (reported by ``pernav session`` in one line, exit 2)."""


@dataclass(frozen=True)
class Condition:
    """What one drive is: a route of a town, the prompts' policy, the user the oracle times for, the context."""

    town: str
    route: int
    policy: str = "explore"
    user: str = "user1"
    context: tuple[tuple[str, str], ...] = ()  # (name, value) of the context fields given

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


@dataclass(frozen=True)
class PlannedDrive:
    """One drive of a participant's session: its number (0: the practice drive), block and world seed."""

    number: int
    block: str
    condition: Condition
    seed: int
    practice: bool = False

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


def _condition(where: str, fields: Mapping[str, Any], route: Any) -> Condition:
    town = fields.get("town", "Town1")
    if town not in TOWN_NAMES:
        raise _fail(where, f"unknown town {town!r}; choose one of {', '.join(TOWN_NAMES)}")
    n_routes = len(get_town(town).routes)
    if isinstance(route, bool) or not isinstance(route, int) or not 0 <= route < n_routes:
        raise _fail(where, f"route {route!r} out of range [0, {n_routes - 1}] for {town}")
    policy = fields.get("policy", "explore")
    if policy not in LAB_POLICIES:
        raise _fail(where, f"unknown policy {policy!r}; choose one of {', '.join(LAB_POLICIES)}")
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
    return Condition(town, route, policy, user, tuple(context))


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
        seen.add(q["id"])
        scale = q.get("scale")
        if scale is not None and not (isinstance(scale, list) and len(scale) == 2
                                      and all(isinstance(v, int) for v in scale) and 0 <= scale[0] < scale[1] <= 9):
            raise _fail(where, f"scale must be [low, high], whole numbers 0-9 with low < high; got {scale!r}")
        out.append(Question(str(q["id"]), str(q["text"]), None if scale is None else (scale[0], scale[1])))
    if not out and command is None:
        raise _fail("questionnaire", "give questions or a command (or leave the questionnaire out)")
    return tuple(out), command


def parse_plan(data: Any, text: str = "") -> SessionPlan:
    """A :class:`SessionPlan` from a session file's contents (a mapping); every bad field is refused by name."""
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
    for name, low in (("seed", 0), ("traffic", 0), ("countdown", 0)):
        value = data.get(name, 0)
        if isinstance(value, bool) or not isinstance(value, (int, float)) or value < low:
            raise _fail(name, f"expected a number >= {low}, got {value!r}")
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
        blocks.append(Block(name, tuple(_condition(f"{where} ({name})", fields, r) for r in routes)))
    practice = None
    if data.get("practice") is not None:
        entry = _check_fields("practice", data["practice"], ("route", *CONDITION_FIELDS))
        practice = _condition("practice", {**defaults, **entry}, entry.get("route", 0))
    questions, command = _questions(data.get("questionnaire"))
    return SessionPlan(tuple(participants), tuple(blocks), str(data.get("name", "session")), counterbalance,
                       int(data.get("seed", 0)), int(data.get("traffic", 8)), float(data.get("countdown", 3.0)),
                       bool(data.get("hide_cost", True)), practice, questions, command, text)


def load_plan(path: str | Path) -> SessionPlan:
    """Read and check a session file (YAML)."""
    path = Path(path)
    if not path.is_file():
        raise SessionFileError(f"session file {str(path)!r} does not exist")
    text = path.read_text()
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise SessionFileError(f"{path}: not valid YAML ({' '.join(str(exc).split())})") from None
    return parse_plan(data, text)


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
    for index in block_order(plan, participant):
        block = plan.blocks[index]
        for c in block.drives:
            drives.append(PlannedDrive(len(drives) + (plan.practice is None), block.name, c,
                                       derive_seed(plan.seed, c.town, c.route)))
    return drives


def _items(plan: SessionPlan, participant: str) -> list[tuple[str, Any]]:
    """The session's steps: each drive, and after each block's last drive its questionnaire."""
    items: list[tuple[str, Any]] = []
    for k, drive in enumerate(drives := drive_list(plan, participant)):
        items.append((drive.key, drive))
        last = k + 1 == len(drives) or drives[k + 1].block != drive.block
        if last and not drive.practice and (plan.questions or plan.command):
            items.append((f"questions:{drive.block}", drive.block))
    return items


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


class LabSession:
    """``participant``'s session of ``plan``, in ``out/<participant>``: drives each item not yet done, in order.

    ``window``: a person drives in one window kept open for the whole session (``controls``: their controls, or a
    class made per drive once the window is open); headless, the scripted bot drives. ``answer``: a function
    ``(question, block) -> answer`` for the questionnaire (scripted tests; default: the window, else the terminal).
    ``resume``: continue a session whose folder exists (with the same session file); without it such a folder is
    refused, so nothing is overwritten.
    """

    def __init__(self, plan: SessionPlan, participant: str, out: str | Path, window: bool = False,
                 controls: Any = None, speaker: Any = None, notice: str | None = None, answer: Answerer | None = None,
                 resume: bool = False, announce: Callable[[str], None] = print) -> None:
        self.plan, self.participant = plan, participant
        self.items = _items(plan, participant)  # refuses a participant the file does not list
        self.folder = Path(out) / participant
        self.window, self.controls, self.speaker, self.notice = window, controls, speaker, notice
        self.answer, self.announce = answer, announce
        self.total_drives = sum(not d.practice for _, d in self.items if isinstance(d, PlannedDrive))
        self.view: Any = None
        progress = self.folder / "progress.jsonl"
        if (self.folder / "plan.yaml").exists() or progress.exists():
            if not resume:
                raise SessionFileError(f"{self.folder} holds a session already: continue it with --resume "
                                       "(nothing was changed)")
            kept = (self.folder / "plan.yaml").read_text() if (self.folder / "plan.yaml").exists() else None
            if kept is not None and kept != plan.text:
                raise SessionFileError(f"{self.folder}/plan.yaml differs from the session file given: resume with "
                                       "the file the session started with (nothing was changed)")
        elif resume:
            raise SessionFileError(f"--resume: {self.folder} holds no session to continue")
        self.records = self._read_progress()

    # ----- the folder --------------------------------------------------------------------------------------
    def _read_progress(self) -> list[dict[str, Any]]:
        path = self.folder / "progress.jsonl"
        if not path.exists():
            return []
        records = []
        for line in path.read_text().splitlines():
            try:
                records.append(json.loads(line))
            except json.JSONDecodeError:  # a line cut by a kill: its item was not committed
                break
        return records

    def done_items(self) -> set[str]:
        """The items whose record is committed (a stopped drive is not done: it is driven again)."""
        return {r["item"] for r in self.records if not r.get("interrupted")}

    def _commit(self, record: dict[str, Any]) -> None:
        """Append one item's record to progress.jsonl: the point at which the item counts as done."""
        csv = self.folder / "session.csv"
        record = {**record, "csv_bytes": csv.stat().st_size if csv.exists() else 0}
        with open(self.folder / "progress.jsonl", "a") as f:
            f.write(json.dumps(record) + "\n")
            f.flush()
            os.fsync(f.fileno())
        self.records.append(record)

    def _start_folder(self) -> None:
        """Write the files a session writes once, or on resume drop what a kill left half written: the CSV's rows
        after the last committed item and a progress line cut short (they belong to no finished item)."""
        (self.folder / "drives").mkdir(parents=True, exist_ok=True)
        if not (self.folder / "plan.yaml").exists():
            (self.folder / "plan.yaml").write_text(self.plan.text)
            order = [self.plan.blocks[i].name for i in block_order(self.plan, self.participant)]
            info = {"participant": self.participant, "session": self.plan.name, "order": order,
                    "counterbalance": self.plan.counterbalance, "started": _now()}
            (self.folder / "session.json").write_text(json.dumps(info, indent=2) + "\n")
        progress = self.folder / "progress.jsonl"
        if progress.exists():
            lines = progress.read_text().splitlines(keepends=True)[: len(self.records)]
            if "".join(lines) != progress.read_text():
                progress.write_text("".join(lines))
        csv = self.folder / "session.csv"
        committed = self.records[-1]["csv_bytes"] if self.records else 0
        if csv.exists() and csv.stat().st_size > committed:
            with open(csv, "r+b") as f:
                f.truncate(committed)

    # ----- the steps ---------------------------------------------------------------------------------------
    def run(self) -> LabResult:
        """Drive (and ask) every item not yet done; stop at a stopped drive or Ctrl-C."""
        self._start_folder()
        done = self.done_items()
        todo = [(key, item) for key, item in self.items if key not in done]
        if done:
            self.announce(f"resuming {self.folder}: {len(done)} of {len(self.items)} step(s) done")
        result = LabResult(self.folder, len(done), len(self.items))
        try:
            self._open_window()
            for key, item in todo:
                if isinstance(item, PlannedDrive):
                    stopped, ctrl_c = self._drive(item)
                    if stopped:
                        result.stopped, result.ctrl_c = True, ctrl_c
                        break
                else:
                    self._ask(key, item)
                result.done += 1
            if result.finished:
                self._finish()
            self._show_end(result)
        except KeyboardInterrupt:
            result.stopped = result.ctrl_c = True
        finally:
            if self.view is not None:
                self.view.close()
                self.view = None
        return result

    def _open_window(self) -> None:
        if not self.window:
            return
        first = next(d for _, d in self.items if isinstance(d, PlannedDrive))
        self.view = PlayView(get_town(first.condition.town), window=True)

    def _meta(self, drive: PlannedDrive) -> dict[str, Any]:
        return {"session": self.plan.name, "participant": self.participant, "block": drive.block,
                "drive": drive.number, "practice": drive.practice, **drive.condition.columns()}

    def _title(self, drive: PlannedDrive) -> str:
        c = drive.condition
        head = "Practice drive" if drive.practice else f"Drive {drive.number} of {self.total_drives}"
        return f"{head}: {c.town} route {c.route}"

    def _drive(self, drive: PlannedDrive) -> tuple[bool, bool]:
        """One drive, recorded; returns (stopped, ctrl_c)."""
        # lazy: the play loop and the drives' files load torch and torchrl; a session file is checked without them
        from pernav.play.loop import PlaySession
        from pernav.trainer.drives import save_drive

        c = drive.condition
        title = self._title(drive)
        self.announce(title)
        if self.view is not None:
            show_waiting(self.view, f"{title} (a few seconds)", None, heading="Preparing the next drive")
        started = _now()
        options = PlayOptions(seed=drive.seed, n_traffic=self.plan.traffic, window=self.window,
                              countdown=self.plan.countdown, title=title, hide_cost=self.plan.hide_cost,
                              notice=self.notice, progress=title.split(":")[0])
        session = PlaySession(c.town, c.route, c.user, dict(c.context), c.policy, speaker=self.speaker, view=self.view,
                              options=options)
        if self.controls is not None:
            session.controls = self._make_controls()
        try:
            result = session.run()
        finally:
            session.close()  # leaves the session's window open: it is this session's
        m = result.metrics
        attempt = 1 + sum(r["item"] == drive.key for r in self.records)
        name = f"{drive.number:02d}-{drive.block}-{c.town}-r{c.route}" + (f"-stopped{attempt}" if m["interrupted"]
                                                                           else "")
        record = {"item": drive.key, **self._meta(drive), "seed": drive.seed, "started": started, "ended": _now(),
                  "interrupted": bool(m["interrupted"]), "file": None,
                  **{k: m[k] for k in ("completed", "time", "tracking_cost", "vehicle_collisions", "edge_strikes",
                                       "missed_turns", "reroutes") if k in m}}
        if result.trajectory is not None:
            record["file"] = save_drive(result.trajectory, {**m, **record}, self.folder / "drives",
                                        name).name
        append_csv(self.folder / "session.csv", drive_rows(result, {**self._meta(drive), "attempt": attempt}))
        self._commit(record)
        state = "stopped" if m["interrupted"] else ("arrived" if m.get("completed") else "did not arrive")
        self.announce(f"  {state} after {m.get('time', 0):.0f} s")
        return bool(m["interrupted"]), bool(result.ctrl_c)

    def _ask(self, key: str, block: str) -> None:
        """The questionnaire after ``block``: each question, then the command; the answers as CSV rows."""
        answers: dict[str, Any] = {}
        for question in self.plan.questions:
            answers[question.id] = self._answer(question, block)
        if self.plan.command is not None:
            answers.update(self._run_command(block))
        meta = {"session": self.plan.name, "participant": self.participant, "block": block}
        append_csv(self.folder / "session.csv", answer_rows(meta, answers))
        self._commit({"item": key, "block": block, "answers": answers, "ended": _now()})

    def _answer(self, question: Question, block: str) -> Any:
        if self.answer is not None:
            return self.answer(question, block)
        if self.view is not None:
            return ask_question(self.view, question.text, question.scale, title=f"After block {block!r}")
        while True:  # headless without a function: the terminal asks
            reply = input(f"{question.text} " + (f"[{question.scale[0]}-{question.scale[1]}] " if question.scale
                                                  else "") + "> ").strip()
            if question.scale is None:
                return reply
            if reply.isdigit() and question.scale[0] <= int(reply) <= question.scale[1]:
                return int(reply)

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
                answers[k.strip()] = v.strip()
        return answers

    def _finish(self) -> None:
        """summary.json: the drives whole, in order (written once, when the last item is done)."""
        drives = [r for r in self.records if r["item"].startswith("drive:") and not r.get("interrupted")]
        answers = {r["block"]: r["answers"] for r in self.records if r["item"].startswith("questions:")}
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


def _now() -> str:
    """Wall-clock time, ISO 8601 in UTC with milliseconds."""
    t = time.time()
    return time.strftime("%Y-%m-%dT%H:%M:%S", time.gmtime(t)) + f".{int(t % 1 * 1000):03d}Z"
