"""Shared by the play tests: a scripted person whose controls are a function of the frame."""

from __future__ import annotations

from collections.abc import Callable

from pernav.world.controls import ControlInput


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
