"""A question of a lab session's questionnaire, asked in the play window between blocks (:mod:`pernav.play.lab`).

A scale question takes a number key (the scale's, e.g. 1-7) and Enter to confirm, Backspace to change it; a
free-text question takes typed text and Enter. The window's close button does nothing here: the experimenter ends
a session between drives with Ctrl-C in the terminal.

Example (events scripted: no keyboard needed):
    >>> import pygame
    >>> from pernav.play.view import PlayView
    >>> from pernav.world.towns import get_town
    >>> keys = [[pygame.event.Event(pygame.KEYDOWN, key=pygame.K_5, unicode="5")],
    ...         [pygame.event.Event(pygame.KEYDOWN, key=pygame.K_RETURN, unicode="\\r")]]
    >>> ask_question(PlayView(get_town("Town1")), "How hard was it?", (1, 7), events=lambda: keys.pop(0))
    5
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

from pernav.play.screens import show_panel

__all__ = ["ask_question"]


def ask_question(view: Any, text: str, scale: tuple[int, int] | None, title: str | None = None,
                 events: Callable[[], list[Any]] | None = None) -> int | str:
    """Show ``text`` on ``view`` until the person answers: a whole number on ``scale`` (inclusive), or free text when
    ``scale`` is None. ``events``: where the key events come from (default: the window's)."""
    import pygame  # lazy: pygame is loaded when a question is shown, not when the module is imported

    events = events or pygame.event.get
    typed = ""
    if scale is not None:
        hint = f"Press a number from {scale[0]} to {scale[1]}, then Enter"
    else:
        hint = "Type your answer, then Enter"
    while True:
        view.surface.fill((0, 0, 0))
        show_panel(view, [text, hint, "Backspace: change the answer"], big=typed or "?", title=title)
        for event in events():
            if event.type != pygame.KEYDOWN:
                continue
            if event.key in (pygame.K_RETURN, pygame.K_KP_ENTER) and typed:
                return int(typed) if scale is not None else typed
            if event.key == pygame.K_BACKSPACE:
                typed = typed[:-1]
            elif scale is not None:
                if event.unicode.isdigit() and scale[0] <= int(event.unicode) <= scale[1]:
                    typed = event.unicode  # one digit: the scales run within 0-9
            elif event.unicode and event.unicode.isprintable() and len(typed) < 200:
                typed += event.unicode
        time.sleep(1 / 30)
