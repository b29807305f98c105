"""What every personalization session checks before its first drive (``pernav personalize``, with a model-based
learner, :class:`pernav.play.personal.PersonalSession`, or with the belief learner,
:class:`pernav.play.believe.BeliefSession`): the town and routes, the seed and the record folder, each refused by name.

Example:
    >>> check_session("Town1", [0, 3], 0, None, resume=False) is None
    True
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

from pernav.play.loop import PlayError
from pernav.world.constants import TOWN_NAMES
from pernav.world.towns import get_town

__all__ = ["SESSION_FILES", "check_session", "check_writable"]

#: what a session writes beside its drives (a folder holding one of them holds a session)
SESSION_FILES = ("session.json", "summary.json", "summary.md", "model.pt", "belief.pt")


def check_session(town: str, routes: Sequence[int], seed: int, record_dir: str | Path | None, resume: bool
                  ) -> Path | None:
    """The session's record folder (``None``: not recorded) once ``town``, ``routes`` (tau's, then at least one more),
    ``seed`` and the folder are valid: a folder holding another session is refused unless ``resume``, when it must
    hold one. :class:`~pernav.play.loop.PlayError` names the bad setting and what is allowed."""
    if town not in TOWN_NAMES:
        raise PlayError(f"unknown town {town!r}; choose one of {', '.join(TOWN_NAMES)}")
    n_routes = len(get_town(town).routes)
    if len(routes) < 2:
        raise PlayError(f"need at least two routes (tau's, then one or more to compare on), got {list(routes)}")
    bad = [r for r in routes if isinstance(r, bool) or not isinstance(r, int) or not 0 <= r < n_routes]
    if bad:
        raise PlayError(f"unknown route {bad[0]!r} in {town}; routes are 0-{n_routes - 1}")
    if seed < 0:
        raise PlayError(f"seed must be >= 0, got {seed}")
    folder = None if record_dir is None else Path(record_dir)
    if resume and folder is None:
        raise PlayError("resuming needs the interrupted session's record folder")
    if folder is not None:
        if folder.exists() and not folder.is_dir():
            raise PlayError(f"record folder {str(folder)!r} exists and is not a folder")
        held = any((folder / name).exists() for name in SESSION_FILES)
        if held and not resume:
            raise PlayError(f"record folder {str(folder)!r} already holds a personalization session; "
                            "choose another, or --resume to continue it")
        if resume and not (folder / "session.json").is_file():
            raise PlayError(f"--resume: record folder {str(folder)!r} holds no personalization session "
                            "to resume (no session.json)")
    return folder


def check_writable(option: str, folder: str | Path) -> None:
    """Write (and remove) a probe file in ``folder`` before anyone drives: a folder that cannot be written is found
    now, not after the drive. Folders made for the probe are removed again (they are made when a drive is saved)."""
    folder = Path(folder)
    made = [p for p in (folder, *folder.parents) if not p.exists()]
    probe = folder / f".pernav-write-test-{os.getpid()}"
    try:
        folder.mkdir(parents=True, exist_ok=True)
        probe.write_bytes(b"pernav")
    except OSError as exc:
        raise PlayError(f"{option} {str(folder)!r} cannot be written ({exc.strerror or exc}): nothing was driven"
                         ) from None
    finally:
        try:
            probe.unlink(missing_ok=True)
        except OSError:  # under a file: there is no probe to remove
            pass
        for p in made:  # deepest first
            try:
                p.rmdir()
            except OSError:
                break
