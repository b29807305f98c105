"""The ``pernav`` command line: towns, drive, study, play, bench, diagnose, ...

Bad input is reported as one line on stderr with exit code 2 (never a traceback). Ctrl-C ends a command with exit
code 130 (`pernav play` and `pernav personalize` record the drive in progress first, marked stopped).

Example:
    $ pernav towns --out maps/
    $ pernav drive --town Town3 --policy oracle --user user3 --visual foggy --routes 0 1 --json
    $ pernav bench sim --json
    $ pernav study --preset default --out runs/default --workers 2
    $ pernav bench planner --json
    $ pernav play --town Town1 --route 0 --policy oracle --user user3 --record drives/
    $ pernav play --town Town1 --route 3 --policy study --study runs/default --tau drives/my-tau.pt
    $ pernav personalize --study runs/default --town Town1 --routes 0 3 5 7 --record drives/me/
    $ pernav personalize --study runs/default --town Town1 --routes 0 3 5 7 --record drives/me/ --learner belief
    $ pernav session docs/examples/session.yaml --participant P01 --out sessions/
    $ pernav diagnose planning --routes 3 --paper-routes 0 --json planning_error.json
"""

from __future__ import annotations

import argparse
import json
import pickle
import sys
from pathlib import Path
from typing import Any

from pernav.cli_session import add_session_parser
from pernav.planner.factory import parse_planner_options
from pernav.play.sessions import check_writable
from pernav.study.config import BELIEF_DEFAULTS, COLLECT, LEARNERS, METHODS, TIMING_DEFAULTS, learner_options
from pernav.study.errors import CheckpointError
from pernav.world.constants import PLAYBACK, TOWN_NAMES
from pernav.world.drivers import CONTEXT_CHOICES, ProfileError
from pernav.world.routing import RouteError
from pernav.world.towns import TownError

# pernav.bench.BENCHMARKS (not imported here: it is slow)
BENCH_CHOICES = ("sim", "planner", "train", "play", "timing", "belief")
MAX_TRAFFIC = 64  # traffic cars of `pernav drive` (each is spawned by rejection sampling around the driver)
INTERRUPTED = 130  # exit code after Ctrl-C (128 + SIGINT, as a shell reports it), in every command
DIAGNOSTICS = {"model": "model_check", "planning": "planning_error"}  # pernav diagnose WHICH: pernav.diagnostics.*


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
        _check_output_file("--gif", args.gif, ".gif")
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


def _check_output_file(option: str, value: str, suffix: str) -> None:
    """A file the command will write: the right suffix, in a folder that exists (checked before any work)."""
    path = Path(value)
    if path.suffix.lower() != suffix:
        raise UsageError(f"{option} {value!r} must name a {suffix} file")
    if not path.parent.is_dir():
        raise UsageError(f"{option} {value!r}: folder {str(path.parent)!r} does not exist")


PLAY_POLICIES = ("explore", "oracle", "study")  # pernav.play.loop.POLICIES and a study's adapted model
PLAY_INPUTS = ("keyboard", "joystick")


def _check_drive_args(args: argparse.Namespace) -> dict[str, str]:
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
        from pernav.play.controls import parse_axes

        parse_axes(args.joystick_axes)  # a ControlsError (one line) for a bad list
    context = {k: getattr(args, k) for k in CONTEXT_CHOICES if getattr(args, k) is not None}
    if "equipment" not in context and not args.headless:  # the oracle times its prompts for the person's device
        context["equipment"] = "wheel" if args.input == "joystick" else "keyboard"
    return context


def _open_speaker(args: argparse.Namespace) -> tuple[Any, str | None]:
    """The speaker; without sound (and without --no-audio) a warning in the terminal, and its words for the screen.
    ``--audio`` without a device is an error (exit 2)."""
    from pernav.play.loop import open_speaker

    speaker, reason = open_speaker(args.audio)
    if reason is None or args.headless:
        return speaker, None
    print(f"pernav {args.command}: warning: no sound, the prompts are shown as text only: {reason} (--audio makes "
          "this an error, --no-audio silences this warning)", file=sys.stderr)
    return speaker, "No sound on this computer: the prompts are shown as text only"


def _controls(args: argparse.Namespace) -> Any:
    """A person's controls made before any window (a joystick: a missing one or axis is exit 2 with no window);
    keyboard controls need the window: their class is returned, made per drive."""
    from pernav.play.controls import JoystickControls, KeyboardControls, parse_axes

    if args.input == "joystick":
        return JoystickControls(**(parse_axes(args.joystick_axes) if args.joystick_axes else {}))
    return KeyboardControls


def _check_learner(learner: str, belief: bool = False) -> str:
    """``belief``: the belief learner is allowed too (``pernav personalize``)."""
    allowed = (*LEARNERS, "belief") if belief else LEARNERS
    if learner not in allowed:
        raise UsageError(f"--learner {learner!r}: choose one of {', '.join(allowed)}")
    return learner


def _study_policy(args: argparse.Namespace) -> tuple[object, dict] | None:
    """``--policy study``: the study's model adapted on ``--tau`` (unadapted without); None for other policies."""
    if args.policy != "study":
        if args.tau is not None or args.learner is not None:
            raise UsageError("--tau and --learner go with --policy study")
        return None
    learner = _check_learner(args.learner or "adapt")
    if args.study is None:
        raise UsageError("--policy study needs --study DIR (a finished pernav study)")
    if args.playback != "normal":
        raise UsageError("--playback applies to explore and oracle; the study's model plans its own prompts")
    if args.tau is not None and not Path(args.tau).is_file():
        raise UsageError(f"--tau {args.tau!r}: no such file")
    from pernav.play.personal import study_policy
    from pernav.trainer.drives import load_drive, read_metrics

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
    return study_policy(args.study, args.town, tau, learner=learner, seed=args.seed)


def _history(args: argparse.Namespace) -> int:
    """The history window to record: the study's (``--study``), or the default study's; ``--history`` must agree
    with a study named."""
    from pernav.play.personal import study_history

    if args.history is not None and not 1 <= args.history <= 50:
        raise UsageError(f"--history must be in [1, 50], got {args.history}")
    if args.study is not None:
        k = study_history(args.study, args.town)
        if args.history is not None and args.history != k:
            raise UsageError(f"--history {args.history}: the study in {args.study!r} reads a history of {k} steps "
                             f"(leave --history out, or give --history {k})")
        return k
    if args.history is not None:
        return args.history
    from pernav.study import preset

    return preset("default").train.K


def _play(args: argparse.Namespace) -> int:
    """A person drives a route (or the scripted bot, ``--headless``); checks everything before the window opens."""
    if args.policy not in PLAY_POLICIES:
        raise UsageError(f"--policy {args.policy!r}: choose one of {', '.join(PLAY_POLICIES)}")
    if args.playback not in PLAYBACK:
        raise UsageError(f"--playback {args.playback!r}: choose one of {', '.join(PLAYBACK)}")
    context = _check_drive_args(args)
    if args.screenshot is not None:
        _check_output_file("--screenshot", args.screenshot, ".png")
    history = _history(args)
    study = _study_policy(args)
    if args.record is not None:
        check_writable("--record", args.record)
    if args.screenshot is not None:
        check_writable("--screenshot", Path(args.screenshot).parent)
    from pernav.play.loop import PlaySession
    from pernav.trainer.drives import save_drive

    speaker, notice = _open_speaker(args)  # before any window: a missing device asked for is an error
    controls = None if args.headless else _controls(args)
    session = PlaySession(args.town, args.route, args.user, context=context, K=history if study is None else None,
                          policy=args.policy if study is None else study[0], seed=args.seed,
                          n_traffic=args.traffic, playback=args.playback, window=not args.headless,
                          speaker=speaker, screenshot=args.screenshot, screenshot_at=args.screenshot_at,
                          countdown=args.countdown, hide_cost=args.hide_cost, notice=notice,
                          title=f"{args.town} route {args.route}",
                          calibrate=args.input == "joystick" and not args.no_calibration)
    try:
        if controls is not None:
            session.controls = controls() if isinstance(controls, type) else controls
        result = session.run()
    finally:
        session.close()
    saved = None
    if args.record is not None and result.trajectory is not None:
        import time

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


def _personalize(args: argparse.Namespace) -> int:
    """Algorithm 1 with the person at the wheel (pernav.play.personal.PersonalSession); checks before any drive."""
    context = _check_drive_args(args)
    if args.updates is not None and args.updates < 0:
        raise UsageError(f"--updates must be >= 0, got {args.updates}")
    _check_learner(args.learner, belief=True)
    if args.resume and args.record is None:
        raise UsageError("--resume needs --record DIR: the interrupted session's folder")
    import time

    from pernav.play.believe import session_class
    from pernav.play.personal import summary_markdown

    record = args.record or str(Path("drives") / f"personal-{args.town}-{time.strftime('%Y%m%d-%H%M%S')}")
    session = session_class(args.learner)(args.study, args.town, args.routes, args.user, context=context, seed=args.seed,
                              record_dir=record, n_traffic=args.traffic, updates=args.updates,
                              learner=args.learner, window=not args.headless, announce=print, resume=args.resume,
                              countdown=args.countdown, hide_cost=args.hide_cost,
                              calibrate=args.input == "joystick" and not args.no_calibration)
    check_writable("--record", record)
    session.speaker, session.notice = _open_speaker(args)
    if not args.headless:
        session.controls = _controls(args)  # keyboard controls: made per drive, once its window is open
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


def _bench(args: argparse.Namespace) -> None:
    from pernav.bench import run_benchmarks

    for option, given in (("--screenshots", args.screenshots is not None), ("--live", args.live)):
        if given and args.which != "play":
            raise UsageError(f"{option} goes with pernav bench play")
    if args.screenshots is not None and not Path(args.screenshots).is_dir():
        raise UsageError(f"--screenshots {args.screenshots!r}: no such folder")
    figures = run_benchmarks(args.which, quick=args.quick, screenshots=args.screenshots, live=args.live)
    if args.json:
        print(json.dumps(figures, indent=2))
    for name, fig in ({} if args.json else figures).items():
        print(f"[{name}]\n" + "\n".join(f"  {k}: {v}" for k, v in fig.items()))


def _drive_options(p: argparse.ArgumentParser, record_help: str) -> None:
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


def _add_study_parser(sub: Any) -> None:
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
    p.add_argument("--resume", action="store_true", help="continue an interrupted study in --out")
    p.add_argument("--workers", type=int, default=1, help="parallel processes (towns run independently)")
    p.add_argument("--ray", nargs="?", const="", metavar="ADDRESS",
                   help="run towns and evaluation episodes as Ray tasks (a local cluster when no ADDRESS)")
    p.set_defaults(func=_study)


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
    _drive_options(p, "save the drive (study format) and its metrics in this folder")
    p.add_argument("--screenshot", metavar="PNG", help="save a picture of the window (one second after the first "
                   "prompt, or at --screenshot-at)")
    p.add_argument("--screenshot-at", type=float, metavar="SECONDS", help="time of the drive for --screenshot")
    p.add_argument("--json", action="store_true", help="print the metrics as JSON")
    p.set_defaults(func=_play)

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
    _drive_options(p, "the session's folder: every drive, summary.json/.md and the personalized model "
                   "(default drives/personal-TOWN-TIME)")
    p.add_argument("--resume", action="store_true", help="continue the interrupted session in --record (same "
                   "settings): its drives and model are kept, the first drive not yet whole comes next")
    p.set_defaults(func=_personalize)

    p = sub.add_parser("bench", help="benchmarks, as ratios measured in one run")
    p.add_argument("which", nargs="?", default="all", choices=[*BENCH_CHOICES, "all"])
    p.add_argument("--json", action="store_true")
    p.add_argument("--quick", action="store_true", help="shorter measurement (for smoke tests)")
    p.add_argument("--screenshots", metavar="DIR", help="with play: save a picture of each view in this folder")
    p.add_argument("--live", action="store_true", help="with play: drive each view in a real window paced to real "
                   "time (the display in DISPLAY, e.g. Xvfb; without one SDL's dummy driver, said so in the result)")
    p.set_defaults(func=_bench)

    _add_study_parser(sub)
    add_session_parser(sub)

    p = sub.add_parser("judge", help="the personal benchmark's pre-registered figures of a learner (docs/personal.md)")
    p.add_argument("studies", nargs="+", help="study folders (or results.json files) of the personal preset; "
                                              "several per seed merge (the same episodes)")
    p.add_argument("--out", required=True, help="folder for judged.json, judged.md (and sweep.png)")
    p.add_argument("--learner", default="timing", help="the method judged (default: timing)")
    p.add_argument("--sweep", nargs="+", help="study folders of the personal_sweep preset: draw sweep.png")
    p.set_defaults(func=_judge)

    p = sub.add_parser("diagnose", help="model and planning diagnostics (pernav diagnose model|planning --help)")
    p.add_argument("which", metavar="{model,planning}", help="pernav.diagnostics.model_check or planning_error")
    p.add_argument("args", nargs=argparse.REMAINDER, help="the diagnostic's own options")
    p.set_defaults(func=_diagnose)
    return parser


def _diagnose(args: argparse.Namespace) -> int:
    """The diagnostic's own command line, imported only when it runs (it loads torch and the simulator)."""
    if args.which not in DIAGNOSTICS:
        raise UsageError(f"unknown diagnostic {args.which!r}; choose one of {', '.join(DIAGNOSTICS)}")
    import importlib

    module = importlib.import_module(f"pernav.diagnostics.{DIAGNOSTICS[args.which]}")
    return module.main(args.args, prog=f"pernav diagnose {args.which}")


def _study(args: argparse.Namespace) -> None:
    import logging

    from pernav.study import load_schedule, preset, run_study

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
    try:
        cfg.train = cfg.train.with_options(args.train_option)
    except ValueError as exc:
        raise UsageError(f"--train-option {exc}") from None
    results = run_study(cfg, args.out, resume=args.resume, workers=args.workers, ray=args.ray is not None,
                        ray_address=args.ray or None)
    from pernav.study.report import collision_table

    print(collision_table(results))
    print(f"results: {Path(args.out) / 'results.json'}, report: {Path(args.out) / 'report.md'} "
          f"({results['wall_time']['wall_s']} s)")


def _judge(args: argparse.Namespace) -> None:
    import json

    from pernav.study.headroom import judge, judge_markdown, plot_sweep

    def load(paths: list[str]) -> list[dict]:
        out = []
        for path in paths:
            file = Path(path) / "results.json" if Path(path).is_dir() else Path(path)
            if not file.is_file():
                raise UsageError(f"{path!r} holds no results.json (run pernav study first)")
            try:
                out.append(json.loads(file.read_text()))
            except json.JSONDecodeError:
                raise UsageError(f"{str(file)!r} is not a results.json (not JSON)") from None
        return out

    target = Path(args.out)
    files = [target / "judged.json", target / "judged.md", *([target / "sweep.png"] if args.sweep else [])]
    taken = [str(f) for f in files if f.exists()]
    if taken:
        raise UsageError(f"{taken[0]!r} exists; choose another --out (nothing is overwritten)")
    try:
        figures = judge(load(args.studies), learner=args.learner)
    except KeyError as exc:
        raise UsageError(f"a study is not of the personal benchmark (round {exc} is not one of its cells)") from None
    target.mkdir(parents=True, exist_ok=True)
    if args.sweep:
        figures["sweep"] = plot_sweep(load(args.sweep), str(target / "sweep.png"))
    (target / "judged.json").write_text(json.dumps(figures, indent=1) + "\n")
    (target / "judged.md").write_text(judge_markdown(figures))
    print(judge_markdown(figures))


def main(argv: list[str] | None = None) -> int:
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


if __name__ == "__main__":
    sys.exit(main())
