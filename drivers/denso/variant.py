"""The b-CAP VARIANT codec (``../shared/notes/bcap.md`` §5), pure functions, little-endian.

A VARIANT on the wire is ``uint16 vt, uint32 count, data``. Scalars have count 1; arrays have
``vt | 0x2000`` and count = number of elements. BSTR data is a uint32 *byte* length followed by UTF-16LE
(no terminator). ``0x200C`` holds ``count`` nested VARIANTs; ``0x2011`` is a raw byte array.

Python side: :class:`Variant` keeps the exact type (``vt``) with a Python value:

* EMPTY/NULL -> ``None``; integer types, ERROR and CY (raw int64, currency × 10000) -> ``int``;
  R4/R8 -> ``float``; BOOL -> ``bool``; BSTR -> ``str``; DATE -> naive ``datetime`` (rounded to 1 ms);
* typed arrays -> ``list`` of those; ``0x2011`` -> ``bytes``; ``0x200C`` -> ``list[Variant]``.

:func:`to_variant` applies the reference client's mapping to plain Python values (int -> I4, float -> R8,
str -> BSTR, bool -> BOOL, datetime -> DATE, bytes -> UI1[], homogeneous list -> typed array, mixed list
-> VARIANT[], None or [] -> EMPTY). Decoding never raises anything but :class:`BcapProtocolError`.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass
from datetime import datetime, timedelta
from typing import Any

from drivers.denso.hresult import BcapProtocolError

VT_EMPTY, VT_NULL, VT_I2, VT_I4, VT_R4, VT_R8, VT_CY, VT_DATE, VT_BSTR = 0, 1, 2, 3, 4, 5, 6, 7, 8
VT_ERROR, VT_BOOL, VT_VARIANT = 10, 11, 12
VT_UI1, VT_UI2, VT_UI4, VT_I8, VT_UI8 = 17, 18, 19, 20, 21
VT_ARRAY = 0x2000

#: fixed-size scalar types: vt -> struct format (little-endian)
_FIXED: dict[int, str] = {
    VT_I2: "<h", VT_I4: "<i", VT_R4: "<f", VT_R8: "<d", VT_CY: "<q", VT_DATE: "<d",
    VT_ERROR: "<i", VT_BOOL: "<h", VT_UI1: "<B", VT_UI2: "<H", VT_UI4: "<I", VT_I8: "<q", VT_UI8: "<Q",
}
_INT_RANGES: dict[int, tuple[int, int]] = {
    VT_I2: (-(1 << 15), (1 << 15) - 1), VT_I4: (-(1 << 31), (1 << 31) - 1),
    VT_CY: (-(1 << 63), (1 << 63) - 1),
    VT_ERROR: (-(1 << 31), (1 << 31) - 1), VT_UI1: (0, 255), VT_UI2: (0, 65535), VT_UI4: (0, (1 << 32) - 1),
    VT_I8: (-(1 << 63), (1 << 63) - 1), VT_UI8: (0, (1 << 64) - 1),
}
SCALAR_TYPES = frozenset({VT_EMPTY, VT_NULL, VT_BSTR, *_FIXED})
ARRAY_TYPES = frozenset({VT_ARRAY | vt for vt in (*_FIXED, VT_BSTR, VT_VARIANT)})
OLE_EPOCH = datetime(1899, 12, 30)
_US_PER_DAY = 86_400_000_000
_MS_PER_DAY = 86_400_000  # DATE decodes to the millisecond (a float64 day count holds ~1 µs near 2000)
MAX_NESTING = 16


@dataclass(frozen=True)
class Variant:
    """A typed VARIANT value (see the module docstring for the Python value of each type)."""

    vt: int
    value: Any = None

    def __post_init__(self) -> None:
        if self.vt not in SCALAR_TYPES and self.vt not in ARRAY_TYPES:
            raise ValueError(f"vt=0x{self.vt:04X}: unsupported VARIANT type")
        if self.vt == VT_ARRAY | VT_UI1 and not isinstance(self.value, bytes):
            object.__setattr__(self, "value", bytes(self.value))  # canonical form of a byte array
        elif self.vt & VT_ARRAY and isinstance(self.value, tuple):
            object.__setattr__(self, "value", list(self.value))

    def to_python(self) -> Any:
        """Plain Python value (nested VARIANT arrays become lists of plain values)."""
        if self.vt == VT_ARRAY | VT_VARIANT:
            return [item.to_python() for item in self.value]
        return self.value


EMPTY = Variant(VT_EMPTY)


def _check_int(vt: int, value: object) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        raise ValueError(f"VARIANT vt={vt}: value {value!r} must be an int")
    low, high = _INT_RANGES[vt]
    if not low <= value <= high:
        raise ValueError(f"VARIANT vt={vt}: value {value} outside {low}..{high}")
    return value


def _pack_scalar(vt: int, value: object) -> bytes:
    """Data bytes of one scalar (without vt/count)."""
    if vt in (VT_EMPTY, VT_NULL):
        return b""
    if vt == VT_BSTR:
        if not isinstance(value, str):
            raise ValueError(f"VT_BSTR value {value!r} must be a str")
        raw = value.encode("utf-16-le", "surrogatepass")
        return struct.pack("<I", len(raw)) + raw
    if vt == VT_BOOL:
        return struct.pack("<h", -1 if value else 0)
    if vt == VT_DATE:
        if isinstance(value, datetime):
            delta = value.replace(tzinfo=None) - OLE_EPOCH
            return struct.pack("<d", (delta // timedelta(microseconds=1)) / _US_PER_DAY)
        raise ValueError(f"VT_DATE value {value!r} must be a datetime")
    if vt in (VT_R4, VT_R8):
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise ValueError(f"VARIANT vt={vt}: value {value!r} must be a number")
        try:
            return struct.pack(_FIXED[vt], float(value))
        except OverflowError as exc:
            raise ValueError(f"VT_R4 value {value!r} exceeds float32 range") from exc
    return struct.pack(_FIXED[vt], _check_int(vt, value))


def encode_variant(value: object) -> bytes:
    """VARIANT bytes (vt, count, data) of a :class:`Variant` or a plain Python value."""
    var = value if isinstance(value, Variant) else to_variant(value)
    vt = var.vt
    if vt in SCALAR_TYPES:
        return struct.pack("<HI", vt, 1) + _pack_scalar(vt, var.value)
    base = vt & ~VT_ARRAY
    if base == VT_UI1 and isinstance(var.value, bytes | bytearray):
        return struct.pack("<HI", vt, len(var.value)) + bytes(var.value)
    items = list(var.value)
    if base == VT_VARIANT:
        body = b"".join(encode_variant(item) for item in items)
    else:
        body = b"".join(_pack_scalar(base, item) for item in items)
    return struct.pack("<HI", vt, len(items)) + body


def to_variant(value: object) -> Variant:
    """The reference client's mapping of a plain Python value to a typed VARIANT."""
    if isinstance(value, Variant):
        return value
    if value is None:
        return EMPTY
    if hasattr(value, "tolist") and not isinstance(value, bytes | bytearray | str):
        value = value.tolist()  # numpy arrays and scalars
    if isinstance(value, bool):
        return Variant(VT_BOOL, value)
    if isinstance(value, int):
        if -(1 << 31) <= value < (1 << 31):
            return Variant(VT_I4, value)
        if -(1 << 63) <= value < (1 << 63):
            return Variant(VT_I8, value)
        raise ValueError(f"int {value} does not fit a 64-bit VARIANT")
    if isinstance(value, float):
        return Variant(VT_R8, value)
    if isinstance(value, str):
        return Variant(VT_BSTR, value)
    if isinstance(value, datetime):
        return Variant(VT_DATE, value)
    if isinstance(value, bytes | bytearray):
        return Variant(VT_ARRAY | VT_UI1, bytes(value))
    if isinstance(value, list | tuple):
        if not value:
            return EMPTY
        kinds = {type(item) for item in value}
        if kinds == {bool}:
            return Variant(VT_ARRAY | VT_BOOL, list(value))
        if kinds == {int} and all(-(1 << 31) <= v < (1 << 31) for v in value):
            return Variant(VT_ARRAY | VT_I4, list(value))
        if kinds == {float}:
            return Variant(VT_ARRAY | VT_R8, list(value))
        if kinds == {str}:
            return Variant(VT_ARRAY | VT_BSTR, list(value))
        return Variant(VT_ARRAY | VT_VARIANT, [to_variant(item) for item in value])
    raise ValueError(f"cannot encode {type(value).__name__} {value!r} as a b-CAP VARIANT")


def _need(buf: bytes, offset: int, size: int, what: str) -> None:
    if size < 0 or offset + size > len(buf):
        raise BcapProtocolError(f"truncated VARIANT: {what} needs {size} bytes at offset {offset}, "
                                f"{max(len(buf) - offset, 0)} left")


def _unpack_scalar(vt: int, buf: bytes, offset: int) -> tuple[Any, int]:
    if vt in (VT_EMPTY, VT_NULL):
        return None, offset
    if vt == VT_BSTR:
        _need(buf, offset, 4, "BSTR length")
        (size,) = struct.unpack_from("<I", buf, offset)
        offset += 4
        _need(buf, offset, size, "BSTR characters")
        if size % 2:
            raise BcapProtocolError(f"BSTR byte length {size} is odd (UTF-16LE needs pairs)")
        return buf[offset:offset + size].decode("utf-16-le", "surrogatepass"), offset + size
    fmt = _FIXED[vt]
    size = struct.calcsize(fmt)
    _need(buf, offset, size, f"vt={vt} data")
    (raw,) = struct.unpack_from(fmt, buf, offset)
    if vt == VT_BOOL:
        return raw != 0, offset + size
    if vt == VT_DATE:
        if not math.isfinite(raw):
            raise BcapProtocolError(f"VT_DATE value {raw!r} is not a finite day count")
        try:
            return OLE_EPOCH + timedelta(milliseconds=round(raw * _MS_PER_DAY)), offset + size
        except OverflowError as exc:
            raise BcapProtocolError(f"VT_DATE value {raw!r} days is outside the datetime range") from exc
    return raw, offset + size


def decode_variant(buf: bytes, offset: int = 0, _depth: int = 0) -> tuple[Variant, int]:
    """Decode one VARIANT at ``offset``; return it and the offset just after it."""
    _need(buf, offset, 6, "VARIANT header")
    vt, count = struct.unpack_from("<HI", buf, offset)
    offset += 6
    if vt in SCALAR_TYPES:
        if vt not in (VT_EMPTY, VT_NULL) and count != 1:
            raise BcapProtocolError(f"scalar VARIANT vt={vt} has count {count}, expected 1")
        value, offset = _unpack_scalar(vt, buf, offset)
        return Variant(vt, value), offset
    if vt not in ARRAY_TYPES:
        raise BcapProtocolError(f"unknown VARIANT type 0x{vt:04X}")
    base = vt & ~VT_ARRAY
    if base == VT_VARIANT:
        if _depth >= MAX_NESTING:
            raise BcapProtocolError(f"VARIANT arrays nested deeper than {MAX_NESTING}")
        _need(buf, offset, 6 * count, f"{count} nested VARIANTs")
        items = []
        for _ in range(count):
            item, offset = decode_variant(buf, offset, _depth + 1)
            items.append(item)
        return Variant(vt, items), offset
    if base == VT_UI1:
        _need(buf, offset, count, "byte array")
        return Variant(vt, bytes(buf[offset:offset + count])), offset + count
    minimum = 4 if base == VT_BSTR else struct.calcsize(_FIXED[base])
    _need(buf, offset, minimum * count, f"{count} elements of vt={base}")
    values = []
    for _ in range(count):
        value, offset = _unpack_scalar(base, buf, offset)
        values.append(value)
    return Variant(vt, values), offset
