"""``pernav session``: a lab's study session from a session file (:mod:`pernav.play.lab`), one participant per run;
it shares the checks of a person's drive (input device, speaker, writable folder) with ``pernav play``.

Example:
    >>> from pernav.cli import main
    >>> main(["session", "docs/examples/session.yaml", "--check"])  # doctest: +SKIP
"""

from __future__ import annotations

import argparse
import sys
from typing import Any

from pernav.cli.common import INTERRUPTED, PLAY_INPUTS, UsageError, open_speaker, person_controls
from pernav.play.lab import LabSession
from pernav.play.labplan import SessionPlan, drive_list, load_plan, square_warning
from pernav.play.sessions import check_writable

__all__ = ["add_parser", "run", "stdin_answers"]


def add_parser(sub: Any) -> None:
    """Register ``pernav session`` on the command line's subparsers."""
    p = sub.add_parser("session", help="a lab's study session: a participant drives the blocks of a session file "
                       "in a counterbalanced order, every frame logged (docs/human.md)")
    p.add_argument("file", help="the session file (YAML): participants, practice, blocks of conditions, "
                   "counterbalancing, questionnaire")
    p.add_argument("--participant", help="the participant's id (one of the file's participants)")
    p.add_argument("--out", default="sessions", help="the study's folder: each participant's files go to "
                   "OUT/<participant> (default sessions)")
    p.add_argument("--resume", action="store_true", help="continue the participant's stopped session: the next "
                   "drive not yet whole comes next, nothing recorded is rewritten")
    p.add_argument("--check", action="store_true", help="check the file and print each participant's order of "
                   "drives; drive nothing")
    p.add_argument("--input", default="keyboard", help="keyboard (arrows/WASD; default) or joystick (a wheel)")
    p.add_argument("--joystick-axes", metavar="STEER,THROTTLE,BRAKE", help="with --input joystick: axis indices "
                   "of the wheel and pedals, ~ inverts one (as pernav play)")
    p.add_argument("--headless", action="store_true", help="no window: a scripted bot drives (a dry run of the file); "
                   "the questions are asked in the terminal, or read from stdin (one answer a line) when it is not one")
    p.add_argument("--audio", dest="audio", action="store_true", default=None,
                   help="require sound (an error without an audio device; default: sound if there is a device)")
    p.add_argument("--no-audio", dest="audio", action="store_false", help="prompts as text only")
    p.set_defaults(func=run)


def stdin_answers(session: LabSession, lines: list[str]) -> Any:
    """The answers a headless session reads from stdin (one a line, in the order the questions come), each checked
    before anything is driven; too few, or one off its scale, is a :class:`UsageError` naming it."""
    questions = session.questions_in_order()
    answers = [line.strip() for line in lines if line.strip()]
    if len(answers) < len(questions):
        first = questions[len(answers)]
        raise UsageError(f"headless: the session asks {len(questions)} answer(s) and stdin gives {len(answers)} (the "
                         f"first missing: {first.id!r}); pipe one answer a line, e.g. < answers.txt, or run with a "
                         "window")
    values: list[Any] = []
    for k, (question, text) in enumerate(zip(questions, answers, strict=False)):
        if question.scale is None:
            values.append(text)
            continue
        if not text.isdigit() or not question.scale[0] <= int(text) <= question.scale[1]:
            raise UsageError(f"headless: stdin line {k + 1} ({text!r}) answers {question.id!r}, whose scale is "
                             f"{question.scale[0]}-{question.scale[1]}: give a whole number in it")
        values.append(int(text))
    values.reverse()
    return lambda question, block: values.pop()


def _equip(speaker: Any, plan: SessionPlan) -> None:
    """The session file's audio settings on the speaker: its volume and voice."""
    if speaker is not None:
        speaker.volume, speaker.voice = plan.audio.volume, plan.audio.voice


def run(args: argparse.Namespace) -> int:
    """Check everything before a window opens, then run (or resume) the participant's session."""
    plan = load_plan(args.file)
    if args.check:
        for participant in plan.participants:
            drives = drive_list(plan, participant)
            print(f"{participant}: " + ", ".join(f"{d.block}/{d.condition.town} r{d.condition.route}"
                                                  for d in drives))
        warning = square_warning(plan)
        if warning is not None:
            print(f"pernav session: {warning}", file=sys.stderr)
        return 0
    if args.participant is None:
        raise UsageError(f"--participant: give the participant's id (one of {', '.join(plan.participants)})")
    if args.input not in PLAY_INPUTS:
        raise UsageError(f"--input {args.input!r}: choose one of {', '.join(PLAY_INPUTS)}")
    if args.joystick_axes is not None and args.input != "joystick":
        raise UsageError("--joystick-axes goes with --input joystick")
    args.command = "session"
    session = LabSession(plan, args.participant, args.out, window=not args.headless, resume=args.resume)
    check_writable("--out", args.out)
    if args.headless and session.questions_in_order() and not sys.stdin.isatty():
        session.answer = stdin_answers(session, sys.stdin.read().splitlines())
    session.speaker, session.notice = open_speaker(args)
    _equip(session.speaker, plan)
    if not args.headless:
        session.controls = person_controls(args)
    result = session.run()
    state = "finished" if result.finished else "stopped"
    print(f"{args.participant}: {state}, {result.done} of {result.total} step(s) done; files in {result.folder}")
    if not result.finished:
        print(f"continue it: pernav session {args.file} --participant {args.participant} --out {args.out} --resume",
              file=sys.stderr)
    return INTERRUPTED if result.ctrl_c else 0
