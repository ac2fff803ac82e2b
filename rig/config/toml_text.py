"""TOML text of a configuration table (the inverse of ``tomllib.loads`` for what a ``rig.toml`` holds).

:func:`to_toml` writes nested dicts of strings, booleans, integers, floats and (nested) lists: scalars and
lists first, then each sub-table under its dotted ``[header]``. Used where the program writes a ``rig.toml``
for the user (``rig mock lab --write-config``); what it writes reads back equal with ``tomllib``.
"""

from __future__ import annotations

import math
import re
from typing import Any

__all__ = ["to_toml"]

_BARE_KEY = re.compile(r"[A-Za-z0-9_-]+")


_ESCAPES = {'"': '\\"', "\\": "\\\\", "\b": "\\b", "\t": "\\t", "\n": "\\n", "\f": "\\f", "\r": "\\r"}


def _string(text: str) -> str:
    """A TOML basic string: quotes, backslashes and control characters (U+0000–U+001F, U+007F) escaped."""
    return '"' + "".join(_ESCAPES.get(c) or (f"\\u{ord(c):04X}" if ord(c) < 0x20 or ord(c) == 0x7F else c)
                         for c in text) + '"'


def _key(name: str) -> str:
    return name if _BARE_KEY.fullmatch(name) else _string(name)


def _value(value: Any, where: str) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if math.isnan(value):
            return "nan"
        return repr(value) if math.isfinite(value) else ("inf" if value > 0 else "-inf")
    if isinstance(value, str):
        return _string(value)
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_value(v, where) for v in value) + "]"
    if isinstance(value, dict):
        return "{ " + ", ".join(f"{_key(k)} = {_value(v, where)}" for k, v in value.items()) + " }"
    raise TypeError(f"{where}: {type(value).__name__} {value!r} has no TOML form")


def _table(table: dict[str, Any], path: tuple[str, ...], lines: list[str]) -> None:
    scalars = {k: v for k, v in table.items() if not isinstance(v, dict) and v is not None}
    tables = {k: v for k, v in table.items() if isinstance(v, dict)}
    if path and (scalars or not tables):
        lines.append(f"\n[{'.'.join(_key(p) for p in path)}]")
    for key, value in scalars.items():
        lines.append(f"{_key(key)} = {_value(value, '.'.join((*path, key)))}")
    for key, sub in tables.items():
        _table(sub, (*path, key), lines)


def to_toml(table: dict[str, Any], header: str = "") -> str:
    """TOML text of ``table`` (None values are left out), after ``header`` lines (each made a comment)."""
    lines = [f"# {line}".rstrip() for line in header.splitlines()]
    _table(table, (), lines)
    return "\n".join(lines).lstrip("\n") + "\n"
