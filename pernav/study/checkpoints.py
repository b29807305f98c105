"""A town's checkpoints: writing one after every entry, resuming from it, and reading a finished study's models.

A checkpoint is a folder ``checkpoints/<town>/entry_NNN`` (``state.pt``: the run's state and every learner's
trainer; ``buffers_<learner>/``: its replay buffers) and ``manifest.json``, which names the folder and every file's
SHA-256. The folder is written under a temporary name and the manifest replaced in one ``os.replace``, so a study
killed at any moment leaves the previous checkpoint whole.

Example:
    >>> model, members = final_models("runs/smoke", "Town1")  # doctest: +SKIP
    >>> model.load_state_dict(members[0])                     # doctest: +SKIP
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
from pathlib import Path
from typing import Any

import torch

from pernav.model.dynamics import DynamicsModel
from pernav.study.errors import CheckpointError
from pernav.trainer.buffers import RoundBuffers

__all__ = ["file_sha256", "final_belief", "final_models", "load_checkpoint", "save_checkpoint"]


def file_sha256(path: str | Path) -> str:
    """The SHA-256 of a file's bytes (hex), read in 1-MiB chunks: buffers can be large."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def save_checkpoint(folder: Path, index: int, state: dict[str, Any], learners: dict[str, Any]) -> None:
    """Write ``folder/entry_{index}`` (``state`` and every learner's ``state()`` and ``buffers``, as
    :class:`~pernav.study.runner.Learner` has them), then atomically point ``folder/manifest.json`` at it."""
    folder.mkdir(parents=True, exist_ok=True)
    final = folder / f"entry_{index:03d}"
    tmp = folder / f".tmp_entry_{index:03d}"
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir()
    torch.save({"state": state, "learners": {k: v.state() for k, v in learners.items()}}, tmp / "state.pt")
    for name, learner in learners.items():
        learner.buffers.save(tmp / f"buffers_{name}")
    files = {str(p.relative_to(tmp)): file_sha256(p) for p in sorted(tmp.rglob("*")) if p.is_file()}
    shutil.rmtree(final, ignore_errors=True)
    os.replace(tmp, final)
    manifest = {"index": index, "folder": final.name, "files": files}
    tmp_manifest = folder / ".manifest.json.tmp"
    tmp_manifest.write_text(json.dumps(manifest))
    os.replace(tmp_manifest, folder / "manifest.json")
    for old in folder.glob("entry_*"):  # keep only the checkpoint the manifest points at
        if old.name != final.name:
            shutil.rmtree(old, ignore_errors=True)


def _verified(folder: Path, only: str | None = None) -> Path | None:
    """The checkpoint folder ``folder``'s manifest points at (``None``: no manifest), its files checked against
    the manifest's checksums (``only``: that file alone); :class:`CheckpointError` naming what is wrong."""
    manifest_path = folder / "manifest.json"
    if not manifest_path.exists():
        return None
    try:
        manifest = json.loads(manifest_path.read_text())
        ckpt = folder / manifest["folder"]
        files = manifest["files"]
    except (json.JSONDecodeError, KeyError, TypeError) as exc:
        raise CheckpointError(f"checkpoint manifest {str(manifest_path)!r} is corrupted ({exc})") from None
    for rel, digest in files.items():
        if only is not None and rel != only:
            continue
        path = ckpt / rel
        if not path.is_file():
            raise CheckpointError(f"checkpoint file {str(path)!r} is missing")
        if file_sha256(path) != digest:
            raise CheckpointError(f"checkpoint file {str(path)!r} is corrupted (checksum mismatch)")
    return ckpt


def load_checkpoint(folder: Path, learners: dict[str, Any]) -> dict[str, Any] | None:
    """Restore ``learners`` (their trainers and buffers) from the manifest's checkpoint and return the run's
    state; ``None`` when there is none. Verifies every file's checksum first."""
    ckpt = _verified(folder)
    if ckpt is None:
        return None
    data = torch.load(ckpt / "state.pt", weights_only=False)
    for name, learner in learners.items():
        learner.trainer.load_state_dict(data["learners"][name])
        loaded = RoundBuffers.load(ckpt / f"buffers_{name}")
        learner.buffers.__dict__.update(loaded.__dict__)
    return data["state"]


def final_models(study: str | Path, town: str, learner: str = "adapt") -> tuple[DynamicsModel, list[dict]]:
    """A finished study's last checkpointed ensemble of ``learner`` in ``town``: a module of its
    architecture and every member's state dict (load one with ``model.load_state_dict``). Checks the
    checksum of the file it reads (not the buffers', which it does not read).

    >>> model, members = final_models("runs/default", "Town1")  # doctest: +SKIP
    """
    ckpt = _verified(Path(study) / "checkpoints" / town, only="state.pt")
    if ckpt is None:
        raise CheckpointError(f"no {town} checkpoint in {str(study)!r} (run the study first)")
    data = torch.load(ckpt / "state.pt", weights_only=False)
    if learner not in data["learners"]:
        raise CheckpointError(f"learner {learner!r} not in the checkpoint; it has {', '.join(data['learners'])}")
    members = data["learners"][learner]["members"]
    return DynamicsModel(**members[0]["model_config"]), [m["model"] for m in members]


def final_belief(study: str | Path, town: str) -> dict[str, Any]:
    """A finished study's belief learner in ``town``: ``{"detector": state dict, "prior": state dict}`` (the answer
    detector and the population prior it fitted offline), from the last checkpoint, its checksum checked.

    >>> model = final_belief("runs/default", "Town1")  # doctest: +SKIP
    """
    ckpt = _verified(Path(study) / "checkpoints" / town, only="state.pt")
    if ckpt is None:
        raise CheckpointError(f"no {town} checkpoint in {str(study)!r} (run the study first)")
    state = torch.load(ckpt / "state.pt", weights_only=False)["state"]
    if "belief_model" not in state:
        raise CheckpointError(f"the study in {str(study)!r} did not run the belief learner (add it to its methods)")
    return state["belief_model"]
