"""`pernav play`: a person (here a scripted bot or a test controller) at the wheel, through the same world."""

from __future__ import annotations

import json
import math
import os
import shutil
import time

import numpy as np
import pytest
import torch
from play_helpers import FrameScript

from pernav.cli import main
from pernav.env.navigation import NavigationEnv
from pernav.play.controls import ScriptedControls
from pernav.play.loop import PlaySession
from pernav.play.options import PlayOptions
from pernav.trainer.drives import load_drive, read_metrics, save_drive
from pernav.world.controls import ControlInput

os.environ.setdefault("SDL_VIDEODRIVER", "dummy")  # windows drawn off screen
os.environ.setdefault("SDL_AUDIODRIVER", "dummy")  # and no sound

METRICS = ("tracking_cost", "vehicle_collisions", "edge_strikes", "missed_turns", "wrong_turns", "reroutes",
           "completed", "time")


@pytest.fixture(scope="module")
def bot_drive():
    """The scripted bot drives Town1's route 0 through the play loop (headless)."""
    return PlaySession("Town1", 0, options=PlayOptions(n_traffic=2, seed=0)).run()


@pytest.mark.slow
def test_bot_drives_a_whole_route(bot_drive):
    m = bot_drive.metrics
    assert m["completed"] and not m["interrupted"]
    assert m["steps"] == bot_drive.trajectory.shape[0] > 60
    for key in ("vehicle_collisions", "edge_strikes", "missed_turns", "reroutes"):
        assert isinstance(m[key], int) and m[key] >= 0
    assert len(bot_drive.frame_ms) == 10 * m["steps"]  # one callback per world frame
    assert bot_drive.frame_stats()["median_ms"] < 50


def _reckless() -> FrameScript:
    """Full throttle, and from the third second the wheel hard right: the car must hit the kerb."""
    return FrameScript(lambda frame: ControlInput(steer=1.0 if frame > 30 else 0.0, throttle=1.0))


def test_events_are_counted_for_a_person():
    result = PlaySession("Town1", 0, controls=_reckless(), options=PlayOptions(n_traffic=0)).run(max_steps=15)
    assert result.metrics["edge_strikes"] >= 1
    assert result.trajectory["next", "edge_strikes"][-1] == result.metrics["edge_strikes"]


class _RouteFollower:
    """A steady analog driver (a wheel and pedals) who follows the route's line at 7 m/s: the car's lanes and its
    choices at junctions are found from where it drives alone (no simulated decisions)."""

    keeps_lanes = False
    quit_requested = False

    def __init__(self, env: NavigationEnv) -> None:
        self.env = env

    def poll(self) -> None:
        pass

    def read(self, car) -> ControlInput:
        route = self.env.route
        progress, _ = route.project(car.position, hint=self.env.progress)
        target = route.point_at(progress + max(car.speed, 3.0) * 1.2)
        aim = math.atan2(target[1] - car.position[1], target[0] - car.position[0])
        turn = (aim - car.heading + math.pi) % (2 * math.pi) - math.pi
        return ControlInput(steer=float(np.clip(2.5 * turn, -1, 1)), throttle=0.6 if car.speed < 7.0 else 0.0,
                            brake=0.3 if car.speed > 8.5 else 0.0)


@pytest.mark.slow
def test_lanes_and_choices_of_a_person_are_found_from_where_the_car_is():
    env = NavigationEnv("Town1", config={"n_traffic": 0})
    _, info = env.reset(seed=0, options={"route": 0})
    env.world.ego.external = _RouteFollower(env)
    done = False
    while not done:
        _, _, term, trunc, info = env.step(0)  # no prompts at all: the person knows the way
        done = term or trunc
    ego = env.world.ego
    assert info["completed"] and info["missed_turns"] == info["wrong_turns"] == info["reroutes"] == 0
    decisions = [m for m in env.route.manoeuvres if m.decision and m.kind in ("left", "right", "straight")]
    assert decisions and all(ego.last_choice.get(m.node) == m.kind for m in decisions)
    assert ego.path[0][:2] in env.route.roads


def _simulated(hooks: bool) -> dict:
    env = NavigationEnv("Town1", config={"n_traffic": 8})
    _, info = env.reset(seed=0, options={"route": 0, "user": "user3"})
    if hooks:  # the extension present but unused: observers that do nothing, controls set and taken away
        env.on_frame, env.on_prompt = (lambda: None), (lambda i, p: None)
        env.world.ego.external = ScriptedControls()
        env.world.ego.external = None
    done = False
    while not done:
        _, _, term, trunc, info = env.step(info["explore_action"])
        done = term or trunc
    return {k: info[k] for k in METRICS}


@pytest.mark.slow
def test_simulated_drivers_are_unchanged_by_the_extension():
    plain = _simulated(hooks=False)
    assert _simulated(hooks=True) == plain
    # the figure of `pernav drive --town Town1 --policy explore --user user3 --routes 0` before the extension
    assert plain["completed"] and plain["time"] == 179.0
    assert plain["tracking_cost"] == pytest.approx(349.1481049516626, rel=1e-6)  # another CPU: 349.14810494758467


@pytest.mark.slow
def test_recorded_drive_trains_a_model(bot_drive, tmp_path):
    from pernav.env.torchrl_env import explore_module
    from pernav.model import DynamicsModel
    from pernav.trainer import FTMLTrainer, RoundBuffers, TrainConfig
    from pernav.trainer.collect import drive, history_env

    path = save_drive(bot_drive.trajectory, bot_drive.metrics, tmp_path, "drive")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["drive.json", "drive.pt"]  # no temporary file left
    td = load_drive(path)
    assert read_metrics(path)["completed"] is True
    # the keys of the study's own trajectories
    study = drive(history_env("Town1", {"route": 0}, config={"n_traffic": 2}, seed=0), explore_module(), max_steps=3)
    assert set(td.keys(True, True)) == set(study.keys(True, True))
    assert (td["action"] == bot_drive.trajectory["action"]).all()
    buffers = RoundBuffers(L=3, seed=0)
    buffers.add(0, td, tau=True)
    buffers.add(0, study)
    trainer = FTMLTrainer(DynamicsModel(hidden=(16,)), buffers, TrainConfig(batch=8, L=3, hidden=[16]), seed=0)
    trainer.fit_normalization()
    assert math.isfinite(trainer.plain_update())


def test_interrupted_save_leaves_nothing(bot_drive, tmp_path, monkeypatch):
    def broken(*args, **kwargs):
        raise OSError("disk full")

    monkeypatch.setattr(torch, "save", broken)
    with pytest.raises(OSError):
        save_drive(bot_drive.trajectory, bot_drive.metrics, tmp_path, "drive")
    assert list(tmp_path.iterdir()) == []


def test_quit_mid_drive_keeps_the_whole_steps():
    result = PlaySession("Town1", 0, controls=ScriptedControls(quit_after=25), options=PlayOptions(n_traffic=2)).run()
    assert result.metrics["interrupted"] and not result.metrics["completed"]
    assert result.trajectory.shape[0] == 2  # the third second was cut short: not recorded


@pytest.mark.slow
def test_cli_records_a_headless_drive(tmp_path, capsys):
    rec = tmp_path / "rec"
    assert main(["play", "--headless", "--traffic", "2", "--no-audio", "--record", str(rec), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["completed"] and out["record"]
    files = sorted(p.suffix for p in rec.iterdir())
    assert files == [".json", ".pt"]
    assert load_drive(out["record"]).shape[0] == out["steps"]


@pytest.mark.parametrize("args", [
    ["--town", "Town9"], ["--route", "12"], ["--policy", "magic"], ["--user", "nobody"], ["--input", "mouse"],
    ["--playback", "fast"], ["--seed", "-1"], ["--audio"], ["--screenshot", "shot.jpg"], ["--history", "0"],
])
def test_cli_bad_input_exits_2_and_writes_nothing(args, tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("SDL_AUDIODRIVER", "dummy")  # --audio asked for, but no device
    rec = tmp_path / "rec"
    assert main(["play", "--headless", "--traffic", "0", "--record", str(rec), *args]) == 2
    err = capsys.readouterr().err
    assert err.startswith("pernav play: error:") and err.count("\n") == 1 and "Traceback" not in err
    assert not rec.exists()


def test_cli_missing_joystick_exits_2(tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("SDL_VIDEODRIVER", "dummy")
    monkeypatch.setenv("SDL_JOYSTICK_DISABLE", "1")  # whatever is plugged in here
    rec = tmp_path / "rec"
    assert main(["play", "--input", "joystick", "--no-audio", "--record", str(rec)]) == 2
    err = capsys.readouterr().err
    assert "joystick" in err and err.count("\n") == 1
    assert not rec.exists()


@pytest.mark.slow
def test_screenshot_shows_road_car_and_prompt(tmp_path):
    import pygame

    png = tmp_path / "play.png"
    session = PlaySession("Town1", 0, options=PlayOptions(n_traffic=2, window=True, realtime=False, screenshot=png))
    session.run(max_steps=12)
    session.close()
    assert session.shot == png and png.is_file()
    image = pygame.surfarray.array3d(pygame.image.load(str(png)))  # [W, H, 3]
    assert image.shape[:2] == (960, 720)
    assert ((image == (50, 200, 0)).all(-1)).sum() > 20  # the car, in green
    assert (image[:, 70:-60] == (255, 255, 255)).all(-1).sum() > 50  # lane markings
    band = image[:, :70]
    assert (band == (255, 255, 255)).all(-1).sum() > 200  # the prompt's white text on its dark band


def test_nothing_below_play_imports_it():
    import pathlib

    root = pathlib.Path(__file__).resolve().parents[2] / "pernav"
    for path in root.rglob("*.py"):
        # the command line and the benchmarks sit on top of every package, play included
        if not {"play", "cli"} & set(path.relative_to(root).parts):
            text = path.read_text()
            assert "from pernav.play" not in text and "import pernav.play" not in text, path


@pytest.mark.slow
def test_bench_play_reports_frame_times(monkeypatch):
    """``pernav bench play`` measures the loop (no timing is asserted here: the target is checked by the bench)."""
    monkeypatch.setenv("SDL_VIDEODRIVER", "dummy")
    from pernav.cli import bench
    from pernav.cli.bench import bench_play

    # two of the six views (a clear one and a foggy one: each view is one more drive of the same loop)
    monkeypatch.setattr(bench, "PLAY_VIEWS", (("first_person", "normal"), ("top", "foggy")))
    out = bench_play(quick=True)
    assert out["slowest_view"] in ("first_person", "top_fog") and "third_person_frame_ms_median" not in out
    assert out["world_frames"] > 100 and 0 < out["frame_ms_median"] <= out["frame_ms_p95"]
    assert 0 < out["frame_without_drawing_ms_median"] and out["drawn_vs_bare_median_ratio"] > 1


def test_cli_without_a_display_exits_2_and_writes_nothing(tmp_path, capfd, monkeypatch):
    """A window asked for (no --headless) where there is no display: one line, exit 2, nothing recorded (capfd:
    nothing printed by SDL itself either, such as its XDG_RUNTIME_DIR complaint)."""
    for name in ("SDL_VIDEODRIVER", "DISPLAY", "WAYLAND_DISPLAY", "XDG_RUNTIME_DIR"):
        monkeypatch.delenv(name, raising=False)
    rec = tmp_path / "rec"
    assert main(["play", "--traffic", "0", "--no-audio", "--record", str(rec)]) == 2
    err = capfd.readouterr().err
    assert "no display" in err and err.count("\n") == 1 and "Traceback" not in err
    assert not rec.exists()


# ----- a session that survives a slip, checks before anyone drives, wheels ------------------------------
class KeyBot(ScriptedControls):
    """The scripted bot drives; at given polls it presses and releases session keys ("press escape", "release
    escape"), on a clock of 0.1 s per poll; ``go_at``: the poll from which it is ready (Enter)."""

    def __init__(self, script: dict[int, list[str]] | None = None, go_at: int = 0, session=None) -> None:
        super().__init__()
        self.script, self.go_at, self.session = script or {}, go_at, session
        self.polls, self.seen = 0, []  # per poll: (world time, the screen shown)

    def poll(self) -> None:
        self.polls += 1
        now = 0.1 * self.polls
        for action in self.script.get(self.polls, []):
            kind, key = action.split()
            self.press(key, now) if kind == "press" else self.release(key)
        self.update(now)
        if self.session is not None:
            self.seen.append((self.session.nav.world.time, self.session.screen))

    def take_go(self) -> bool:
        return self.polls >= self.go_at


def _keys_drive(script: dict[int, list[str]], max_steps: int = 6):
    session = PlaySession("Town1", 0, options=PlayOptions(n_traffic=2, seed=0, countdown=0))
    session.controls = KeyBot(script, session=session)
    return session, session.run(max_steps=max_steps)


@pytest.fixture(scope="module")
def plain_six():
    return PlaySession("Town1", 0, options=PlayOptions(n_traffic=2, seed=0)).run(max_steps=6)


def _same_drive(a, b) -> None:
    assert torch.equal(a.trajectory["action"], b.trajectory["action"])
    assert torch.equal(a.trajectory["next", "observation"], b.trajectory["next", "observation"])
    assert a.metrics["time"] == b.metrics["time"] and a.metrics["tracking_cost"] == b.metrics["tracking_cost"]


def test_an_accidental_q_or_a_single_esc_does_not_end_the_drive(plain_six):
    # Q beside W and A; Esc pressed and released, then an arrow key: the quit question goes away
    session, result = _keys_drive({12: ["press q"], 20: ["press escape"], 21: ["release escape"], 24: ["press left"]})
    assert not result.metrics["interrupted"] and result.trajectory.shape[0] == 6
    assert [screen for _, screen in session.controls.seen].count("confirm") >= 3  # the question was shown
    _same_drive(result, plain_six)  # and the world stood still meanwhile: the drive is the bot's own


@pytest.mark.parametrize("script", [{20: ["press escape"], 21: ["release escape"], 23: ["press yes"]},
                                    {20: ["press escape"]}])  # Esc then Y; Esc held for a second
def test_a_deliberate_quit_ends_the_drive_and_keeps_it(script):
    _, result = _keys_drive(script)
    assert result.metrics["interrupted"] and result.metrics["stopped_by"] == "person"
    assert result.trajectory.shape[0] == 1  # the second second was cut short
    assert result.metrics["time"] == pytest.approx(1.0)


def test_pause_stops_the_world_clock(plain_six):
    session, result = _keys_drive({25: ["press pause"], 60: ["press pause"]})
    times = [t for t, _ in session.controls.seen]
    assert len(set(times[24:60])) == 1  # 35 polls paused: the world's time stood still
    assert result.metrics["pauses"] == 1 and not result.metrics["interrupted"]
    _same_drive(result, plain_six)  # the drive itself is as if there had been no pause


def test_a_real_time_pause_is_not_made_up_afterwards():
    class Pauser(ScriptedControls):
        def __init__(self) -> None:
            super().__init__()
            self.polls, self.since, self.walls = 0, None, []

        def poll(self) -> None:
            self.polls += 1
            if self.polls == 3:
                self.press("pause")
                self.since = time.perf_counter()
            elif self.paused and time.perf_counter() - self.since > 0.4:
                self.press("pause")
            if not self.paused:
                self.walls.append(time.perf_counter())

    options = PlayOptions(n_traffic=0, seed=0, realtime=True, countdown=0)
    session = PlaySession("Town1", 0, controls=Pauser(), options=options)
    start = time.perf_counter()
    result = session.run(max_steps=1)
    wall = time.perf_counter() - start
    assert result.metrics["time"] == pytest.approx(1.0) and result.metrics["paused_s"] >= 0.4
    assert wall >= 1.0 + 0.4 - 0.05  # the frames after the pause kept their pace: no rush to catch up
    gaps = np.diff(session.controls.walls[3:])
    assert gaps.size and gaps.min() > 0.05


def test_the_clock_starts_after_the_person_is_ready_and_the_countdown():
    session = PlaySession("Town1", 0, options=PlayOptions(n_traffic=0, seed=0, draw=True, ready=True, countdown=0.3))
    session.controls = KeyBot(go_at=8, session=session)
    before = time.perf_counter()
    result = session.run(max_steps=2)
    seen = session.controls.seen
    screens = [screen for _, screen in seen]
    assert screens[:7] == ["ready"] * 7 and "countdown" in screens and screens[-1] == "result"
    first_frame = screens.index(None)
    assert all(t == 0.0 for t, _ in seen[:first_frame])  # no world time before the drive
    assert screens[first_frame - 1] == "countdown" and session.t0 - before >= 0.3
    assert result.metrics["time"] == pytest.approx(2.0) and not result.metrics["interrupted"]


def test_ctrl_c_keeps_the_drive_so_far():
    class CtrlC(ScriptedControls):
        def poll(self) -> None:
            if self.frames >= 25:
                raise KeyboardInterrupt

    result = PlaySession("Town1", 0, controls=CtrlC(), options=PlayOptions(n_traffic=2)).run()
    assert result.ctrl_c and result.metrics["interrupted"] and result.metrics["stopped_by"] == "ctrl-c"
    assert result.trajectory.shape[0] == 2


def test_cli_ctrl_c_records_the_stopped_drive_and_exits_130(tmp_path, capsys, monkeypatch):
    def poll(self) -> None:
        if self.frames >= 25:
            raise KeyboardInterrupt

    monkeypatch.setattr(ScriptedControls, "poll", poll)
    rec = tmp_path / "rec"
    assert main(["play", "--headless", "--traffic", "0", "--no-audio", "--record", str(rec)]) == 130
    captured = capsys.readouterr()
    assert "stopped after 2 s" in captured.out and captured.err.startswith("interrupted (Ctrl-C)")
    (pt,) = rec.glob("*.pt")
    assert read_metrics(pt)["interrupted"] and load_drive(pt).shape[0] == 2


def test_window_events_map_to_the_session_keys():
    import pygame

    from pernav.play.controls import KeyboardControls

    pygame.display.init()
    pygame.display.set_mode((32, 32))
    try:
        keys = KeyboardControls()

        def send(*events) -> None:
            for kind, key in events:
                pygame.event.post(pygame.event.Event(kind, key=key))
            keys.poll()

        send((pygame.KEYDOWN, pygame.K_q), (pygame.KEYDOWN, pygame.K_w))
        assert not keys.holding and not keys.quit_requested  # Q does nothing
        send((pygame.KEYDOWN, pygame.K_p))
        assert keys.paused
        send((pygame.KEYDOWN, pygame.K_RETURN))
        assert not keys.paused  # Enter drives on
        send((pygame.KEYDOWN, pygame.K_ESCAPE), (pygame.KEYUP, pygame.K_ESCAPE))
        assert keys.confirming and not keys.quit_requested
        send((pygame.KEYDOWN, pygame.K_n))
        assert not keys.confirming and not keys.quit_requested
        pygame.event.post(pygame.event.Event(pygame.QUIT))
        keys.poll()
        assert keys.confirming  # the close button asks too
        send((pygame.KEYDOWN, pygame.K_y))
        assert keys.quit_requested
    finally:
        pygame.display.quit()


def test_cli_unwritable_record_folder_is_refused_before_the_drive(tmp_path, capsys, monkeypatch):
    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    assert main(["play", "--headless", "--traffic", "0", "--no-audio", "--record", str(blocker / "rec")]) == 2
    err = capsys.readouterr().err
    assert "--record" in err and "cannot be written" in err and err.count("\n") == 1
    from pathlib import Path

    def read_only(self, data):
        raise OSError(30, "Read-only file system")

    monkeypatch.setattr(Path, "write_bytes", read_only)
    rec = tmp_path / "deep" / "rec"
    assert main(["play", "--headless", "--traffic", "0", "--no-audio", "--record", str(rec)]) == 2
    err = capsys.readouterr().err
    assert "Read-only file system" in err and err.count("\n") == 1 and "Traceback" not in err
    assert not (tmp_path / "deep").exists()  # the folders made for the probe are gone again


@pytest.mark.slow
def test_probe_leaves_a_writable_folder_as_it_was(tmp_path, capsys):
    rec = tmp_path / "rec"
    rec.mkdir()
    assert main(["play", "--headless", "--traffic", "0", "--no-audio", "--record", str(rec)]) == 0
    assert sorted(p.suffix for p in rec.iterdir()) == [".json", ".pt"]  # the drive, and no probe file left


def test_no_audio_device_is_a_warning_on_screen_and_in_the_terminal(tmp_path, capsys, monkeypatch):
    from pernav.play.framelog import PlayResult

    monkeypatch.setenv("SDL_VIDEODRIVER", "dummy")
    monkeypatch.setenv("SDL_AUDIODRIVER", "dummy")
    notices = []

    def run(self, max_steps=0):  # the window opened; the person stops at once
        notices.append(self.notice)
        return PlayResult(None, {"interrupted": True, "completed": False})

    monkeypatch.setattr(PlaySession, "run", run)
    assert main(["play", "--traffic", "0"]) == 0
    err = capsys.readouterr().err
    assert err.startswith("pernav play: warning: no sound") and err.count("\n") == 1
    assert notices and "No sound" in notices[0]
    assert main(["play", "--traffic", "0", "--no-audio"]) == 0
    assert capsys.readouterr().err == "" and notices[-1] is None


@pytest.mark.slow
def test_history_defaults_to_the_default_study(tmp_path, capsys):
    from pernav.study import preset

    rec = tmp_path / "rec"
    assert main(["play", "--headless", "--traffic", "0", "--no-audio", "--record", str(rec), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert load_drive(out["record"])["history"].shape[-2] == preset("default").train.K == 10


def test_a_random_pt_gets_our_own_words(tmp_path):
    import argparse

    from pernav.study import ScheduleError, load_schedule

    torch.save(argparse.Namespace(weights=torch.zeros(2)), tmp_path / "model.pt")
    (tmp_path / "noise.pt").write_bytes(b"\x00garbage")
    for name in ("model.pt", "noise.pt"):
        with pytest.raises(ValueError, match="is not a pernav drive") as err:
            load_drive(tmp_path / name)
        assert "weights_only" not in str(err.value)
        (tmp_path / "s.json").write_text(json.dumps([{"label": "P", "phase": "online", "drives": [name]}]))
        with pytest.raises(ScheduleError, match="is not a pernav drive") as err:
            load_schedule(tmp_path / "s.json")
        assert "weights_only" not in str(err.value) and "\n" not in str(err.value)


@pytest.mark.parametrize("text,words", [("0", "STEER,THROTTLE,BRAKE"), ("0,x,2", "not an axis"),
                                        ("0,1,1", "used twice")])
def test_cli_bad_joystick_axes_exit_2(text, words, tmp_path, capsys):
    assert main(["play", "--input", "joystick", "--joystick-axes", text, "--no-audio"]) == 2
    err = capsys.readouterr().err
    assert words in err and err.count("\n") == 1


class FakeStick:
    """A wheel (axis 0) and two pedals resting at -1 (axes 2 and 3), moved by the test."""

    def __init__(self) -> None:
        self.axes = [0.0, 0.0, -1.0, -1.0]

    def get_numaxes(self) -> int:
        return len(self.axes)

    def get_name(self) -> str:
        return "fake wheel"

    def get_axis(self, i: int) -> float:
        return self.axes[i]


def test_joystick_axes_with_inversion_and_the_calibration_screen():
    from pernav.play.controls import JoystickControls, parse_axes

    stick = FakeStick()
    wheel = JoystickControls(**parse_axes("~0,2,3"), stick=stick)
    stick.axes = [0.5, 0.0, 1.0, -1.0]
    assert wheel.axes_now() == {"steer": -0.5, "throttle": 1.0, "brake": 0.0}  # the steering axis inverted

    moves = [[-1.0, 0, -1.0, -1.0], [1.0, 0, -1.0, -1.0], [0.0, 0, 1.0, -1.0], [0.0, 0, -1.0, 1.0]]

    class Wheel(JoystickControls):
        polls = 0

        def poll(self) -> None:
            self.polls += 1
            stick.axes = list(moves[min(self.polls - 1, len(moves) - 1)])

        def take_go(self) -> bool:  # the experimenter presses Enter once every axis was seen moving
            return all(session.calibration.values()) if session.calibration else False

    session = PlaySession("Town1", 0, options=PlayOptions(n_traffic=0, draw=True, ready=True, countdown=0, calibrate=True))
    session.controls = Wheel(**parse_axes("0,2,3"), stick=stick)
    result = session.run(max_steps=1)
    assert session.calibration == {"steer": True, "throttle": True, "brake": True}
    assert result.trajectory.shape[0] == 1


XVFB = shutil.which("Xvfb")


@pytest.mark.slow
@pytest.mark.skipif(XVFB is None, reason="Xvfb is not installed (a virtual X display for the real window)")
def test_real_window_under_xvfb(tmp_path):
    """The real window (SDL's x11 driver on a virtual display): keys posted to its event queue, the bot's keys
    driving; ready, countdown, an accidental Q, pause and resume, arrival, the result screen."""
    import subprocess
    import sys

    display = ":97"
    server = subprocess.Popen([XVFB, display, "-screen", "0", "1024x768x24"], stdout=subprocess.DEVNULL,
                              stderr=subprocess.DEVNULL)
    try:
        time.sleep(1.0)
        env = {**os.environ, "DISPLAY": display, "SDL_VIDEODRIVER": "x11", "SDL_AUDIODRIVER": "dummy"}
        code = subprocess.run([sys.executable, "-c", XVFB_SCRIPT, str(tmp_path)], env=env, timeout=400,
                              capture_output=True, text=True)
        assert code.returncode == 0, code.stderr[-2000:]
        out = json.loads(code.stdout.strip().splitlines()[-1])
        assert out["completed"] and not out["interrupted"] and out["pauses"] == 1
        assert out["times_while_paused"] == 1 and out["screens"][:2] == ["ready", "countdown"]
        assert load_drive(out["file"]).shape[0] == out["steps"]
    finally:
        server.terminate()
        server.wait(10)


XVFB_SCRIPT = r'''
import json, sys
import pygame
from pernav.play.controls import KeyboardControls, ScriptedControls
from pernav.play.loop import PlayOptions, PlaySession
from pernav.trainer import RoundBuffers
from pernav.trainer.drives import save_drive


class Keys(KeyboardControls):
    """Posts key events into the real window's queue; the bot chooses the driving keys."""
    def __init__(self, session):
        super().__init__()
        self.bot, self.session, self.polls, self.screens, self.paused_times = ScriptedControls(), session, 0, [], set()
        self.sent, self.pause_polls = set(), 0
    def poll(self):
        self.polls += 1
        screen = self.session.screen
        if not self.screens or self.screens[-1] != screen:
            self.screens.append(screen)
        post = lambda key: pygame.event.post(pygame.event.Event(pygame.KEYDOWN, key=key))
        if screen == "ready" and self.polls == 5:
            post(pygame.K_RETURN)
        frames = self.session.frames
        if screen is None and frames in (20, 40) and frames not in self.sent:
            self.sent.add(frames)
            post(pygame.K_q if frames == 20 else pygame.K_p)  # an accidental Q; then a pause
        if screen == "pause":
            self.paused_times.add(self.session.nav.world.time)
            self.pause_polls += 1
            if self.pause_polls == 30:  # thirty polls paused
                post(pygame.K_p)
        if screen == "result":
            post(pygame.K_RETURN)
        super().poll()
    def read(self, car):
        return self.bot.read(car)

options = PlayOptions(n_traffic=2, window=True, realtime=False, ready=True, countdown=1.0, fps=5)
session = PlaySession("Town1", 0, options=options)
session.controls = Keys(session)
result = session.run()
session.close()
path = save_drive(result.trajectory, result.metrics, sys.argv[1], "xvfb")
buffers = RoundBuffers(L=3)
buffers.add(0, result.trajectory, tau=True)
print(json.dumps({**{k: result.metrics[k] for k in ("completed", "interrupted", "pauses", "steps")},
                  "times_while_paused": len(session.controls.paused_times),
                  "screens": [s for s in session.controls.screens if s], "file": str(path)}))
'''
