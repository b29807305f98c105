"""``pernav diagnose model|planning``: the model and planning diagnostics, each with its own options
(``pernav diagnose model --help``).

Example:
    $ pernav diagnose planning --routes 3 --paper-routes 0 --json planning_error.json
"""

from __future__ import annotations

import argparse
from typing import Any

from pernav.cli.common import UsageError
from pernav.diagnostics import model_check, planning_error

DIAGNOSTICS = {"model": model_check, "planning": planning_error}  # pernav diagnose WHICH


def add_parser(sub: Any) -> None:
    """Register ``pernav diagnose``."""
    p = sub.add_parser("diagnose", help="model and planning diagnostics (pernav diagnose model|planning --help)")
    p.add_argument("which", metavar="{model,planning}", help="pernav.diagnostics.model_check or planning_error")
    p.add_argument("args", nargs=argparse.REMAINDER, help="the diagnostic's own options")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """The diagnostic's own command line."""
    if args.which not in DIAGNOSTICS:
        raise UsageError(f"unknown diagnostic {args.which!r}; choose one of {', '.join(DIAGNOSTICS)}")
    return DIAGNOSTICS[args.which].main(args.args, prog=f"pernav diagnose {args.which}")
