"""The screens a participant sees around a drive, drawn over the play view: ready, countdown, pause, the quit
question, the axes' calibration and the drive's result; and between the drives of a session (its window kept
open): the waiting screen while the next drive is prepared, and the session's end.

They draw only on the view's ``surface`` (and call its ``present``), so they work with whatever the view draws
beneath. Text is white on an opaque dark panel in the middle of the window. :func:`wait_for_go` keeps a screen up
until the person's go for a caller outside a drive (a session between its drives).

Example (no display needed: an off-screen view; the scripted bot is always ready):
    >>> from pernav.play.controls import ScriptedControls
    >>> from pernav.play.loop import PlayOptions, PlaySession
    >>> session = PlaySession("Town1", 0, options=PlayOptions(n_traffic=0, draw=True))
    >>> show_panel(session.view, ["Drive 1 of 3", "Press Enter when ready"], big="Ready?")
    >>> show_waiting(session.view, "the navigation is learning from your drive", 35.0)
    >>> show_finished(session.view, ["You drove all 3 drives."], controls=ScriptedControls())
    True
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Mapping, Sequence
from functools import cache
from typing import Any

from pernav.play.view import PlayView
from pernav.world.towns import get_town

__all__ = ["CLOSING", "FINISHED", "STOPPED", "WAITING", "SessionWindow", "result_lines", "show_axes", "show_finished",
           "show_panel", "show_waiting", "time_left", "wait_for_go"]

WAITING = "Preparing your next drive"
CLOSING = "Finishing the session"  # the waiting screen's heading when no drive follows
FINISHED = "Session finished. Thank you."
STOPPED = "Session stopped. Thank you."
SCREEN_HZ = 30  # pictures per second of a screen kept up by wait_for_go
BACKGROUND = (8, 10, 14)  # behind the screens between drives: no stale picture of the last drive
PANEL = (20, 24, 32)
TEXT = (255, 255, 255)
DIM = (190, 190, 200)
DONE = (90, 220, 90)


@cache
def _font(size: int) -> Any:
    import pygame  # lazy: pygame is loaded when a screen is drawn, not when the module is imported

    pygame.font.init()
    return pygame.font.Font(None, size)


def show_panel(view: Any, lines: Sequence[str], big: str | None = None, title: str | None = None) -> None:
    """Draw a panel with ``big`` (a large word or number), then ``lines``, over what ``view`` shows; ``title`` (e.g.
    "Drive 2 of 7: Town1 route 3") in a band at the top. Presents the picture."""
    import pygame  # lazy: pygame is loaded when a screen is drawn, not when the module is imported

    surface = view.surface
    w, h = surface.get_size()
    rendered = ([_font(120).render(big, True, TEXT)] if big else []) + [
        _font(34 if i == 0 and not big else 30).render(line, True, TEXT if i == 0 else DIM)
        for i, line in enumerate(lines)]
    if rendered:
        height = sum(r.get_height() + 12 for r in rendered) + 40
        width = min(max(r.get_width() for r in rendered) + 80, w - 20)
        top = (h - height) // 2
        pygame.draw.rect(surface, PANEL, pygame.Rect((w - width) // 2, top, width, height), border_radius=10)
        y = top + 20
        for r in rendered:
            surface.blit(r, ((w - r.get_width()) // 2, y))
            y += r.get_height() + 12
    if title:
        band = _font(34).render(title, True, TEXT)
        pygame.draw.rect(surface, PANEL, pygame.Rect(0, 0, w, band.get_height() + 20))
        surface.blit(band, ((w - band.get_width()) // 2, 10))
    view.present()


def show_axes(view: Any, values: Mapping[str, float], moved: Mapping[str, bool], title: str | None = None) -> None:
    """The calibration screen: a bar per control (steering -1 .. 1 from the middle, pedals 0 .. 1) and whether it
    has been moved through its range yet."""
    import pygame  # lazy: pygame is loaded when a screen is drawn, not when the module is imported

    surface = view.surface
    w, h = surface.get_size()
    surface.fill(PANEL)
    rows = [("steer", "Steering: turn fully left and right"), ("throttle", "Throttle: press it down"),
            ("brake", "Brake: press it down")]
    bar_w, y = min(600, w - 160), h // 2 - 150
    for name, text in rows:
        value, ok = float(values.get(name, 0.0)), bool(moved.get(name))
        surface.blit(_font(30).render(text + ("  - seen" if ok else ""), True, DONE if ok else TEXT), (80, y))
        box = pygame.Rect(80, y + 32, bar_w, 26)
        pygame.draw.rect(surface, DIM, box, 2)
        if name == "steer":
            mid = box.centerx
            end = mid + int(max(-1.0, min(1.0, value)) * (bar_w // 2 - 2))
            pygame.draw.rect(surface, DONE if ok else TEXT, pygame.Rect(min(mid, end), y + 34, abs(end - mid) + 1, 22))
        else:
            pygame.draw.rect(surface, DONE if ok else TEXT,
                             pygame.Rect(82, y + 34, int(max(0.0, min(1.0, value)) * (bar_w - 4)), 22))
        y += 100
    hint = _font(30).render("Check each control moves its bar. Enter (or a button): start", True, TEXT)
    surface.blit(hint, ((w - hint.get_width()) // 2, y + 10))
    if title:
        band = _font(34).render(title, True, TEXT)
        surface.blit(band, ((w - band.get_width()) // 2, 20))
    view.present()


def result_lines(metrics: Mapping[str, Any], hide_cost: bool = False, counters: bool = True) -> list[str]:
    """The end screen's lines for a drive's metrics (the cost left out with ``hide_cost``, the counts of collisions,
    kerb strikes and missed turns without ``counters``).

    >>> result_lines({"completed": True, "time": 129.4, "tracking_cost": 112.0, "vehicle_collisions": 0,
    ...               "edge_strikes": 2, "missed_turns": 1})
    ['Arrived after 129 s', 'vehicle collisions 0   kerb strikes 2   missed turns 1', 'tracking cost 112']
    """
    state = "Arrived" if metrics.get("completed") else "Not arrived"
    lines = [f"{state} after {metrics.get('time', 0):.0f} s"]
    if counters:
        lines.append(f"vehicle collisions {metrics.get('vehicle_collisions', 0)}   kerb strikes "
                     f"{metrics.get('edge_strikes', 0)}   missed turns {metrics.get('missed_turns', 0)}")
    if not hide_cost:
        lines.append(f"tracking cost {metrics.get('tracking_cost', 0):.0f}")
    return lines


def time_left(seconds: float) -> str:
    """How long is left, as a person reads it (rounded to what an estimate is worth).

    >>> time_left(3.2), time_left(34.0), time_left(150.0), time_left(0.2)
    ('about 4 s left', 'about 35 s left', 'about 3 min left', 'almost done')
    """
    if seconds < 1.0:
        return "almost done"
    if seconds < 10.0:
        return f"about {math.ceil(seconds)} s left"
    if seconds < 90.0:
        return f"about {5 * math.ceil(seconds / 5)} s left"
    return f"about {math.ceil(seconds / 60)} min left"


def _drain_keys(view: Any) -> None:
    """Take the window's pending events off its queue but a close button's (the next screen's controls ask about
    that): the window keeps answering the system while nothing polls it, and a key pressed while waiting does not
    start the next drive."""
    import pygame  # lazy: pygame is loaded when a screen is drawn, not when the module is imported

    if getattr(view, "window", False) and pygame.display.get_init():
        pygame.event.get(exclude=pygame.QUIT)


def show_waiting(view: Any, what: str, seconds_left: float | None, title: str | None = None,
                 heading: str = WAITING) -> None:
    """The waiting screen between two drives: ``heading`` ("Preparing your next drive"), ``what`` is happening
    ("the navigation is learning from your drive") and about how long it will take (``seconds_left``, an estimate;
    ``None``: not said). Draw it again as the time goes down; each call also answers the window's events."""
    view.surface.fill(BACKGROUND)
    line = what if seconds_left is None else f"{what}: {time_left(max(float(seconds_left), 0.0))}"
    show_panel(view, [heading, line], title=title)
    _drain_keys(view)


def show_finished(view: Any, lines: Sequence[str], title: str | None = None, controls: Any = None,
                  heading: str = FINISHED) -> bool:
    """The session's end: ``heading`` ("Session finished. Thank you."; :data:`STOPPED` after a stopped drive) and
    ``lines``. With ``controls`` it stays until the person's go (:func:`wait_for_go`, whose answer it returns: True
    on Enter); without, it is drawn once (True)."""
    shown = [heading, *lines, *(["Press Enter to close"] if controls is not None else [])]

    def draw() -> None:
        view.surface.fill(BACKGROUND)
        show_panel(view, shown, title=title)

    draw()
    return True if controls is None else wait_for_go(controls, draw)


def wait_for_go(controls: Any, redraw: Callable[[], None] | None = None, hz: float = SCREEN_HZ) -> bool:
    """Keep a screen up (``redraw`` draws it, ``hz`` times a second) until the person's go (Enter, space, a wheel
    button): True; or until they ask to leave (Esc, Esc held, the window's close button): False. The window's
    events are read by ``controls.poll`` as on the screens of a drive. The controls' earlier state does not count:
    a go pressed before, or the quit that ended the last drive."""
    for flag in ("quit_requested", "confirming", "paused"):
        if getattr(controls, flag, False):
            setattr(controls, flag, False)
    take_go = getattr(controls, "take_go", lambda: True)
    take_go()
    while True:
        if redraw is not None:
            redraw()
        time.sleep(1.0 / hz)
        controls.poll()
        if getattr(controls, "quit_requested", False) or getattr(controls, "confirming", False):
            return False
        if take_go():
            return True


class SessionWindow:
    """The one window of a session of several drives (``pernav personalize``): opened once, given to each drive's
    :class:`~pernav.play.loop.PlaySession` (``view``), the waiting screen between drives, the end screen, closed at
    the end (``with SessionWindow(...)``: whatever happens). Headless (``window=False``): ``view`` is None and
    nothing is drawn."""

    def __init__(self, town: str, window: bool) -> None:
        self.view: Any = None
        if window:
            self.view = PlayView(get_town(town), window=True)

    def __enter__(self) -> SessionWindow:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def waiting(self, what: str, seconds_left: float | None, title: str | None = None, last: bool = False) -> None:
        """:func:`show_waiting` (``last``: no drive follows)."""
        if self.view is not None:
            show_waiting(self.view, what, seconds_left, title=title, heading=CLOSING if last else WAITING)

    def learning(self, what: str, started: float, estimate: float, last: bool = False) -> None:
        """The waiting screen while the navigation learns: ``estimate`` seconds from ``started``
        (``time.perf_counter()``), the time left counting down as it is drawn again."""
        self.waiting(what, estimate - (time.perf_counter() - started), last=last)

    def finish(self, controls: Callable[[], Any], whole: int, total: int, stopped: bool) -> bool:
        """The end screen (``whole`` of ``total`` drives driven whole) until the person's go, read by fresh
        ``controls()``. True when Ctrl-C was pressed there (the session is recorded by then)."""
        if self.view is None:
            return False
        lines = [f"{whole} of {total} drives driven; what you drove is kept." if stopped
                 else f"You drove all {total} drives."]
        try:
            show_finished(self.view, lines, controls=controls(), heading=STOPPED if stopped else FINISHED)
        except KeyboardInterrupt:
            return True
        return False

    def close(self) -> None:
        """Close the window (again: nothing)."""
        if self.view is not None:
            self.view.close()
            self.view = None
