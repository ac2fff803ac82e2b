"""The mock RC8's own b-CAP codec: packets, VARIANTs, result codes (``../shared/notes/bcap.md`` §2–5, §9).

Written from the byte layout, independently of the driver's codec (``drivers/denso/bcap.py``,
``variant.py``, ``hresult.py``): the mock and the driver never share encoding code, so a mistake in one end
fails the end-to-end tests instead of being mirrored by the other. Both codecs are held to the same vendor
frames byte for byte (``tests/test_bcap_wire.py``, ``test_bcap_codec.py``, ``test_bcap_replay.py``).

Packet: ``SOH | u32 length | u16 serial | u16 reserved | i32 function/HRESULT | u16 argc | argc × (u32 L,
VARIANT) | [u16 CRC-16/CCITT-FALSE, serial line only] | EOT``, little-endian; the length counts every byte.
VARIANT: ``u16 vt | u32 count | data``; ``vt | 0x2000`` arrays hold ``count`` elements (``0x200C``: nested
VARIANTs without a length prefix; ``0x2011``: raw bytes). Decoded values (:class:`Value`): integers and
ERROR/CY/DATE as raw numbers (DATE stays a float day count), R4/R8 floats, BOOL bool, BSTR str (UTF-16LE,
lone surrogates kept), typed arrays lists, byte arrays bytes, VARIANT arrays lists of :class:`Value`.
Anything malformed raises :class:`WireError`, never another exception.
"""

from __future__ import annotations

import struct
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

SOH, EOT = 0x01, 0x04
HEAD = struct.Struct("<BIHHiH")  # SOH, length, serial, reserved, function/HRESULT, argc
MIN_TCP, MIN_SERIAL = 16, 18
MAX_SERIAL_LINE = 503          # serial and UDP packets (reference dn_udp.h)
MAX_TCP = 16 * 1024 * 1024     # our choice: the reference accepts any uint32 length on TCP
MAX_DEPTH = 16                 # nested VARIANT arrays (our choice)

EMPTY_VT, NULL_VT, I2, I4, R4, R8, CY, DATE, BSTR = 0, 1, 2, 3, 4, 5, 6, 7, 8
ERROR_VT, BOOL, VARIANT, UI1, UI2, UI4, I8, UI8 = 10, 11, 12, 17, 18, 19, 20, 21
ARRAY = 0x2000
_FORMAT = {I2: "<h", I4: "<i", R4: "<f", R8: "<d", CY: "<q", DATE: "<d", ERROR_VT: "<i", BOOL: "<h",
           UI1: "<B", UI2: "<H", UI4: "<I", I8: "<q", UI8: "<Q"}

# result codes (bcap.md §9; the reference server's headers)
S_OK, S_EXECUTING = 0x00000000, 0x00000900
E_INVALID_CMD_NAME, E_MAX_OBJECT, E_MAX_CONNECT = 0x80000904, 0x80000905, 0x8000090B
E_BUSY_PROC = 0x809100AA  # OSERR2HRESULT(ERROR_BUSY = 170)
E_NOTIMPL, E_FAIL, DISP_E_TYPEMISMATCH = 0x80004001, 0x80004005, 0x80020005
E_ACCESSDENIED, E_HANDLE, E_INVALIDARG = 0x80070005, 0x80070006, 0x80070057
E_CAO_OBJECT_NOTFOUND = 0x80000204
DESCRIPTIONS = {
    E_INVALID_CMD_NAME: "Invalid command name", E_MAX_OBJECT: "Too many objects",
    E_MAX_CONNECT: "Too many clients connected", E_BUSY_PROC: "A previous request is still executing",
    E_NOTIMPL: "Not implemented", E_FAIL: "Unspecified failure", DISP_E_TYPEMISMATCH: "Type mismatch",
    E_ACCESSDENIED: "Access denied", E_HANDLE: "Invalid handle", E_INVALIDARG: "Invalid argument",
    E_CAO_OBJECT_NOTFOUND: "Object not found",
}


class WireError(ValueError):
    """Bytes that do not follow the b-CAP layout."""


def unsigned(code: int) -> int:
    return int(code) & 0xFFFFFFFF


def signed(code: int) -> int:
    code = unsigned(code)
    return code - (1 << 32) if code & 0x80000000 else code


def failed(code: int) -> bool:
    return bool(unsigned(code) & 0x80000000)


def controller_error(code: int) -> bool:
    """0x83xxxxxx / 0x84xxxxxx: controller errors, described by GetErrorDescription."""
    return unsigned(code) >> 24 in (0x83, 0x84)


@dataclass(frozen=True)
class Value:
    """One VARIANT: type ``vt`` and its Python value (module docstring)."""

    vt: int
    value: Any = None

    def to_python(self) -> Any:
        if self.vt == ARRAY | VARIANT:
            return [item.to_python() for item in self.value]
        return self.value


EMPTY = Value(EMPTY_VT)


@dataclass(frozen=True)
class Packet:
    serial: int
    reserved: int
    code: int  # function ID of a request, signed HRESULT of a reply
    args: tuple[Value, ...] = ()


# ------------------------------------------------------------------------------------------ VARIANT
def _element(vt: int, value: object) -> bytes:
    if vt == BSTR:
        raw = str(value).encode("utf-16-le", "surrogatepass")
        return struct.pack("<I", len(raw)) + raw
    if vt == BOOL:
        return struct.pack("<h", -1 if value else 0)
    return struct.pack(_FORMAT[vt], value)


def write_value(item: Value) -> bytes:
    """``vt | count | data`` of one VARIANT."""
    vt = item.vt
    if vt in (EMPTY_VT, NULL_VT):
        return struct.pack("<HI", vt, 1)
    if not vt & ARRAY:
        return struct.pack("<HI", vt, 1) + _element(vt, item.value)
    base = vt & ~ARRAY
    if base == UI1:
        return struct.pack("<HI", vt, len(item.value)) + bytes(item.value)
    if base == VARIANT:
        return struct.pack("<HI", vt, len(item.value)) + b"".join(write_value(v) for v in item.value)
    return struct.pack("<HI", vt, len(item.value)) + b"".join(_element(base, v) for v in item.value)


def _take(data: bytes, pos: int, size: int) -> int:
    """The end of ``size`` bytes at ``pos``; WireError when the data is shorter."""
    end = pos + size
    if end > len(data):
        raise WireError(f"VARIANT truncated: {size} bytes wanted at offset {pos}, {len(data) - pos} left")
    return end


def _read_element(vt: int, data: bytes, pos: int) -> tuple[Any, int]:
    if vt == BSTR:
        (size,) = struct.unpack_from("<I", data, _take(data, pos, 4) - 4)
        start = pos + 4
        end = _take(data, start, size)
        if size % 2:
            raise WireError(f"BSTR of {size} bytes: UTF-16LE needs an even byte count")
        return data[start:end].decode("utf-16-le", "surrogatepass"), end
    fmt = _FORMAT[vt]
    end = _take(data, pos, struct.calcsize(fmt))
    (raw,) = struct.unpack_from(fmt, data, pos)
    return (raw != 0 if vt == BOOL else raw), end


def read_value(data: bytes, pos: int = 0, depth: int = 0) -> tuple[Value, int]:
    """One VARIANT at ``pos`` → (value, offset after it)."""
    _take(data, pos, 6)
    vt, count = struct.unpack_from("<HI", data, pos)
    pos += 6
    base = vt & ~ARRAY
    if vt in (EMPTY_VT, NULL_VT):
        return Value(vt), pos
    if not vt & ARRAY:
        if vt not in _FORMAT and vt != BSTR:
            raise WireError(f"VARIANT type 0x{vt:04X} is not supported")
        if count != 1:
            raise WireError(f"scalar VARIANT 0x{vt:04X} with count {count}")
        value, pos = _read_element(vt, data, pos)
        return Value(vt, value), pos
    if base == UI1:
        end = _take(data, pos, count)
        return Value(vt, bytes(data[pos:end])), end
    if base == VARIANT:
        if depth >= MAX_DEPTH:
            raise WireError(f"VARIANT arrays nested deeper than {MAX_DEPTH}")
        _take(data, pos, 6 * count)  # every element has at least its header
        items = []
        for _ in range(count):
            item, pos = read_value(data, pos, depth + 1)
            items.append(item)
        return Value(vt, items), pos
    if base not in _FORMAT and base != BSTR:
        raise WireError(f"VARIANT array type 0x{vt:04X} is not supported")
    _take(data, pos, count * (4 if base == BSTR else struct.calcsize(_FORMAT[base])))
    values = []
    for _ in range(count):
        value, pos = _read_element(base, data, pos)
        values.append(value)
    return Value(vt, values), pos


# ------------------------------------------------------------------------------------------- packets
def crc16(data: bytes) -> int:
    """CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF, MSB first, no final XOR)."""
    crc = 0xFFFF
    for byte in data:
        crc ^= byte << 8
        for _ in range(8):
            crc = (crc << 1 ^ 0x1021 if crc & 0x8000 else crc << 1) & 0xFFFF
    return crc


def build(serial: int, reserved: int, code: int, args: Iterable[Value] = (), *,
          serial_line: bool = False) -> bytes:
    """The bytes of one packet."""
    encoded = [write_value(a) for a in args]
    body = b"".join(struct.pack("<I", len(raw)) + raw for raw in encoded)
    argc = len(encoded)
    length = HEAD.size + len(body) + (3 if serial_line else 1)
    head = HEAD.pack(SOH, length, serial, reserved, signed(code), argc)
    if serial_line:
        return head + body + struct.pack("<H", crc16(head[1:] + body)) + bytes([EOT])
    return head + body + bytes([EOT])


def parse(frame: bytes, *, serial_line: bool = False) -> Packet:
    """Decode one complete frame (SOH .. EOT, its length field equal to its size)."""
    minimum = MIN_SERIAL if serial_line else MIN_TCP
    if len(frame) < minimum:
        raise WireError(f"packet of {len(frame)} bytes, the minimum is {minimum}")
    soh, length, serial, reserved, code, argc = HEAD.unpack_from(frame)
    if soh != SOH or frame[-1] != EOT or length != len(frame):
        raise WireError(f"bad frame: SOH 0x{soh:02X}, EOT 0x{frame[-1]:02X}, length {length} of {len(frame)}")
    end = len(frame) - (3 if serial_line else 1)
    if serial_line and struct.unpack_from("<H", frame, end)[0] != crc16(frame[1:end]):
        raise WireError("CRC mismatch")
    pos, args = HEAD.size, []
    for index in range(argc):
        if pos + 4 > end:
            raise WireError(f"argument {index + 1} of {argc} missing")
        (size,) = struct.unpack_from("<I", frame, pos)
        pos += 4
        if pos + size > end:
            raise WireError(f"argument {index + 1}: {size} bytes do not fit the packet")
        item, stop = read_value(frame[pos:pos + size])
        if stop != size:
            raise WireError(f"argument {index + 1}: length {size}, its VARIANT has {stop} bytes")
        args.append(item)
        pos += size
    if pos != end:
        raise WireError(f"{end - pos} bytes after the last argument")
    return Packet(serial, reserved, code, tuple(args))


class Framer:
    """Cuts a byte stream into packets, as the reference server's receiver does: scan for SOH, skip a
    length field out of range (and, on a serial line, a packet whose CRC fails — counted in
    ``crc_errors``); a packet that is framed but malformed raises :class:`WireError` from :meth:`next`."""

    def __init__(self, *, serial_line: bool = False, max_length: int | None = None) -> None:
        self.serial_line = serial_line
        self.minimum = MIN_SERIAL if serial_line else MIN_TCP
        self.maximum = max_length or (MAX_SERIAL_LINE if serial_line else MAX_TCP)
        self.buffer = bytearray()
        self.crc_errors = 0

    def feed(self, data: bytes) -> None:
        self.buffer += data

    def next(self) -> Packet | None:
        buf = self.buffer
        while True:
            start = buf.find(SOH)
            del buf[:start if start >= 0 else len(buf)]
            if len(buf) < 5:
                return None
            (length,) = struct.unpack_from("<I", buf, 1)
            if not self.minimum <= length <= self.maximum:
                del buf[:1]
                continue
            if len(buf) < length:
                return None
            frame = bytes(buf[:length])
            if self.serial_line and frame[-1] == EOT:
                end = length - 3
                if struct.unpack_from("<H", frame, end)[0] != crc16(frame[1:end]):
                    self.crc_errors += 1  # dropped silently; the client retries
                    del buf[:1]
                    continue
            del buf[:length]
            return parse(frame, serial_line=self.serial_line)
