"""A town's checkpoints: writing one after every entry, resuming from it, and reading a finished study's models.

A checkpoint is a folder ``checkpoints/<town>/entry_NNN`` (``state.pt``: the run's :class:`RunState` as a plain
dict and every learner's trainer; ``buffers_<learner>/``: its replay buffers) and ``manifest.json``, which names the
folder and every file's SHA-256. The folder is written under a temporary name and the manifest replaced in one
``os.replace``, so a study killed at any moment leaves the previous checkpoint whole.

Example:
    >>> model, members = final_models("runs/smoke", "Town1")  # doctest: +SKIP
    >>> model.load_state_dict(members[0])                     # doctest: +SKIP
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any, ClassVar

import torch

from pernav.env.layout import STATE_DIM
from pernav.model.dynamics import DynamicsModel
from pernav.study.errors import CheckpointError
from pernav.trainer.buffers import RoundBuffers

__all__ = ["RunState", "file_sha256", "final_belief", "final_models", "load_checkpoint", "save_checkpoint"]


@dataclass
class RunState:
    """What one town's run has done so far, beside its learners: what a checkpoint keeps to resume it.

    Per-round dicts are keyed by the entry's label. Saved as a plain dict (:meth:`to_dict`), so that a checkpoint
    does not depend on where this class lives, and read back by :meth:`from_dict`, which also reads the state of a
    checkpoint written before the rename of ``timing`` (the rounds' wall time) to ``wall_time``.
    """

    next: int = 0  # the index of the next entry to run
    results: list[dict[str, Any]] = field(default_factory=list)  # per entry run: label, phase, methods' figures
    warm: dict[str, Any] | None = None  # every learner's trainer state after the warm start (Eq. 1)
    online_losses: dict[str, float] = field(default_factory=dict)  # adapt's loss on the round's data, adapted
    unadapted_losses: dict[str, float] = field(default_factory=dict)  # ... and without adaptation
    fixed_step_losses: dict[str, float] = field(default_factory=dict)  # ... adapted with the paper's fixed step
    wall_time: dict[str, float] = field(default_factory=dict)  # s each round took, wall clock
    profile: dict[str, float] = field(default_factory=dict)  # s of wall clock per phase (collection_s, ...)
    timing_model: dict[str, Any] | None = None  # the timing learner's state dict, fitted offline
    timing_beliefs: dict[str, dict[str, float]] = field(default_factory=dict)  # its belief about each round's user
    belief_model: dict[str, Any] | None = None  # the belief learner's {"detector", "prior"} state dicts
    belief_posteriors: dict[str, dict[str, Any]] = field(default_factory=dict)  # per user (profile and context)
    belief_rounds: dict[str, dict[str, Any]] = field(default_factory=dict)  # its posterior after each round's tau
    hindsight: dict[str, Any] | None = None  # the hindsight model's evaluations and losses, once trained
    driver: dict[str, Any] | None = None  # adapt_driver's offline fit, meta model, evidence and estimates
    shifts: dict[str, dict[str, Any]] = field(default_factory=dict)  # best_shift's selection per round

    #: keys of checkpoints written before a field was renamed -> the field
    RENAMED: ClassVar[dict[str, str]] = {"timing": "wall_time"}

    def to_dict(self) -> dict[str, Any]:
        """The fields as a plain dict (the objects themselves, not copies)."""
        return {f.name: getattr(self, f.name) for f in fields(self)}

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> RunState:
        """The state :meth:`to_dict` gave, or an older checkpoint's (a field it lacks takes its default)."""
        return cls(**{cls.RENAMED.get(k, k): v for k, v in data.items()})


def file_sha256(path: str | Path) -> str:
    """The SHA-256 of a file's bytes (hex), read in 1-MiB chunks: buffers can be large."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def save_checkpoint(folder: Path, index: int, state: RunState, learners: dict[str, Any]) -> None:
    """Write ``folder/entry_{index}`` (``state`` and every learner's ``state()`` and ``buffers``, as
    :class:`~pernav.study.runner.Learner` has them), then atomically point ``folder/manifest.json`` at it."""
    folder.mkdir(parents=True, exist_ok=True)
    final = folder / f"entry_{index:03d}"
    tmp = folder / f".tmp_entry_{index:03d}"
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir()
    torch.save({"state": state.to_dict(), "learners": {k: v.state() for k, v in learners.items()}}, tmp / "state.pt")
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


def load_checkpoint(folder: Path, learners: dict[str, Any]) -> RunState | None:
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
    return RunState.from_dict(data["state"])


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
    config = dict(members[0]["model_config"])
    # a checkpoint from before the delta was saved: "auto" then meant the navigation's layout for any 14-d state
    config.setdefault("delta", "egocentric" if config.get("state_dim") == STATE_DIM else "plain")
    return DynamicsModel(**config), [m["model"] for m in members]


def final_belief(study: str | Path, town: str) -> dict[str, Any]:
    """A finished study's belief learner in ``town``: ``{"detector": state dict, "prior": state dict}`` (the answer
    detector and the population prior it fitted offline), from the last checkpoint, its checksum checked.

    >>> model = final_belief("runs/default", "Town1")  # doctest: +SKIP
    """
    ckpt = _verified(Path(study) / "checkpoints" / town, only="state.pt")
    if ckpt is None:
        raise CheckpointError(f"no {town} checkpoint in {str(study)!r} (run the study first)")
    state = RunState.from_dict(torch.load(ckpt / "state.pt", weights_only=False)["state"])
    if state.belief_model is None:
        raise CheckpointError(f"the study in {str(study)!r} did not run the belief learner (add it to its methods)")
    return state.belief_model
