"""``pernav play``: a person drives a route (keyboard or wheel) with the navigation's prompts: explore's, the
oracle's, or a finished study's adapted model (``--policy study``); ``--headless`` lets the scripted bot drive.

Example:
    $ pernav play --town Town1 --route 0 --policy oracle --user user3 --record drives/
    $ pernav play --town Town1 --route 3 --policy study --study runs/default --tau drives/my-tau.pt
"""

from __future__ import annotations

import argparse
import json
import pickle
import sys
import time
from pathlib import Path
from typing import Any

from pernav.cli.common import (
    INTERRUPTED,
    UsageError,
    check_drive_args,
    check_learner,
    check_output_file,
    drive_options,
    open_speaker,
    person_controls,
)
from pernav.play.loop import PlaySession
from pernav.play.options import PLAY_POLICIES, PlayOptions
from pernav.play.sessions import check_writable
from pernav.study.config import preset
from pernav.study.finished import FinishedStudy
from pernav.trainer.drives import load_drive, read_metrics, save_drive
from pernav.world.constants import PLAYBACK, TOWN_NAMES


def add_parser(sub: Any) -> None:
    """Register ``pernav play``."""
    p = sub.add_parser("play", help="drive a route yourself (keyboard or wheel) with the navigation's prompts")
    p.add_argument("--town", default="Town1", help=f"one of {', '.join(TOWN_NAMES)} (default Town1)")
    p.add_argument("--route", type=int, default=0, help="route index 0-9 (default 0)")
    p.add_argument("--policy", default="explore",
                   help="explore (default), oracle, or study (a finished study's model, adapted on --tau)")
    p.add_argument("--study", metavar="DIR", help="the finished study the drive is for (pernav study --out DIR): its "
                   "history window is recorded; with --policy study its model plans the prompts")
    p.add_argument("--tau", metavar="FILE", help="with --policy study: a recorded explore drive (.pt) of the person "
                   "to adapt the model on (default: unadapted)")
    p.add_argument("--learner", help="with --policy study: the study's learner whose model plans: adapt (default), "
                   "adapt_speed (chooses the playback speed too) or sysid")
    p.add_argument("--playback", default="normal", help="speed of the spoken prompts: slower, normal, faster")
    p.add_argument("--history", type=int, metavar="K", help="steps of the recorded history window (default: what "
                   "the study that will learn from the drive reads: --study's, else the default preset's, 10)")
    drive_options(p, "save the drive (study format) and its metrics in this folder")
    p.add_argument("--screenshot", metavar="PNG", help="save a picture of the window (one second after the first "
                   "prompt, or at --screenshot-at)")
    p.add_argument("--screenshot-at", type=float, metavar="SECONDS", help="time of the drive for --screenshot")
    p.add_argument("--json", action="store_true", help="print the metrics as JSON")
    p.set_defaults(func=run)


def _study_policy(args: argparse.Namespace) -> tuple[object, dict] | None:
    """``--policy study``: the study's model adapted on ``--tau`` (unadapted without); None for other policies."""
    if args.policy != "study":
        if args.tau is not None or args.learner is not None:
            raise UsageError("--tau and --learner go with --policy study")
        return None
    learner = check_learner(args.learner or "adapt")
    if args.study is None:
        raise UsageError("--policy study needs --study DIR (a finished pernav study)")
    if args.playback != "normal":
        raise UsageError("--playback applies to explore and oracle; the study's model plans its own prompts")
    if args.tau is not None and not Path(args.tau).is_file():
        raise UsageError(f"--tau {args.tau!r}: no such file")
    tau = None
    if args.tau is not None:
        try:
            tau = load_drive(args.tau)
            town = read_metrics(args.tau).get("town")
        except (ValueError, OSError, RuntimeError, EOFError, pickle.UnpicklingError, AttributeError):
            raise UsageError(f"--tau {args.tau!r} is not a drive recorded by pernav play") from None
        if town != args.town:
            raise UsageError(f"--tau {args.tau!r} was recorded in {town}; this drive is in {args.town} (adapt on a "
                             f"drive of {args.town})")
    return FinishedStudy.open(args.study).policy(learner, args.town, tau, seed=args.seed)


def _history(args: argparse.Namespace) -> int:
    """The history window to record: the study's (``--study``), or the default study's; ``--history`` must agree
    with a study named."""
    if args.history is not None and not 1 <= args.history <= 50:
        raise UsageError(f"--history must be in [1, 50], got {args.history}")
    if args.study is not None:
        k = FinishedStudy.open(args.study).history(args.town)
        if args.history is not None and args.history != k:
            raise UsageError(f"--history {args.history}: the study in {args.study!r} reads a history of {k} steps "
                             f"(leave --history out, or give --history {k})")
        return k
    if args.history is not None:
        return args.history
    return preset("default").train.K


def run(args: argparse.Namespace) -> int:
    """A person drives a route (or the scripted bot, ``--headless``); checks everything before the window opens."""
    if args.policy not in PLAY_POLICIES:
        raise UsageError(f"--policy {args.policy!r}: choose one of {', '.join(PLAY_POLICIES)}")
    if args.playback not in PLAYBACK:
        raise UsageError(f"--playback {args.playback!r}: choose one of {', '.join(PLAYBACK)}")
    context = check_drive_args(args)
    if args.screenshot is not None:
        check_output_file("--screenshot", args.screenshot, ".png")
    history = _history(args)
    study = _study_policy(args)
    if args.record is not None:
        check_writable("--record", args.record)
    if args.screenshot is not None:
        check_writable("--screenshot", Path(args.screenshot).parent)
    speaker, notice = open_speaker(args)  # before any window: a missing device asked for is an error
    controls = None if args.headless else person_controls(args)
    options = PlayOptions(seed=args.seed, n_traffic=args.traffic, playback=args.playback, window=not args.headless,
                          K=history if study is None else None, screenshot=args.screenshot,
                          screenshot_at=args.screenshot_at, countdown=args.countdown, hide_cost=args.hide_cost,
                          notice=notice, title=f"{args.town} route {args.route}",
                          calibrate=args.input == "joystick" and not args.no_calibration)
    session = PlaySession(args.town, args.route, args.user, context, args.policy if study is None else study[0],
                          speaker=speaker, options=options)
    try:
        if controls is not None:
            session.controls = controls() if isinstance(controls, type) else controls
        result = session.run()
    finally:
        session.close()
    saved = None
    if args.record is not None and result.trajectory is not None:
        name = f"{args.town}-r{args.route}-{args.policy}-{time.strftime('%Y%m%d-%H%M%S')}"
        metrics = {**result.metrics, "frames": result.frame_stats(), **({} if study is None else {"study": study[1]})}
        saved = save_drive(result.trajectory, metrics, args.record, name)
    if args.json:
        print(json.dumps({**result.metrics, "frames": result.frame_stats(),
                          **({} if study is None else {"study": study[1]}),
                          "record": None if saved is None else str(saved),
                          "screenshot": None if session.shot is None else str(session.shot)}, indent=2))
    else:
        m = result.metrics
        state = "stopped" if m["interrupted"] else ("arrived" if m["completed"] else "not arrived")
        print(f"{args.town} route {args.route}: {state} after {m.get('time', 0):.0f} s, tracking cost "
              f"{m.get('tracking_cost', 0):.0f}, vehicle collisions {m.get('vehicle_collisions', 0)}, kerb strikes "
              f"{m.get('edge_strikes', 0)}, missed turns {m.get('missed_turns', 0)}, re-routes {m.get('reroutes', 0)}")
        if saved is not None:
            print(f"recorded: {saved}")
        if session.shot is not None:
            print(f"screenshot: {session.shot}")
    if result.ctrl_c:
        print("interrupted (Ctrl-C): the drive so far is kept" if saved is not None else "interrupted (Ctrl-C)",
              file=sys.stderr)
        return INTERRUPTED
    return 0
