"""What the subcommands share: the usage error (one line, exit 2), exit codes, and the checks and options of a
person's drive (`pernav play`, `pernav personalize`, `pernav session`).

Example:
    >>> check_learner("adapt")
    'adapt'
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from pernav.play.controls import JoystickControls, KeyboardControls, parse_axes
from pernav.play.loop import open_speaker as open_device
from pernav.study.config import LEARNERS
from pernav.world.constants import TOWN_NAMES
from pernav.world.drivers import CONTEXT_CHOICES

__all__ = ["INTERRUPTED", "MAX_TRAFFIC", "PLAY_INPUTS", "UsageError", "check_drive_args", "check_learner",
           "check_output_file", "drive_options", "open_speaker", "person_controls"]

MAX_TRAFFIC = 64  # traffic cars of `pernav drive` (each is spawned by rejection sampling around the driver)
INTERRUPTED = 130  # exit code after Ctrl-C (128 + SIGINT, as a shell reports it), in every command
PLAY_INPUTS = ("keyboard", "joystick")


class UsageError(ValueError):
    """Bad command-line input (reported in one line, exit code 2)."""


def check_output_file(option: str, value: str, suffix: str) -> None:
    """A file the command will write: the right suffix, in a folder that exists (checked before any work)."""
    path = Path(value)
    if path.suffix.lower() != suffix:
        raise UsageError(f"{option} {value!r} must name a {suffix} file")
    if not path.parent.is_dir():
        raise UsageError(f"{option} {value!r}: folder {str(path.parent)!r} does not exist")


def check_drive_args(args: argparse.Namespace) -> dict[str, str]:
    """The checks `pernav play` and `pernav personalize` share (before any window opens or file is written); the
    user's context overrides, with the person's equipment when a person drives."""
    if args.input not in PLAY_INPUTS:
        raise UsageError(f"--input {args.input!r}: choose one of {', '.join(PLAY_INPUTS)}")
    if args.town not in TOWN_NAMES:
        raise UsageError(f"unknown town {args.town!r}; choose one of {', '.join(TOWN_NAMES)}")
    if args.seed < 0:
        raise UsageError(f"--seed must be >= 0, got {args.seed}")
    if not 0 <= args.traffic <= MAX_TRAFFIC:
        raise UsageError(f"--traffic must be in [0, {MAX_TRAFFIC}], got {args.traffic}")
    if args.record is not None and Path(args.record).exists() and not Path(args.record).is_dir():
        raise UsageError(f"--record {args.record!r} exists and is not a folder")
    if args.countdown < 0:
        raise UsageError(f"--countdown must be >= 0 seconds, got {args.countdown}")
    if args.joystick_axes is not None:
        if args.input != "joystick":
            raise UsageError("--joystick-axes goes with --input joystick")
        parse_axes(args.joystick_axes)  # a ControlsError (one line) for a bad list
    context = {k: getattr(args, k) for k in CONTEXT_CHOICES if getattr(args, k) is not None}
    if "equipment" not in context and not args.headless:  # the oracle times its prompts for the person's device
        context["equipment"] = "wheel" if args.input == "joystick" else "keyboard"
    return context


def open_speaker(args: argparse.Namespace) -> tuple[Any, str | None]:
    """The speaker; without sound (and without --no-audio) a warning in the terminal, and its words for the screen.
    ``--audio`` without a device is an error (exit 2)."""
    speaker, reason = open_device(args.audio)
    if reason is None or args.headless:
        return speaker, None
    print(f"pernav {args.command}: warning: no sound, the prompts are shown as text only: {reason} (--audio makes "
          "this an error, --no-audio silences this warning)", file=sys.stderr)
    return speaker, "No sound on this computer: the prompts are shown as text only"


def person_controls(args: argparse.Namespace) -> Any:
    """A person's controls made before any window (a joystick: a missing one or axis is exit 2 with no window);
    keyboard controls need the window: their class is returned, made per drive."""
    if args.input == "joystick":
        return JoystickControls(**(parse_axes(args.joystick_axes) if args.joystick_axes else {}))
    return KeyboardControls


def check_learner(learner: str, belief: bool = False) -> str:
    """``belief``: the belief learner is allowed too (``pernav personalize``)."""
    allowed = (*LEARNERS, "belief") if belief else LEARNERS
    if learner not in allowed:
        raise UsageError(f"--learner {learner!r}: choose one of {', '.join(allowed)}")
    return learner


def drive_options(p: argparse.ArgumentParser, record_help: str) -> None:
    """The options of a person's drive that `pernav play` and `pernav personalize` share."""
    p.add_argument("--user", default="user1",
                   help="who the oracle times its prompts for and the scripted bot drives as (and the car): "
                        "user1..user7 or a profile file")
    for key, choices in CONTEXT_CHOICES.items():
        p.add_argument(f"--{key}", choices=choices, help=f"context override ({key})")
    p.add_argument("--input", default="keyboard", help="keyboard (arrows/WASD; default) or joystick (a wheel)")
    p.add_argument("--record", metavar="DIR", help=record_help)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--traffic", type=int, default=8, help="traffic cars around the driver (default 8)")
    p.add_argument("--headless", action="store_true", help="no window: a scripted bot drives (demos, tests)")
    p.add_argument("--audio", dest="audio", action="store_true", default=None,
                   help="require sound (an error without an audio device; default: sound if there is a device)")
    p.add_argument("--no-audio", dest="audio", action="store_false", help="prompts as text only")
    p.add_argument("--hide-cost", action="store_true", help="keep the tracking cost off the participant's screen")
    p.add_argument("--countdown", type=float, default=3.0, metavar="SECONDS",
                   help="countdown in the window after the person is ready (default 3)")
    p.add_argument("--joystick-axes", metavar="STEER,THROTTLE,BRAKE",
                   help="with --input joystick: axis indices of the wheel and pedals, ~ inverts one (e.g. 0,~2,~3); "
                        "STEER,PEDAL for one axis for both pedals (default 0,1)")
    p.add_argument("--no-calibration", action="store_true",
                   help="with --input joystick: skip the screen showing each axis moving before the first drive")
