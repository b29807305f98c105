"""The ``pernav`` command line: towns, drive, play, personalize, bench, study, session, diagnose.

One module per subcommand, each with its ``add_parser`` and ``run``.

Bad input is reported as one line on stderr with exit code 2 (never a traceback). Ctrl-C ends a command with exit
code 130 (`pernav play` and `pernav personalize` record the drive in progress first, marked stopped).

Example:
    $ pernav towns --out maps/
    $ pernav drive --town Town3 --policy oracle --user user3 --visual foggy --routes 0 1 --json
    $ pernav study --preset default --out runs/default --workers 2
    $ pernav bench planner --json
    $ pernav play --town Town1 --route 0 --policy oracle --user user3 --record drives/
    $ pernav personalize --study runs/default --town Town1 --routes 0 3 5 7 --record drives/me/ --learner belief
    $ pernav session docs/examples/session.yaml --participant P01 --out sessions/
    $ pernav diagnose planning --routes 3 --paper-routes 0 --json planning_error.json
"""

from __future__ import annotations

import argparse
import sys

from pernav.cli import bench, diagnose, drive, personalize, play, session, study, towns
from pernav.cli.common import INTERRUPTED, MAX_TRAFFIC, UsageError
from pernav.study.errors import CheckpointError
from pernav.world.drivers import ProfileError
from pernav.world.routing import RouteError
from pernav.world.towns import TownError

__all__ = ["COMMANDS", "INTERRUPTED", "MAX_TRAFFIC", "UsageError", "build_parser", "main"]

#: the subcommands, in the order ``pernav --help`` lists them
COMMANDS = (towns, drive, play, personalize, bench, study, session, diagnose)


def build_parser() -> argparse.ArgumentParser:
    """The parser of every subcommand."""
    parser = argparse.ArgumentParser(prog="pernav", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    for command in COMMANDS:
        command.add_parser(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Run ``pernav ARGV``; returns the exit code (2 for bad input, one line on stderr)."""
    args = build_parser().parse_args(argv)
    try:
        code = args.func(args)
    except (UsageError, TownError, ProfileError, RouteError, ValueError, OSError, CheckpointError) as exc:
        # OSError: an output path that cannot be written (a file in the way, no permission, name too long)
        message = " ".join(str(exc).split()) or type(exc).__name__  # always one line
        print(f"pernav {args.command}: error: {message}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("interrupted (Ctrl-C)", file=sys.stderr)
        return INTERRUPTED
    return int(code or 0)
