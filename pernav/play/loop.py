"""A person at the wheel: the real-time play loop.

:class:`PlaySession` drives one route of a town with the study's navigation env (the TorchRL env with its history
window, :func:`pernav.trainer.collect.history_env`), so every decision step is what the study records. The
navigation policy chooses an instruction once per simulated second exactly as in the study (the env's prompt rule
says whether it is played: then it is heard by the simulated driver, spoken by the speaker and shown); the car is
driven by the controls (:mod:`pernav.play.controls`). The env calls back after every world frame: the loop draws
there, reads the window's events and paces the drive to the wall clock.

Real time: world frame ``n`` is due ``n / frequency`` seconds after the start. With fewer world frames per second
than the window's ``fps`` each frame is drawn ``ceil(fps / frequency)`` times, the cars placed part of the way from
their last frame to this one (the picture lags the world by one frame, 0.1 s); a picture already late is skipped,
and a loop that falls far behind (a stall) restarts its clock rather than rushing to catch up.

A person's drive (a window in real time, or ``ready=True``): a calibration screen for a wheel (``calibrate``), a
ready screen (the drive's ``title``, a ``notice`` such as "no sound") until the person presses Enter, a countdown,
and at the end the result until Enter again; the world's clock runs only between the countdown and the end. The
world stands still while the person pauses (P) or is asked whether to quit (Esc; Y quits, any other key drives
on; Esc held a second quits): the wall-clock time of a pause counts neither in the drive's time nor against the
pacing, and a countdown follows a pause. Ctrl-C stops the drive like a quit and keeps what was driven
(``PlayResult.ctrl_c`` says so: the command line records it, then exits 130).

Policies: ``"explore"``, ``"oracle"`` (the rule timed for the chosen user's profile) or any callable that takes the
step's TensorDict (observation, history, route_ahead, action_mask, explore_future, ...) and returns it with an
``"action"`` (e.g. a study's MPC policy module; in the env's action space: 7 instructions, or 21 with playback).

Example (headless: the scripted bot drives, nothing is drawn):
    >>> result = PlaySession("Town1", 0, n_traffic=2).run()
    >>> result.metrics["completed"], result.trajectory["history"].shape[1:]
    (True, torch.Size([5, 21]))
"""

from __future__ import annotations

import math
import statistics
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from tensordict import TensorDictBase

from pernav.env.navigation import load_user
from pernav.play.controls import ScriptedControls
from pernav.play.framelog import DriveLog, InputTap
from pernav.play.handling import apply_handling
from pernav.world.constants import ACTION_NAMES, PLAYBACK, TOWN_NAMES, audio_duration
from pernav.world.drivers import CONTEXT_CHOICES, ProfileError
from pernav.world.towns import TownError, get_town

__all__ = ["POLICIES", "PlayError", "PlayQuit", "PlayResult", "PlaySession", "make_speaker", "open_speaker"]

POLICIES = ("explore", "oracle")
MAX_STEPS = 2000  # the env's time limit ends a drive far earlier; this only bounds a runaway loop
SCREEN_HZ = 30  # pictures per second of the screens around a drive (ready, pause, countdown)


class PlayError(ValueError):
    """Bad play settings (reported by ``pernav play`` in one line)."""


class PlayQuit(Exception):
    """The person quit (Esc then Y, Esc held, or the window's close button then Y)."""


@dataclass
class PlayResult:
    """A finished (or quit) drive: its ``[T]`` trajectory (``None`` if quit before the first step), its metrics and
    the compute time of every world frame (ms: the world, the step's bookkeeping at a second's start, drawing);
    ``ctrl_c``: Ctrl-C was pressed (the drive is kept, marked interrupted if it was cut short; the caller stops);
    ``log``: every world frame, decision and prompt as driven, a quit drive's last part second too
    (:mod:`pernav.play.framelog`: its rows of a session's CSV)."""

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


def open_speaker(audio: bool | None) -> tuple[Any, str | None]:
    """The speaker of the prompts and, when there is no sound although none was refused, why (to tell the person):
    ``(None, None)`` when ``audio`` is False; ``(None, reason)`` when it is None (the default: sound if possible) and
    no speaker or device is there; with ``audio=True`` a missing one is a :class:`PlayError`. ``pernav.play.audio``
    is loaded here, so play works (text only) without it."""
    if audio is False:
        return None, None
    try:
        from pernav.play.audio import Speaker
    except ImportError as exc:
        if audio:
            raise PlayError(f"no audio: the speaker is not available ({exc})") from None
        return None, f"the speaker is not available ({exc})"
    if audio:
        try:
            return Speaker(enabled=True, require=True), None
        except RuntimeError as exc:
            raise PlayError(str(exc)) from None
    speaker = Speaker(enabled=True)
    if getattr(speaker, "available", False):
        return speaker, None
    return None, f"no audio device ({speaker.reason})"


def make_speaker(audio: bool | None) -> Any:
    """The speaker alone of :func:`open_speaker` (``None``: text only)."""
    return open_speaker(audio)[0]


def _flag(controls: Any, name: str) -> bool:
    """A session key's state on any controls (a test's or a bot's may have none of them)."""
    return bool(getattr(controls, name, False))


def _with_playback(module: Callable[[TensorDictBase], TensorDictBase], playback: str) -> Callable:
    """A rule-based policy of the 21-action env (whose rules speak at normal speed) speaking at ``playback``."""
    index = PLAYBACK.index(playback)

    def policy(td: TensorDictBase) -> TensorDictBase:
        td = module(td)
        td["action"] = td["action"] // 3 * 3 + index
        return td

    return policy


def _check_drive_arguments(town: str, route: Any, policy: Any, playback: str, seed: int, fps: int,
                           countdown: float) -> None:
    """Refuse a drive's bad arguments before anything is built, naming the argument and what is allowed."""
    if town not in TOWN_NAMES:
        raise TownError(f"unknown town {town!r}; choose one of {', '.join(TOWN_NAMES)}")
    n_routes = len(get_town(town).routes)
    if isinstance(route, bool) or not isinstance(route, (int, np.integer)) or not 0 <= route < n_routes:
        raise TownError(f"route index {route!r} out of range [0, {n_routes - 1}] for {town}")
    if isinstance(policy, str) and policy not in POLICIES:
        raise PlayError(f"unknown policy {policy!r}; choose one of {', '.join(POLICIES)} (or pass a callable)")
    if playback not in PLAYBACK:
        raise PlayError(f"unknown playback {playback!r}; choose one of {', '.join(PLAYBACK)}")
    if seed < 0:
        raise PlayError(f"seed must be >= 0, got {seed}")
    if fps < 1:
        raise PlayError(f"fps must be >= 1, got {fps}")
    if countdown < 0:
        raise PlayError(f"countdown must be >= 0 seconds, got {countdown}")


class PlaySession:
    """One drive of ``route`` in ``town`` by a person (or the scripted bot) with prompts from ``policy``.

    ``user`` (name, mapping or file, with ``context`` overrides) is who the oracle times its prompts for, and the
    car's vehicle; ``controls`` default to :class:`~pernav.play.controls.ScriptedControls`. ``window``: a pygame
    window (paced to real time); ``draw``: draw off screen too (a screenshot, a timing); ``realtime`` defaults to
    ``window``. ``screenshot``: a PNG of the window saved at ``screenshot_at`` seconds of the drive (default: one
    second after the first prompt is played, or at the end). ``ready`` (default: a window in real time, a person):
    the screens around the drive (``calibrate``: a wheel's axes first; a ready screen showing ``title`` and
    ``notice``; a ``countdown`` of seconds; the result at the end); ``hide_cost`` keeps the tracking cost off the
    screen; ``progress`` ("Drive 2 of 6") stays in a corner during the drive (default: the ``title``). ``view``: an
    open :class:`~pernav.play.view.PlayView` to draw into instead of a new one (a session of drives keeps one
    window; :meth:`close` leaves it open). ``K`` (history window, default 5) and ``env_config``
    (entries of the navigation env's config, e.g. a study's planning context lengths) default to the policy's
    ``K`` and ``env_config`` attributes where it has them (a study's policy: :func:`pernav.play.personal.study_policy`).

    >>> session = PlaySession("Town1", 0, policy="oracle", user="user3", n_traffic=2)
    >>> result = session.run(max_steps=3)
    >>> result.trajectory.shape, result.metrics["interrupted"]
    (torch.Size([3]), False)
    """

    def __init__(self, town: str = "Town1", route: int = 0, user: Any = "user1", context: dict | None = None,
                 policy: str | Callable[[TensorDictBase], TensorDictBase] = "explore", controls: Any = None,
                 seed: int = 0, n_traffic: int = 8, playback: str = "normal", window: bool = False, draw: bool = False,
                 speaker: Any = None, realtime: bool | None = None, fps: int = 30, K: int | None = None,
                 size: tuple[int, int] = (960, 720), screenshot: str | Path | None = None,
                 screenshot_at: float | None = None, env_config: Mapping[str, Any] | None = None,
                 ready: bool | None = None, countdown: float = 3.0, title: str | None = None,
                 notice: str | None = None, hide_cost: bool = False, calibrate: bool = False,
                 progress: str | None = None, view: Any = None) -> None:
        from pernav.env.torchrl_env import explore_module, navigation_of, oracle_module
        from pernav.trainer.collect import history_env

        _check_drive_arguments(town, route, policy, playback, seed, fps, countdown)
        profile, ctx = load_user(user)
        ctx_dict = {**(ctx.to_dict() if ctx else {}), **(context or {})}
        unknown = sorted(set(ctx_dict) - set(CONTEXT_CHOICES))
        if unknown:
            raise ProfileError(f"unknown context field {unknown[0]!r}; allowed: {', '.join(CONTEXT_CHOICES)}")
        self.town, self.route, self.seed, self.playback = town, int(route), int(seed), playback
        self.user = user if isinstance(user, str) else "custom"
        # a learned policy plans on the env its study used (history K, planning context lengths): a policy that
        # carries them (pernav.play.personal.StudyPolicy) gives the defaults, so its drive needs no settings
        env_config = getattr(policy, "env_config", None) if env_config is None else env_config
        K = int(getattr(policy, "K", 5)) if K is None else int(K)
        config = {"n_traffic": int(n_traffic), "adaptive_speed": playback != "normal", **dict(env_config or {})}
        options = {"route": int(route), "user": profile, "context": ctx_dict}
        self.env = history_env(town, options, config=config, seed=int(seed), K=K)
        self.nav = navigation_of(self.env)
        if isinstance(policy, str):
            module = explore_module() if policy == "explore" else oracle_module()
            self.policy = _with_playback(module, playback) if playback != "normal" else module
            self.policy_name = policy
        else:
            self.policy, self.policy_name = policy, getattr(policy, "__name__", type(policy).__name__)
        self.controls = controls if controls is not None else ScriptedControls()
        self.speaker = speaker
        self.realtime = window if realtime is None else bool(realtime)
        self.ready = (window and self.realtime) if ready is None else bool(ready)
        self.countdown, self.title, self.notice = float(countdown), title, notice
        self.hide_cost, self.calibrate = bool(hide_cost), bool(calibrate)
        self.pauses, self.paused_s = 0, 0.0  # pauses taken, and their wall-clock seconds (the world stood still)
        self.screen: str | None = None  # the screen shown now: calibrate, ready, countdown, pause, confirm, result
        self.calibration: dict[str, bool] | None = None  # per control, whether the calibration saw it move
        self.screenshot_path = None if screenshot is None else Path(screenshot)
        self.screenshot_at = screenshot_at
        self.progress = progress  # the HUD's counter during the drive ("Drive 2 of 6"; else the title)
        # the announced manoeuvre of the prompt on screen (see prompt_text); the car's route progress every frame
        self._prompted: tuple[int, str, float] | None = None
        self._announced: tuple[Any, Any] | None = None  # (route, manoeuvre), None: nothing ahead when it played
        self.route_progress = 0.0
        self.view = view
        self._own_view = view is None  # a view given stays open at close(): its owner (a session of drives) closes it
        if view is not None:
            view.new_drive(self.nav.town)
        elif window or draw or screenshot is not None:
            from pernav.play.view import PlayView

            self.view = PlayView(self.nav.town, size=size, window=window)
        frequency = int(self.nav.config["frequency"])
        self.dt = 1.0 / frequency
        self.draws_per_frame = max(1, math.ceil(fps / frequency))
        self.prompt: tuple[int, str, float] | None = None  # (instruction, playback, world time) last played
        self.distance = math.inf  # m to the next decision manoeuvre (updated every frame)
        self.next_manoeuvre = "none"
        self.frame_ms: list[float] = []
        self._snap: dict[int, tuple[np.ndarray, float]] = {}
        self.frames = 0
        self.shot: Path | None = None
        self.log = DriveLog(frequency)  # the lab's record of the drive (pernav.play.framelog)
        self._tap: InputTap | None = None  # the car's controls in a drive, keeping for the log what it got each frame

    # ----- what the window shows ---------------------------------------------------------------------
    def interpolated(self, alpha: float) -> dict[int, tuple[np.ndarray, float]]:
        """Every car's (position, heading) ``alpha`` of the way from its last frame to this one."""
        out = {}
        for car in self.nav.world.cars:
            last = self._snap.get(id(car))
            if last is None or alpha >= 1.0:
                out[id(car)] = (car.position, car.heading)
                continue
            pos, heading = last
            turn = (car.heading - heading + np.pi) % (2 * np.pi) - np.pi
            out[id(car)] = (pos + alpha * (car.position - pos), heading + alpha * turn)
        return out

    def prompt_text(self) -> str | None:
        """The prompt on screen with the live distance to its manoeuvre (else None).

        A prompt holds until the next one or until the car has passed the manoeuvre that was next when it played
        (the person may still need it 50 m before the junction, or stopped at its line); a re-route drops it (its
        junction is on the old route: the navigation speaks again for the new one). A prompt played with no
        manoeuvre ahead (near the destination) names none to wait for: it stays 5 s after its audio, as all did."""
        if self.prompt is None:
            return None
        if self.prompt is not self._prompted:  # played since the last frame: note what it announced now
            self._update_distance()
        instruction, playback, at = self.prompt
        if self._announced is None:
            if self.nav.world.time - at > audio_duration(instruction, playback) + 5.0:
                return None
            distance = self.distance
        else:
            route, manoeuvre = self._announced
            if route is not self.nav.route or self.route_progress >= manoeuvre.s:
                return None
            distance = manoeuvre.s - self.route_progress
        far = f"  -  {distance:.0f} m" if math.isfinite(distance) else ""
        return f"{ACTION_NAMES[instruction]}{far}"

    def _update_distance(self) -> None:
        """The car's route progress and the next decision manoeuvre (kind, distance); a prompt played since the
        last call is tied to that manoeuvre (what :meth:`prompt_text` holds it for)."""
        nav = self.nav
        progress, _ = nav.route.project(nav.world.ego.position, hint=nav.progress)
        ahead = nav.route.upcoming(progress)
        self.route_progress = progress
        self.distance = float(ahead[0].s - progress) if ahead else math.inf
        self.next_manoeuvre = ahead[0].kind if ahead else "none"
        if self.prompt is not self._prompted:
            self._prompted = self.prompt
            self._announced = (nav.route, ahead[0]) if ahead else None

    def _snapshot(self) -> None:
        self._snap = {id(c): (c.position.copy(), float(c.heading)) for c in self.nav.world.cars}

    # ----- the env's callbacks ---------------------------------------------------------------------
    def _on_prompt(self, instruction: int, playback: str) -> None:
        self.prompt = (instruction, playback, self.nav.world.time)
        said = self.speaker.say(instruction, playback) if self.speaker is not None else False
        # Speaker.say tells False when nobody hears it (no device, a file missing); a speaker that tells nothing played
        self.log.add_prompt(self.nav.world.time, instruction, playback, spoken=said is not False)

    def _sleep_until(self, due: float) -> None:
        wait = due - time.perf_counter()
        if wait > 0:
            time.sleep(wait)

    def _on_frame(self) -> None:
        self.log.add_frame(self.nav, self._tap)  # first: the frame as the env sensed it (its cost counts in frame_ms)
        start = time.perf_counter()
        compute = start - self._t_out  # the world frame (at a second's start also the policy, the env's step)
        self.frames += 1
        self._update_distance()
        drawing = 0.0
        if self.view is not None:
            k = self.draws_per_frame
            for j in range(1, k + 1):
                due = self.t0 + (self.frames - 1 + j / k) * self.dt
                if self.realtime and j < k and time.perf_counter() > due:
                    continue  # late already: skip this in-between picture
                t = time.perf_counter()
                self.view.draw(self, j / k)
                self.view.present()
                drawing += time.perf_counter() - t
                if self.realtime:
                    self._sleep_until(due)
            self._maybe_screenshot()
        elif self.realtime:
            self._sleep_until(self.t0 + self.frames * self.dt)
        self.frame_ms.append(1000.0 * (compute + drawing))
        self.controls.poll()
        if _flag(self.controls, "quit_requested"):
            raise PlayQuit
        if _flag(self.controls, "holding"):
            self._hold()
        self._snapshot()
        now = time.perf_counter()
        if self.realtime and now > self.t0 + self.frames * self.dt + 0.25:  # a stall: go on from here
            self.t0 = now - self.frames * self.dt
        self._t_out = time.perf_counter()

    def _maybe_screenshot(self) -> None:
        if self.screenshot_path is None or self.shot is not None:
            return
        world_time = self.nav.world.time
        if self.screenshot_at is not None:
            due = world_time >= self.screenshot_at
        else:
            due = self.prompt is not None and world_time >= self.prompt[2] + 1.0
        if due:
            self.shot = self.view.screenshot(self.screenshot_path)

    def screenshot(self, path: str | Path) -> Path:
        """Draw the world as it is now and save the picture as a PNG (the window's surface)."""
        if self.view is None:
            from pernav.play.view import PlayView

            self.view = PlayView(self.nav.town, window=False)
        self.view.draw(self, 1.0)
        return self.view.screenshot(path)

    # ----- the drive --------------------------------------------------------------------------------
    def run(self, max_steps: int = MAX_STEPS) -> PlayResult:
        """Drive until arrival, the time limit, ``max_steps`` decisions or the person quits."""
        from pernav.trainer.collect import episode_metrics

        td = self.env.reset()
        nav = self.nav
        self._tap = InputTap(self.controls)  # the controls now: a caller may have set them after __init__
        nav.world.ego.external = self._tap
        apply_handling(nav.world.ego)  # the person's truck steers as slowly as the simulated truck driver's
        nav.world.ego.color = (50, 200, 0)  # drawn green among the blue traffic
        nav.on_prompt, nav.on_frame = self._on_prompt, self._on_frame
        self._snapshot()
        self._update_distance()
        if self.view is not None:
            self.view.draw(self, 1.0)
            self.view.present()
        steps: list[TensorDictBase] = []
        interrupted = ctrl_c = False
        try:
            if self.ready:  # the clock starts after the person's go and the countdown
                if self.calibrate and hasattr(self.controls, "axes_now"):
                    self._calibrate()
                self._wait_ready()
                self._count_down()
            self.log.start()
            self.t0 = self._t_out = time.perf_counter()
            with torch.no_grad():
                for _ in range(max_steps):
                    td.update(self.policy(td))
                    self.log.add_step(nav.world.time, *nav.decode(td["action"]))
                    td = self.env.step(td)
                    nxt = self.env.step_mdp(td)  # what env.rollout does between two steps
                    steps.append(td.copy())
                    if bool(td["next", "done"].any()):
                        break
                    td = nxt
        except PlayQuit:
            interrupted = True
        except KeyboardInterrupt:  # Ctrl-C: kept as a quit drive; the caller stops after recording it
            interrupted = ctrl_c = True
        finally:
            nav.on_prompt = nav.on_frame = None
            self.screen = None
            self.log.stop()
        if self.view is not None and self.screenshot_path is not None and self.shot is None:
            self.shot = self.screenshot(self.screenshot_path)  # the drive ended before the moment asked for
        trajectory = torch.stack(steps).contiguous() if steps else None
        metrics: dict[str, Any] = {}
        if trajectory is not None:
            metrics = episode_metrics(trajectory)
            last = trajectory[-1]["next"]
            metrics.update(reroutes=int(last["reroutes"]), time=float(last["time"]))
        else:
            metrics.update(completed=False, steps=0)
        metrics.update(interrupted=interrupted, town=self.town, route=self.route, user=self.user,
                       policy=self.policy_name, seed=self.seed, playback=self.playback,
                       controls=type(self.controls).__name__, frequency=int(nav.config["frequency"]),
                       pauses=self.pauses, paused_s=round(self.paused_s, 2), stopped_by=(
                           "ctrl-c" if ctrl_c else "person" if interrupted else None))
        if self.ready and not interrupted:
            try:
                self._show_result(metrics)
            except KeyboardInterrupt:  # the drive is whole; the caller stops after recording it
                ctrl_c = True
        return PlayResult(trajectory, metrics, list(self.frame_ms), ctrl_c, self.log)

    # ----- the screens around a drive ----------------------------------------------------------------
    def _screen_tick(self) -> None:
        """One picture's wait of a screen, then the person's keys (a quit confirmed raises :class:`PlayQuit`)."""
        if self.realtime:
            time.sleep(1.0 / SCREEN_HZ)
        self.controls.poll()
        if _flag(self.controls, "quit_requested"):
            raise PlayQuit

    def _panel(self, lines: list[str], big: str | None = None) -> None:
        if self.view is None:
            return
        from pernav.play.screens import show_panel

        self.view.draw(self, 1.0)
        if _flag(self.controls, "confirming"):
            big, lines = "Quit?", ["Y: stop this drive (what was driven is kept)", "any other key: go on driving",
                                   "(or hold Esc for a second)"]
        show_panel(self.view, lines, big=big, title=self.title)

    def _set_caption(self) -> None:
        if self.view is not None and getattr(self.view, "window", False):
            self.view.pygame.display.set_caption(f"pernav play - {self.title}" if self.title else "pernav play")

    def _wait_ready(self) -> None:
        """The ready screen until the person's go (Enter, space or a button); Esc asks whether to quit."""
        self.screen = "ready"
        self._set_caption()
        getattr(self.controls, "take_go", lambda: False)()  # a go pressed before the screen does not count
        lines = [f"{self.town}, route {self.route}", "Press Enter (or a wheel button) when you are ready",
                 "P: pause   Esc: stop (asks first)"]
        if self.notice:
            lines.append(self.notice)
        while True:
            self._panel(lines, big="Ready?")
            self._screen_tick()
            if getattr(self.controls, "take_go", lambda: True)() and not _flag(self.controls, "holding"):
                break

    def _count_down(self) -> None:
        """The countdown, the world still (seconds shown 3, 2, 1)."""
        self.screen = "countdown"
        end = time.perf_counter() + self.countdown
        while (left := end - time.perf_counter()) > 0:
            self._panel(["Get ready"], big=str(math.ceil(left)))
            self._screen_tick()
            if not self.realtime:
                time.sleep(min(left, 1.0 / SCREEN_HZ))  # a screen tick did not wait: the countdown still takes its time
        self.screen = None

    def _hold(self) -> None:
        """The world stands still while the person pauses or is asked whether to quit; a countdown follows a pause.
        The wall clock of the drive goes on from here (a pause counts neither in its time nor in the pacing)."""
        start = time.perf_counter()
        paused = False
        while _flag(self.controls, "holding"):
            if _flag(self.controls, "paused") and not paused:
                paused, self.pauses = True, self.pauses + 1
            self.screen = "confirm" if _flag(self.controls, "confirming") else "pause"
            self._panel(["P or Enter: drive on", "Esc: stop (asks first)"], big="Paused")
            self._screen_tick()
        if paused and self.countdown > 0:
            self._count_down()
        self.screen = None
        held = time.perf_counter() - start
        if paused:
            self.paused_s += held
        self.t0 += held

    def _calibrate(self) -> None:
        """A wheel's axes, live, until the person's go (skip it at once with Enter)."""
        from pernav.play.controls import AxisCheck
        from pernav.play.screens import show_axes

        self.screen = "calibrate"
        self._set_caption()
        check = AxisCheck()
        getattr(self.controls, "take_go", lambda: False)()
        while True:
            values = self.controls.axes_now()
            check.update(values)
            self.calibration = check.moved()
            if self.view is not None:
                show_axes(self.view, values, self.calibration, title=self.title)
            self._screen_tick()
            if self.controls.take_go() and not _flag(self.controls, "holding"):
                break

    def _show_result(self, metrics: Mapping[str, Any]) -> None:
        """The drive's result until the person's go."""
        from pernav.play.screens import result_lines

        self.screen = "result"
        getattr(self.controls, "take_go", lambda: False)()
        lines = [*result_lines(metrics, self.hide_cost), "Press Enter to continue"]
        try:
            while True:
                self._panel(lines)
                self._screen_tick()
                if getattr(self.controls, "take_go", lambda: True)() and not _flag(self.controls, "holding"):
                    break
        except PlayQuit:  # quitting at the end screen leaves it: the drive is over anyway
            pass
        finally:
            self.screen = None

    def close(self) -> None:
        """Close the window and the speaker; a session given its ``view`` is one drive of a longer session, whose
        owner closes the window and the speaker after its last drive: both stay open."""
        if not self._own_view:
            return
        if self.view is not None:
            self.view.close()
        if self.speaker is not None and hasattr(self.speaker, "close"):
            self.speaker.close()
