"""Modbus RTU and Modbus TCP framing — the bytes on the wire — shared by the VFD driver and the mock drive.

Sources: "MODBUS Application Protocol Specification V1.1b3" (PDUs, quantity limits, exception codes,
§7 exception responses carry the request's function code | 0x80); "MODBUS over Serial Line Specification
and Implementation Guide V1.02" (§2.5.1 RTU frame, CRC-16 low byte first, t3.5 silence between frames —
a fixed 1.750 ms above 19200 baud —, §2.1 broadcast address 0 answered by nobody); "MODBUS Messaging on
TCP/IP Implementation Guide V1.0b" (§3.1.3 MBAP header: transaction id, protocol id 0, length, unit id).

Only what a VFD needs: FC03 read holding registers, FC06 write single register, FC16 write multiple
registers. Pure functions: no I/O here (the master is :mod:`drivers.modbus_link`, the slave
:mod:`drivers.mock.vfd_server`).
"""

from __future__ import annotations

import struct
from enum import IntEnum

__all__ = ["BROADCAST", "FC_READ_HOLDING", "FC_WRITE_MULTIPLE", "FC_WRITE_SINGLE", "MAX_PDU_BYTES",
           "MAX_READ_QUANTITY", "MAX_WRITE_QUANTITY", "MBAP_BYTES", "ExceptionCode", "ModbusExceptionReply",
           "ReplyMismatch", "crc16", "decode_reply", "exception_pdu", "mbap_adu", "parse_mbap",
           "read_request", "request_pdu_length", "rtu_adu", "rtu_reply_length", "rtu_silence_s",
           "split_rtu", "write_multiple_request", "write_single_request"]

FC_READ_HOLDING = 0x03
FC_WRITE_SINGLE = 0x06
FC_WRITE_MULTIPLE = 0x10
MAX_READ_QUANTITY = 125   # Application Protocol §6.3
MAX_WRITE_QUANTITY = 123  # Application Protocol §6.12
MAX_PDU_BYTES = 253       # Serial Line §2.5.1: 256-byte RTU ADU − address − CRC
MBAP_BYTES = 7
BROADCAST = 0


class ExceptionCode(IntEnum):
    """Application Protocol §7."""

    ILLEGAL_FUNCTION = 1
    ILLEGAL_DATA_ADDRESS = 2
    ILLEGAL_DATA_VALUE = 3
    SERVER_DEVICE_FAILURE = 4
    ACKNOWLEDGE = 5
    SERVER_DEVICE_BUSY = 6
    GATEWAY_PATH_UNAVAILABLE = 10
    GATEWAY_TARGET_NO_RESPONSE = 11


class ModbusExceptionReply(Exception):  # noqa: N818 (it is a reply, not a failure of ours)
    """The slave answered the request with a Modbus exception response."""

    def __init__(self, function_code: int, exception_code: int) -> None:
        self.function_code = function_code
        self.exception_code = exception_code
        super().__init__(f"exception {exception_code} to function 0x{function_code:02X}")


class ReplyMismatch(Exception):  # noqa: N818
    """A well-formed frame that does not answer the request (the link is out of step)."""


# CRC-16/MODBUS (poly 0xA001 reflected, init 0xFFFF) ---------------------------------------------------
def _crc_table() -> list[int]:
    table = []
    for byte in range(256):
        crc = byte
        for _ in range(8):
            crc = (crc >> 1) ^ 0xA001 if crc & 1 else crc >> 1
        table.append(crc)
    return table


_CRC_TABLE = _crc_table()


def crc16(data: bytes) -> bytes:
    """CRC-16/MODBUS of ``data``, low byte first (as it goes on the wire)."""
    crc = 0xFFFF
    for byte in data:
        crc = (crc >> 8) ^ _CRC_TABLE[(crc ^ byte) & 0xFF]
    return bytes((crc & 0xFF, crc >> 8))


def rtu_silence_s(baudrate: int) -> float:
    """t3.5 (s): 3.5 character times of 11 bits at ``baudrate``; 1.750 ms above 19200 baud
    (Serial Line §2.5.1.1)."""
    if baudrate <= 0:
        raise ValueError(f"baudrate={baudrate!r}: must be > 0")
    return 0.00175 if baudrate > 19200 else 3.5 * 11.0 / baudrate


# ADUs --------------------------------------------------------------------------------------------------
def rtu_adu(unit: int, pdu: bytes) -> bytes:
    """Address + PDU + CRC."""
    body = bytes((unit,)) + pdu
    return body + crc16(body)


def split_rtu(adu: bytes) -> tuple[int, bytes] | None:
    """(unit, PDU) of an RTU frame with a valid CRC, else None (too short or CRC error)."""
    if len(adu) < 4 or crc16(adu[:-2]) != adu[-2:]:
        return None
    return adu[0], adu[1:-2]


def mbap_adu(transaction_id: int, unit: int, pdu: bytes) -> bytes:
    """MBAP header (transaction id, protocol 0, length = unit + PDU) + PDU."""
    return struct.pack(">HHHB", transaction_id & 0xFFFF, 0, len(pdu) + 1, unit) + pdu


def parse_mbap(header: bytes) -> tuple[int, int, int, int]:
    """(transaction id, protocol id, length, unit) of a 7-byte MBAP header."""
    if len(header) != MBAP_BYTES:
        raise ValueError(f"MBAP header is {MBAP_BYTES} bytes, got {len(header)}")
    return struct.unpack(">HHHB", header)


# request PDUs ------------------------------------------------------------------------------------------
def _u16(name: str, value: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value <= 0xFFFF:
        raise ValueError(f"{name}={value!r}: must be an integer 0..65535")
    return value


def read_request(address: int, count: int) -> bytes:
    """FC03 request PDU."""
    if not 1 <= count <= MAX_READ_QUANTITY:
        raise ValueError(f"count={count!r}: must be 1..{MAX_READ_QUANTITY} registers")
    return struct.pack(">BHH", FC_READ_HOLDING, _u16("address", address), count)


def write_single_request(address: int, value: int) -> bytes:
    """FC06 request PDU."""
    return struct.pack(">BHH", FC_WRITE_SINGLE, _u16("address", address), _u16("value", value))


def write_multiple_request(address: int, values: list[int]) -> bytes:
    """FC16 request PDU."""
    if not 1 <= len(values) <= MAX_WRITE_QUANTITY:
        raise ValueError(f"{len(values)} values: must be 1..{MAX_WRITE_QUANTITY} registers")
    regs = [_u16("value", v) for v in values]
    return struct.pack(f">BHHB{len(regs)}H", FC_WRITE_MULTIPLE, _u16("address", address), len(regs),
                       2 * len(regs), *regs)


def exception_pdu(function_code: int, code: int) -> bytes:
    """Exception response PDU: the request's function code | 0x80, then the exception code."""
    return bytes(((function_code | 0x80) & 0xFF, code))


def request_pdu_length(prefix: bytes) -> int | None:
    """Length of a request PDU from its first bytes: an int when known, 0 when more bytes are needed to
    tell, None for a function code whose length this slave cannot know (it ends at the t3.5 silence)."""
    if not prefix:
        return 0
    fc = prefix[0]
    if fc in (FC_READ_HOLDING, FC_WRITE_SINGLE):
        return 5
    if fc == FC_WRITE_MULTIPLE:
        return 6 + prefix[5] if len(prefix) >= 6 else 0
    return None


def rtu_reply_length(request_fc: int, head: bytes) -> int | None:
    """Total RTU reply length (address to CRC) from its first 3 bytes, for a request with ``request_fc``;
    None when the function code answers another request."""
    fc = head[1]
    if fc == (request_fc | 0x80):
        return 5
    if fc != request_fc:
        return None
    if fc == FC_READ_HOLDING:
        return 5 + head[2]
    return 8  # FC06 / FC16: address, value/quantity echo


def decode_reply(request: bytes, reply: bytes) -> list[int]:
    """Validate ``reply`` (a PDU) against ``request`` (a PDU): function code, byte count, address/value or
    address/quantity echo. Returns the registers read (FC03) or [] (writes). Raises
    :class:`ModbusExceptionReply` for an exception response, :class:`ReplyMismatch` for anything else."""
    if not reply:
        raise ReplyMismatch("empty reply")
    fc = request[0]
    if reply[0] == (fc | 0x80):
        if len(reply) != 2:
            raise ReplyMismatch(f"exception reply of {len(reply)} bytes, expected 2")
        raise ModbusExceptionReply(fc, reply[1])
    if reply[0] != fc:
        raise ReplyMismatch(f"function code 0x{reply[0]:02X} in reply to 0x{fc:02X}")
    if fc == FC_READ_HOLDING:
        count = struct.unpack(">H", request[3:5])[0]
        if len(reply) < 2 or reply[1] != 2 * count or len(reply) != 2 + 2 * count:
            raise ReplyMismatch(f"read reply with byte count {reply[1] if len(reply) > 1 else None} and "
                                f"{len(reply) - 2} data bytes, expected {2 * count}")
        return list(struct.unpack(f">{count}H", reply[2:]))
    if fc == FC_WRITE_SINGLE:
        if reply != request:
            raise ReplyMismatch(f"write reply echoes {reply[1:].hex(' ')}, sent {request[1:].hex(' ')}")
        return []
    if fc == FC_WRITE_MULTIPLE:
        if reply != request[:5]:
            raise ReplyMismatch(f"write reply echoes {reply[1:].hex(' ')}, sent {request[1:5].hex(' ')}")
        return []
    raise ValueError(f"function code 0x{fc:02X} is not one this master sends")
