"""``pernav drive``: drive routes with one policy (explore or the oracle) and one user; per-episode metrics.

Example:
    $ pernav drive --town Town3 --policy oracle --user user3 --visual foggy --routes 0 1 --json
"""

from __future__ import annotations

import argparse
import json
from typing import Any

from pernav.cli.common import MAX_TRAFFIC, UsageError, check_output_file
from pernav.env.episodes import drive_routes
from pernav.world.constants import TOWN_NAMES
from pernav.world.drivers import CONTEXT_CHOICES


def add_parser(sub: Any) -> None:
    """Register ``pernav drive``."""
    p = sub.add_parser("drive", help="drive routes with one policy and one user; per-episode metrics")
    p.add_argument("--town", required=True, help=f"one of {', '.join(TOWN_NAMES)}")
    p.add_argument("--policy", required=True, choices=["explore", "oracle"])
    p.add_argument("--user", required=True, help="user1..user7, or a JSON/YAML profile (with context) file")
    p.add_argument("--routes", nargs="+", type=int, help="route indices 0-9 (default: all ten)")
    for key, choices in CONTEXT_CHOICES.items():
        p.add_argument(f"--{key}", choices=choices, help=f"context override ({key})")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--traffic", type=int, default=8, help="traffic cars around the driver (default 8)")
    p.add_argument("--json", action="store_true", help="print JSON")
    p.add_argument("--gif", help="write an animated replay of the first route to this file")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> None:
    if args.seed < 0:
        raise UsageError(f"--seed must be >= 0, got {args.seed}")
    if not 0 <= args.traffic <= MAX_TRAFFIC:
        raise UsageError(f"--traffic must be in [0, {MAX_TRAFFIC}], got {args.traffic}")
    if args.gif is not None:  # checked before driving, not after the first route
        check_output_file("--gif", args.gif, ".gif")
    context = {k: getattr(args, k) for k in CONTEXT_CHOICES if getattr(args, k) is not None}
    results = drive_routes(args.town, args.policy, args.user, routes=args.routes, context=context,
                           seed=args.seed, n_traffic=args.traffic, gif=args.gif)
    if args.json:
        print(json.dumps(results, indent=2))
        return
    print(f"{'route':>5} {'done':>5} {'time':>6} {'cost':>9} {'coll':>5} {'edge':>5} {'miss':>5} {'wrong':>5}")
    for r in results["episodes"]:
        print(f"{r['route']:>5} {str(r['completed']):>5} {r['time']:>6.0f} {r['tracking_cost']:>9.0f} "
              f"{r['vehicle_collisions']:>5} {r['edge_strikes']:>5} {r['missed_turns']:>5} {r['wrong_turns']:>5}")
    s = results["summary"]
    print(f"mean tracking cost {s['tracking_cost']:.0f}, collisions {s['collisions']}, "
          f"completion {s['completion']:.0%}")
