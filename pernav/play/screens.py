"""The screens a participant sees around a drive, drawn over the play view: ready, countdown, pause, the quit
question, the axes' calibration and the drive's result.

They draw only on the view's ``surface`` (and call its ``present``), so they work with whatever the view draws
beneath. Text is white on an opaque dark panel in the middle of the window.

Example (no display needed: an off-screen view):
    >>> from pernav.play.loop import PlaySession
    >>> session = PlaySession("Town1", 0, n_traffic=0, draw=True)
    >>> show_panel(session.view, ["Drive 1 of 3", "Press Enter when ready"], big="Ready?")
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from functools import cache
from typing import Any

__all__ = ["result_lines", "show_axes", "show_panel"]

PANEL = (20, 24, 32)
TEXT = (255, 255, 255)
DIM = (190, 190, 200)
DONE = (90, 220, 90)


@cache
def _font(size: int) -> Any:
    import pygame

    pygame.font.init()
    return pygame.font.Font(None, size)


def show_panel(view: Any, lines: Sequence[str], big: str | None = None, title: str | None = None) -> None:
    """Draw a panel with ``big`` (a large word or number), then ``lines``, over what ``view`` shows; ``title`` (e.g.
    "Drive 2 of 7: Town1 route 3") in a band at the top. Presents the picture."""
    import pygame

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
    import pygame

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


def result_lines(metrics: Mapping[str, Any], hide_cost: bool = False) -> list[str]:
    """The end screen's lines for a drive's metrics (the cost left out with ``hide_cost``).

    >>> result_lines({"completed": True, "time": 129.4, "tracking_cost": 112.0, "vehicle_collisions": 0,
    ...               "edge_strikes": 2, "missed_turns": 1})
    ['Arrived after 129 s', 'vehicle collisions 0   kerb strikes 2   missed turns 1', 'tracking cost 112']
    """
    state = "Arrived" if metrics.get("completed") else "Not arrived"
    lines = [f"{state} after {metrics.get('time', 0):.0f} s",
             f"vehicle collisions {metrics.get('vehicle_collisions', 0)}   kerb strikes "
             f"{metrics.get('edge_strikes', 0)}   missed turns {metrics.get('missed_turns', 0)}"]
    if not hide_cost:
        lines.append(f"tracking cost {metrics.get('tracking_cost', 0):.0f}")
    return lines
