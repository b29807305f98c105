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

Example (the session file's order: :mod:`pernav.play.labplan`):
    >>> from pernav.play.labplan import drive_list, parse_plan
    >>> plan = parse_plan({"participants": ["P1", "P2"], "traffic": 0,
    ...                    "blocks": [{"name": "a", "routes": [0]}, {"name": "b", "policy": "oracle", "routes": [0]}]})
    >>> [d.block for d in drive_list(plan, "P1")], [d.block for d in drive_list(plan, "P2")]
    (['a', 'b'], ['b', 'a'])
"""

from __future__ import annotations

import json
import os
import subprocess
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from pernav.play import ssq
from pernav.play.framelog import COLUMNS, answer_rows, csv_text, drive_rows
from pernav.play.labdata import ANSWER_TABLE, DRIVE_TABLE, answer_table_rows, dictionary_text, drive_table_row
from pernav.play.labfolder import FolderError, ParticipantFolder, now
from pernav.play.labplan import (
    LAB_POLICIES,
    PlannedDrive,
    Question,
    SessionFileError,
    SessionPlan,
    Step,
    block_order,
    session_steps,
)
from pernav.play.options import PlayOptions
from pernav.play.questionnaire import ask_question
from pernav.play.screens import FINISHED, STOPPED, show_finished, show_panel, show_waiting, wait_for_go
from pernav.play.view import PlayView
from pernav.world.towns import get_town

__all__ = ["LabOptions", "LabResult", "LabSession", "MissingAnswer"]


class MissingAnswer(ValueError):
    """A question with no answer to read (headless, stdin ended): one line, exit 2."""


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
        self.items = session_steps(plan, participant)  # refuses a participant the file does not list
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
