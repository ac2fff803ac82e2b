"""IEEE 488.2 / SCPI-99 status model of a mock instrument: error queue, Standard Event Status Register
(ESR) with its enable mask (ESE), Service Request Enable (SRE) and the Status Byte (STB).

* every error pushed sets its ESR class bit (IEEE 488.2 §11.5.1 and SCPI-99 vol. 2 §21.8: −100…−199
  command error CME, −200…−299 execution error EXE, −300…−399 and positive codes device-dependent DDE,
  −400…−499 query error QYE);
* the error queue is 20 deep; on overflow the newest entry becomes −350 "Queue overflow" (SCPI-99
  §21.8.2; depth as the Keysight 33500 series);
* STB bit 2 (EAV) = error queue not empty (SCPI-99 §9.1), bit 4 MAV = a reply is waiting in the output
  queue, bit 5 ESB = ESR & ESE ≠ 0, bit 6 MSS = (STB & SRE) ≠ 0 with SRE bit 6 ignored (IEEE 488.2 §11.2);
* PON (ESR bit 7) is set at power-on, i.e. when the mock starts (IEEE 488.2 §11.5.1.1.2).

Not thread-safe by itself: the instrument calls it under its own lock.
"""

from __future__ import annotations

from collections import deque

__all__ = ["ERROR_QUEUE_DEPTH", "ESR_BITS", "StatusModel", "standard_message"]

ERROR_QUEUE_DEPTH = 20
ESR_BITS = {"OPC": 0, "RQC": 1, "QYE": 2, "DDE": 3, "EXE": 4, "CME": 5, "URQ": 6, "PON": 7}
STB_EAV, STB_MAV, STB_ESB, STB_MSS = 2, 4, 5, 6

_MESSAGES = {
    -100: "Command error", -101: "Invalid character", -102: "Syntax error", -104: "Data type error",
    -108: "Parameter not allowed", -109: "Missing parameter", -113: "Undefined header",
    -114: "Header suffix out of range", -131: "Invalid suffix", -150: "String data error",
    -200: "Execution error", -221: "Settings conflict", -222: "Data out of range",
    -223: "Too much data", -224: "Illegal parameter value", -300: "Device-specific error",
    -310: "System error", -330: "Self-test failed", -350: "Queue overflow", -400: "Query error",
    -410: "Query INTERRUPTED", -420: "Query UNTERMINATED",
}


def standard_message(code: int) -> str:
    """The SCPI-99 message of a standard error code ("Device-specific error" for other codes)."""
    return _MESSAGES.get(code, "Device-specific error")


def _event_bit(code: int) -> int:
    if -199 <= code <= -100:
        return ESR_BITS["CME"]
    if -299 <= code <= -200:
        return ESR_BITS["EXE"]
    if -499 <= code <= -400:
        return ESR_BITS["QYE"]
    return ESR_BITS["DDE"]  # −300…−399 and device-defined (positive) codes


class StatusModel:
    """Error queue + ESR/ESE/SRE registers; :meth:`status_byte` computes the STB."""

    def __init__(self) -> None:
        self.errors: deque[tuple[int, str]] = deque()
        self.esr = 1 << ESR_BITS["PON"]
        self.ese = 0
        self.sre = 0

    def push_error(self, code: int, message: str | None = None) -> None:
        """Queue (code, message) and set its ESR class bit; on overflow the newest entry becomes −350."""
        if code == 0:
            return
        self.esr |= 1 << _event_bit(code)
        entry = (code, standard_message(code) if message is None else message)
        if len(self.errors) < ERROR_QUEUE_DEPTH:
            self.errors.append(entry)
        else:
            self.errors[-1] = (-350, "Queue overflow")

    def pop_error(self) -> tuple[int, str]:
        """Oldest queued error, or (0, "No error")."""
        return self.errors.popleft() if self.errors else (0, "No error")

    def operation_complete(self) -> None:
        """``*OPC``: no overlapped commands, so every operation is complete at once: set ESR bit 0."""
        self.esr |= 1 << ESR_BITS["OPC"]

    def read_esr(self) -> int:
        """``*ESR?``: the register's value; reading clears it (IEEE 488.2 §11.5.1.2.2)."""
        value, self.esr = self.esr, 0
        return value

    def clear(self) -> None:
        """``*CLS``: clear ESR and the error queue (not ESE/SRE, IEEE 488.2 §10.3)."""
        self.esr = 0
        self.errors.clear()

    def status_byte(self, message_available: bool) -> int:
        """STB with MSS (bit 6) as ``*STB?`` reports it (reading does not clear it)."""
        stb = 0
        if self.errors:
            stb |= 1 << STB_EAV
        if message_available:
            stb |= 1 << STB_MAV
        if self.esr & self.ese:
            stb |= 1 << STB_ESB
        if stb & self.sre & ~(1 << STB_MSS):
            stb |= 1 << STB_MSS
        return stb
