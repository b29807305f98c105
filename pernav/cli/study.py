"""``pernav study``: the online meta-learning study (Algorithm 1 with every method) from a preset, with its
options; ``--resume`` continues an interrupted one, ``--workers`` and ``--ray`` run towns in parallel.

Example:
    $ pernav study --preset default --out runs/default --workers 2
"""

from __future__ import annotations

import argparse
import logging
from pathlib import Path
from typing import Any

from pernav.cli.common import UsageError
from pernav.planner.factory import parse_planner_options
from pernav.study.config import BELIEF_DEFAULTS, COLLECT, METHODS, TIMING_DEFAULTS, learner_options, preset
from pernav.study.report import collision_table
from pernav.study.schedule import load_schedule
from pernav.study.study import run_study


def add_parser(sub: Any) -> None:
    """``pernav study``: its many options in one place."""
    p = sub.add_parser("study", help="the online meta-learning study (Algorithm 1, every method)")
    p.add_argument("--preset", default="default",
                   help="smoke | default | paper | personal | personal_paper | personal_sweep | split | repeat")
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
                   help="one of the model-learning options (pernav.trainer.TrainConfig, e.g. updates=150, "
                        "personal_updates=100, or backtrack=null for the paper's fixed adaptation step); repeatable")
    p.add_argument("--timing-option", action="append", default=[], metavar="KEY=VALUE",
                   help=f"one of the timing learner's options ({', '.join(TIMING_DEFAULTS)}; VALUE a number); "
                        "repeatable")
    p.add_argument("--belief-option", action="append", default=[], metavar="KEY=VALUE",
                   help=f"one of the belief learner's options ({', '.join(BELIEF_DEFAULTS)}; VALUE a number); "
                        "repeatable")
    p.add_argument("--methods", nargs="+", choices=METHODS, help="only these methods (default: the preset's)")
    p.add_argument("--collect", choices=COLLECT,
                   help="the learners' non-MPC data: explore (the paper) or retimed (explore with prompts re-timed "
                        "at random; the default preset's choice)")
    p.add_argument("--tau-policy", dest="tau_policy", choices=COLLECT,
                   help="the policy of each round's adaptation trajectory: explore (the paper's rule; default) or "
                        "retimed (explore with prompts re-timed at random, so tau shows the driver's timing)")
    p.add_argument("--calibration", type=int, metavar="N",
                   help="re-timed drives of each online round's user before its evaluation (default: the preset's)")
    p.add_argument("--time-limit-factor", dest="time_limit_factor", type=float, metavar="F",
                   help="cut every episode after F x the route's nominal time + 30 s (default: the env's limit, "
                        "2.0): quick checks of the machinery, not figures")
    p.add_argument("--resume", action="store_true", help="continue an interrupted study in --out")
    p.add_argument("--workers", type=int, default=1, help="parallel processes (towns run independently)")
    p.add_argument("--ray", nargs="?", const="", metavar="ADDRESS",
                   help="run towns and evaluation episodes as Ray tasks (a local cluster when no ADDRESS)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> None:
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
    try:
        learner_options(args.timing_option, cfg.timing, "timing", ("offline_drivers",))
        learner_options(args.belief_option, cfg.belief, "belief", ("offline_drivers", "guard", "decision"))
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    if args.collect is not None:
        cfg.collect = args.collect
    if args.tau_policy is not None:
        cfg.tau_policy = args.tau_policy
    if args.calibration is not None:
        cfg.calibration = args.calibration
    if args.time_limit_factor is not None:
        cfg.time_limit_factor = args.time_limit_factor
    try:
        cfg.train = cfg.train.with_options(args.train_option)
    except ValueError as exc:
        raise UsageError(f"--train-option {exc}") from None
    results = run_study(cfg, args.out, resume=args.resume, workers=args.workers, ray=args.ray is not None,
                        ray_address=args.ray or None)
    print(collision_table(results))
    print(f"results: {Path(args.out) / 'results.json'}, report: {Path(args.out) / 'report.md'} "
          f"({results['wall_time']['wall_s']} s)")
