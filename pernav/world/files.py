"""Reading the YAML or JSON files users hand in (driver profiles, schedules).

Example:
    >>> import json, tempfile
    >>> with tempfile.NamedTemporaryFile("w", suffix=".json", delete=False) as f:
    ...     json.dump({"user": "user1"}, f)
    >>> read_data_file(f.name)
    {'user': 'user1'}
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import yaml

__all__ = ["DataFileError", "is_file", "key_values", "read_data_file"]


class DataFileError(ValueError):
    """The file cannot be read or parsed; the message is the first line of the cause."""


def is_file(path: Path) -> bool:
    """``path.is_file()``, but a name too long for a path, or with a NUL byte, is no file either."""
    try:
        return path.is_file()
    except (OSError, ValueError):
        return False


def read_data_file(path: str | Path) -> Any:
    """The parsed content of a ``.yaml``/``.yml`` (YAML) or any other (JSON) file."""
    path = Path(path)
    try:
        text = path.read_text()
        if path.suffix.lower() in (".yaml", ".yml"):
            return yaml.safe_load(text)
        return json.loads(text)
    except Exception as exc:  # noqa: BLE001 - any read/parse error is the user's file, reported in one line
        raise DataFileError((str(exc).splitlines() or [type(exc).__name__])[0]) from None


def key_values(pairs: list[str], allowed: Any, what: str) -> list[tuple[str, Any, str]]:
    """``KEY=VALUE`` strings of a command line (``--train-option`` and the like) as ``(key, value, pair)``: the
    value parsed as JSON where it is JSON (else the raw string, for the caller to refuse); ``ValueError`` naming
    the pair and ``what`` it must be one of.

    >>> key_values(["agree=0.67", "max_spread=null"], ["agree", "max_spread"], "the options")
    [('agree', 0.67, 'agree=0.67'), ('max_spread', None, 'max_spread=null')]
    """
    out = []
    for pair in pairs:
        key, sep, raw = pair.partition("=")
        if not sep or key not in allowed:
            raise ValueError(f"{pair!r}: need KEY=VALUE with KEY one of {what}: {', '.join(allowed)}")
        try:
            value = json.loads(raw)
        except json.JSONDecodeError:
            value = raw
        out.append((key, value, pair))
    return out
