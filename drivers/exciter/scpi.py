"""SCPI codec for the function generator driver: pure functions, no I/O.

Program messages are LF-terminated ASCII lines. Numbers are sent in a form every SCPI parser accepts
(NR1/NR2/NR3, shortest exact decimal, no unit suffix); replies are parsed leniently: ``+1.000000E+01``,
``1.000000E+01``, ``10``, ``10HZ`` (Siglent appends units) all give 10.0.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

__all__ = ["Identity", "ScpiReplyError", "format_command", "format_number", "parse_bool", "parse_error",
           "parse_identity", "parse_number"]

_HEADER = re.compile(r"^(\*[A-Za-z]{2,}\??|:?[A-Za-z][A-Za-z0-9]*(:[A-Za-z][A-Za-z0-9]*)*\??)$")
_NUMBER = re.compile(r"^\s*([+-]?(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?)\s*([A-Za-z]*)\s*$")
_ERROR = re.compile(r'^\s*([+-]?\d+)\s*,\s*"(.*)"\s*$')


class ScpiReplyError(ValueError):
    """A reply could not be parsed as the expected type."""


def format_number(value: float) -> str:
    """A finite number as SCPI NR1/NR2/NR3 text (shortest repr that round-trips)."""
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise ValueError(f"value={value!r}: must be a finite number")
    if float(value).is_integer() and abs(value) < 1e15:
        return str(int(value))
    return repr(float(value)).replace("e", "E")


def format_command(header: str, *args: float | str) -> str:
    """``header`` (e.g. ``SOUR1:FREQ``) and its parameters as one program message unit, no terminator.

    Numbers go through :func:`format_number`; strings are sent as given (character data such as ``ON``,
    ``SIN``, ``LIN``) and must not contain separators or newlines.
    """
    if not _HEADER.match(header):
        raise ValueError(f"header={header!r}: not a SCPI command header")
    params = []
    for arg in args:
        if isinstance(arg, str):
            if not arg or any(c in arg for c in ";\n\r,"):
                raise ValueError(f"parameter {arg!r}: must be non-empty character data "
                                 "without ; , or newline")
            params.append(arg)
        else:
            params.append(format_number(arg))
    return header + (" " + ",".join(params) if params else "")


def parse_number(reply: str) -> float:
    """A numeric reply (NR1/NR2/NR3, optionally with a unit suffix) as float."""
    m = _NUMBER.match(reply)
    if not m:
        raise ScpiReplyError(f"reply {reply!r}: not a number")
    value = float(m.group(1))
    if abs(value) >= 9.9e37:  # SCPI's "infinity" (e.g. OUTP:LOAD? → 9.9E+37 for INF)
        return math.copysign(math.inf, value)
    return value


def parse_bool(reply: str) -> bool:
    """``1``/``0``/``ON``/``OFF`` (Keysight answers 1/0, Rigol ON/OFF)."""
    text = reply.strip().upper()
    if text in ("1", "ON"):
        return True
    if text in ("0", "OFF"):
        return False
    raise ScpiReplyError(f"reply {reply!r}: not a boolean (1/0/ON/OFF)")


def parse_error(reply: str) -> tuple[int, str]:
    """A ``SYST:ERR?`` reply such as ``-113,"Undefined header"`` → (-113, "Undefined header")."""
    m = _ERROR.match(reply)
    if not m:
        raise ScpiReplyError(f"reply {reply!r}: not an error-queue entry (<code>,\"<message>\")")
    return int(m.group(1)), m.group(2)


@dataclass(frozen=True)
class Identity:
    """``*IDN?`` fields: manufacturer, model, serial number, firmware (stripped; may be empty)."""

    manufacturer: str
    model: str
    serial: str
    firmware: str


def parse_identity(reply: str) -> Identity:
    """Parse ``maker,model,serial,firmware`` loosely (Rigol pads with spaces and leaves fields empty)."""
    fields = [f.strip() for f in reply.strip().split(",")]
    if len(fields) < 4 or not fields[0] or not fields[1]:
        raise ScpiReplyError(f"*IDN? reply {reply!r}: expected manufacturer,model,serial,firmware")
    return Identity(fields[0], fields[1], fields[2], ",".join(fields[3:]))
