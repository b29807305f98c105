"""A person's controls of the navigated car (keyboard, joystick or wheel) and a scripted bot that presses keys.

Each is an :class:`~pernav.world.simulation.ExternalControls`: set it as ``world.ego.external`` and the car takes
its steering, throttle and brake from ``read(car)`` every frame, through the same vehicle physics, traffic,
right of way and event counting as the simulated drivers. The simulated driver still hears every prompt.

Keys: arrows or WASD (left/right steer, up/W throttle, down/S or space brake); Esc or Q quits.

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
from typing import Any

from pernav.world.simulation import ControlInput, DriverCar

__all__ = ["ControlsError", "JoystickControls", "KeyboardControls", "ScriptedControls"]

os.environ.setdefault("PYGAME_HIDE_SUPPORT_PROMPT", "1")


class ControlsError(ValueError):
    """The controls cannot be used (no display for the keyboard, no joystick connected)."""


class _Controls:
    """Common part: the quit request and the window's events."""

    keeps_lanes = False
    quit_requested = False

    def poll(self) -> None:
        """Handle the window's pending events (Esc, Q or closing the window quits); called once per drawn frame."""
        import pygame

        if not pygame.display.get_init():
            return
        for event in pygame.event.get():
            if event.type == pygame.QUIT or (event.type == pygame.KEYDOWN and event.key in (pygame.K_ESCAPE, pygame.K_q)):
                self.quit_requested = True

    def read(self, car: DriverCar) -> ControlInput:  # pragma: no cover - each kind defines it
        raise NotImplementedError


class KeyboardControls(_Controls):
    """Arrow keys or WASD, on or off (the wheel turns at a fixed rate while a key is held and centres when released).

    Needs the pygame window (its keyboard focus): make it after the window is open.
    """

    def __init__(self) -> None:
        import pygame

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


class JoystickControls(_Controls):
    """A joystick, gamepad or wheel: continuous steering, throttle and brake.

    ``steer_axis`` gives the steering (-1 left .. 1 right). Pedals: with ``throttle_axis`` and ``brake_axis`` each
    pedal is its own axis, at ``pedal_rest`` (-1 or 1) when released (gamepad triggers and most wheels' pedals);
    without them one stick's ``pedal_axis`` does both (pushed forward, negative: throttle; pulled back: brake).
    ``dead_zone`` of the stick is ignored. Raises :class:`ControlsError` when no joystick is connected.
    """

    def __init__(self, index: int = 0, steer_axis: int = 0, pedal_axis: int = 1, throttle_axis: int | None = None,
                 brake_axis: int | None = None, pedal_rest: float = -1.0, dead_zone: float = 0.05) -> None:
        import pygame

        pygame.joystick.init()
        count = pygame.joystick.get_count()
        if count == 0:
            raise ControlsError("no joystick or wheel connected (plug one in, or use --input keyboard)")
        if not 0 <= index < count:
            raise ControlsError(f"joystick {index} not connected; connected: 0-{count - 1}")
        self.stick: Any = pygame.joystick.Joystick(index)
        self.stick.init()
        axes = self.stick.get_numaxes()
        wanted = [steer_axis, *([pedal_axis] if throttle_axis is None else [throttle_axis, brake_axis])]
        if any(a is None or not 0 <= a < axes for a in wanted):
            raise ControlsError(f"joystick {self.stick.get_name()!r} has axes 0-{axes - 1}, not {wanted}")
        self.steer_axis, self.pedal_axis = steer_axis, pedal_axis
        self.throttle_axis, self.brake_axis = throttle_axis, brake_axis
        self.pedal_rest, self.dead_zone = float(pedal_rest), float(dead_zone)

    def _pedal(self, axis: int) -> float:
        """0 (released) .. 1 (pressed) of a pedal axis resting at ``pedal_rest``."""
        return min(max(abs(self.stick.get_axis(axis) - self.pedal_rest) / 2.0, 0.0), 1.0)

    def read(self, car: DriverCar) -> ControlInput:
        steer = float(self.stick.get_axis(self.steer_axis))
        steer = 0.0 if abs(steer) < self.dead_zone else steer
        if self.throttle_axis is None:
            pedal = float(self.stick.get_axis(self.pedal_axis))
            pedal = 0.0 if abs(pedal) < self.dead_zone else pedal
            return ControlInput(steer=steer, throttle=max(-pedal, 0.0), brake=max(pedal, 0.0))
        return ControlInput(steer=steer, throttle=self._pedal(self.throttle_axis), brake=self._pedal(self.brake_axis))


class ScriptedControls(_Controls):
    """A bot that presses the keys the simulated driver would: each frame it asks the simulated driver of the
    same car what it would do (:meth:`~pernav.world.simulation.DriverCar.simulated_controls`, which also makes its
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
