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
``"action"`` (e.g. a study's MPC policy module, :meth:`pernav.study.finished.FinishedStudy.policy`; in the env's
action space: the instructions, or each instruction at each playback speed). Everything but the world, the people
and the objects of a drive is one :class:`~pernav.play.options.PlayOptions`.

Example (headless: the scripted bot drives, nothing is drawn):
    >>> result = PlaySession("Town1", 0, options=PlayOptions(n_traffic=2)).run()
    >>> result.metrics["completed"], result.trajectory["history"].shape[1:]
    (True, torch.Size([5, 21]))
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np
import torch
from tensordict import TensorDictBase

from pernav.env.navigation import load_user
from pernav.env.torchrl_env import explore_module, navigation_of, oracle_module
from pernav.play.audio import Speaker
from pernav.play.controls import AxisCheck, ScriptedControls
from pernav.play.framelog import DriveLog, InputTap, PlayResult
from pernav.play.handling import apply_handling
from pernav.play.options import PLAY_POLICIES, POLICIES, PlayError, PlayOptions, check_drive
from pernav.play.screens import result_lines, show_axes, show_panel
from pernav.play.view import PlayView
from pernav.trainer.collect import episode_metrics, history_env
from pernav.world.constants import ACTION_NAMES, N_PLAYBACKS, PLAYBACK, audio_duration
from pernav.world.drivers import CONTEXT_CHOICES, ProfileError

__all__ = ["PLAY_POLICIES", "POLICIES", "PlayError", "PlayOptions", "PlayQuit", "PlayResult", "PlaySession",
           "make_speaker", "open_speaker"]

MAX_STEPS = 2000  # the env's time limit ends a drive far earlier; this only bounds a runaway loop
SCREEN_HZ = 30  # pictures per second of the screens around a drive (ready, pause, countdown)


class PlayQuit(Exception):
    """The person quit (Esc then Y, Esc held, or the window's close button then Y)."""


def open_speaker(audio: bool | None) -> tuple[Any, str | None]:
    """The speaker of the prompts and, when there is no sound although none was refused, why (to tell the person):
    ``(None, None)`` when ``audio`` is False; ``(None, reason)`` when it is None (the default: sound if possible) and
    no speaker or device is there (pygame missing among them); with ``audio=True`` a missing one is a
    :class:`PlayError`."""
    if audio is False:
        return None, None
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
    """A rule-based policy of the env with playback actions (whose rules speak at normal speed) speaking at
    ``playback``."""
    index = PLAYBACK.index(playback)

    def policy(td: TensorDictBase) -> TensorDictBase:
        td = module(td)
        td["action"] = td["action"] // N_PLAYBACKS * N_PLAYBACKS + index
        return td

    return policy


class PlaySession:
    """One drive of ``route`` in ``town`` by a person (or the scripted bot) with prompts from ``policy``.

    ``user`` (name, mapping or file, with ``context`` overrides) is who the oracle times its prompts for, and the
    car's vehicle; ``controls`` default to :class:`~pernav.play.controls.ScriptedControls`; ``speaker`` says the
    prompts played (None: text only). ``view``: an open :class:`~pernav.play.view.PlayView` to draw into instead of
    a new one (a session of drives keeps one window; :meth:`close` leaves it open). ``options``: how the drive runs
    (:class:`~pernav.play.options.PlayOptions`: the world's seed and traffic, the window, the screens around the
    drive); its ``K`` and ``env_config`` default to the policy's ``K`` and ``env_config`` attributes where it has
    them (a study's policy, :meth:`pernav.study.finished.FinishedStudy.policy`). ``settings``: fields of
    :class:`PlayOptions` by keyword, over ``options`` (the keyword form of the options, for callers that give them
    one by one).

    >>> session = PlaySession("Town1", 0, user="user3", policy="oracle", options=PlayOptions(n_traffic=2))
    >>> result = session.run(max_steps=3)
    >>> result.trajectory.shape, result.metrics["interrupted"]
    (torch.Size([3]), False)
    """

    def __init__(self, town: str = "Town1", route: int = 0, user: Any = "user1", context: dict | None = None,
                 policy: str | Callable[[TensorDictBase], TensorDictBase] = "explore", controls: Any = None,
                 speaker: Any = None, view: Any = None, options: PlayOptions | None = None) -> None:
        options = options if options is not None else PlayOptions()
        check_drive(town, route, policy, options)
        self.options = options
        self.town, self.route, self.seed, self.playback = town, int(route), int(options.seed), options.playback
        self.user = user if isinstance(user, str) else "custom"
        self.env = self._make_env(user, context, policy)
        self.nav = navigation_of(self.env)
        if isinstance(policy, str):
            module = explore_module() if policy == "explore" else oracle_module()
            self.policy = _with_playback(module, self.playback) if self.playback != "normal" else module
            self.policy_name = policy
        else:
            self.policy, self.policy_name = policy, getattr(policy, "__name__", type(policy).__name__)
        self.controls = controls if controls is not None else ScriptedControls()
        self.speaker = speaker
        self.realtime = options.window if options.realtime is None else bool(options.realtime)
        self.ready = (options.window and self.realtime) if options.ready is None else bool(options.ready)
        self.countdown, self.title, self.notice = float(options.countdown), options.title, options.notice
        self.hide_cost, self.calibrate = bool(options.hide_cost), bool(options.calibrate)
        self.counters = bool(options.counters)  # the live counters on the HUD and the result screen
        self.pauses, self.paused_s = 0, 0.0  # pauses taken, and their wall-clock seconds (the world stood still)
        self.screen: str | None = None  # the screen shown now: calibrate, ready, countdown, pause, confirm, result
        self.calibration: dict[str, bool] | None = None  # per control, whether the calibration saw it move
        self.screenshot_path = None if options.screenshot is None else Path(options.screenshot)
        self.screenshot_at = options.screenshot_at
        self.progress = options.progress  # the HUD's counter during the drive ("Drive 2 of 6"; else the title)
        # the announced manoeuvre of the prompt on screen (see prompt_text); the car's route progress every frame
        self._prompted: tuple[int, str, float] | None = None
        self._announced: tuple[Any, Any] | None = None  # (route, manoeuvre), None: nothing ahead when it played
        self.route_progress = 0.0
        self.view = view
        self._own_view = view is None  # a view given stays open at close(): its owner (a session of drives) closes it
        if view is not None:
            view.new_drive(self.nav.town)
        elif options.window or options.draw or options.screenshot is not None:
            self.view = PlayView(self.nav.town, size=options.size, window=options.window)
        frequency = int(self.nav.config["frequency"])
        self.dt = 1.0 / frequency
        self.draws_per_frame = max(1, math.ceil(options.fps / frequency))
        self.prompt: tuple[int, str, float] | None = None  # (instruction, playback, world time) last played
        self.distance = math.inf  # m to the next decision manoeuvre (updated every frame)
        self.next_manoeuvre = "none"
        self.frame_ms: list[float] = []
        self._snap: dict[int, tuple[np.ndarray, float]] = {}
        self.frames = 0
        self.shot: Path | None = None
        self.log = DriveLog(frequency)  # the lab's record of the drive (pernav.play.framelog)
        self._tap: InputTap | None = None  # the car's controls in a drive, keeping for the log what it got each frame

    def _make_env(self, user: Any, context: Mapping[str, Any] | None, policy: Any) -> Any:
        """The study's navigation env of this drive (its history window), for ``user`` with ``context``."""
        options = self.options
        profile, ctx = load_user(user)
        ctx_dict = {**(ctx.to_dict() if ctx else {}), **(context or {})}
        unknown = sorted(set(ctx_dict) - set(CONTEXT_CHOICES))
        if unknown:
            raise ProfileError(f"unknown context field {unknown[0]!r}; allowed: {', '.join(CONTEXT_CHOICES)}")
        # a learned policy plans on the env its study used (history K, planning context lengths): a policy that
        # carries them (pernav.study.finished.StudyPolicy) gives the defaults, so its drive needs no settings
        env_config = getattr(policy, "env_config", None) if options.env_config is None else options.env_config
        K = int(getattr(policy, "K", 5)) if options.K is None else int(options.K)
        config = {"n_traffic": int(options.n_traffic), "adaptive_speed": options.playback != "normal",
                  **dict(env_config or {})}
        reset = {"route": int(self.route), "user": profile, "context": ctx_dict}
        return history_env(self.town, reset, config=config, seed=int(options.seed), K=K)

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
            self.view = PlayView(self.nav.town, window=False)
        self.view.draw(self, 1.0)
        return self.view.screenshot(path)

    # ----- the drive --------------------------------------------------------------------------------
    def run(self, max_steps: int = MAX_STEPS) -> PlayResult:
        """Drive until arrival, the time limit, ``max_steps`` decisions or the person quits."""
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
        self.screen = "result"
        getattr(self.controls, "take_go", lambda: False)()
        lines = [*result_lines(metrics, self.hide_cost, self.counters), "Press Enter to continue"]
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
