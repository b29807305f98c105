"""A participant's folder of a lab session (:mod:`pernav.play.lab`): made by the session, refused when it holds
anything the session did not write, and only ever appended to.

The checks (:meth:`ParticipantFolder.check`, before anything is written; a refusal changes no byte):

- ``OUT`` must not itself be a participant's folder (``--out sessions/S01 --participant S02``);
- without ``resume`` the participant's folder must not exist or be empty;
- with ``resume`` it must hold this participant's session (``session.json``'s participant, the records' participant)
  of the same session file, and nothing else: every file the session writes in ``drives/`` is announced in
  ``events.jsonl`` before it is written, so a file nobody announced (another participant's drive, a CSV copied in)
  is refused.

Committing an item (:meth:`ParticipantFolder.commit`): its drive files are written first, then its record is
appended to ``progress.jsonl`` (the commit point) with the byte offset and the bytes it adds to each table, then the
tables are appended. A kill between any two of these is repaired on resume by appending, never by truncating: the
tables' missing bytes are appended from the record (or the drive's own rows file), a drive's files written but never
committed are renamed ``...-killed1`` (kept, and said in an event), a progress line cut short is ended with a newline.
``events.jsonl`` gets a line for every start, resume, kill (found on resume: a run with no end), end, file and
consent.
"""

from __future__ import annotations

import json
import os
import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any

__all__ = ["MARKERS", "TOP_FILES", "FolderError", "ParticipantFolder", "now"]

#: what marks a folder as a participant's (a session wrote it)
MARKERS = ("session.json", "progress.jsonl", "events.jsonl", "plan.yaml")
#: every file a session writes at the top of a participant's folder (and drives/)
TOP_FILES = (*MARKERS, "session.csv", "drives.csv", "answers.csv", "dictionary.csv", "summary.json", "belief.pt")


class FolderError(ValueError):
    """A participant's folder the session refuses (one line; nothing was changed)."""


def now() -> str:
    """Wall-clock time, ISO 8601 in UTC with milliseconds."""
    t = time.time()
    return time.strftime("%Y-%m-%dT%H:%M:%S", time.gmtime(t)) + f".{int(t % 1 * 1000):03d}Z"


def _append(path: Path, data: bytes) -> None:
    with open(path, "ab") as f:  # one write, then to disk: what is appended survives a crash after it
        f.write(data)
        f.flush()
        os.fsync(f.fileno())


def _size(path: Path) -> int:
    return path.stat().st_size if path.exists() else 0


def _temp_of(name: str) -> str | None:
    """The file an atomic write's temporary file (``.NAME.PID.tmp``) was for, else None."""
    if name.startswith(".") and name.endswith(".tmp") and name.count(".") >= 3:
        return name[1:].rsplit(".", 2)[0]
    return None


class ParticipantFolder:
    """``out/participant``: its checks, its records (``progress.jsonl``), its events and its append-only tables."""

    def __init__(self, out: str | Path, participant: str, plan_text: str, resume: bool) -> None:
        self.out, self.participant = Path(out), participant
        self.path = self.out / participant
        self.plan_text, self.resume = plan_text, resume
        self.records: list[dict[str, Any]] = []
        self.events: list[dict[str, Any]] = []

    # ----- reading and checking ----------------------------------------------------------------------------
    @staticmethod
    def _jsonl(path: Path) -> list[dict[str, Any]]:
        if not path.exists():
            return []
        out = []
        for line in path.read_text().splitlines():
            try:
                out.append(json.loads(line))
            except json.JSONDecodeError:  # a line cut by a kill: its item was not committed
                continue
        return out

    def check(self) -> None:
        """Refuse a folder this session may not write into (:class:`FolderError`); read its records and events."""
        out, folder = self.out, self.path
        marked = [m for m in MARKERS if (out / m).exists()]
        if marked:
            raise FolderError(f"--out {str(out)!r} is a participant's folder (it holds {marked[0]}): give the "
                              "study's folder, in which each participant's folder is made (nothing was changed)")
        if folder.exists() and not folder.is_dir():
            raise FolderError(f"{str(folder)!r} exists and is not a folder (nothing was changed)")
        entries = sorted(p.name for p in folder.iterdir()) if folder.is_dir() else []
        if not self.resume:
            if any(m in entries for m in MARKERS):
                raise FolderError(f"{str(folder)!r} holds a session already: continue it with --resume (nothing was "
                                  "changed)")
            if entries:
                raise FolderError(f"{str(folder)!r} holds files this session did not write ({', '.join(entries[:3])}"
                                  f"{', ...' if len(entries) > 3 else ''}): a participant's folder is made by the "
                                  "session; give another --out (nothing was changed)")
            return
        if not (folder / "session.json").is_file():
            raise FolderError(f"--resume: {str(folder)!r} holds no session to continue")
        try:
            info = json.loads((folder / "session.json").read_text())
        except (json.JSONDecodeError, UnicodeDecodeError):
            raise FolderError(f"--resume: {str(folder / 'session.json')!r} cannot be read (nothing was changed)") from None
        if not isinstance(info, dict) or info.get("participant") != self.participant:
            who = info.get("participant") if isinstance(info, dict) else None
            raise FolderError(f"--resume: {str(folder)!r} holds participant {who!r}'s session, not "
                              f"{self.participant!r}'s (a copied or renamed folder?); nothing was changed")
        kept = (folder / "plan.yaml").read_text() if (folder / "plan.yaml").exists() else None
        if kept is not None and kept != self.plan_text:
            raise FolderError(f"{folder}/plan.yaml differs from the session file given: resume with the file the "
                              "session started with (nothing was changed)")
        self.records = self._jsonl(folder / "progress.jsonl")
        self.events = self._jsonl(folder / "events.jsonl")
        others = sorted({str(r.get("participant")) for r in self.records if r.get("participant") not in
                         (None, self.participant)})
        if others:
            raise FolderError(f"--resume: {str(folder / 'progress.jsonl')!r} holds participant {others[0]!r}'s "
                              "drives (nothing was changed)")
        foreign = [name for name in entries if name not in TOP_FILES and name != "drives"
                   and _temp_of(name) not in TOP_FILES]
        announced = {e["file"] for e in self.events if e.get("event") in ("file", "kept") and "file" in e}
        if (folder / "drives").is_dir():
            for p in sorted((folder / "drives").iterdir()):
                name = p.name if _temp_of(p.name) is None else _temp_of(p.name)
                if f"drives/{name}" not in announced:
                    foreign.append(f"drives/{p.name}")
        if foreign:
            raise FolderError(f"--resume: {str(folder)!r} holds files this session did not write "
                              f"({', '.join(foreign[:3])}{', ...' if len(foreign) > 3 else ''}); nothing was changed")
        for record in self.records:
            for table, append in (record.get("appends") or {}).items():
                if _size(folder / table) < append["at"]:
                    raise FolderError(f"--resume: {table} is shorter than progress.jsonl says it was (edited?); "
                                      "nothing was changed")

    # ----- writing -----------------------------------------------------------------------------------------
    def event(self, kind: str, **fields: Any) -> None:
        """Append one event to ``events.jsonl``."""
        event = {"event": kind, "time": now(), **fields}
        _append(self.path / "events.jsonl", (json.dumps(event) + "\n").encode())
        self.events.append(event)

    def begin(self, info: Mapping[str, Any], headers: Mapping[str, str]) -> None:
        """Make the folder (or take it up on resume): the start or resume event (and a kill found: the last run
        has no end), the files written once (``session.json``, ``plan.yaml``, the tables' headers, ``extra``)
        where missing, and what a kill left half done repaired by appending."""
        folder = self.path
        folder.mkdir(parents=True, exist_ok=True)
        (folder / "drives").mkdir(exist_ok=True)
        if self.resume:
            runs = [e for e in self.events if e.get("event") in ("start", "resume", "end")]
            if runs and runs[-1]["event"] != "end":
                self.event("killed", detected=now(), last_event=self.events[-1]["time"])
            self.event("resume", done=len(self.records))
        else:
            self.event("start")
        if not (folder / "session.json").exists():
            (folder / "session.json").write_text(json.dumps(dict(info), indent=2) + "\n")
        if not (folder / "plan.yaml").exists():
            (folder / "plan.yaml").write_text(self.plan_text)
        for name, text in headers.items():
            if not (folder / name).exists():
                _append(folder / name, text.encode())
        progress = folder / "progress.jsonl"
        if progress.exists() and progress.read_bytes()[-1:] not in (b"", b"\n"):
            _append(progress, b"\n")  # a line cut by a kill: ended, kept (it is no record)
            self.event("kept", what="a progress line cut short by a kill")
        self._keep_uncommitted()
        self._complete()

    def _keep_uncommitted(self) -> None:
        """Rename the drive files written but never committed (a kill between them and their record)."""
        committed = {f for r in self.records for f in (r.get("files") or [])}
        for e in [e for e in self.events if e.get("event") == "file"]:
            name = e["file"]
            path = self.path / name
            if name in committed or not path.exists():
                continue
            stem, suffix = path.name.split(".", 1)
            k = 1
            while (path.parent / f"{stem}-killed{k}.{suffix}").exists():
                k += 1
            target = path.parent / f"{stem}-killed{k}.{suffix}"
            self.event("kept", file=f"drives/{target.name}", was=name, why="written, not committed before a kill")
            os.rename(path, target)

    def announce(self, name: str) -> None:
        """Say (``events.jsonl``) that the session writes ``drives/NAME`` next."""
        self.event("file", file=f"drives/{name}")

    def free_name(self, base: str, suffixes: tuple[str, ...]) -> str:
        """``base`` or, where a file of that name exists (a stopped attempt's), ``base-2``, ``base-3``, ..."""
        k, name = 1, base
        while any((self.path / "drives" / f"{name}{s}").exists() for s in suffixes):
            k += 1
            name = f"{base}-{k}"
        return name

    def commit(self, record: dict[str, Any], appends: Mapping[str, str | Path]) -> dict[str, Any]:
        """Commit one item: its record, with what it appends to each table (text, or a file of the rows), appended
        to ``progress.jsonl``; then the tables appended. Returns the record as committed."""
        folder = self.path
        spans = {}
        for table, what in appends.items():
            data = what.read_bytes() if isinstance(what, Path) else what.encode()
            spans[table] = {"at": _size(folder / table), "bytes": len(data)}
            if isinstance(what, Path):
                spans[table]["rows_file"] = str(what.relative_to(folder))
            else:
                spans[table]["text"] = what
        record = {**record, "appends": spans,
                  "csv_bytes": spans["session.csv"]["at"] + spans["session.csv"]["bytes"] if "session.csv" in spans
                  else _size(folder / "session.csv")}
        _append(folder / "progress.jsonl", (json.dumps(record) + "\n").encode())
        self.records.append(record)
        self._complete()
        return record

    def _complete(self) -> None:
        """Append to each table what a committed record adds to it and it lacks (a kill during the appends)."""
        for record in self.records:
            for table, span in (record.get("appends") or {}).items():
                path = self.path / table
                size, end = _size(path), span["at"] + span["bytes"]
                if size >= end:
                    continue
                data = ((self.path / span["rows_file"]).read_bytes() if "rows_file" in span
                        else span["text"].encode())
                _append(path, data[size - span["at"]:])
