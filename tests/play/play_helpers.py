"""Shared by the play tests (and tests/study/test_finished.py): the small finished studies a person's session runs
on, built once per test session; a scripted person whose controls are a function of the frame; a windowed session
watched."""

from __future__ import annotations

import signal
import subprocess
import time
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

from navigation_helpers import TIME_LIMIT, shared_folder

from pernav.world.controls import ControlInput

PLANNER = {"kind": "retime", "horizon": 8, "advance": 4}  # not the defaults: the env must follow the study
K = 3  # nor is this history window


def model_study(tmp_path_factory) -> Path:
    """A finished study in seconds (episodes cut at TIME_LIMIT): smoke's model, one offline and one online round,
    adapt and adapt_speed, U on tau, with :data:`PLANNER` and a history window of :data:`K` (built once per test session)."""

    def build(out: Path) -> None:
        from pernav.study import preset, run_study

        cfg = preset("smoke")
        cfg.methods, cfg.schedule, cfg.calibration = ["adapt", "adapt_speed"], cfg.schedule[:2], 0
        cfg.train.personal_updates, cfg.train.K, cfg.train.warm_updates = 0, K, 10
        cfg.planner, cfg.time_limit_factor = dict(PLANNER), TIME_LIMIT
        run_study(cfg, out, report=False)

    return shared_folder(tmp_path_factory, "play_model_study", build)


def retimed_study(tmp_path_factory) -> Path:
    """A finished study of the learners that re-time explore's rule: explore, timing and belief (one offline and one
    online round, four offline drivers each; built once per test session)."""

    def build(out: Path) -> None:
        from pernav.study import preset, run_study

        cfg = preset("smoke")
        cfg.methods, cfg.schedule, cfg.calibration = ["explore", "timing", "belief"], cfg.schedule[:2], 0
        run_study(cfg, out, report=False)  # whole drives: the tests read what its timing model learned of them

    return shared_folder(tmp_path_factory, "play_retimed_study", build)


class FrameScript:
    """The controls ``script(frame)`` gives at each world frame (1, 2, ...), with no session keys pressed."""

    keeps_lanes = False
    quit_requested = False

    def __init__(self, script: Callable[[int], ControlInput]) -> None:
        self.script, self.frames = script, 0

    def poll(self) -> None:
        pass

    def read(self, car) -> ControlInput:
        self.frames += 1
        return self.script(self.frames)


def watch_session_window(monkeypatch) -> dict[str, list]:
    """Drive a windowed personalization session (``pernav.play.personal`` or ``.believe``) fast: each drive's
    PlaySession is made without its window (nothing drawn, not paced), noting the ``view`` it was given and whether
    the session's window was open then (``views``: ``(view, open)``); every panel drawn is noted (``panels``: its
    lines)."""
    import pygame

    import pernav.play.screens as screens
    import pernav.play.sessions as sessions

    seen: dict[str, list] = {"views": [], "panels": []}

    class Drive(sessions.PlaySession):
        def __init__(self, *args, **kwargs) -> None:
            seen["views"].append((kwargs.pop("view"), pygame.display.get_init()))
            super().__init__(*args, **{**kwargs, "options": replace(kwargs["options"], window=False)})

    panel = screens.show_panel
    monkeypatch.setattr(sessions, "PlaySession", Drive)
    monkeypatch.setattr(screens, "show_panel",
                        lambda view, lines, **kw: seen["panels"].append(list(lines)) or panel(view, lines, **kw))
    return seen


def lab_study(tmp_path_factory) -> Path:
    """A finished study whose learners a lab session's blocks name: explore, adapt and belief (one offline and one
    online round; built once per test session)."""

    def build(out: Path) -> None:
        from pernav.study import preset, run_study

        cfg = preset("smoke")
        cfg.methods, cfg.schedule, cfg.calibration = ["explore", "adapt", "belief"], cfg.schedule[:2], 0
        cfg.train.warm_updates, cfg.time_limit_factor = 10, TIME_LIMIT
        run_study(cfg, out, report=False)

    return shared_folder(tmp_path_factory, "play_lab_study", build)


def kill_when(process: subprocess.Popen, ready: Callable[[], bool], settle: float, timeout: float = 240.0) -> None:
    """SIGKILL ``process`` ``settle`` s after ``ready()`` first holds (a session's kill at a chosen point), and check
    that it was killed there, not finished before."""
    deadline = time.time() + timeout
    while time.time() < deadline and process.poll() is None:
        if ready():
            time.sleep(settle)
            process.send_signal(signal.SIGKILL)
            break
        time.sleep(0.02)
    process.wait()
    assert process.returncode == -signal.SIGKILL, "the session finished before it could be killed"
