"""A small SCPI program-message parser for the mock instruments (independent of the driver's codec).

Implements the parts of IEEE 488.2 / SCPI-99 a function generator's users rely on:

* a line (program message) holds message units separated by ``;``; a unit is a header and optional
  parameters separated by ``,``; quotes protect ``;`` and ``,``;
* a header starting with ``:`` is absolute; otherwise it continues from the path of the previous unit
  (``SOUR1:FREQ 10;VOLT 1`` means ``SOUR1:VOLT 1``); common commands (``*IDN?``) do not move the path;
* mnemonics match their short form or their long form, case-insensitively (``FREQ``/``FREQuency``);
  optional nodes are written ``[...]`` in patterns, a ``#`` allows a numeric suffix (``SOURce#``).

Errors are :class:`ScpiCommandError` with the standard code and message.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

__all__ = ["Pattern", "ScpiCommandError", "Unit", "split_units"]

_MNEMONIC = re.compile(r"^([A-Za-z][A-Za-z_]*?)(\d*)$")


class ScpiCommandError(Exception):
    """An SCPI error to push on the error queue: ``code`` (negative, standard) and ``message``."""

    def __init__(self, code: int, message: str) -> None:
        super().__init__(f"{code},\"{message}\"")
        self.code = code
        self.message = message


@dataclass(frozen=True)
class Unit:
    """One message unit: header nodes (without ``:``), whether it is a query, the parameters (stripped
    text), and whether it is a common (``*``) command."""

    nodes: tuple[str, ...]
    query: bool
    params: tuple[str, ...]
    common: bool
    text: str


def _split_outside_quotes(text: str, sep: str) -> list[str]:
    parts, current, quote = [], [], ""
    for ch in text:
        if quote:
            current.append(ch)
            if ch == quote:
                quote = ""
        elif ch in "\"'":
            quote = ch
            current.append(ch)
        elif ch == sep:
            parts.append("".join(current))
            current = []
        else:
            current.append(ch)
    if quote:
        raise ScpiCommandError(-150, "String data error")
    parts.append("".join(current))
    return parts


def split_units(line: str) -> list[Unit]:
    """Parse one program message (without its terminator) into units with absolute header paths."""
    units: list[Unit] = []
    path: tuple[str, ...] = ()
    for raw in _split_outside_quotes(line, ";"):
        text = raw.strip()
        if not text:
            if units or raw:  # an empty unit between separators is a syntax error
                raise ScpiCommandError(-102, "Syntax error")
            continue
        header, _, rest = text.partition(" ")
        if "\t" in header:
            header, _, more = header.partition("\t")
            rest = more + " " + rest
        query = header.endswith("?")
        if query:
            header = header[:-1]
        params = tuple(p.strip() for p in _split_outside_quotes(rest, ",")) if rest.strip() else ()
        if any(not p for p in params):
            raise ScpiCommandError(-102, "Syntax error")
        if header.startswith("*"):
            if not re.fullmatch(r"\*[A-Za-z]{2,}", header):
                raise ScpiCommandError(-113, "Undefined header")
            units.append(Unit((header.upper(),), query, params, True, text))
            continue
        absolute = header.startswith(":")
        nodes = tuple(header.lstrip(":").split(":")) if header.lstrip(":") else ()
        if not nodes:
            raise ScpiCommandError(-102, "Syntax error")
        if any(not _MNEMONIC.match(n) for n in nodes):
            raise ScpiCommandError(-113, "Undefined header")
        full = nodes if absolute else path + nodes
        units.append(Unit(full, query, params, False, text))
        path = full[:-1]
    return units


@dataclass(frozen=True)
class _Node:
    short: str
    long: str
    optional: bool
    suffix: bool


class Pattern:
    """A command header pattern such as ``[SOURce#:]FREQuency:STARt``; :meth:`match` returns the numeric
    suffixes given (``{"SOURCE": 1}``) or ``None``."""

    def __init__(self, pattern: str) -> None:
        self.text = pattern
        self.common = pattern.upper() if pattern.startswith("*") else None
        nodes = []
        for token in re.findall(r"\[?:?[A-Za-z]+#?:?\]?", pattern):
            optional = token.startswith("[")
            name = token.strip("[]:")
            suffix = name.endswith("#")
            name = name.rstrip("#")
            short = "".join(c for c in name if c.isupper())
            nodes.append(_Node(short, name.upper(), optional, suffix))
        self.nodes = tuple(nodes)

    def match(self, given: tuple[str, ...]) -> dict[str, int] | None:
        if self.common is not None:
            return {} if given == (self.common,) else None
        return self._match(0, given, {})

    def _match(self, i: int, given: tuple[str, ...], suffixes: dict[str, int]) -> dict[str, int] | None:
        if i == len(self.nodes):
            return suffixes if not given else None
        node = self.nodes[i]
        if given:
            m = _MNEMONIC.match(given[0])
            if m and m.group(1).upper() in (node.short, node.long) and (node.suffix or not m.group(2)):
                found = dict(suffixes)
                if node.suffix:
                    digits = m.group(2)  # a suffix too long for int() is simply out of range
                    found[node.long] = int(digits) if 0 < len(digits) < 10 else (1 if not digits else 10**10)
                result = self._match(i + 1, given[1:], found)
                if result is not None:
                    return result
        if node.optional:
            return self._match(i + 1, given, suffixes)
        return None
