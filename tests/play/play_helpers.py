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


def watch_session_window(monkeypatch, module) -> dict[str, list]:
    """Drive a windowed session of ``module`` (``pernav.play.personal`` or ``.believe``) fast: each drive's
    PlaySession is made without its window (nothing drawn, not paced), noting the ``view`` it was given and whether
    the session's window was open then (``views``: ``(view, open)``); every panel drawn is noted (``panels``: its
    lines)."""
    import pygame

    import pernav.play.screens as screens

    seen: dict[str, list] = {"views": [], "panels": []}

    class Drive(module.PlaySession):
        def __init__(self, *args, **kwargs) -> None:
            seen["views"].append((kwargs.pop("view"), pygame.display.get_init()))
            super().__init__(*args, **{**kwargs, "window": False})

    panel = screens.show_panel
    monkeypatch.setattr(module, "PlaySession", Drive)
    monkeypatch.setattr(screens, "show_panel",
                        lambda view, lines, **kw: seen["panels"].append(list(lines)) or panel(view, lines, **kw))
    return seen
