"""A small strict validator that builds frozen dataclasses from TOML tables.

Each dataclass field may carry ``metadata=spec(...)``: a numeric range, a set of allowed choices, a fixed
length for arrays, a custom check. :func:`build` converts a TOML table into the dataclass and raises
:class:`ConfigError` naming the dotted field, the value found and what is allowed, for:
unknown fields, missing required fields, wrong types, values out of range, values not among the choices.

Supported annotations: ``bool``, ``int``, ``float`` (an int is accepted), ``str``, ``X | None``,
``tuple[float, ...]`` / ``tuple[int, ...]`` (TOML arrays; length from ``spec(length=...)``),
``tuple[tuple[float, ...], ...]`` (arrays of arrays), nested config dataclasses, and
``dict[str, Dataclass]`` (a table of named sub-tables, e.g. ``[cameras.left]``) or ``dict[str, T]``.
"""

from __future__ import annotations

import dataclasses
import math
import types
import typing
from collections.abc import Callable
from typing import TYPE_CHECKING, Any, TypeVar

if TYPE_CHECKING:
    from _typeshed import DataclassInstance

T = TypeVar("T", bound="DataclassInstance")


class ConfigError(ValueError):
    """The rig configuration is invalid; the message names the field, the value and what is allowed."""

    def __init__(self, field: str, message: str) -> None:
        self.field = field
        super().__init__(f"{field}: {message}" if field else message)


def spec(*, lo: float | None = None, hi: float | None = None, lo_open: bool = False,
         choices: tuple[Any, ...] | None = None, length: int | tuple[int, int] | None = None,
         check: Callable[[Any, str], None] | None = None, doc: str = "") -> dict[str, Any]:
    """Field metadata: ``lo``/``hi`` inclusive bounds (``lo_open``: lower bound exclusive), ``choices``,
    array ``length`` (exact or (min, max)), a ``check(value, path)`` raising ConfigError, and a doc line."""
    return {"lo": lo, "hi": hi, "lo_open": lo_open, "choices": choices, "length": length, "check": check,
            "doc": doc}


def _describe(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def _range_text(meta: dict[str, Any]) -> str:
    lo, hi = meta.get("lo"), meta.get("hi")
    left = "" if lo is None else f"{lo:g} {'<' if meta.get('lo_open') else '≤'} "
    right = "" if hi is None else f" ≤ {hi:g}"
    return f"{left}value{right}"


def _type_name(tp: Any) -> str:
    origin = typing.get_origin(tp)
    if origin in (typing.Union, types.UnionType):
        return " or ".join(_type_name(a) for a in typing.get_args(tp) if a is not type(None))
    if origin is tuple:
        return "an array"
    if origin is dict or (dataclasses.is_dataclass(tp)):
        return "a table"
    return {bool: "a boolean", int: "an integer", float: "a number", str: "a string"}.get(tp, str(tp))


def _scalar(value: Any, tp: Any, path: str, meta: dict[str, Any]) -> Any:
    if tp is bool:
        if not isinstance(value, bool):
            raise ConfigError(path, f"{_describe(value)} has the wrong type; allowed: true or false")
        out: Any = value
    elif tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(path, f"{_describe(value)} has the wrong type; allowed: an integer")
        out = value
    elif tp is float:
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise ConfigError(path, f"{_describe(value)} has the wrong type; allowed: a number")
        out = float(value)
        if not math.isfinite(out):
            raise ConfigError(path, f"{_describe(value)} is not finite; allowed: a finite number")
    elif tp is str:
        if not isinstance(value, str):
            raise ConfigError(path, f"{_describe(value)} has the wrong type; allowed: a string")
        out = value
    else:
        raise TypeError(f"unsupported config annotation {tp!r} at {path}")
    if tp in (int, float):
        lo, hi = meta.get("lo"), meta.get("hi")
        below = lo is not None and (out <= lo if meta.get("lo_open") else out < lo)
        if below or (hi is not None and out > hi):
            raise ConfigError(path, f"{_describe(value)} is out of range; allowed: {_range_text(meta)}")
    return out


def convert(value: Any, tp: Any, path: str, meta: dict[str, Any] | None = None) -> Any:
    """Convert one TOML value to the annotation ``tp`` (recursively); raise ConfigError naming ``path``."""
    meta = meta or {}
    if tp is Any:
        if isinstance(value, dict | list):
            raise ConfigError(path, f"{_describe(value)} has the wrong type; "
                                    "allowed: a number, string or boolean")
        return value
    origin = typing.get_origin(tp)
    if origin in (typing.Union, types.UnionType):
        args = [a for a in typing.get_args(tp) if a is not type(None)]
        if value is None:
            return None
        return convert(value, args[0], path, meta)
    out: Any
    if isinstance(tp, type) and dataclasses.is_dataclass(tp):
        out = build(tp, value, path)
    elif origin is tuple:
        if not isinstance(value, list):
            raise ConfigError(path, f"{_describe(value)} has the wrong type; allowed: an array")
        length = meta.get("length")
        if isinstance(length, int) and len(value) != length:
            raise ConfigError(path, f"{_describe(value)} has {len(value)} elements; "
                                    f"allowed: exactly {length}")
        if isinstance(length, tuple) and not length[0] <= len(value) <= length[1]:
            raise ConfigError(path, f"{_describe(value)} has {len(value)} elements; allowed: "
                                    f"{length[0]} to {length[1]}")
        inner = typing.get_args(tp)[0]
        item_meta = {k: meta[k] for k in ("lo", "hi", "lo_open") if k in meta}
        out = tuple(convert(v, inner, f"{path}[{i}]", item_meta) for i, v in enumerate(value))
    elif origin is dict:
        if not isinstance(value, dict):
            raise ConfigError(path, f"{_describe(value)} has the wrong type; allowed: a table")
        inner = typing.get_args(tp)[1]
        out = {str(k): convert(v, inner, f"{path}.{k}") for k, v in value.items()}
    else:
        out = _scalar(value, tp, path, meta)
    choices = meta.get("choices")
    if choices is not None and out not in choices:
        allowed = ", ".join(repr(c) for c in choices)
        raise ConfigError(path, f"{_describe(value)} is not allowed; allowed: {allowed}")
    check = meta.get("check")
    if check is not None:
        check(out, path)
    return out


def build(cls: type[T], table: Any, path: str) -> T:
    """Build dataclass ``cls`` from ``table``; unknown keys, missing keys and bad values raise."""
    if not isinstance(table, dict):
        raise ConfigError(path, f"{_describe(table)} has the wrong type; allowed: a table")
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls) if f.init}
    prefix = f"{path}." if path else ""
    unknown = sorted(set(table) - set(fields))
    if unknown:
        raise ConfigError(f"{prefix}{unknown[0]}", f"unknown field; allowed in [{path or 'top level'}]: "
                                                   f"{', '.join(sorted(fields))}")
    kwargs = {}
    for name, f in fields.items():
        if name not in table:
            if f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
                raise ConfigError(f"{prefix}{name}", f"required field missing ({_type_name(hints[name])})")
            continue
        kwargs[name] = convert(table[name], hints[name], f"{prefix}{name}", dict(f.metadata))
    try:
        return cls(**kwargs)
    except ConfigError:
        raise
    except (TypeError, ValueError) as exc:
        raise ConfigError(path, str(exc)) from exc


def to_dict(obj: Any) -> Any:
    """Plain-dict view of a built config (tuples → lists), for snapshots and round trips."""
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return {f.name: to_dict(getattr(obj, f.name)) for f in dataclasses.fields(obj)}
    if isinstance(obj, dict):
        return {k: to_dict(v) for k, v in obj.items()}
    if isinstance(obj, tuple | list):
        return [to_dict(v) for v in obj]
    return obj


def describe(cls: type, path: str = "") -> list[dict[str, Any]]:
    """Every field of the schema rooted at ``cls``: dotted name, type, default, allowed values, doc.

    Nested dataclasses are expanded (``dict[str, X]`` tables as ``<name>``), so the reference printed by
    ``rig check --schema`` always matches what validation accepts.
    """
    rows: list[dict[str, Any]] = []
    hints = typing.get_type_hints(cls)
    for f in dataclasses.fields(cls):
        if not f.init:
            continue
        name = f"{path}.{f.name}" if path else f.name
        tp = hints[f.name]
        args = [a for a in typing.get_args(tp) if a is not type(None)]
        inner = args[0] if typing.get_origin(tp) in (typing.Union, types.UnionType) and len(args) == 1 else tp
        if isinstance(inner, type) and dataclasses.is_dataclass(inner):
            rows += describe(inner, name)
            continue
        if typing.get_origin(inner) is dict and dataclasses.is_dataclass(typing.get_args(inner)[1]):
            rows += describe(typing.get_args(inner)[1], f"{name}.<name>")
            continue
        meta = dict(f.metadata)
        if f.default is not dataclasses.MISSING:
            default: Any = to_dict(f.default)
        elif f.default_factory is not dataclasses.MISSING:
            default = to_dict(f.default_factory())
        else:
            default = "(required)"
        allowed = ""
        if meta.get("choices"):
            allowed = ", ".join(repr(c) for c in meta["choices"])
        elif meta.get("lo") is not None or meta.get("hi") is not None:
            allowed = _range_text(meta)
        if meta.get("length"):
            n = meta["length"]
            allowed = (f"{n} elements" if isinstance(n, int) else f"{n[0]}-{n[1]} elements") + (
                f"; each {allowed}" if allowed else "")
        rows.append({"field": name, "type": _type_name(tp), "default": default, "allowed": allowed,
                     "doc": meta.get("doc", "")})
    return rows
