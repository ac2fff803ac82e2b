"""JSON encoding for run-record documents: numpy scalars and arrays, paths, dataclasses, enums.

The record is standard JSON (RFC 8259), so non-finite floats (NaN, ±inf) cannot be written as numbers:
they are written as ``null`` — in a record, NaN means "no value". Everything else is converted
losslessly: numpy integers → int, numpy floats → float (full precision), numpy bools → bool, arrays →
nested lists, tuples and sets → lists (sets sorted), ``Path`` → str, ``datetime`` → ISO 8601,
``Enum`` → its value, dataclasses → dicts. Anything else raises :class:`TypeError` naming the type.
"""

from __future__ import annotations

import dataclasses
import datetime as _dt
import enum
import json
import math
from pathlib import PurePath
from typing import Any

import numpy as np


def to_jsonable(value: Any) -> Any:
    """Return ``value`` converted to plain JSON types (dict, list, str, int, float, bool, None)."""
    if value is None or isinstance(value, (bool, str)):
        return value
    if isinstance(value, int) and not isinstance(value, bool):
        return int(value)
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, np.bool_):
        return bool(value)
    if isinstance(value, np.integer):
        return int(value)
    if isinstance(value, np.floating):
        f = float(value)
        return f if math.isfinite(f) else None
    if isinstance(value, np.ndarray):
        return [to_jsonable(v) for v in value.tolist()] if value.ndim else to_jsonable(value.item())
    if isinstance(value, dict):
        return {_key(k): to_jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [to_jsonable(v) for v in value]
    if isinstance(value, (set, frozenset)):
        return [to_jsonable(v) for v in sorted(value, key=repr)]
    if isinstance(value, PurePath):
        return value.as_posix()
    if isinstance(value, (_dt.datetime, _dt.date)):
        return value.isoformat()
    if isinstance(value, enum.Enum):
        return to_jsonable(value.value)
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {f.name: to_jsonable(getattr(value, f.name)) for f in dataclasses.fields(value)}
    raise TypeError(f"cannot record a value of type {type(value).__name__!r} in the run record: "
                    f"{value!r:.80}")


def _key(key: Any) -> str:
    if isinstance(key, str):
        return key
    if isinstance(key, (int, np.integer, float, np.floating, bool, enum.Enum)):
        return str(to_jsonable(key))
    raise TypeError(f"run-record dict keys must be str or numbers, got {type(key).__name__!r}: {key!r:.80}")


def dumps(document: dict[str, Any]) -> str:
    """Return one compact JSON line (no newline) for ``document``; strict JSON, UTF-8 text."""
    return json.dumps(to_jsonable(document), ensure_ascii=False, separators=(",", ":"), allow_nan=False)
