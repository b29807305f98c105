"""What a drive is asked to be: its options (:class:`PlayOptions`), the policies a drive names, and the refusal of
bad settings (:class:`PlayError`, one line for the command line).

:class:`~pernav.play.loop.PlaySession` takes the world, the people and the objects of a drive (town, route, user,
context, policy, controls, speaker, view) as its arguments, and everything else as one :class:`PlayOptions`.

Example:
    >>> options = PlayOptions(seed=3, n_traffic=2, playback="faster")
    >>> options.countdown, options.window
    (3.0, False)
    >>> check_drive("Town1", 0, "study", options)
    Traceback (most recent call last):
    ...
    pernav.play.options.PlayError: unknown policy 'study'; choose one of explore, oracle (or pass a callable)
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from pernav.world.constants import PLAYBACK, TOWN_NAMES
from pernav.world.towns import TownError, get_town

__all__ = ["PLAY_POLICIES", "POLICIES", "PlayError", "PlayOptions", "check_drive"]

#: the rule-based policies a drive names (any other policy is a callable: a study's model, a re-timed rule)
POLICIES = ("explore", "oracle")
#: what ``pernav play --policy`` accepts: the rules, and ``study`` (a finished study's model, adapted on a drive)
PLAY_POLICIES = (*POLICIES, "study")


class PlayError(ValueError):
    """Bad play settings (reported by ``pernav play`` in one line)."""


@dataclass(frozen=True)
class PlayOptions:
    """How a drive runs, beside who and what drives it (:class:`~pernav.play.loop.PlaySession`'s arguments).

    The world's: ``seed``, ``n_traffic``, ``playback`` (the speed the rule-based policies speak at; another than
    ``normal`` makes the env's action space each instruction at each speed), ``K`` and ``env_config``. The
    picture's: ``window``, ``draw``, ``realtime``, ``fps``, ``size``, ``screenshot``, ``screenshot_at``. A person's
    screens around the drive: ``ready``, ``countdown``, ``title``, ``notice``, ``hide_cost``, ``counters``,
    ``calibrate``, ``progress``.
    """

    seed: int = 0
    """The world's seed (its traffic and luck); >= 0."""
    n_traffic: int = 8
    """Traffic cars around the person's."""
    playback: str = "normal"
    """The playback speed of explore's and the oracle's prompts (``slower``, ``normal``, ``faster``)."""
    K: int | None = None
    """The history window recorded (steps); None: the policy's ``K`` where it has one (a study's), else 5."""
    env_config: Mapping[str, Any] | None = None
    """Entries of the navigation env's config (e.g. a study's planning context lengths, a belief); None: the
    policy's ``env_config`` where it has one."""
    window: bool = False
    """A pygame window, paced to real time."""
    draw: bool = False
    """Draw off screen too (a screenshot, a timing)."""
    realtime: bool | None = None
    """Pace the drive to the wall clock; None: as ``window``."""
    fps: int = 30
    """Pictures per second of the window (the cars drawn between two world frames); >= 1."""
    size: tuple[int, int] = (960, 720)
    """The picture's size in pixels."""
    screenshot: str | Path | None = None
    """A PNG of the window saved during the drive (at ``screenshot_at``)."""
    screenshot_at: float | None = None
    """Seconds of the drive at which the screenshot is taken; None: a second after the first prompt played (or at
    the end)."""
    ready: bool | None = None
    """The screens around the drive (calibration, ready, countdown, result); None: a window in real time (a
    person)."""
    countdown: float = 3.0
    """Seconds of the countdown after the ready screen and after a pause; >= 0."""
    title: str | None = None
    """The drive's title on the ready screen and the window's caption."""
    notice: str | None = None
    """A line on the ready screen (e.g. "no sound on this computer")."""
    hide_cost: bool = False
    """Keep the tracking cost off the screen."""
    counters: bool = True
    """Show the live counters (collisions, kerb strikes, missed turns, re-routes) during the drive and on its result
    screen; False: the drive's time and speed only."""
    calibrate: bool = False
    """A wheel's calibration screen first (controls with axes)."""
    progress: str | None = None
    """The counter in a corner during the drive ("Drive 2 of 6"); None: the title."""


def check_drive(town: str, route: Any, policy: Any, options: PlayOptions) -> None:
    """Refuse a drive's bad settings before anything is built, naming the setting and what is allowed."""
    if town not in TOWN_NAMES:
        raise TownError(f"unknown town {town!r}; choose one of {', '.join(TOWN_NAMES)}")
    n_routes = len(get_town(town).routes)
    if isinstance(route, bool) or not isinstance(route, (int, np.integer)) or not 0 <= route < n_routes:
        raise TownError(f"route index {route!r} out of range [0, {n_routes - 1}] for {town}")
    if isinstance(policy, str) and policy not in POLICIES:
        raise PlayError(f"unknown policy {policy!r}; choose one of {', '.join(POLICIES)} (or pass a callable)")
    if options.playback not in PLAYBACK:
        raise PlayError(f"unknown playback {options.playback!r}; choose one of {', '.join(PLAYBACK)}")
    if options.seed < 0:
        raise PlayError(f"seed must be >= 0, got {options.seed}")
    if options.fps < 1:
        raise PlayError(f"fps must be >= 1, got {options.fps}")
    if options.countdown < 0:
        raise PlayError(f"countdown must be >= 0 seconds, got {options.countdown}")
