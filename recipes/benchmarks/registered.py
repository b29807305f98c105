"""The benchmarks' pre-registrations, read from the data files beside this module (``preregistered/NAME.yaml``):
seeds and targets fixed in a commit before any learner ran on them. Reading one takes milliseconds.

Example:
    >>> sorted(registration("headroom"))
    ['seeds', 'targets']
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml

__all__ = ["PREREGISTERED", "registration"]

PREREGISTERED = Path(__file__).parent / "preregistered"


def registration(name: str) -> dict[str, Any]:
    """The pre-registration ``preregistered/NAME.yaml`` (``headroom``, ``split``, ``follow``, ``later_looks``)."""
    path = PREREGISTERED / f"{name}.yaml"
    if not path.is_file():
        known = ", ".join(sorted(p.stem for p in PREREGISTERED.glob("*.yaml")))
        raise ValueError(f"no pre-registration {name!r}; known: {known}")
    return yaml.safe_load(path.read_text(encoding="utf-8"))
