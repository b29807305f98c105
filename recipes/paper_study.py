"""Reproduce the paper's study: 5 towns x 10 routes x the full schedule, every method.

Usage:
    .venv/bin/python recipes/paper_study.py OUT_DIR [--workers N] [--resume]

This is ``pernav study --preset paper`` (hours on a laptop; use ``--workers`` = number of cores, or run
it with ``--resume`` after an interruption). The schedule is the paper's table (recipes/configs/paper.yaml
spells it out as a file you can edit and pass with ``--schedule``).
"""

from __future__ import annotations

import argparse
import sys

from pernav.cli import main

if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out")
    parser.add_argument("--workers", type=int, default=1)
    parser.add_argument("--resume", action="store_true")
    args = parser.parse_args()
    argv = ["study", "--preset", "paper", "--out", args.out, "--workers", str(args.workers)]
    sys.exit(main(argv + (["--resume"] if args.resume else [])))
