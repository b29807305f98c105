"""`pernav play`: a person (here a scripted bot or a test controller) at the wheel, through the same world."""

from __future__ import annotations

import json
import math
import os

import numpy as np
import pytest
import torch

from pernav.cli import main
from pernav.env.navigation import NavigationEnv
from pernav.play.controls import ScriptedControls
from pernav.play.loop import PlaySession
from pernav.trainer.drives import load_drive, read_metrics, save_drive
from pernav.world.simulation import ControlInput

os.environ.setdefault("SDL_VIDEODRIVER", "dummy")  # windows drawn off screen
os.environ.setdefault("SDL_AUDIODRIVER", "dummy")  # and no sound

METRICS = ("tracking_cost", "vehicle_collisions", "edge_strikes", "missed_turns", "wrong_turns", "reroutes",
           "completed", "time")


@pytest.fixture(scope="module")
def bot_drive():
    """The scripted bot drives Town1's route 0 through the play loop (headless)."""
    return PlaySession("Town1", 0, n_traffic=2, seed=0).run()


def test_bot_drives_a_whole_route(bot_drive):
    m = bot_drive.metrics
    assert m["completed"] and not m["interrupted"]
    assert m["steps"] == bot_drive.trajectory.shape[0] > 60
    for key in ("vehicle_collisions", "edge_strikes", "missed_turns", "reroutes"):
        assert isinstance(m[key], int) and m[key] >= 0
    assert len(bot_drive.frame_ms) == 10 * m["steps"]  # one callback per world frame
    assert bot_drive.frame_stats()["median_ms"] < 50


class _Reckless:
    """Full throttle, and from the third second the wheel hard right: the car must hit the kerb."""

    keeps_lanes = False
    quit_requested = False

    def __init__(self) -> None:
        self.frames = 0

    def poll(self) -> None:
        pass

    def read(self, car) -> ControlInput:
        self.frames += 1
        return ControlInput(steer=1.0 if self.frames > 30 else 0.0, throttle=1.0)


def test_events_are_counted_for_a_person():
    result = PlaySession("Town1", 0, n_traffic=0, controls=_Reckless()).run(max_steps=15)
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


def test_simulated_drivers_are_unchanged_by_the_extension():
    plain = _simulated(hooks=False)
    assert _simulated(hooks=True) == plain
    # the figure of `pernav drive --town Town1 --policy explore --user user3 --routes 0` before the extension
    assert plain["completed"] and plain["time"] == 179.0
    assert plain["tracking_cost"] == pytest.approx(349.1481049516626, abs=1e-9)


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
    result = PlaySession("Town1", 0, n_traffic=2, controls=ScriptedControls(quit_after=25)).run()
    assert result.metrics["interrupted"] and not result.metrics["completed"]
    assert result.trajectory.shape[0] == 2  # the third second was cut short: not recorded


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


def test_screenshot_shows_road_car_and_prompt(tmp_path):
    import pygame

    png = tmp_path / "play.png"
    session = PlaySession("Town1", 0, n_traffic=2, window=True, realtime=False, screenshot=png)
    session.run(max_steps=12)
    session.close()
    assert session.shot == png and png.is_file()
    image = pygame.surfarray.array3d(pygame.image.load(str(png)))  # [W, H, 3]
    assert image.shape[:2] == (960, 720)
    assert ((image == (50, 200, 0)).all(-1)).sum() > 20  # the car, in green
    assert (image[:, 70:-60] == (255, 255, 255)).all(-1).sum() > 50  # lane markings
    band = image[:, :70]
    assert (band == (255, 255, 255)).all(-1).sum() > 200  # the prompt's white text on its dark band


def test_docstring_examples():
    import doctest

    import pernav.play.controls
    import pernav.play.loop
    import pernav.play.view
    import pernav.trainer.drives

    for module in (pernav.play.controls, pernav.play.loop, pernav.trainer.drives, pernav.play.view):
        assert doctest.testmod(module).failed == 0, module.__name__


def test_nothing_below_play_imports_it():
    import pathlib

    root = pathlib.Path(__file__).resolve().parents[1] / "pernav"
    for path in root.rglob("*.py"):
        # the command line and the benchmarks sit on top of every package, play included
        if "play" not in path.relative_to(root).parts and path.name not in ("cli.py", "bench.py"):
            text = path.read_text()
            assert "from pernav.play" not in text and "import pernav.play" not in text, path


def test_bench_play_reports_frame_times(monkeypatch):
    """``pernav bench play`` measures the loop (no timing is asserted here: the target is checked by the bench)."""
    monkeypatch.setenv("SDL_VIDEODRIVER", "dummy")
    from pernav.bench import bench_play

    out = bench_play(quick=True)
    assert out["world_frames"] > 100 and 0 < out["frame_ms_median"] <= out["frame_ms_p95"]
    assert 0 < out["frame_without_drawing_ms_median"] and out["drawn_vs_bare_median_ratio"] > 1


def test_cli_without_a_display_exits_2_and_writes_nothing(tmp_path, capsys, monkeypatch):
    """A window asked for (no --headless) where there is no display: one line, exit 2, nothing recorded."""
    for name in ("SDL_VIDEODRIVER", "DISPLAY", "WAYLAND_DISPLAY"):
        monkeypatch.delenv(name, raising=False)
    rec = tmp_path / "rec"
    assert main(["play", "--traffic", "0", "--no-audio", "--record", str(rec)]) == 2
    err = capsys.readouterr().err
    assert "no display" in err and err.count("\n") == 1 and "Traceback" not in err
    assert not rec.exists()
