"""The lab's log of a drive (pernav.play.framelog): every world frame, every decision and prompt, one tidy CSV."""

from __future__ import annotations

import math
import os

import numpy as np
import pandas as pd
import pytest
from play_helpers import FrameScript

from pernav.env.navigation import FRAME_KEYS
from pernav.play.controls import JoystickControls, ScriptedControls
from pernav.play.framelog import COLUMNS, answer_rows, append_csv, drive_rows
from pernav.play.loop import PlaySession
from pernav.play.options import PlayOptions
from pernav.world.constants import ACTION_NAMES, PLAYBACK
from pernav.world.controls import ControlInput

os.environ.setdefault("SDL_VIDEODRIVER", "dummy")  # nothing drawn on screen
os.environ.setdefault("SDL_AUDIODRIVER", "dummy")  # and no sound

STEPS = 6
META = {"session": "s1", "participant": "p01", "block": 1, "drive": 1, "practice": False, "vehicle": "car",
        "visual": "foggy", "camera": "top", "equipment": "keyboard"}


class _Speaker:
    """A speaker that plays every other prompt (its device drops out in between)."""

    def __init__(self) -> None:
        self.said: list[tuple[int, str]] = []

    def say(self, instruction: int, playback: str) -> bool:
        self.said.append((instruction, playback))
        return len(self.said) % 2 == 1


def _rows(rows: list[dict], kind: str) -> list[dict]:
    return [r for r in rows if r["row"] == kind]


@pytest.fixture(scope="module")
def drive():
    """The scripted bot drives a few steps of Town1's route 0 (headless), with a speaker that sometimes fails."""
    session = PlaySession("Town1", 0, speaker=_Speaker(), options=PlayOptions(n_traffic=2, seed=0))
    return session.run(max_steps=STEPS), session.speaker


def test_one_frame_row_per_world_frame_and_they_are_taus_frames(drive):
    result, _ = drive
    rows = drive_rows(result, META)
    frames = _rows(rows, "frame")
    assert [r["row"] for r in rows] == ["frame"] * 10 * STEPS + ["prompt"] * STEPS + ["drive"]
    assert [r["frame"] for r in frames] == list(range(10 * STEPS))
    assert [r["step"] for r in frames] == [k // 10 for k in range(10 * STEPS)]
    logged = np.array([[r[k] for k in FRAME_KEYS] for r in frames], dtype=np.float32)
    assert np.array_equal(logged, result.trajectory["next", "frames"].reshape(-1, len(FRAME_KEYS)).numpy())
    sim = np.array([r["sim_time"] for r in frames])
    assert np.allclose(sim, 0.1 * np.arange(1, 10 * STEPS + 1))
    wall = np.array([r["wall_s"] for r in frames])
    assert (np.diff(wall) > 0).all() and (np.diff([r["wall_time"] for r in frames]) >= 0).all()
    assert {r["keys"] for r in frames} <= {"", "left", "right", "throttle", "brake", "left+throttle",
                                           "right+throttle", "brake+left", "brake+right"}
    assert any("throttle" in r["keys"] and r["throttle_input"] == 1.0 for r in frames)  # the bot's keys and inputs
    assert all(r.get("wheel") is None for r in frames)  # keys have no axes
    assert frames[-1]["x"] == pytest.approx(float(result.trajectory[-1]["next", "observation"][0]), abs=1e-4)


def test_prompt_rows_are_the_chosen_instructions_and_what_played(drive):
    result, speaker = drive
    prompts = _rows(drive_rows(result, META), "prompt")
    traj = result.trajectory
    assert [r["instruction"] for r in prompts] == [ACTION_NAMES[a] for a in traj["action"].reshape(-1).tolist()]
    played = traj["next", "played"].reshape(-1).tolist()
    assert [r["played"] for r in prompts] == played and any(played)
    assert [r["sim_time"] for r in prompts] == pytest.approx(list(range(STEPS)))
    for row, end in zip(prompts, traj["next", "prompt_end"].reshape(-1).tolist(), strict=True):
        if row["played"]:
            assert row["audio_end"] == pytest.approx(end, abs=1e-5) and row["audio_start"] == row["sim_time"]
        else:
            assert "audio_start" not in row and not row["spoken"]
    # the speaker heard every prompt played, and told which it did not play
    assert [ACTION_NAMES[i] for i, _ in speaker.said] == [r["instruction"] for r in prompts if r["played"]]
    assert [r["spoken"] for r in prompts if r["played"]] == [k % 2 == 0 for k in range(len(speaker.said))]
    first = next(r["step"] for r in prompts if r["played"])
    assert "prompt" in _rows(drive_rows(result, META), "frame")[10 * first]["events"]


def test_prompt_rows_of_a_21_action_env_name_instruction_and_playback():
    result = PlaySession("Town1", 0, options=PlayOptions(n_traffic=0, playback="faster")).run(max_steps=3)
    prompts = _rows(drive_rows(result, {}), "prompt")
    actions = result.trajectory["action"].reshape(-1).tolist()
    assert [(r["instruction"], r["playback"]) for r in prompts] == [(ACTION_NAMES[a // 3], PLAYBACK[a % 3])
                                                                     for a in actions]
    assert [r["spoken"] for r in prompts] == [False] * 3  # no speaker


def test_events_and_a_persons_analog_inputs_are_logged():
    script = FrameScript(lambda frame: ControlInput(steer=1.0 if frame > 30 else 0.0, throttle=1.0))
    result = PlaySession("Town1", 0, controls=script, options=PlayOptions(n_traffic=0)).run(max_steps=15)
    frames = _rows(drive_rows(result, {}), "frame")
    kerbs = sum("kerb" in r["events"].split(";") for r in frames)
    assert kerbs == result.metrics["edge_strikes"] >= 1
    assert [r["steer_input"] for r in frames[29:32]] == [0.0, 1.0, 1.0] and {r["keys"] for r in frames} == {""}
    reroutes = sum("reroute" in r["events"] for r in frames)
    assert reroutes == result.metrics["reroutes"]
    assert all(r["frame"] % 10 == 9 for r in frames if "reroute" in r["events"])  # at the end of its step


class _Stick:
    """A wheel with one pedal axis, turned a little left, the pedal a third pressed."""

    def get_numaxes(self) -> int:
        return 2

    def get_name(self) -> str:
        return "test wheel"

    def get_axis(self, axis: int) -> float:
        return (-0.25, -0.3)[axis]


def test_a_wheels_axes_are_logged():
    controls = JoystickControls(stick=_Stick())
    result = PlaySession("Town1", 0, controls=controls, options=PlayOptions(n_traffic=0)).run(max_steps=2)
    frames = _rows(drive_rows(result, {}), "frame")
    assert len(frames) == 20
    assert {(r["wheel"], r["throttle_pedal"], r["brake_pedal"]) for r in frames} == {(-0.25, 0.3, 0.0)}
    assert {(r["steer_input"], r["throttle_input"], r["brake_input"]) for r in frames} == {(-0.25, 0.3, 0.0)}


def test_session_csv_reads_with_pandas_and_appends_never_rewrite(drive, tmp_path):
    result, _ = drive
    path = tmp_path / "session.csv"
    append_csv(path, drive_rows(result, META))
    first = path.read_bytes()
    quit_drive = PlaySession("Town1", 1, controls=ScriptedControls(quit_after=12), options=PlayOptions(n_traffic=2)).run()
    append_csv(path, [*drive_rows(quit_drive, {**META, "drive": 2}),
                      *answer_rows({**META, "drive": 2}, {"workload": 4, "comment": "too fast, at times"})])
    assert path.read_bytes().startswith(first) and first.count(b"\n") == 10 * STEPS + STEPS + 2  # header too
    df = pd.read_csv(path)
    assert tuple(df.columns) == COLUMNS
    assert df["row"].value_counts().to_dict() == {"frame": 10 * STEPS + 12, "prompt": STEPS + 2, "drive": 2,
                                                  "answer": 2}
    for column in ("wall_time", "sim_time", "speed", "lane_offset", "played", "spoken", "completed", "audio_end"):
        assert df[column].dtype == np.float64, column
    for column in ("frame", "step"):  # numbers where they apply, empty elsewhere
        assert df[column].dtype == np.float64 and df.loc[df["row"] == "frame", column].notna().all()
    assert df["drive"].dtype == np.int64 and df["practice"].dtype == np.int64 and (df["practice"] == 0).all()
    driven = df[df["row"] != "answer"]  # the town and route are the drive's own; answers have the caller's meta only
    assert set(driven["town"]) == {"Town1"} and set(driven["route"]) == {0, 1} and set(df["participant"]) == {"p01"}
    drives = df[df["row"] == "drive"].set_index("drive")
    assert drives.loc[1, "interrupted"] == 0 and drives.loc[2, "interrupted"] == 1
    assert drives.loc[2, "stopped_by"] == "person" and math.isnan(drives.loc[1, "stopped_by"])
    assert drives.loc[1, "wall_end"] >= drives.loc[1, "wall_start"] > 1.6e9
    answers = df[df["row"] == "answer"]
    assert answers["answer"].tolist() == ["4", "too fast, at times"]
    frames = df[df["row"] == "frame"].iloc[: 10 * STEPS]
    assert np.allclose(frames[list(FRAME_KEYS)].to_numpy(dtype=np.float32),
                       result.trajectory["next", "frames"].reshape(-1, len(FRAME_KEYS)).numpy())


def test_unknown_fields_and_other_tables_are_refused(tmp_path):
    path = tmp_path / "session.csv"
    with pytest.raises(ValueError, match="'speedy'"):
        append_csv(path, [{"row": "frame", "frame": 0}, {"row": "frame", "speedy": 1.0}])
    assert not path.exists()  # nothing written
    with pytest.raises(ValueError, match="'colour'"):
        answer_rows({"participant": "p01", "colour": "red"}, {"workload": 3})
    other = tmp_path / "other.csv"
    other.write_text("a,b\n1,2\n")
    with pytest.raises(ValueError, match="other columns"):
        append_csv(other, answer_rows({}, {"workload": 3}))
    assert other.read_text() == "a,b\n1,2\n"


def test_a_quit_drive_logs_what_was_driven():
    result = PlaySession("Town1", 0, controls=ScriptedControls(quit_after=25), options=PlayOptions(n_traffic=2)).run()
    rows = drive_rows(result, {"participant": "p02"})
    assert result.trajectory.shape[0] == 2  # the third second was cut short ...
    assert len(_rows(rows, "frame")) == 25 and len(_rows(rows, "prompt")) == 3  # ... but its frames and decision are logged
    (last,) = _rows(rows, "drive")
    assert last["interrupted"] and last["stopped_by"] == "person" and last["town"] == "Town1"
    assert last["wall_end"] >= last["wall_start"]
