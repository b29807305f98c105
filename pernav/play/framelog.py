"""A drive's record: its result (:class:`PlayResult`), a lab study's log of it at the world's frame rate, and one
tidy CSV per session.

:class:`~pernav.play.loop.PlaySession` fills a :class:`DriveLog` while it drives (one record per world frame, one per
decision step, one per prompt played) and hands it back in its :class:`PlayResult` (``result.log``);
:func:`drive_rows` turns a drive into rows of one tidy table (:data:`COLUMNS`), :func:`answer_rows` a
questionnaire's answers, and :func:`append_csv` appends rows to a session's CSV, which ``pandas.read_csv(path)``
reads without arguments. Booleans are written 1/0 and a field that does not apply to a row is left empty, so pandas
reads numbers (float64 where a column has empty cells) and text.

Columns (units in brackets):

- ``row``: ``frame`` (one per world frame, 10 per simulated second), ``prompt`` (one per decision step),
  ``drive`` (one per drive, last), ``answer`` (one per questionnaire answer).
- identity, on every row: ``session``, ``participant``, ``block``, ``position`` (the block's place in the
  participant's order: 1, 2, ...; 0 for the practice drive and what comes before the first block), ``drive`` (the
  drive's number in the session),
  ``attempt`` (1, or 2, 3, ... for a drive driven again after it was stopped), ``practice`` (1/0), and the
  condition: ``town``, ``route``, ``vehicle``, ``visual`` (the weather: normal, rgb, foggy), ``camera``,
  ``equipment``, ``policy`` and ``user`` (who the oracle times its prompts for) (what the caller's ``meta`` gives;
  ``town``, ``route`` and ``policy`` default to the drive's own).
- frame: ``frame`` (index in the drive, from 0), ``step`` (decision step it belongs to, from 0), ``wall_time``
  (unix s, when the world frame was computed), ``wall_s`` (s since the drive's clock started after the countdown;
  a pause shows as a gap), ``sim_time`` (simulated s after the frame), ``keys`` (keys held, ``+``-joined, e.g.
  ``left+throttle``; empty when none or analog controls), ``steer_input`` (-1 left .. 1 right), ``throttle_input``
  and ``brake_input`` (0 .. 1): the controls the car got that frame; ``wheel`` (-1 .. 1), ``throttle_pedal`` and
  ``brake_pedal`` (0 .. 1): a wheel's or joystick's axes before the dead zone (empty for keys); ``x``, ``y`` (m),
  ``heading`` (rad); ``speed`` (m/s), ``acceleration`` (m/s^2), ``brake`` (pedal 0 .. 1), ``steering`` (-1 .. 1 of
  the lock), ``lane_offset`` (m): exactly what the navigation senses into the trajectory's ``("next", "frames")``;
  ``events`` (``;``-joined: ``collision``, ``kerb``, ``missed_turn``, ``reroute`` (both at the end of the step the
  navigation noticed them in), ``prompt`` (the frame a prompt began)).
- prompt: ``step``, ``sim_time`` (simulated s of the decision), ``instruction`` (the chosen instruction's name,
  "no instruction" included), ``playback`` (slower, normal, faster), ``played`` (1/0: the env's prompt rule let it
  play), ``audio_start`` and ``audio_end`` (simulated s, where played), ``spoken`` (1/0: the speaker played it),
  ``reaction_s`` (s after the prompt's audio end at which the car's frames show it taking effect, as a study's
  belief learner reads a "turn" or "prepare" prompt's answer; empty where not read: :mod:`pernav.play.labdata`).
- drive: ``completed`` (1/0), ``time`` (simulated s), ``tracking_cost``, ``vehicle_collisions``, ``edge_strikes``,
  ``missed_turns``, ``reroutes`` (counts over the whole steps driven), ``interrupted`` (1/0), ``stopped_by``
  (``person``, ``ctrl-c`` or empty), ``frame_median_ms`` and ``frame_p95_ms`` (compute time of a world frame, ms),
  ``wall_start`` and ``wall_end`` (unix s of the drive's clock).
- answer: ``question``, ``answer``.

Example (the scripted bot drives three steps):
    >>> from pernav.play.loop import PlayOptions, PlaySession
    >>> result = PlaySession("Town1", 0, options=PlayOptions(n_traffic=2)).run(max_steps=3)
    >>> rows = drive_rows(result, {"session": "s1", "participant": "p01", "drive": 1})
    >>> [sum(r["row"] == kind for r in rows) for kind in ("frame", "prompt", "drive")]
    [30, 3, 1]
"""

from __future__ import annotations

import csv
import io
import math
import os
import statistics
import time
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, NamedTuple

from pernav.env.navigation import FRAME_KEYS
from pernav.world.constants import ACTION_NAMES, audio_duration
from pernav.world.controls import ControlInput

if TYPE_CHECKING:  # a drive's log and rows need no torch (a lab's session file is checked without it)
    from tensordict import TensorDictBase

__all__ = ["COLUMNS", "IDENTITY", "DriveLog", "InputTap", "PlayResult", "answer_rows", "append_csv", "csv_text",
           "drive_rows"]

IDENTITY = ("session", "participant", "block", "position", "drive", "attempt", "practice",
            "town", "route", "vehicle", "visual", "camera", "equipment", "policy", "user")
FRAME_COLUMNS = ("frame", "step", "wall_time", "wall_s", "sim_time", "keys", "steer_input", "throttle_input",
                 "brake_input", "wheel", "throttle_pedal", "brake_pedal", "x", "y", "heading", *FRAME_KEYS, "events")
PROMPT_COLUMNS = ("instruction", "playback", "played", "audio_start", "audio_end", "spoken", "reaction_s")
DRIVE_COLUMNS = ("completed", "time", "tracking_cost", "vehicle_collisions", "edge_strikes", "missed_turns",
                 "reroutes", "interrupted", "stopped_by", "frame_median_ms", "frame_p95_ms", "wall_start", "wall_end")
ANSWER_COLUMNS = ("question", "answer")
#: the session table's columns, in order (see the module's docstring)
COLUMNS = ("row", *IDENTITY, *FRAME_COLUMNS, *PROMPT_COLUMNS, *DRIVE_COLUMNS, *ANSWER_COLUMNS)
_KNOWN = frozenset(COLUMNS)
AXES = {"steer": "wheel", "throttle": "throttle_pedal", "brake": "brake_pedal"}  # axes_now()'s names -> columns


class InputTap:
    """The person's controls as the car sees them (``car.external``), keeping what the car got this frame:
    ``inputs`` (the :class:`ControlInput`), ``keys`` (the controls' ``keys`` held, where they tell) and ``axes``
    (``axes_now()`` read at the same moment, where the controls have axes). Everything else is the controls'.

    >>> from pernav.play.controls import ScriptedControls
    >>> tap = InputTap(ScriptedControls())
    >>> tap.keeps_lanes, tap.inputs, tap.axes
    (True, None, None)
    """

    def __init__(self, controls: Any) -> None:
        self.controls = controls
        self.inputs: ControlInput | None = None
        self.keys: frozenset[str] | None = None
        self.axes: dict[str, float] | None = None

    def __getattr__(self, name: str) -> Any:  # only for names not set above: keeps_lanes, poll, ...
        return getattr(self.controls, name)

    def read(self, car: Any) -> ControlInput:
        """The controls' input for this frame (kept)."""
        controls = self.controls
        self.inputs = controls.read(car)
        self.keys = getattr(controls, "keys", None)
        self.axes = controls.axes_now() if hasattr(controls, "axes_now") else None
        return self.inputs


class _Frame(NamedTuple):
    """One world frame as recorded in the real-time loop (raw: formatted only by :func:`drive_rows`)."""

    wall_time: float
    wall_s: float
    sim_time: float
    keys: frozenset[str] | None
    inputs: ControlInput | None
    axes: dict[str, float] | None
    x: float
    y: float
    heading: float
    sensed: tuple[float, ...]  # FRAME_KEYS
    collisions: int  # the world's counts so far: a frame's events are their increments
    kerbs: int


@dataclass
class DriveLog:
    """What a drive logs as it goes: ``frames`` (one per world frame), ``steps`` (per decision: simulated time,
    chosen instruction, playback) and ``prompts`` (per step that played one: audio start, audio end, spoken)."""

    frequency: int = 10
    frames: list[_Frame] = field(default_factory=list)
    steps: list[tuple[float, int, str]] = field(default_factory=list)
    prompts: dict[int, tuple[float, float, bool]] = field(default_factory=dict)
    wall_start: float = math.nan
    wall_end: float = math.nan
    clock: float = 0.0  # time.perf_counter() when the drive's clock started

    def start(self) -> None:
        """The drive's clock starts now."""
        self.wall_start, self.clock = time.time(), time.perf_counter()

    def stop(self) -> None:
        """The drive ends now (if its clock started: a drive quit on a screen before it has no times)."""
        if not math.isnan(self.wall_start):
            self.wall_end = time.time()

    def add_step(self, sim_time: float, instruction: int, playback: str) -> None:
        """A decision: the instruction chosen (played or not)."""
        self.steps.append((float(sim_time), int(instruction), playback))

    def add_prompt(self, sim_time: float, instruction: int, playback: str, spoken: bool) -> None:
        """The prompt of the current step played at ``sim_time`` (``spoken``: the speaker played it)."""
        self.prompts[len(self.steps) - 1] = (float(sim_time), float(sim_time) + audio_duration(instruction, playback),
                                             bool(spoken))

    def add_frame(self, nav: Any, tap: InputTap) -> None:
        """The world frame just computed by ``nav`` (a NavigationEnv) and the controls the car got (~10 us)."""
        world = nav.world
        ego, events = world.ego, world.events
        # the env's own sensing of this frame, as it wrote it into tau: the log's frames are tau's frames
        self.frames.append(_Frame(time.time(), time.perf_counter() - self.clock, world.time, tap.keys, tap.inputs,
                                  tap.axes, float(ego.position[0]), float(ego.position[1]), float(ego.heading),
                                  nav.last_frame, events.vehicle_collisions, events.edge_strikes))


@dataclass
class PlayResult:
    """A finished (or quit) drive: its ``[T]`` trajectory (``None`` if quit before the first step), its metrics and
    the compute time of every world frame (ms: the world, the step's bookkeeping at a second's start, drawing);
    ``ctrl_c``: Ctrl-C was pressed (the drive is kept, marked interrupted if it was cut short; the caller stops);
    ``log``: every world frame, decision and prompt as driven, a quit drive's last part second too (its rows of a
    session's CSV: :func:`drive_rows`)."""

    trajectory: TensorDictBase | None
    metrics: dict[str, Any]
    frame_ms: list[float] = field(default_factory=list)
    ctrl_c: bool = False
    log: DriveLog | None = None

    def frame_stats(self) -> dict[str, float]:
        """Median and 95th percentile of the frame times (ms)."""
        if not self.frame_ms:
            return {"median_ms": math.nan, "p95_ms": math.nan, "frames": 0}
        ordered = sorted(self.frame_ms)
        return {"median_ms": round(statistics.median(ordered), 3),
                "p95_ms": round(ordered[min(int(0.95 * len(ordered)), len(ordered) - 1)], 3), "frames": len(ordered)}


def _identity(meta: Mapping[str, Any], defaults: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """The identity columns of ``meta`` over ``defaults``; a key that is no identity column is a ValueError."""
    unknown = sorted(set(meta) - set(IDENTITY), key=str)
    if unknown:
        raise ValueError(f"unknown identity field {unknown[0]!r}; allowed: {', '.join(IDENTITY)}")
    return {**{k: v for k, v in (defaults or {}).items() if k in IDENTITY}, **meta}


def _step_events(trajectory: Any) -> dict[int, list[str]]:
    """Per whole step, the missed turns and re-routes the navigation counted at its end."""
    if trajectory is None:
        return {}
    out: dict[int, list[str]] = {}
    for key, name in (("missed_turns", "missed_turn"), ("reroutes", "reroute")):
        counts = [0, *trajectory["next", key].reshape(-1).tolist()]
        for t in range(len(counts) - 1):
            if counts[t + 1] > counts[t]:
                out.setdefault(t, []).append(name)
    return out


def _keys_text(frame: _Frame) -> str:
    """The keys held: the controls' own names, else those a digital input implies (a keyboard)."""
    keys, inputs = frame.keys, frame.inputs
    if keys is None and inputs is not None and inputs.digital:
        keys = {name for name, on in (("left", inputs.steer < 0), ("right", inputs.steer > 0),
                                      ("throttle", inputs.throttle > 0), ("brake", inputs.brake > 0)) if on}
    return "+".join(sorted(keys or ()))


def _frame_rows(log: DriveLog, ids: Mapping[str, Any], step_events: Mapping[int, list[str]]) -> list[dict[str, Any]]:
    rows = []
    collisions = kerbs = 0
    f = log.frequency
    for k, fr in enumerate(log.frames):
        step = k // f
        events = ["collision"] * (fr.collisions > collisions) + ["kerb"] * (fr.kerbs > kerbs)
        if k % f == f - 1:
            events += step_events.get(step, [])
        if k % f == 0 and step in log.prompts:
            events.append("prompt")
        collisions, kerbs = fr.collisions, fr.kerbs
        inputs = fr.inputs
        row = {"row": "frame", **ids, "frame": k, "step": step, "wall_time": fr.wall_time, "wall_s": fr.wall_s,
               "sim_time": fr.sim_time, "keys": _keys_text(fr), "x": fr.x, "y": fr.y, "heading": fr.heading,
               **dict(zip(FRAME_KEYS, fr.sensed, strict=True)), "events": ";".join(events)}
        if inputs is not None:
            row.update(steer_input=inputs.steer, throttle_input=inputs.throttle, brake_input=inputs.brake)
        if fr.axes is not None:
            row.update({AXES[name]: value for name, value in fr.axes.items() if name in AXES})
        rows.append(row)
    return rows


def _prompt_rows(log: DriveLog, ids: Mapping[str, Any]) -> list[dict[str, Any]]:
    rows = []
    for step, (sim_time, instruction, playback) in enumerate(log.steps):
        row = {"row": "prompt", **ids, "step": step, "sim_time": sim_time, "instruction": ACTION_NAMES[instruction],
               "playback": playback, "played": step in log.prompts, "spoken": False}
        if step in log.prompts:
            row["audio_start"], row["audio_end"], row["spoken"] = log.prompts[step]
        rows.append(row)
    return rows


def drive_rows(result: PlayResult, meta: Mapping[str, Any]) -> list[dict[str, Any]]:
    """A drive's rows of the session table: its frames, its decision steps (prompts), then the drive itself.

    ``meta`` fills the identity columns (:data:`IDENTITY`; ``town``, ``route`` and ``policy`` default to the
    drive's); a drive without a log (``result.log`` None) has its drive row only.
    """
    m = result.metrics
    ids = _identity(meta, m)
    log = result.log
    rows = [] if log is None else [*_frame_rows(log, ids, _step_events(result.trajectory)), *_prompt_rows(log, ids)]
    stats = result.frame_stats()
    drive = {"row": "drive", **ids, **{k: m[k] for k in DRIVE_COLUMNS if k in m},
             "frame_median_ms": stats["median_ms"], "frame_p95_ms": stats["p95_ms"]}
    if log is not None:
        drive.update(wall_start=log.wall_start, wall_end=log.wall_end)
    return [*rows, drive]


def answer_rows(meta: Mapping[str, Any], answers: Mapping[str, Any]) -> list[dict[str, Any]]:
    """One row per questionnaire answer (``{question: answer}``), identified by ``meta``.

    >>> answer_rows({"participant": "p01", "drive": 2}, {"workload": 4})
    [{'row': 'answer', 'participant': 'p01', 'drive': 2, 'question': 'workload', 'answer': 4}]
    """
    ids = _identity(meta)
    return [{"row": "answer", **ids, "question": str(q), "answer": a} for q, a in answers.items()]


def _cell(value: Any) -> Any:
    """A value as written: booleans 1/0, missing (None, NaN) empty, numpy scalars as Python's."""
    if hasattr(value, "item") and not isinstance(value, (str, bytes)):
        value = value.item()  # numpy and torch scalars
    if isinstance(value, bool):
        return int(value)
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return ""
    return value


def csv_text(rows: Iterable[Mapping[str, Any]], columns: Iterable[str], header: bool = False) -> str:
    """``rows`` as CSV lines of ``columns`` (missing fields empty, booleans 1/0), the header line first if asked.

    >>> csv_text([{"a": True, "b": None}], ("a", "b"), header=True)
    'a,b\\n1,\\n'
    """
    columns = tuple(columns)
    text = io.StringIO()
    writer = csv.writer(text, lineterminator="\n")
    if header:
        writer.writerow(columns)
    writer.writerows([_cell(row.get(c)) for c in columns] for row in rows)
    return text.getvalue()


def append_csv(path: str | os.PathLike[str], rows: Iterable[Mapping[str, Any]]) -> Path:
    """Append ``rows`` to the session table at ``path`` (:data:`COLUMNS` in order, missing fields empty): the
    header only when the file is new; existing lines are never rewritten. A field that is not a column, or an
    existing file with another header, is a ValueError (nothing written).

    >>> import tempfile
    >>> path = Path(tempfile.mkdtemp()) / "session.csv"
    >>> _ = append_csv(path, answer_rows({"participant": "p01"}, {"workload": 4}))
    >>> _ = append_csv(path, answer_rows({"participant": "p01"}, {"effort": 3}))
    >>> import pandas; pandas.read_csv(path)[["row", "participant", "question", "answer"]].values.tolist()
    [['answer', 'p01', 'workload', 4], ['answer', 'p01', 'effort', 3]]
    """
    path = Path(path)
    rows = list(rows)
    for row in rows:
        unknown = sorted(set(row) - _KNOWN, key=str)
        if unknown:
            raise ValueError(f"unknown field {unknown[0]!r}: not a column of the session table")
    new = not path.exists() or path.stat().st_size == 0
    if not new:
        with path.open(newline="") as f:
            header = next(csv.reader(f), [])
        if tuple(header) != COLUMNS:
            raise ValueError(f"{path} has other columns than this session table's: not appended")
    with path.open("a", newline="") as f:  # one write, then to disk: a lab's data survives a crash after it
        f.write(csv_text(rows, COLUMNS, header=new))
        f.flush()
        os.fsync(f.fileno())
    return path
