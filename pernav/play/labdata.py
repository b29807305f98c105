"""A lab session's data ready for analysis: the tidy per-drive and per-answer tables beside the frame-level
``session.csv`` (:mod:`pernav.play.framelog`), the data dictionary written with them, and the reaction to each
prompt read from the car's frames.

- ``drives.csv``: one row per drive driven (a stopped attempt too, ``interrupted`` 1), with the block's place in the
  participant's order, the conditions, the drive's number, its wall-clock times and its measures.
- ``answers.csv``: one row per answer (the block's questionnaire, the simulator-sickness questionnaire and its
  scores), with the block's place in the order, the conditions of the block just driven, the number of the last
  drive before it and when it was given; ``value`` holds a numeric answer, ``text`` a free-text one.
- ``dictionary.csv``: every column of the three tables: ``table``, ``column``, ``type`` (int, float, text), ``unit``
  and ``meaning``.

Whole-number columns are never empty (pandas reads them as int64); a float column's empty cell is a measure that does
not apply (NaN).

The reaction to a prompt (``reaction_s``) is read as a study's belief learner reads a prompt's answer
(:func:`pernav.play.labpersonal.prompt_reactions`: :func:`pernav.learners.belief.answers_of` and the study's
answer detector): the candidate frames from 0.25 s to 9 s after a
"turn" or "prepare" prompt's audio end are scored as the moment the prompt took effect (the car began to slow, to
change lane, to turn); the reaction is that moment's delay after the audio end when the detector reads an answer at
all (probability at least one half), else empty. A session reads it with the detector of the finished study it names
(``study:``) for the drive's town; without one the column stays empty.

Example:
    >>> [c for c in DICTIONARY if c[0] == "drives.csv"][:3]  # doctest: +NORMALIZE_WHITESPACE
    [('drives.csv', 'session', 'text', '', "the session's name (the session file's name)"),
     ('drives.csv', 'participant', 'text', '', "the participant's id"),
     ('drives.csv', 'position', 'int', '', "the block's place in the participant's order (1, 2, ...; 0: the practice
     drive)")]
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

from pernav.play.framelog import COLUMNS, csv_text
from pernav.world.constants import TURNS

__all__ = ["ANSWER_TABLE", "DICTIONARY", "DRIVE_TABLE", "TABLES", "answer_table_rows", "dictionary_text",
           "drive_table_row"]

_ID = [("session", "text", "", "the session's name (the session file's name)"),
       ("participant", "text", "", "the participant's id")]
_CONDITIONS = [
    ("town", "text", "", "the town driven"),
    ("vehicle", "text", "", "the car (empty: the user's own)"),
    ("visual", "text", "", "the weather: normal, rgb, foggy (empty: the user's own)"),
    ("camera", "text", "", "the view: third_person, first_person, top (empty: the user's own)"),
    ("equipment", "text", "", "the controls the condition names (empty: the user's own)"),
    ("policy", "text", "", "who chose the prompts: explore, oracle, or a learner of the study (belief, adapt, ...)"),
    ("user", "text", "", "whom the oracle times its prompts for"),
    ("counters", "int", "", "1: collisions, missed turns and re-routes were shown live; 0: not"),
]
#: the per-drive table's columns: (column, type, unit, meaning)
DRIVE_TABLE = [
    *_ID,
    ("position", "int", "", "the block's place in the participant's order (1, 2, ...; 0: the practice drive)"),
    ("block", "text", "", "the block's name (never shown to the participant)"),
    ("drive", "int", "", "the drive's number in the session (0: the practice drive)"),
    ("attempt", "int", "", "1, or 2, 3, ... for a drive driven again after it was stopped"),
    ("practice", "int", "", "1: the practice drive; 0: a block's"),
    ("route", "int", "", "the route's index in its town"),
    *_CONDITIONS,
    ("seed", "int", "", "the world's seed (the same route meets the same traffic in every block)"),
    ("completed", "int", "", "1: arrived at the destination"),
    ("interrupted", "int", "", "1: stopped before its end (Esc then Y, or Ctrl-C): driven again on resume"),
    ("time", "float", "s", "simulated time driven"),
    ("tracking_cost", "float", "cost units", "the study's tracking cost summed over the drive's steps (lower: "
     "closer to the route at the planned speed)"),
    ("collisions", "int", "count", "vehicle_collisions + edge_strikes (the study's collisions)"),
    ("vehicle_collisions", "int", "count", "collisions with other cars"),
    ("edge_strikes", "int", "count", "kerb strikes"),
    ("missed_turns", "int", "count", "junctions where the car left the route"),
    ("reroutes", "int", "count", "times the navigation planned a new route"),
    ("prompts", "int", "count", "prompts played"),
    ("turn_prompts", "int", "count", "\"turn\" prompts played"),
    ("reactions", "int", "count", "prompts whose reaction was read (reaction_s in session.csv)"),
    ("reaction_mean_s", "float", "s", "mean reaction to the prompts whose reaction was read"),
    ("reaction_turn_s", "float", "s", "mean reaction to a \"turn\" prompt (empty: none read)"),
    ("started", "text", "ISO 8601 UTC", "wall-clock time the drive was prepared"),
    ("ended", "text", "ISO 8601 UTC", "wall-clock time the drive ended"),
    ("wall_start", "float", "unix s", "wall-clock time the drive's clock started (after the countdown)"),
    ("wall_end", "float", "unix s", "wall-clock time the drive's clock stopped"),
    ("file", "text", "", "the drive's recorded tau in drives/ (empty: stopped before its first step)"),
]
#: the per-answer table's columns
ANSWER_TABLE = [
    *_ID,
    ("questionnaire", "text", "", "block (the session file's questions after a block), command (its command's "
     "answers), ssq (the simulator-sickness questionnaire), learned (the participant read what the navigation "
     "learned of them)"),
    ("when", "text", "", "before (the first drive), after_block, after (the last block)"),
    ("position", "int", "", "the place in the order of the block just driven (0: before the first block)"),
    ("block", "text", "", "the block just driven (empty: before the first block, or after the last for ssq after)"),
    ("drive", "int", "", "the number of the last drive before the answer (0: none yet, or the practice drive)"),
    *_CONDITIONS[:1], *_CONDITIONS[5:7],
    ("question", "text", "", "the question's id (ssq_...: a symptom, rated 0-3, or a score)"),
    ("value", "float", "", "a numeric answer: a scale's rating, an SSQ rating (0 none .. 3 severe) or score "
     "(weighted: nausea 9.54, oculomotor 7.58, disorientation 13.92, total 3.74)"),
    ("text", "text", "", "a free-text answer"),
    ("asked", "text", "ISO 8601 UTC", "wall-clock time the answers were committed"),
]
#: the frame-level table's columns (pernav.play.framelog's docstring in one line each)
_SESSION_MEANINGS = {
    "row": ("text", "", "frame, prompt, drive or answer"),
    "attempt": ("float", "", "1, 2, ...: the drive's attempt (empty in answer rows)"),
    "frame": ("float", "", "frame index in the drive (frame rows)"),
    "step": ("float", "", "decision step (one per simulated second)"),
    "wall_time": ("float", "unix s", "when the world frame was computed"),
    "wall_s": ("float", "s", "since the drive's clock started"), "sim_time": ("float", "s", "simulated time"),
    "keys": ("text", "", "keys held, +-joined"), "steer_input": ("float", "-1..1", "steering the car got"),
    "throttle_input": ("float", "0..1", "throttle the car got"), "brake_input": ("float", "0..1", "brake the car got"),
    "wheel": ("float", "-1..1", "a wheel's raw axis"), "throttle_pedal": ("float", "0..1", "raw throttle axis"),
    "brake_pedal": ("float", "0..1", "raw brake axis"), "x": ("float", "m", "car position"),
    "y": ("float", "m", "car position"), "heading": ("float", "rad", "car heading"),
    "speed": ("float", "m/s", "car speed"), "acceleration": ("float", "m/s^2", "car acceleration"),
    "brake": ("float", "0..1", "brake pedal as sensed"), "steering": ("float", "-1..1", "steering as sensed"),
    "lane_offset": ("float", "m", "offset from the lane centre"),
    "events": ("text", "", "collision, kerb, missed_turn, reroute, prompt (;-joined)"),
    "instruction": ("text", "", "the instruction chosen"), "playback": ("text", "", "slower, normal, faster"),
    "played": ("float", "", "1: the prompt played"), "audio_start": ("float", "s", "simulated time the audio began"),
    "audio_end": ("float", "s", "simulated time the audio ended"), "spoken": ("float", "", "1: the speaker played it"),
    "reaction_s": ("float", "s", "reaction to the prompt after its audio end, as the belief reads it"),
    "stopped_by": ("text", "", "person, ctrl-c or empty"),
    "frame_median_ms": ("float", "ms", "median compute time of a world frame"),
    "frame_p95_ms": ("float", "ms", "95th percentile compute time of a world frame"),
    "question": ("text", "", "the question's id"), "answer": ("text", "", "the answer as given"),
}
TABLES = {"drives.csv": DRIVE_TABLE, "answers.csv": ANSWER_TABLE}
#: the whole-number columns of session.csv that no row leaves empty
SESSION_INTS = ("position", "drive", "practice")


def _dictionary() -> list[tuple[str, str, str, str, str]]:
    known = {c[0]: c for c in DRIVE_TABLE + ANSWER_TABLE}
    session = []
    for column in COLUMNS:
        if column in _SESSION_MEANINGS:
            kind, unit, meaning = _SESSION_MEANINGS[column]
        elif column in known:
            _, kind, unit, meaning = known[column]
            kind = kind if kind != "int" or column in SESSION_INTS else "float"  # empty in some rows
        else:  # pragma: no cover - a new column of session.csv must be described above
            raise AssertionError(f"session.csv column {column!r} has no meaning in the data dictionary")
        session.append(("session.csv", column, kind, unit, meaning))
    return session + [(t, *c) for t, cols in TABLES.items() for c in cols]


#: every column of session.csv, drives.csv and answers.csv: (table, column, type, unit, meaning)
DICTIONARY = _dictionary()


def dictionary_text() -> str:
    """``dictionary.csv``: the data dictionary (header, then one line per column)."""
    names = ("table", "column", "type", "unit", "meaning")
    return csv_text([dict(zip(names, c, strict=True)) for c in DICTIONARY], names, header=True)


def _int(value: Any) -> int:
    return 0 if value is None or (isinstance(value, float) and math.isnan(value)) else int(value)


def _mean(values: Sequence[float]) -> float | None:
    return round(sum(values) / len(values), 4) if values else None


def drive_table_row(record: Mapping[str, Any], reactions: Sequence[tuple[int, float]], prompts: Sequence[int]
                    ) -> dict[str, Any]:
    """A drive's row of ``drives.csv``: its progress record, the (instruction, reaction s) of its prompts whose
    reaction was read and the instructions of the prompts it played."""
    row = {name: record.get(name) for name, *_ in DRIVE_TABLE}
    for name, kind, *_ in DRIVE_TABLE:
        if kind == "int":
            row[name] = _int(record.get(name))
    turns = [r for i, r in reactions if i in TURNS]
    row["collisions"] = row["vehicle_collisions"] + row["edge_strikes"]
    row.update(prompts=len(prompts), turn_prompts=sum(i in TURNS for i in prompts), reactions=len(reactions),
               reaction_mean_s=_mean([r for _, r in reactions]), reaction_turn_s=_mean(turns))
    return row


def answer_table_rows(meta: Mapping[str, Any], answers: Mapping[str, Any]) -> list[dict[str, Any]]:
    """The rows of ``answers.csv`` for one questionnaire's ``answers`` (``{question: answer}``): a number in
    ``value``, text in ``text``; ``meta``: the other columns."""
    rows = []
    for question, answer in answers.items():
        number = isinstance(answer, (int, float)) and not isinstance(answer, bool)
        row = {**{name: meta.get(name) for name, *_ in ANSWER_TABLE}, "question": str(question),
               "value": answer if number else None, "text": None if number else str(answer)}
        for name, kind, *_ in ANSWER_TABLE:
            if kind == "int":
                row[name] = _int(row[name])
        rows.append(row)
    return rows
