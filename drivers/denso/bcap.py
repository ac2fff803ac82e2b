"""b-CAP packet codec (``../shared/notes/bcap.md`` §2–4): pure functions and a streaming decoder, no I/O.

Layout, all little-endian::

    SOH 0x01 | uint32 total length | uint16 serial | uint16 reserved | int32 function ID / HRESULT
    | uint16 argc | argc × (uint32 L, VARIANT of L bytes) | [uint16 CRC, serial line only] | EOT 0x04

The total length counts every byte including SOH, EOT and the CRC. On serial lines the CRC-16/CCITT-FALSE
covers bytes 1 .. length-4 (everything but SOH, CRC and EOT) and is stored little-endian. Serial and UDP
packets are capped at :data:`SERIAL_MAX_PACKET` (503) bytes.
"""

from __future__ import annotations

import struct
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field

from drivers.denso.hresult import E_TOO_MUCH_DATA, S_EXECUTING, BcapError, BcapProtocolError, to_signed
from drivers.denso.variant import Variant, decode_variant, encode_variant, to_variant

SOH = 0x01
EOT = 0x04
HEADER_SIZE = 15  # SOH .. argc
MIN_PACKET = 16
MIN_PACKET_SERIAL = 18
SERIAL_MAX_PACKET = 503
TCP_MAX_PACKET = 16 * 1024 * 1024
MAX_SERIAL_NUMBER = 0xFFFF

# Function IDs (bcap.md §6)
SERVICE_START, SERVICE_STOP = 1, 2
CONTROLLER_CONNECT, CONTROLLER_DISCONNECT = 3, 4
CONTROLLER_GET_ROBOT, CONTROLLER_GET_TASK, CONTROLLER_GET_VARIABLE = 7, 8, 9
CONTROLLER_GET_ROBOT_NAMES = 13
CONTROLLER_EXECUTE = 17
ROBOT_GET_VARIABLE, ROBOT_EXECUTE = 62, 64
ROBOT_HALT, ROBOT_HOLD, ROBOT_MOVE, ROBOT_SPEED, ROBOT_UNHOLD = 70, 71, 72, 74, 76
ROBOT_RELEASE = 84
TASK_START, TASK_STOP, TASK_RELEASE = 88, 89, 99
VARIABLE_GET_VALUE, VARIABLE_PUT_VALUE, VARIABLE_RELEASE = 101, 102, 111

FUNCTION_NAMES: dict[int, str] = {
    SERVICE_START: "Service_Start", SERVICE_STOP: "Service_Stop",
    CONTROLLER_CONNECT: "Controller_Connect", CONTROLLER_DISCONNECT: "Controller_Disconnect",
    CONTROLLER_GET_ROBOT: "Controller_GetRobot", CONTROLLER_GET_TASK: "Controller_GetTask",
    CONTROLLER_GET_VARIABLE: "Controller_GetVariable", CONTROLLER_GET_ROBOT_NAMES: "Controller_GetRobotNames",
    CONTROLLER_EXECUTE: "Controller_Execute", ROBOT_GET_VARIABLE: "Robot_GetVariable",
    ROBOT_EXECUTE: "Robot_Execute", ROBOT_HALT: "Robot_Halt", ROBOT_HOLD: "Robot_Hold",
    ROBOT_MOVE: "Robot_Move", ROBOT_SPEED: "Robot_Speed", ROBOT_UNHOLD: "Robot_Unhold",
    ROBOT_RELEASE: "Robot_Release", TASK_START: "Task_Start", TASK_STOP: "Task_Stop",
    TASK_RELEASE: "Task_Release", VARIABLE_GET_VALUE: "Variable_GetValue",
    VARIABLE_PUT_VALUE: "Variable_PutValue", VARIABLE_RELEASE: "Variable_Release",
}


def function_name(function_id: int) -> str:
    return FUNCTION_NAMES.get(function_id, f"function {function_id}")


def crc16_ccitt(data: bytes, crc: int = 0xFFFF) -> int:
    """CRC-16/CCITT-FALSE: poly 0x1021, init 0xFFFF, not reflected, no final XOR ("123456789" -> 0x29B1)."""
    for byte in data:
        crc ^= byte << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1021) & 0xFFFF if crc & 0x8000 else (crc << 1) & 0xFFFF
    return crc


def next_serial(serial: int) -> int:
    """The serial number after ``serial``: 1..65535, wrapping to 1 (never 0)."""
    return 1 if serial >= MAX_SERIAL_NUMBER else serial + 1


@dataclass(frozen=True)
class Packet:
    """One b-CAP packet. ``code`` is the function ID of a request or the signed HRESULT of a reply."""

    serial: int
    reserved: int
    code: int
    args: tuple[Variant, ...] = field(default_factory=tuple)

    @property
    def is_keepalive(self) -> bool:
        return self.code == S_EXECUTING and not self.args


def encode_packet(serial: int, reserved: int, code: int, args: Iterable[object] = (), *,
                  serial_line: bool = False, max_length: int | None = None) -> bytes:
    """Bytes of one packet. ``args`` are :class:`Variant` or plain values (mapped by ``to_variant``).

    ``max_length`` (default 503 on a serial line, none on TCP) raises ``BcapError(E_TOO_MUCH_DATA)``
    before anything could be sent, as the reference client does.
    """
    if not 0 <= serial <= MAX_SERIAL_NUMBER:
        raise ValueError(f"serial={serial}: must be 0..65535")
    if not 0 <= reserved <= MAX_SERIAL_NUMBER:
        raise ValueError(f"reserved={reserved}: must be 0..65535")
    encoded = [encode_variant(to_variant(arg)) for arg in args]
    body = b"".join(struct.pack("<I", len(item)) + item for item in encoded)
    length = HEADER_SIZE + len(body) + (3 if serial_line else 1)
    limit = max_length if max_length is not None else (SERIAL_MAX_PACKET if serial_line else TCP_MAX_PACKET)
    if length > limit:
        raise BcapError(E_TOO_MUCH_DATA,
                        description=f"packet of {length} bytes exceeds the {limit}-byte limit")
    head = struct.pack("<IHHiH", length, serial, reserved, to_signed(code), len(encoded))
    if serial_line:
        return bytes([SOH]) + head + body + struct.pack("<H", crc16_ccitt(head + body)) + bytes([EOT])
    return bytes([SOH]) + head + body + bytes([EOT])


def _parse_body(frame: bytes, end: int) -> Packet:
    """Parse a framed packet (SOH .. EOT already checked); ``end`` is where the arguments must stop."""
    _length, serial, reserved, code, argc = struct.unpack_from("<IHHiH", frame, 1)
    offset = HEADER_SIZE
    args = []
    for index in range(argc):
        if offset + 4 > end:
            raise BcapProtocolError(f"serial {serial}: argument {index} of {argc} missing (packet too short)")
        (size,) = struct.unpack_from("<I", frame, offset)
        offset += 4
        if size < 6 or offset + size > end:
            raise BcapProtocolError(
                f"serial {serial}: argument {index} length {size} does not fit the packet")
        item, stop = decode_variant(frame[offset:offset + size])
        if stop != size:
            raise BcapProtocolError(
                f"serial {serial}: argument {index} declares {size} bytes, VARIANT has {stop}")
        args.append(item)
        offset += size
    if offset != end:
        raise BcapProtocolError(f"serial {serial}: {end - offset} stray bytes after {argc} arguments")
    return Packet(serial, reserved, code, tuple(args))


def decode_packet(data: bytes, *, serial_line: bool = False) -> Packet:
    """Decode exactly one packet (no resynchronisation); raise :class:`BcapProtocolError` if malformed."""
    minimum = MIN_PACKET_SERIAL if serial_line else MIN_PACKET
    if len(data) < minimum:
        raise BcapProtocolError(f"packet of {len(data)} bytes is shorter than the minimum {minimum}")
    if data[0] != SOH:
        raise BcapProtocolError(f"packet starts with 0x{data[0]:02X}, expected SOH 0x01")
    (length,) = struct.unpack_from("<I", data, 1)
    if length != len(data):
        raise BcapProtocolError(f"length field {length} != {len(data)} bytes received")
    if data[-1] != EOT:
        raise BcapProtocolError(f"packet ends with 0x{data[-1]:02X}, expected EOT 0x04")
    end = length - 1
    if serial_line:
        end = length - 3
        (crc,) = struct.unpack_from("<H", data, end)
        expected = crc16_ccitt(data[1:end])
        if crc != expected:
            raise BcapProtocolError(f"CRC 0x{crc:04X} != computed 0x{expected:04X}")
    return _parse_body(bytes(data), end)


class PacketDecoder:
    """Streaming decoder: feed bytes, take packets. Resynchronises on SOH.

    Framing damage (no SOH, length out of range, missing EOT, bad CRC) is skipped byte by byte and counted
    in ``skipped_bytes`` / ``crc_errors``, never raised — a bad-CRC packet is silently dropped, as on a
    real serial line. A packet that is framed correctly but whose arguments are malformed is removed from
    the stream and reported by :meth:`next_packet` raising :class:`BcapProtocolError`.
    """

    def __init__(self, *, serial_line: bool = False, max_length: int | None = None) -> None:
        self.serial_line = serial_line
        self.min_length = MIN_PACKET_SERIAL if serial_line else MIN_PACKET
        self.max_length = max_length or (SERIAL_MAX_PACKET if serial_line else TCP_MAX_PACKET)
        self._buffer = bytearray()
        self.skipped_bytes = 0
        self.crc_errors = 0

    def feed(self, data: bytes) -> None:
        self._buffer += data

    @property
    def buffered(self) -> int:
        return len(self._buffer)

    def _skip(self, count: int) -> None:
        del self._buffer[:count]
        self.skipped_bytes += count

    def next_packet(self) -> Packet | None:
        """The next complete packet, or None if more bytes are needed."""
        buf = self._buffer
        while True:
            start = buf.find(SOH)
            if start < 0:
                self._skip(len(buf))
                return None
            if start:
                self._skip(start)
            if len(buf) < 5:
                return None
            (length,) = struct.unpack_from("<I", buf, 1)
            if not self.min_length <= length <= self.max_length:
                self._skip(1)
                continue
            if len(buf) < length:
                return None
            if buf[length - 1] != EOT:
                self._skip(1)
                continue
            end = length - 1
            if self.serial_line:
                end = length - 3
                (crc,) = struct.unpack_from("<H", buf, end)
                if crc != crc16_ccitt(bytes(buf[1:end])):
                    self.crc_errors += 1
                    self._skip(1)
                    continue
            frame = bytes(buf[:length])
            del buf[:length]
            return _parse_body(frame, end)

    def packets(self) -> list[Packet]:
        """Every complete packet now buffered (stops at, and raises, the first malformed one)."""
        found = []
        while (packet := self.next_packet()) is not None:
            found.append(packet)
        return found


def args_repr(args: Sequence[Variant]) -> str:
    return ", ".join(f"vt=0x{a.vt:04X}:{a.value!r}" for a in args)
