"""Shared by the test folders: the navigation state's size, a fast Town1 drive, a small seeded DynamicsModel, and
what the pytest-xdist workers build once for both.

Imported as ``navigation_helpers`` from any folder: pytest puts ``tests/`` on ``sys.path`` when it loads
``tests/conftest.py`` (its default ``prepend`` import mode, no ``__init__.py``), as it puts each test's own
folder there for ``study_helpers`` and ``play_helpers``.
"""

from __future__ import annotations

import os
import pickle
import shutil
from collections.abc import Callable
from pathlib import Path
from typing import Any

import torch
from filelock import FileLock

from pernav.model import DynamicsModel

S = 14  # the navigation state's size
TOWN1 = ("Town1", {"route": 0, "user": "user1"})
FAST = {"n_traffic": 2}


def seeded_model(seed: int, n_actions: int = 7, K: int = 5, hidden: tuple[int, ...] = (16, 16)) -> DynamicsModel:
    """A DynamicsModel initialized after ``torch.manual_seed(seed)`` (the same weights for the same arguments)."""
    torch.manual_seed(seed)
    return DynamicsModel(n_actions=n_actions, K=K, hidden=hidden)


# the test suite's studies cut every episode at 0.15 x the route's nominal time + 30 s (about 50 s of Town1's 150 s
# routes; StudyConfig.time_limit_factor): what they check (the schema, a resume, a pool, Ray, recorded drives, the
# policies a finished study hands out) does not depend on whole drives, and their episodes are most of their time
TIME_LIMIT = 0.15


def shared_folder(tmp_path_factory, name: str, build: Callable[[Path], None]) -> Path:
    """A folder that ``build(folder)`` fills once per test session, in a place that the pytest-xdist workers share:
    each waits on a file lock while the first builds it, so that tests spread over both workers do not each run
    the same study again. Returns the folder."""
    base = tmp_path_factory.getbasetemp()
    shared = base.parent if os.environ.get("PYTEST_XDIST_WORKER") else base  # this session's workers share it
    out = shared / name
    with FileLock(str(shared / f"{name}.lock")):
        if not (shared / f"{name}.done").exists():
            shutil.rmtree(out, ignore_errors=True)  # what a build that failed left
            out.mkdir(parents=True)
            build(out)
            (shared / f"{name}.done").touch()
    return out


def shared_value(tmp_path_factory, name: str, build: Callable[[], Any]) -> Any:
    """``build()``, computed once per test session for both pytest-xdist workers (:func:`shared_folder`) and
    pickled: a module fixture that each worker would otherwise build again. Returns the value."""

    def save(out: Path) -> None:
        (out / "value.pkl").write_bytes(pickle.dumps(build()))

    return pickle.loads((shared_folder(tmp_path_factory, name, save) / "value.pkl").read_bytes())
