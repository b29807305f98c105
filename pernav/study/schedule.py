"""The study schedule (docs/study.md): the paper's table as data, and user schedule files (YAML or JSON).

An entry: ``label``, ``phase`` (offline | online), ``driver`` (a named user ``user1``..``user7`` or a
mapping of :class:`~pernav.world.drivers.DriverProfile` fields, optionally with ``user`` as a base),
``vehicle``, ``camera``, ``visual``, ``equipment`` and optionally ``towns`` (the towns that run it; all
when absent). Instead of ``driver`` (and the context fields), ``drives``: recorded drives (``pernav play
--record``; files or globs, relative to the schedule file) that are the round's data, the first of a town its
tau (docs/study.md, "Recorded drives in a schedule"). Any mistake is a :class:`ScheduleError` naming the entry
and the field (and the file).

Example:
    >>> entries = paper_schedule()
    >>> len(entries), entries[0].label, entries[3].phase
    (18, 'Offline 0', 'online')
    >>> parse_schedule([{"label": "x", "phase": "online", "driver": "user9"}])  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    pernav.study.schedule.ScheduleError: schedule entry 0 ('x'): field 'driver': unknown user 'user9'; ...
"""

from __future__ import annotations

import glob
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from pernav.env.layout import STATE_DIM
from pernav.study.checkpoints import file_sha256
from pernav.trainer.drives import load_drive, read_metrics
from pernav.world.constants import (  # the study's drives: the 7 instructions (adapt_speed re-encodes)
    N_INSTRUCTIONS,
    TOWN_NAMES,
)
from pernav.world.drivers import CONTEXT_CHOICES, NAMED_USERS, Context, DriverProfile, ProfileError, named_user
from pernav.world.files import DataFileError, is_file, read_data_file

__all__ = ["Entry", "ScheduleError", "check_recorded", "load_schedule", "paper_schedule", "parse_schedule"]

FIELDS = ("label", "phase", "driver", "vehicle", "camera", "visual", "equipment", "towns", "drives")
# what a recorded drive must hold: the transitions the learners store (RoundBuffers.KEYS) and the route ahead
# (the model's road inputs, as in every simulated drive)
DRIVE_KEYS = ("observation", "action", "history", ("next", "observation"), "route_ahead")


class ScheduleError(ValueError):
    """A schedule file or entry is invalid (the message names the entry and the field)."""


@dataclass(frozen=True)
class Entry:
    """One iteration of the study: who drives, in which context, in which towns."""

    label: str
    phase: str
    driver: Any  # a user name or a mapping of profile fields
    vehicle: str = "camaro"
    camera: str = "third_person"
    visual: str = "normal"
    equipment: str = "keyboard"
    towns: tuple[str, ...] | None = None
    drives: tuple[str, ...] | None = None  # recorded drive files (resolved), in order; then ``driver`` is None

    def profile(self) -> DriverProfile:
        if self.driver is None:
            raise ScheduleError(f"schedule entry {self.label!r} is driven by recorded drives, not a simulated driver")
        if isinstance(self.driver, str):
            return named_user(self.driver)
        spec = dict(self.driver)
        base = spec.pop("user", None)
        values = named_user(base).to_dict() if base else DriverProfile().to_dict()
        values.update(spec)
        return DriverProfile.from_dict(values)  # names an unknown field (of any key type)

    def context(self) -> Context:
        return Context(vehicle=self.vehicle, camera=self.camera, visual=self.visual, equipment=self.equipment)

    def runs_in(self, town: str) -> bool:
        return self.towns is None or town in self.towns

    def drives_in(self, town: str) -> list[str]:
        """The entry's recorded drives of ``town``, in the schedule's order (the first is the round's tau)."""
        return [p for p in self.drives or () if _drive_town(p) == town]

    def user(self) -> dict[str, Any]:
        """The full resolved profile and context (what results.json records); for recorded drives, their files."""
        if self.drives:
            return {"name": "recorded", "drives": [Path(p).name for p in self.drives], "profile": None, "context": None}
        name = self.driver if isinstance(self.driver, str) else dict(self.driver).get("user", "custom")
        return {"name": name, "profile": self.profile().to_dict(), "context": self.context().to_dict()}

    def to_dict(self) -> dict[str, Any]:
        out = asdict(self)
        out["towns"] = list(self.towns) if self.towns is not None else None
        del out["drives"]  # absent without drives: a study's fingerprint stays what it was before the field
        if self.drives:  # the files' contents too: a resumed study must learn from the same drives
            out["drives"] = [{"file": p, "sha256": file_sha256(p)} for p in self.drives]
        return out


def _drive_town(path: str) -> Any:
    return read_metrics(path).get("town")


def _load(where: str, path: str) -> Any:
    """A recorded drive's ``[T]`` trajectory, or a :class:`ScheduleError` naming the entry and the file."""
    try:
        return load_drive(path)
    except ValueError:  # load_drive's own one line (never torch's advice to unpickle the file unsafely)
        raise ScheduleError(f"{where}: field 'drives': {path!r} is not a pernav drive (not written by pernav play "
                            "--record or save_drive)") from None
    except Exception as exc:  # noqa: BLE001 - an unreadable file (permissions, a folder)
        raise ScheduleError(f"{where}: field 'drives': {path!r} cannot be read ({' '.join(str(exc).split())})"
                            ) from None


def _check_drive(where: str, path: str) -> None:
    """What a drive must be whatever the study: loadable, the study's keys and state size, the 7 instructions,
    a town in its metrics file (the K of its history is checked against the study in :func:`check_recorded`)."""
    td = _load(where, path)
    bad = f"{where}: field 'drives': drive {path!r}"
    keys = set(td.keys(include_nested=True))
    missing = next((k for k in DRIVE_KEYS if k not in keys), None)
    if missing is not None:
        raise ScheduleError(f"{bad} has no {missing!r} (not recorded in the study's format)")
    if td.ndim != 1 or td.shape[0] == 0:
        raise ScheduleError(f"{bad} is not a non-empty [T] trajectory ({tuple(td.shape)})")
    width = STATE_DIM + N_INSTRUCTIONS
    if td["observation"].shape[-1] != STATE_DIM or td["history"].ndim != 3 or td["history"].shape[-1] != width:
        raise ScheduleError(f"{bad} has observations of {tuple(td['observation'].shape[1:])} and a history of "
                            f"{tuple(td['history'].shape[1:])}; the study's are ({STATE_DIM},) and (K, {width})")
    action = td["action"]
    if action.is_floating_point() or int(action.min()) < 0 or int(action.max()) >= N_INSTRUCTIONS:
        raise ScheduleError(f"{bad} has actions outside the study's {N_INSTRUCTIONS} instructions (0..{N_INSTRUCTIONS - 1}"
                            "; a drive with another playback than normal has 21)")
    if "action_mask" in keys and td["action_mask"].shape[-1] != N_INSTRUCTIONS:
        raise ScheduleError(f"{bad} has an action mask of {td['action_mask'].shape[-1]} actions, the study "
                            f"{N_INSTRUCTIONS}")
    try:
        town = _drive_town(path)
    except (OSError, ValueError) as exc:
        raise ScheduleError(f"{bad} has no readable metrics file beside it ({exc})") from None
    if town not in TOWN_NAMES:
        raise ScheduleError(f"{bad}: its metrics name no known town ({town!r})")


def _drives(where: str, raw: Any, base: Path) -> tuple[str, ...]:
    """The files of a ``drives`` field: each item a file or a glob (sorted matches), relative to ``base``."""
    if not isinstance(raw, list) or not raw or not all(isinstance(x, str) and x for x in raw):
        raise ScheduleError(f"{where}: field 'drives' must be a non-empty list of drive files (.pt) or glob patterns")
    files: list[str] = []
    for item in raw:
        path = Path(item).expanduser()
        path = path if path.is_absolute() else base / path
        if glob.has_magic(item):
            matches = sorted(m for m in glob.glob(str(path), recursive=True) if Path(m).is_file())
            if not matches:
                raise ScheduleError(f"{where}: field 'drives': no file matches {item!r} (in {str(base)!r})")
        elif not path.is_file():
            raise ScheduleError(f"{where}: field 'drives': drive file {str(path)!r} does not exist")
        else:
            matches = [str(path)]
        for m in matches:
            resolved = str(Path(m).resolve())
            if resolved not in files:  # a file named twice (a file and a glob) counts once
                files.append(resolved)
    for f in files:
        _check_drive(where, f)
    return tuple(files)


def _entry(i: int, raw: Any, base: Path) -> Entry:
    where = f"schedule entry {i}"
    if not isinstance(raw, dict):
        raise ScheduleError(f"{where}: must be a mapping with {', '.join(FIELDS)}, not {type(raw).__name__}")
    label = raw.get("label", f"#{i}")
    where = f"schedule entry {i} ({label!r})"
    unknown = sorted(set(raw) - set(FIELDS), key=str)  # keys of any type (YAML: 1, null)
    if unknown:
        raise ScheduleError(f"{where}: unknown field {unknown[0]!r}; allowed: {', '.join(FIELDS)}")
    recorded = "drives" in raw
    if recorded:  # the drives' person drove in the context of the drives: a simulated driver or context is not used
        other = next((k for k in ("driver", *CONTEXT_CHOICES) if k in raw), None)
        if other is not None:
            raise ScheduleError(f"{where}: field {other!r}: an entry with 'drives' is driven by the person who recorded "
                                "them; give 'drives' or a simulated 'driver' (with its context), not both")
    for key in ("label", "phase") if recorded else ("label", "phase", "driver"):
        if key not in raw:
            raise ScheduleError(f"{where}: field {key!r} is missing")
    if not isinstance(label, str) or not label:
        raise ScheduleError(f"{where}: field 'label' must be a non-empty string")
    if raw["phase"] not in ("offline", "online"):
        raise ScheduleError(f"{where}: field 'phase': {raw['phase']!r} is not offline or online")
    driver = raw.get("driver")
    if recorded:
        pass
    elif isinstance(driver, str):
        if driver not in NAMED_USERS:
            raise ScheduleError(f"{where}: field 'driver': unknown user {driver!r}; choose one of "
                                f"{', '.join(NAMED_USERS)} or a mapping of profile fields")
    elif not isinstance(driver, dict):
        raise ScheduleError(f"{where}: field 'driver' must be a user name or a mapping, not {type(driver).__name__}")
    for key, choices in CONTEXT_CHOICES.items():
        if key in raw and raw[key] not in choices:
            raise ScheduleError(f"{where}: field {key!r}: {raw[key]!r} is not one of {', '.join(choices)}")
    towns = raw.get("towns")
    if towns is not None:
        if not isinstance(towns, list) or not towns:
            raise ScheduleError(f"{where}: field 'towns' must be a non-empty list of town names")
        bad = [t for t in towns if t not in TOWN_NAMES]
        if bad:
            raise ScheduleError(f"{where}: field 'towns': unknown town {bad[0]!r}; choose from {', '.join(TOWN_NAMES)}")
        towns = tuple(towns)
    drives = _drives(where, raw["drives"], base) if recorded else None
    entry = Entry(label=label, phase=raw["phase"], driver=driver, towns=towns, drives=drives,
                  **{k: raw[k] for k in CONTEXT_CHOICES if k in raw})
    if not recorded:
        try:
            entry.profile()
        except (ProfileError, TypeError, ValueError) as exc:
            raise ScheduleError(f"{where}: field 'driver': {exc}") from None
    return entry


def parse_schedule(raw: Any, base: str | Path | None = None) -> list[Entry]:
    """Validate a schedule (a list of entry mappings, or ``{"schedule": [...]}``); ``base``: the folder that
    relative ``drives`` are in (the schedule file's; the working directory when None)."""
    if isinstance(raw, dict) and set(raw) == {"schedule"}:
        raw = raw["schedule"]
    if not isinstance(raw, list) or not raw:
        raise ScheduleError("a schedule must be a non-empty list of entries")
    base = Path.cwd() if base is None else Path(base)
    entries = [_entry(i, e, base) for i, e in enumerate(raw)]
    labels = [e.label for e in entries]
    dup = next((x for x in labels if labels.count(x) > 1), None)
    if dup is not None:
        raise ScheduleError(f"schedule entry {labels.index(dup, labels.index(dup) + 1)} ({dup!r}): field 'label' repeats")
    if not any(e.phase == "offline" for e in entries):
        raise ScheduleError("schedule: no entry has phase 'offline' (the warm start needs offline data)")
    if not any(e.phase == "online" for e in entries):
        raise ScheduleError("schedule: no entry has phase 'online'")
    first_online = next(i for i, e in enumerate(entries) if e.phase == "online")
    late = next((i for i, e in enumerate(entries) if e.phase == "offline" and i > first_online), None)
    if late is not None:
        raise ScheduleError(f"schedule entry {late} ({entries[late].label!r}): field 'phase': offline entries must "
                            "come before the online ones")
    return entries


def load_schedule(path: str | Path) -> list[Entry]:
    """Read and validate a YAML or JSON schedule file."""
    path = Path(path)
    if not is_file(path):
        raise ScheduleError(f"schedule file {str(path)!r} does not exist")
    try:
        raw = read_data_file(path)
    except DataFileError as exc:
        raise ScheduleError(f"cannot parse schedule file {str(path)!r}: {exc}") from None
    return parse_schedule(raw, base=path.parent)


def check_recorded(entries: list[Entry], towns: list[str], K: int) -> None:
    """Check an entry's recorded drives against the study that runs them: each drive of a town the entry runs in
    (``towns`` of the entry, else the study's), every such town with at least one drive (its tau), and a
    history of the study's length ``K``. A :class:`ScheduleError` names the entry and the file.

    >>> check_recorded(paper_schedule(), ["Town1"], K=5)  # no recorded drives: nothing to check
    """
    for i, entry in enumerate(entries):
        if not entry.drives:
            continue
        where = f"schedule entry {i} ({entry.label!r}): field 'drives'"
        runs = [t for t in towns if entry.runs_in(t)]
        allowed = list(entry.towns) if entry.towns is not None else towns
        for path in entry.drives:
            town = _drive_town(path)
            if town not in allowed:
                whose = "the entry's towns" if entry.towns is not None else "the study's towns"
                raise ScheduleError(f"{where}: drive {path!r} is of {town}, not one of {whose} ({', '.join(allowed)})")
            k = _load(f"schedule entry {i} ({entry.label!r})", path)["history"].shape[1]
            if k != K:
                raise ScheduleError(f"{where}: drive {path!r} has a history of K = {k} steps, the study's model "
                                    f"reads K = {K} (--train-option K={k} fits it)")
        empty = next((t for t in runs if not entry.drives_in(t)), None)
        if empty is not None:
            raise ScheduleError(f"{where}: the entry runs in {empty} but none of its drives is of {empty}; give it "
                                f"'towns' with the towns of its drives")


def paper_schedule() -> list[Entry]:
    """The paper's Table "Iteration Details" (docs/study.md); Online 7-12 in Town1-3 only."""
    rows: list[dict[str, Any]] = [
        {"label": "Offline 0", "phase": "offline", "driver": "user1", "vehicle": "camaro", "camera": "first_person"},
        {"label": "Offline 1", "phase": "offline", "driver": "user1", "vehicle": "camaro", "camera": "third_person"},
        {"label": "Offline 2", "phase": "offline", "driver": "user1", "vehicle": "cybertruck", "camera": "first_person"},
        {"label": "Online 0", "phase": "online", "driver": "user1", "vehicle": "cybertruck", "camera": "third_person"},
        {"label": "Online 1", "phase": "online", "driver": "user1", "vehicle": "camaro", "camera": "first_person",
         "visual": "rgb"},
        {"label": "Online 2", "phase": "online", "driver": "user1", "vehicle": "camaro", "camera": "third_person",
         "visual": "foggy"},
        {"label": "Online 3", "phase": "online", "driver": "user1", "vehicle": "camaro", "camera": "first_person",
         "visual": "foggy"},
        {"label": "Online 4", "phase": "online", "driver": "user1", "vehicle": "cybertruck", "camera": "third_person",
         "visual": "foggy"},
        {"label": "Online 5", "phase": "online", "driver": "user1", "vehicle": "cybertruck", "camera": "first_person",
         "visual": "foggy"},
        {"label": "Online 6", "phase": "online", "driver": "user1", "vehicle": "cybertruck", "camera": "top",
         "visual": "foggy"},
    ]
    for k, user in enumerate(("user2", "user3", "user4", "user5", "user6", "user7")):
        rows.append({"label": f"Online {7 + k}", "phase": "online", "driver": user, "vehicle": "camaro",
                     "camera": "third_person", "towns": ["Town1", "Town2", "Town3"]})
    rows.append({"label": "Online 13", "phase": "online", "driver": "user1", "camera": "first_person",
                 "equipment": "wheel"})
    rows.append({"label": "Online 14", "phase": "online", "driver": "user1", "camera": "third_person",
                 "equipment": "wheel"})
    return parse_schedule(rows)
