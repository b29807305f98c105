"""The study schedule (docs/study.md): the paper's table as data, and user schedule files (YAML or JSON).

An entry: ``label``, ``phase`` (offline | online), ``driver`` (a named user ``user1``..``user7`` or a
mapping of :class:`~pernav.world.drivers.DriverProfile` fields, optionally with ``user`` as a base),
``vehicle``, ``camera``, ``visual``, ``equipment`` and optionally ``towns`` (the towns that run it; all
when absent). Any mistake is a :class:`ScheduleError` naming the entry and the field.

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

from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from pernav.world.drivers import CONTEXT_CHOICES, NAMED_USERS, Context, DriverProfile, ProfileError, named_user
from pernav.world.files import DataFileError, is_file, read_data_file
from pernav.world.towns import TOWN_NAMES

__all__ = ["Entry", "ScheduleError", "load_schedule", "paper_schedule", "parse_schedule"]

FIELDS = ("label", "phase", "driver", "vehicle", "camera", "visual", "equipment", "towns")


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

    def profile(self) -> DriverProfile:
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

    def user(self) -> dict[str, Any]:
        """The full resolved profile and context (what results.json records)."""
        name = self.driver if isinstance(self.driver, str) else dict(self.driver).get("user", "custom")
        return {"name": name, "profile": self.profile().to_dict(), "context": self.context().to_dict()}

    def to_dict(self) -> dict[str, Any]:
        out = asdict(self)
        out["towns"] = list(self.towns) if self.towns is not None else None
        return out


def _entry(i: int, raw: Any) -> Entry:
    where = f"schedule entry {i}"
    if not isinstance(raw, dict):
        raise ScheduleError(f"{where}: must be a mapping with {', '.join(FIELDS)}, not {type(raw).__name__}")
    label = raw.get("label", f"#{i}")
    where = f"schedule entry {i} ({label!r})"
    unknown = sorted(set(raw) - set(FIELDS), key=str)  # keys of any type (YAML: 1, null)
    if unknown:
        raise ScheduleError(f"{where}: unknown field {unknown[0]!r}; allowed: {', '.join(FIELDS)}")
    for key in ("label", "phase", "driver"):
        if key not in raw:
            raise ScheduleError(f"{where}: field {key!r} is missing")
    if not isinstance(label, str) or not label:
        raise ScheduleError(f"{where}: field 'label' must be a non-empty string")
    if raw["phase"] not in ("offline", "online"):
        raise ScheduleError(f"{where}: field 'phase': {raw['phase']!r} is not offline or online")
    driver = raw["driver"]
    if isinstance(driver, str):
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
    entry = Entry(label=label, phase=raw["phase"], driver=driver, towns=towns,
                  **{k: raw[k] for k in CONTEXT_CHOICES if k in raw})
    try:
        entry.profile()
    except (ProfileError, TypeError, ValueError) as exc:
        raise ScheduleError(f"{where}: field 'driver': {exc}") from None
    return entry


def parse_schedule(raw: Any) -> list[Entry]:
    """Validate a schedule (a list of entry mappings, or ``{"schedule": [...]}``)."""
    if isinstance(raw, dict) and set(raw) == {"schedule"}:
        raw = raw["schedule"]
    if not isinstance(raw, list) or not raw:
        raise ScheduleError("a schedule must be a non-empty list of entries")
    entries = [_entry(i, e) for i, e in enumerate(raw)]
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
    return parse_schedule(raw)


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
