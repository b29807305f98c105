"""The ``pernav`` command line: towns, drive, bench.

Bad input is reported as one line on stderr with exit code 2 (never a traceback).

Example:
    $ pernav towns --out maps/
    $ pernav drive --town Town3 --policy oracle --user user3 --visual foggy --routes 0 1 --json
    $ pernav bench sim --json
    $ pernav study --preset default --out runs/default --workers 2
    $ pernav bench planner --json
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from pernav.planner.factory import parse_planner_options
from pernav.study.config import COLLECT, METHODS
from pernav.study.errors import CheckpointError
from pernav.world.drivers import CONTEXT_CHOICES, ProfileError
from pernav.world.routing import RouteError
from pernav.world.towns import TOWN_NAMES, TownError

BENCH_CHOICES = ("sim", "planner", "train")  # pernav.bench.BENCHMARKS (not imported here: it is slow)
MAX_TRAFFIC = 64  # traffic cars of `pernav drive` (each is spawned by rejection sampling around the driver)


class UsageError(ValueError):
    """Bad command-line input (reported in one line, exit code 2)."""


def _towns(args: argparse.Namespace) -> None:
    from pernav.world.plotting import plot_town

    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise UsageError(f"--out {str(out)!r} exists and is not a folder")
    out.mkdir(parents=True, exist_ok=True)
    for name in args.towns or TOWN_NAMES:
        path = plot_town(name, out / f"{name}.png")
        print(path)


def _drive(args: argparse.Namespace) -> None:
    from pernav.env.episodes import drive_routes

    if args.seed < 0:
        raise UsageError(f"--seed must be >= 0, got {args.seed}")
    if not 0 <= args.traffic <= MAX_TRAFFIC:
        raise UsageError(f"--traffic must be in [0, {MAX_TRAFFIC}], got {args.traffic}")
    if args.gif is not None:  # checked before driving, not after the first route
        gif = Path(args.gif)
        if gif.suffix.lower() != ".gif":
            raise UsageError(f"--gif {args.gif!r} must name a .gif file")
        if not gif.parent.is_dir():
            raise UsageError(f"--gif {args.gif!r}: folder {str(gif.parent)!r} does not exist")
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


def _bench(args: argparse.Namespace) -> None:
    from pernav.bench import run_benchmarks

    figures = run_benchmarks(args.which, quick=args.quick)
    if args.json:
        print(json.dumps(figures, indent=2))
    else:
        for name, fig in figures.items():
            print(f"[{name}]")
            for k, v in fig.items():
                print(f"  {k}: {v}")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="pernav", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("towns", help="draw every town with its routes (one PNG per town)")
    p.add_argument("--out", required=True, help="output folder")
    p.add_argument("--towns", nargs="+", choices=TOWN_NAMES, help="only these towns")
    p.set_defaults(func=_towns)

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
    p.set_defaults(func=_drive)

    p = sub.add_parser("bench", help="benchmarks, as ratios measured in one run")
    p.add_argument("which", nargs="?", default="all", choices=[*BENCH_CHOICES, "all"])
    p.add_argument("--json", action="store_true")
    p.add_argument("--quick", action="store_true", help="shorter measurement (for smoke tests)")
    p.set_defaults(func=_bench)

    p = sub.add_parser("study", help="the online meta-learning study (Algorithm 1, every method)")
    p.add_argument("--preset", default="default", help="smoke | default | paper")
    p.add_argument("--out", required=True, help="output folder (results.json, report.md, figures/)")
    p.add_argument("--schedule", help="YAML/JSON schedule file replacing the preset's schedule (docs/study.md)")
    p.add_argument("--towns", nargs="+", help="towns to run (default: the preset's)")
    p.add_argument("--seed", type=int)
    p.add_argument("--planner", choices=["retime", "paper"],
                   help="the learners' planner: retime (default: long horizon, re-timed explore prompts) or paper "
                        "(horizon-5 masked tree)")
    p.add_argument("--planner-option", action="append", default=[], metavar="KEY=VALUE",
                   help="one of the planner's options (pernav.planner.factory.PLANNER_DEFAULTS; VALUE in JSON, e.g. "
                        "max_spread=null); repeatable")
    p.add_argument("--train-option", action="append", default=[], metavar="KEY=VALUE",
                   help="one of the model-learning options (pernav.trainer.TrainConfig, e.g. updates=150); "
                        "repeatable")
    p.add_argument("--methods", nargs="+", choices=METHODS, help="only these methods (default: all six)")
    p.add_argument("--collect", choices=COLLECT,
                   help="the learners' non-MPC data: explore (the paper) or retimed (explore with prompts re-timed "
                        "at random; the default preset's choice)")
    p.add_argument("--tau", choices=COLLECT,
                   help="the policy of each round's adaptation trajectory: explore (the paper's rule; default) or "
                        "retimed (explore with prompts re-timed at random, so tau shows the driver's timing)")
    p.add_argument("--calibration", type=int, metavar="N",
                   help="re-timed drives of each online round's user before its evaluation (default: the preset's)")
    p.add_argument("--personal-updates", type=int, metavar="N",
                   help="adapt by N updates on the round user's drives instead of one step on tau (0: the paper's U)")
    p.add_argument("--adapt-step", choices=["backtrack", "fixed"],
                   help="test-time U's step: backtrack (default: halve alpha until tau's loss decreases enough) or "
                        "fixed (the paper's alpha)")
    p.add_argument("--resume", action="store_true", help="continue an interrupted study in --out")
    p.add_argument("--workers", type=int, default=1, help="parallel processes (towns run independently)")
    p.add_argument("--ray", nargs="?", const="", metavar="ADDRESS",
                   help="run towns and evaluation episodes as Ray tasks (a local cluster when no ADDRESS)")
    p.set_defaults(func=_study)
    return parser


def _study(args: argparse.Namespace) -> None:
    import logging

    from pernav.study import load_schedule, preset, run_study
    from pernav.trainer.ftml import TrainConfig

    logging.getLogger("torchrl").setLevel(logging.WARNING)
    if args.workers < 1:
        raise UsageError(f"--workers must be >= 1, got {args.workers}")
    cfg = preset(args.preset)
    if args.schedule:
        cfg.schedule = load_schedule(args.schedule)
    if args.towns:
        cfg.towns = list(args.towns)
    if args.seed is not None:
        cfg.seed = args.seed
    if args.planner is not None:
        cfg.planner = {"kind": args.planner}
    try:
        cfg.planner = {**cfg.planner, **parse_planner_options(cfg.planner.get("kind", "retime"), args.planner_option)}
    except ValueError as exc:
        raise UsageError(f"--planner-option {exc}") from None
    if args.methods is not None:
        cfg.methods = [m for m in METHODS if m in args.methods]
    if args.collect is not None:
        cfg.collect = args.collect
    if args.tau is not None:
        cfg.tau = args.tau
    if args.calibration is not None:
        cfg.calibration = args.calibration
    try:
        cfg.train = cfg.train.with_options(args.train_option)
    except ValueError as exc:
        raise UsageError(f"--train-option {exc}") from None
    if args.personal_updates is not None:
        cfg.train.personal_updates = args.personal_updates
    if args.adapt_step is not None:
        cfg.train.backtrack = None if args.adapt_step == "fixed" else TrainConfig().backtrack
    results = run_study(cfg, args.out, resume=args.resume, workers=args.workers, ray=args.ray is not None,
                        ray_address=args.ray or None)
    from pernav.study.report import collision_table

    print(collision_table(results))
    print(f"results: {Path(args.out) / 'results.json'}, report: {Path(args.out) / 'report.md'} "
          f"({results['timing']['wall_s']} s)")


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        args.func(args)
    except (UsageError, TownError, ProfileError, RouteError, ValueError, OSError, CheckpointError) as exc:
        # OSError: an output path that cannot be written (a file in the way, no permission, name too long)
        message = " ".join(str(exc).split()) or type(exc).__name__  # always one line
        print(f"pernav {args.command}: error: {message}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
    return 0


if __name__ == "__main__":
    sys.exit(main())
