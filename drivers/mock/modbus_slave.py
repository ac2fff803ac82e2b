"""The Modbus slave's PDU handler for the mock drives: one request PDU for a unit → the reply PDU (or
none), per the MODBUS Application Protocol V1.1b3 and, for unit ids and broadcast, "MODBUS over Serial
Line V1.02" / "MODBUS Messaging on TCP/IP Implementation Guide V1.0b" (docs/exciter.md §4.1)."""

from __future__ import annotations

import struct

from drivers.mock.vfd_drive import DriveModel
from drivers.modbus import (
    BROADCAST,
    FC_READ_HOLDING,
    FC_WRITE_MULTIPLE,
    FC_WRITE_SINGLE,
    MAX_READ_QUANTITY,
    MAX_WRITE_QUANTITY,
    ExceptionCode,
    exception_pdu,
    request_pdu_length,
)

__all__ = ["ModbusSlave"]


class ModbusSlave:
    """The PDU handler: request PDU for ``unit`` → reply PDU (None: no reply), per the Application
    Protocol V1.1b3 (§6.3 FC03, §6.6 FC06, §6.12 FC16, §7 exceptions)."""

    def __init__(self, drives: list[DriveModel], mode: str) -> None:
        self.drives = {d.map.unit_id: d for d in drives}
        self.mode = mode

    def addressed(self, unit: int) -> bool:
        """Whether a request to ``unit`` is for this line's slave(s) (RTU broadcast included)."""
        return self.mode == "tcp" or unit in self.drives or unit == BROADCAST

    def _target(self, unit: int) -> DriveModel | None:
        if unit in self.drives:
            return self.drives[unit]
        if self.mode == "tcp" and unit in (0, 0xFF) and len(self.drives) == 1:
            return next(iter(self.drives.values()))  # TCP guide §4.4.2: 0xFF (or 0) addresses the server
        return None

    def handle(self, unit: int, pdu: bytes) -> bytes | None:
        broadcast = self.mode == "rtu" and unit == BROADCAST
        target = self._target(unit)
        if target is None and not broadcast:
            if self.mode == "rtu":
                return None  # another slave's request
            return exception_pdu(pdu[0] if pdu else 0, ExceptionCode.GATEWAY_TARGET_NO_RESPONSE)
        if not pdu:
            return None
        fc = pdu[0]
        reply = self._execute(target, fc, pdu, broadcast)
        return None if broadcast else reply

    def _execute(self, target: DriveModel | None, fc: int, pdu: bytes, broadcast: bool) -> bytes:
        if fc not in (FC_READ_HOLDING, FC_WRITE_SINGLE, FC_WRITE_MULTIPLE):
            return exception_pdu(fc, ExceptionCode.ILLEGAL_FUNCTION)
        if len(pdu) != request_pdu_length(pdu):
            return exception_pdu(fc, ExceptionCode.ILLEGAL_DATA_VALUE)  # short or overlong request
        address, quantity = struct.unpack(">HH", pdu[1:5])
        if fc == FC_READ_HOLDING:
            if broadcast or target is None:
                return b""  # a broadcast read is not a request (Serial Line §2.1)
            if not 1 <= quantity <= MAX_READ_QUANTITY:
                return exception_pdu(fc, ExceptionCode.ILLEGAL_DATA_VALUE)
            if address + quantity > 0x10000:
                return exception_pdu(fc, ExceptionCode.ILLEGAL_DATA_ADDRESS)
            result = target.read(address, quantity)
            if isinstance(result, ExceptionCode):
                return exception_pdu(fc, result)
            return struct.pack(f">BB{quantity}H", fc, 2 * quantity, *result)
        if fc == FC_WRITE_SINGLE:
            values, echo = [quantity], pdu
        else:
            if not 1 <= quantity <= MAX_WRITE_QUANTITY or pdu[5] != 2 * quantity:
                return exception_pdu(fc, ExceptionCode.ILLEGAL_DATA_VALUE)
            if address + quantity > 0x10000:
                return exception_pdu(fc, ExceptionCode.ILLEGAL_DATA_ADDRESS)
            values, echo = list(struct.unpack(f">{quantity}H", pdu[6:])), pdu[:5]
        drives = list(self.drives.values()) if broadcast else [target]
        results = [d.write(address, values) for d in drives if d is not None]
        failed = next((r for r in results if r is not None), None)
        return exception_pdu(fc, failed) if failed is not None else echo
