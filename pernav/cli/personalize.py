"""``pernav personalize``: Algorithm 1 with a person at the wheel: an explore drive, then each route with the
study's model adapted to them (or the belief learner) and with explore, in a hidden order.

Example:
    $ pernav personalize --study runs/default --town Town1 --routes 0 3 5 7 --record drives/me/
    $ pernav personalize --study runs/default --town Town1 --routes 0 3 5 7 --record drives/me/ --learner belief
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Any

from pernav.cli.common import (
    INTERRUPTED,
    UsageError,
    check_drive_args,
    check_learner,
    drive_options,
    open_speaker,
    person_controls,
)
from pernav.play.believe import session_class
from pernav.play.sessions import SessionOptions, check_writable, summary_markdown


def add_parser(sub: Any) -> None:
    """Register ``pernav personalize``."""
    p = sub.add_parser("personalize", help="the study's model learns you: an explore drive, then each route with the "
                       "adapted model and with explore in a hidden order, meta updates between rounds")
    p.add_argument("--study", required=True, metavar="DIR", help="a finished study (pernav study --out DIR)")
    p.add_argument("--town", required=True, help="a town the study ran")
    p.add_argument("--routes", required=True, nargs="+", type=int, metavar="R",
                   help="route indices 0-9: the first for the explore drive the model adapts on, each next one "
                        "driven twice (at least two routes)")
    p.add_argument("--updates", type=int, metavar="N", help="meta updates after each round (default: the study's, "
                   "at most 10)")
    p.add_argument("--learner", default="adapt", help="the study's learner: adapt (default), adapt_speed (chooses the "
                   "playback speed too), sysid (not adapted to you: a control) or belief (times the prompts for you, "
                   "shows your reaction time after each drive)")
    drive_options(p, "the session's folder: every drive, summary.json/.md and the personalized model "
                   "(default drives/personal-TOWN-TIME)")
    p.add_argument("--resume", action="store_true", help="continue the interrupted session in --record (same "
                   "settings): its drives and model are kept, the first drive not yet whole comes next")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Algorithm 1 with the person at the wheel (pernav.play.personal.PersonalSession); checks before any drive."""
    context = check_drive_args(args)
    if args.updates is not None and args.updates < 0:
        raise UsageError(f"--updates must be >= 0, got {args.updates}")
    check_learner(args.learner, belief=True)
    if args.resume and args.record is None:
        raise UsageError("--resume needs --record DIR: the interrupted session's folder")
    record = args.record or str(Path("drives") / f"personal-{args.town}-{time.strftime('%Y%m%d-%H%M%S')}")
    options = SessionOptions(seed=args.seed, record_dir=record, n_traffic=args.traffic, updates=args.updates,
                             learner=args.learner, window=not args.headless, resume=args.resume,
                             countdown=args.countdown, hide_cost=args.hide_cost,
                             calibrate=args.input == "joystick" and not args.no_calibration)
    session = session_class(args.learner)(args.study, args.town, args.routes, args.user, context, announce=print,
                                          options=options)
    check_writable("--record", record)
    session.speaker, session.notice = open_speaker(args)
    if not args.headless:
        session.controls = person_controls(args)  # keyboard controls: made per drive, once its window is open
    if args.resume:
        kept = sum(not d["interrupted"] for d in session.drives)
        print(f"resuming {record}: {kept} drive(s) kept, the model after {len(session.learned)} round(s)")
    result = session.run()
    print(f"summary: {result.folder}/summary.md" if args.hide_cost else summary_markdown(result.summary))
    if result.interrupted:
        print("the session was stopped early; what was driven is kept" + (
            "" if args.learner == "belief" else f" (continue it: pernav personalize ... --record {record} --resume)"))
    if any(d["file"] for d in result.drives):
        print(f"recorded: {result.folder}")
    if result.ctrl_c:
        print("interrupted (Ctrl-C)", file=sys.stderr)
        return INTERRUPTED
    return 0
