"""``pernav towns``: draw every town with its routes, one PNG per town (seconds).

Example:
    $ pernav towns --out maps/
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from pernav.cli.common import UsageError
from pernav.world.constants import TOWN_NAMES
from pernav.world.plotting import plot_town


def add_parser(sub: Any) -> None:
    """Register ``pernav towns``."""
    p = sub.add_parser("towns", help="draw every town with its routes (one PNG per town)")
    p.add_argument("--out", required=True, help="output folder")
    p.add_argument("--towns", nargs="+", choices=TOWN_NAMES, help="only these towns")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> None:
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise UsageError(f"--out {str(out)!r} exists and is not a folder")
    out.mkdir(parents=True, exist_ok=True)
    for name in args.towns or TOWN_NAMES:
        path = plot_town(name, out / f"{name}.png")
        print(path)
