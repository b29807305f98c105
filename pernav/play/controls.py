"""A person's controls of the navigated car (keyboard, joystick or wheel) and a scripted bot that presses keys.

Each is an :class:`~pernav.world.controls.ExternalControls`: set it as ``world.ego.external`` and the car takes
its steering, throttle and brake from ``read(car)`` every frame, through the same vehicle physics, traffic,
right of way and event counting as the simulated drivers. The simulated driver still hears every prompt.

Keys: arrows or WASD (left/right steer, up/W throttle, down/S or space brake). The session's keys
(:class:`SessionKeys`) need a deliberate act to quit: Esc asks, Y confirms (any other key drives on), or Esc held for
a second; P pauses the world. Q does nothing (beside W and A, it was pressed by accident).

Example:
    >>> from pernav.world.towns import get_town
    >>> from pernav.world.drivers import resolve, named_user, Context
    >>> from pernav.world.simulation import World
    >>> town = get_town("Town1")
    >>> world = World(town, resolve(named_user("user1"), Context()), town.routes[0], seed=0, n_traffic=2)
    >>> world.ego.external = ScriptedControls()
    >>> for _ in range(30):
    ...     world.frame()
    >>> world.ego.speed > 1.0  # the bot pressed the throttle key
    True
"""

from __future__ import annotations

import os
import time
from collections.abc import Collection, Mapping
from typing import Any

from pernav.world.controls import ControlInput
from pernav.world.driver_car import DriverCar

__all__ = ["AxisCheck", "ControlsError", "JoystickControls", "KeyboardControls", "ScriptedControls", "SessionKeys",
           "parse_axes"]

HOLD_TO_QUIT_S = 1.0  # Esc held this long quits without the confirmation

os.environ.setdefault("PYGAME_HIDE_SUPPORT_PROMPT", "1")


class ControlsError(ValueError):
    """The controls cannot be used (no display for the keyboard, no joystick connected)."""


class SessionKeys:
    """The session's keys as a small state machine, apart from pygame (its events are fed in by ``poll``).

    ``press("escape")`` asks to quit (``confirming``: the world holds); then ``press("yes")`` quits and any other key
    drives on; Esc held :data:`HOLD_TO_QUIT_S` (``update``) quits without asking. ``press("pause")`` toggles
    ``paused``; ``press("go")`` (Enter, space, a joystick button) starts a drive, leaves an end screen or a pause.
    Every other key (Q among them) does nothing. ``holding``: the world must stand still.

    >>> keys = SessionKeys()
    >>> keys.press("q"); keys.quit_requested
    False
    >>> keys.press("escape", now=0.0); keys.release("escape"); keys.press("left"); keys.holding, keys.quit_requested
    (False, False)
    >>> keys.press("escape", now=0.0); keys.update(now=1.2); keys.quit_requested
    True
    """

    quit_requested = False
    paused = False
    confirming = False
    _escape_since: float | None = None
    _go = False

    @property
    def holding(self) -> bool:
        """Whether the world stands still (paused, or the quit question is on screen)."""
        return self.paused or self.confirming

    def press(self, key: str, now: float | None = None) -> None:
        """A key went down: ``escape``, ``yes``, ``pause``, ``go`` or any other name."""
        if key == "escape":
            self.confirming, self._escape_since = True, time.monotonic() if now is None else now
        elif self.confirming:  # the quit question: Y quits, anything else drives on
            self.confirming = False
            self.quit_requested = key == "yes"
        elif key == "pause":
            self.paused = not self.paused
        elif key == "go":
            if self.paused:
                self.paused = False
            else:
                self._go = True

    def release(self, key: str) -> None:
        """A key went up (only Esc's matters: how long it was held)."""
        if key == "escape":
            self._escape_since = None

    def close_window(self) -> None:
        """The window's close button: asks as Esc does."""
        self.confirming = True

    def update(self, now: float | None = None) -> None:
        """Quit when Esc has been held long enough."""
        now = time.monotonic() if now is None else now
        if self._escape_since is not None and now - self._escape_since >= HOLD_TO_QUIT_S:
            self.quit_requested = True

    def take_go(self) -> bool:
        """Whether "go" was pressed since the last call (and forget it)."""
        go, self._go = self._go, False
        return go


def _key_name(pygame: Any, key: int) -> str:
    if key == pygame.K_ESCAPE:
        return "escape"
    if key == pygame.K_y:
        return "yes"
    if key == pygame.K_p:
        return "pause"
    if key in (pygame.K_RETURN, pygame.K_KP_ENTER, pygame.K_SPACE):
        return "go"
    return pygame.key.name(key) or str(key)


class _Controls(SessionKeys):
    """Common part: the session's keys, fed from the window's events."""

    keeps_lanes = False

    def poll(self) -> None:
        """Handle the window's pending events (see :class:`SessionKeys`); called once per drawn frame."""
        import pygame  # lazy: pygame is loaded by controls in use, not when the module is imported

        if not pygame.display.get_init():
            return
        for event in pygame.event.get():
            if event.type == pygame.QUIT:
                self.close_window()
            elif event.type == pygame.KEYDOWN:
                self.press(_key_name(pygame, event.key))
            elif event.type == pygame.KEYUP:
                self.release(_key_name(pygame, event.key))
            elif event.type == pygame.JOYBUTTONDOWN:
                self.press("go")
        self.update()

    def read(self, car: DriverCar) -> ControlInput:  # pragma: no cover - each kind defines it
        raise NotImplementedError


class KeyboardControls(_Controls):
    """Arrow keys or WASD, on or off (the wheel turns at a fixed rate while a key is held and centres when released).

    Needs the pygame window (its keyboard focus): make it after the window is open.
    """

    def __init__(self) -> None:
        import pygame  # lazy: pygame is loaded by controls in use, not when the module is imported

        if not pygame.display.get_init() or pygame.display.get_surface() is None:
            raise ControlsError("keyboard controls need the game window: open it first (or use --headless)")
        self.pygame = pygame

    def read(self, car: DriverCar) -> ControlInput:
        pg = self.pygame
        keys = pg.key.get_pressed()
        left = keys[pg.K_LEFT] or keys[pg.K_a]
        right = keys[pg.K_RIGHT] or keys[pg.K_d]
        return ControlInput(steer=float(right) - float(left), throttle=float(keys[pg.K_UP] or keys[pg.K_w]),
                            brake=float(keys[pg.K_DOWN] or keys[pg.K_s] or keys[pg.K_SPACE]), digital=True)


AXIS_NAMES = ("steer", "throttle", "brake")


def parse_axes(text: str) -> dict[str, Any]:
    """``--joystick-axes``: ``STEER,THROTTLE,BRAKE`` axis indices (or ``STEER,PEDAL``: one axis for both pedals), each
    inverted by a ``~`` prefix (``-`` works too, after the first); :class:`JoystickControls`' keyword arguments.

    >>> parse_axes("0,~2,3")
    {'steer_axis': 0, 'throttle_axis': 2, 'brake_axis': 3, 'invert': ('throttle',)}
    >>> parse_axes("~0,1")
    {'steer_axis': 0, 'pedal_axis': 1, 'invert': ('steer',)}
    """
    parts = [p.strip() for p in str(text).split(",")]
    if len(parts) not in (2, 3):
        raise ControlsError(f"--joystick-axes {text!r}: give STEER,THROTTLE,BRAKE (or STEER,PEDAL) axis indices, "
                            "e.g. 0,2,3 or 0,~2,~3 (~ inverts an axis)")
    names = AXIS_NAMES if len(parts) == 3 else ("steer", "pedal")
    out: dict[str, Any] = {}
    invert = []
    for name, part in zip(names, parts, strict=True):
        flipped = part[:1] in ("~", "-")
        digits = part[1:] if flipped else part
        if not digits.isdigit():
            raise ControlsError(f"--joystick-axes {text!r}: {part!r} is not an axis index (0, 1, ... with ~ to invert)")
        out[f"{name}_axis"] = int(digits)
        if flipped:
            invert.append(name)
    if len(set(out.values())) != len(out):
        raise ControlsError(f"--joystick-axes {text!r}: an axis is used twice")
    out["invert"] = tuple(invert)
    return out


class JoystickControls(_Controls):
    """A joystick, gamepad or wheel: continuous steering, throttle and brake.

    ``steer_axis`` gives the steering (-1 left .. 1 right). Pedals: with ``throttle_axis`` and ``brake_axis`` each
    pedal is its own axis, at ``pedal_rest`` (-1 or 1) when released (gamepad triggers and most wheels' pedals);
    without them one stick's ``pedal_axis`` does both (pushed forward, negative: throttle; pulled back: brake).
    ``invert`` names the axes read negated (``steer``, ``throttle``, ``brake``, ``pedal``; a pedal resting at +1 is an
    inverted one). ``dead_zone`` of the stick is ignored. A button is "go" (start a drive, leave a screen).
    ``stick``: an opened pygame joystick (or anything with ``get_axis``, ``get_numaxes``, ``get_name``; default:
    joystick ``index``). Raises :class:`ControlsError` when no joystick is connected or an axis is missing.
    """

    def __init__(self, index: int = 0, steer_axis: int = 0, pedal_axis: int = 1, throttle_axis: int | None = None,
                 brake_axis: int | None = None, pedal_rest: float = -1.0, dead_zone: float = 0.05,
                 invert: Collection[str] = (), stick: Any = None) -> None:
        if stick is None:
            import pygame  # lazy: pygame is loaded by controls in use, not when the module is imported

            pygame.joystick.init()
            count = pygame.joystick.get_count()
            if count == 0:
                raise ControlsError("no joystick or wheel connected (plug one in, or use --input keyboard)")
            if not 0 <= index < count:
                raise ControlsError(f"joystick {index} not connected; connected: 0-{count - 1}")
            stick = pygame.joystick.Joystick(index)
            stick.init()
        self.stick: Any = stick
        if (throttle_axis is None) != (brake_axis is None):
            raise ControlsError("give both a throttle and a brake axis, or neither (one pedal axis)")
        unknown = sorted(set(invert) - {*AXIS_NAMES, "pedal"})
        if unknown:
            raise ControlsError(f"cannot invert {unknown[0]!r}: the axes are steer, throttle, brake, pedal")
        axes = self.stick.get_numaxes()
        wanted = [steer_axis, *([pedal_axis] if throttle_axis is None else [throttle_axis, brake_axis])]
        if any(not 0 <= a < axes for a in wanted):
            raise ControlsError(f"joystick {self.stick.get_name()!r} has axes 0-{axes - 1}, not {wanted}")
        self.steer_axis, self.pedal_axis = steer_axis, pedal_axis
        self.throttle_axis, self.brake_axis = throttle_axis, brake_axis
        self.pedal_rest, self.dead_zone = float(pedal_rest), float(dead_zone)
        self.invert = frozenset(invert)

    def _axis(self, name: str, axis: int) -> float:
        value = float(self.stick.get_axis(axis))
        return -value if name in self.invert else value

    def _pedal(self, name: str, axis: int) -> float:
        """0 (released) .. 1 (pressed) of a pedal axis resting at ``pedal_rest``."""
        return min(max(abs(self._axis(name, axis) - self.pedal_rest) / 2.0, 0.0), 1.0)

    def axes_now(self) -> dict[str, float]:
        """The steering (-1 .. 1), throttle and brake (0 .. 1) the axes give now, before the dead zone."""
        steer = self._axis("steer", self.steer_axis)
        if self.throttle_axis is None:
            pedal = self._axis("pedal", self.pedal_axis)
            return {"steer": steer, "throttle": max(-pedal, 0.0), "brake": max(pedal, 0.0)}
        return {"steer": steer, "throttle": self._pedal("throttle", self.throttle_axis),
                "brake": self._pedal("brake", self.brake_axis)}

    def read(self, car: DriverCar) -> ControlInput:
        now = self.axes_now()
        steer = 0.0 if abs(now["steer"]) < self.dead_zone else now["steer"]
        if self.throttle_axis is None:  # one stick: its dead zone for both pedals
            return ControlInput(steer=steer, throttle=now["throttle"] if now["throttle"] >= self.dead_zone else 0.0,
                                brake=now["brake"] if now["brake"] >= self.dead_zone else 0.0)
        return ControlInput(steer=steer, throttle=now["throttle"], brake=now["brake"])


class AxisCheck:
    """The calibration step's bookkeeping: how far each control has travelled (``update`` with
    :meth:`JoystickControls.axes_now`), and whether it has been moved through its range (steering both ways past
    half, each pedal past half).

    >>> check = AxisCheck()
    >>> check.update({"steer": -0.8, "throttle": 0.0, "brake": 0.9}); check.update({"steer": 0.7})
    >>> check.moved()
    {'steer': True, 'throttle': False, 'brake': True}
    """

    def __init__(self) -> None:
        self.low = dict.fromkeys(AXIS_NAMES, 0.0)
        self.high = dict.fromkeys(AXIS_NAMES, 0.0)

    def update(self, values: Mapping[str, float]) -> None:
        """Take the controls' values now."""
        for name, value in values.items():
            self.low[name], self.high[name] = min(self.low[name], value), max(self.high[name], value)

    def moved(self) -> dict[str, bool]:
        """Per control, whether it went through its range."""
        return {"steer": self.low["steer"] < -0.5 and self.high["steer"] > 0.5,
                "throttle": self.high["throttle"] > 0.5, "brake": self.high["brake"] > 0.5}


class ScriptedControls(_Controls):
    """A bot that presses the keys the simulated driver would: each frame it asks the simulated driver of the
    same car what it would do (:meth:`~pernav.world.driver_car.DriverCar.simulated_controls`, which also makes its
    branch and lane decisions from what it heard), then holds the steering key that brings the wheel closest to
    that, and the pedal key that keeps the acceleration it got on average closest to the one wanted (the error
    carries over to the next frames: a driver tapping the brake). ``quit_after`` frames, it asks to quit (a
    person pressing Esc). Works without any display.

    >>> bot = ScriptedControls()
    >>> bot.keeps_lanes, bot.keys
    (True, frozenset())
    """

    keeps_lanes = True  # lane changes are the simulated driver's decisions on the car's path

    def __init__(self, quit_after: int | None = None) -> None:
        self.quit_after = quit_after
        self.frames = 0
        self.debt = 0.0  # acceleration wanted but not yet given (m/s^2, summed over frames)
        self.keys: frozenset[str] = frozenset()  # the keys held this frame: left, right, throttle, brake

    def poll(self) -> None:
        if self.quit_after is not None and self.frames >= self.quit_after:
            self.quit_requested = True

    def take_go(self) -> bool:
        """The bot is always ready."""
        return True

    def read(self, car: DriverCar) -> ControlInput:
        self.frames += 1
        want_steer, want_acc = car.simulated_controls()
        steer = min((0.0, -1.0, 1.0), key=lambda k: abs(car.steer_after(ControlInput(steer=k, digital=True)) - want_steer))
        pedals = [ControlInput(steer=steer, digital=True), ControlInput(steer=steer, throttle=1.0, digital=True),
                  ControlInput(steer=steer, brake=1.0, digital=True)]
        target = want_acc + self.debt
        chosen = min(pedals, key=lambda p: abs(car.accel_of(p) - target))
        # the error carries over, within bounds (no wind-up while stopped at a line or at full throttle)
        self.debt = min(max(target - car.accel_of(chosen), -6.0), 3.0)
        self.keys = frozenset(name for name, on in (("left", steer < 0), ("right", steer > 0),
                                                    ("throttle", chosen.throttle > 0), ("brake", chosen.brake > 0))
                              if on)
        return chosen
