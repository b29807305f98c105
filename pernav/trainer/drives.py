"""A recorded drive on disk (a person's, ``pernav play --record``; or any simulated one): its decision steps in the
study's trajectory format, and its metrics beside them. The study reads them as schedule data.

One drive is two files: ``NAME.pt`` (``torch.save`` of the ``[T]`` trajectory as a plain dict of tensors: the
keys that :func:`pernav.trainer.collect.drive` produces, observation, action, history, ("next", "observation"),
route_ahead, action_mask, ...) and ``NAME.json`` (the episode's metrics and what was driven). Both are written
to a temporary name and then renamed, so an interrupted drive leaves no half-written file.

Example:
    >>> import tempfile
    >>> from pernav.env.torchrl_env import explore_module
    >>> from pernav.trainer import RoundBuffers
    >>> from pernav.trainer.collect import drive, episode_metrics, history_env
    >>> trajectory = drive(history_env("Town1", {"route": 0}, config={"n_traffic": 2}), explore_module(), max_steps=5)
    >>> folder = tempfile.mkdtemp()
    >>> path = save_drive(trajectory, {**episode_metrics(trajectory), "town": "Town1"}, folder, "demo")
    >>> td = load_drive(path)
    >>> td.shape, read_metrics(path)["steps"]
    (torch.Size([5]), 5)
    >>> RoundBuffers(L=3).add(0, td, tau=True)
"""

from __future__ import annotations

import json
import os
import pickle
from pathlib import Path
from typing import Any

import torch
from tensordict import TensorDict, TensorDictBase

__all__ = ["FORMAT", "atomic_write", "load_drive", "read_metrics", "save_drive"]

FORMAT = 1  # version of the .pt layout


def atomic_write(path: Path, write: Any) -> None:
    """``write(tmp)`` then rename ``tmp`` to ``path`` (same folder: the rename is atomic), so a reader never sees a
    half-written file and an interrupted write leaves none."""
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        write(tmp)
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


def save_drive(trajectory: TensorDictBase, metrics: dict[str, Any], folder: str | Path, name: str) -> Path:
    """Write ``folder/name.pt`` (the trajectory) and ``folder/name.json`` (``metrics``); returns the ``.pt`` path.

    The folder is made if missing; an existing drive of the same name is replaced."""
    if trajectory.ndim != 1 or trajectory.shape[0] == 0:
        raise ValueError(f"a drive must be a non-empty [T] trajectory, got {tuple(trajectory.shape)}")
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    pt, meta = folder / f"{name}.pt", folder / f"{name}.json"
    data = {"format": FORMAT, "batch_size": list(trajectory.shape), "trajectory": trajectory.cpu().to_dict()}
    atomic_write(pt, lambda tmp: torch.save(data, tmp))
    atomic_write(meta, lambda tmp: tmp.write_text(json.dumps(metrics, indent=2)))
    return pt


def load_drive(path: str | Path) -> TensorDictBase:
    """The ``[T]`` trajectory of a drive saved by :func:`save_drive` (ready for ``RoundBuffers.add``)."""
    try:
        data = torch.load(Path(path), weights_only=True)
    except (RuntimeError, EOFError, pickle.UnpicklingError, ValueError, UnicodeDecodeError):
        # any other .pt (a checkpoint, a model) or none: our own words, not torch's advice to unpickle it unsafely
        data = None
    if not isinstance(data, dict) or data.get("format") != FORMAT:
        raise ValueError(f"{str(path)!r} is not a pernav drive (not written by pernav play --record or save_drive)")
    return TensorDict(data["trajectory"], batch_size=data["batch_size"])


def read_metrics(path: str | Path) -> dict[str, Any]:
    """The metrics written beside a drive (``path``: the ``.pt`` or the ``.json``)."""
    return json.loads(Path(path).with_suffix(".json").read_text())
