"""Modbus driver for a variable-frequency drive (VFD), register map as data.

The driver receives an open :class:`drivers.modbus_link.ModbusLink` (Modbus RTU on an RS-485 line or
Modbus TCP) and never opens a port itself. It speaks only FC03 (read holding registers) and FC06 (write
single register), the two function codes every drive supports, and writes absolute values only (the
link repeats a request after a lost or out-of-step reply, so every write must be idempotent).

Frequencies here are **drive output frequencies** in Hz (the motor side); the exciter and the rotor
(:mod:`drivers.exciter.exciter`, :mod:`drivers.exciter.rotor`) convert through their gear ratio.

Every failure raises a :class:`VfdError` subclass naming the operation, the register and what went
wrong. When a command or read fails, the driver first **attempts a stop** (unless the failure happened
while stopping) and says in the message whether that stop went through. A stop is repeated on a fresh
link (reopened port or connection, after the line's silence) until ``stop_deadline_s`` has passed, so an
out-of-step link never makes it fail.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import TypeVar

from drivers.exciter.register_map import DELTA_MAP, RegisterMap
from drivers.heartbeat import ContactRecord
from drivers.modbus import ModbusExceptionReply, write_single_request
from drivers.modbus_link import ModbusLink, ModbusLinkError

__all__ = ["DriveStatus", "VfdCommunicationError", "VfdDriver", "VfdError", "VfdExceptionResponseError",
           "VfdFaultError", "VfdProtocolError"]

log = logging.getLogger(__name__)

EXCEPTION_NAMES = {1: "illegal function", 2: "illegal data address", 3: "illegal data value",
                   4: "device failure", 5: "acknowledge", 6: "device busy", 7: "negative acknowledge",
                   8: "memory parity error", 10: "gateway path unavailable", 11: "gateway target no response"}

# Fault codes the mock drive uses (docs/exciter.md). A real drive has its own table: pass ``fault_names``.
MOCK_FAULT_NAMES = {5: "oL: drive overload", 0x41: "oSPd: overspeed",
                    0x42: "CE10: Modbus communication time-out (watchdog)"}

_T = TypeVar("_T")


class VfdError(RuntimeError):
    """Base of every VFD driver error. ``stop_attempted`` / ``stop_ok`` say what was done after it."""

    stop_attempted: bool = False
    stop_ok: bool | None = None


class VfdCommunicationError(VfdError):
    """No valid reply: time-out, CRC error, out-of-step reply, lost connection (after the link's retries)."""


class VfdExceptionResponseError(VfdError):
    """The drive answered with a Modbus exception response."""

    def __init__(self, message: str, exception_code: int) -> None:
        super().__init__(message)
        self.exception_code = exception_code


class VfdProtocolError(VfdError):
    """The drive answered, but not what was asked (wrong echo, wrong register count, bad read-back)."""


class VfdFaultError(VfdError):
    """The drive reports a fault (non-zero fault code)."""

    def __init__(self, message: str, fault_code: int) -> None:
        super().__init__(message)
        self.fault_code = fault_code


@dataclass(frozen=True)
class DriveStatus:
    """One read of the drive's monitor registers.

    state: "stopped" | "running" | "decelerating" | "standby" | "unknown(0xNN)";
    direction: "forward" | "reverse" | "reversing"; frequencies in Hz; current in A (None if unmapped).
    """

    fault_code: int
    warning_code: int
    state: str
    direction: str
    freq_cmd_hz: float
    freq_out_hz: float
    current_a: float | None
    status_word: int


def check_output_hz(frequency_hz: float, max_output_hz: float) -> None:
    """A drive output frequency (Hz) within 0..``max_output_hz``; ValueError naming it otherwise."""
    if not 0.0 <= frequency_hz <= max_output_hz:
        raise ValueError(f"frequency_hz={frequency_hz!r}: drive output must be within "
                         f"0..{max_output_hz:g} Hz (max_output_hz)")


class VfdDriver:
    """A VFD on a Modbus line.

    link: the open Modbus line (:class:`~drivers.modbus_link.ModbusLink`); its ``timeout_s`` and
        ``retries`` bound every call (worst case ≈ timeout × (retries + 1)). Drives on one RS-485 bus
        share one link.
    register_map: where the drive keeps what (default: Delta).
    max_output_hz: the drive's maximum output frequency (its parameter, e.g. Delta 01-00); setpoints
        above it raise, and ramp times are defined as the time from 0 Hz to it.
    fault_names: fault code → text for messages.
    stop_deadline_s: how long (s, on the link's clock) a stop command is repeated on fresh links before
        it is reported as failed; default twice the link's worst case for one request,
        2 × timeout × (retries + 1), at least 1 s (the runner makes the devices safe one after the other,
        so a dead drive must not hold up the others for long).

    Thread-safe: every request holds the link's lock; ``contact`` records the wall time of the drive's
    last reply (an exception response counts: the drive answered) for the heartbeat.
    """

    def __init__(self, link: ModbusLink, register_map: RegisterMap = DELTA_MAP, *,
                 max_output_hz: float = 50.0, fault_names: dict[int, str] | None = None,
                 stop_deadline_s: float | None = None) -> None:
        if not max_output_hz > 0:
            raise ValueError(f"max_output_hz={max_output_hz!r}: must be > 0 Hz")
        if stop_deadline_s is None:
            stop_deadline_s = max(1.0, 2.0 * link.timeout_s * (link.retries + 1))
        if not stop_deadline_s > 0:
            raise ValueError(f"stop_deadline_s={stop_deadline_s!r}: must be > 0 s")
        register_map.freq_to_register(max_output_hz)
        self.link = link
        self.map = register_map
        self.max_output_hz = float(max_output_hz)
        self.fault_names = dict(MOCK_FAULT_NAMES if fault_names is None else fault_names)
        self.stop_deadline_s = float(stop_deadline_s)
        self._stopping = False
        self.contact = ContactRecord(link.lock)
        self.stop_attempts = 0  # requests the last stop command needed

    # low level ---------------------------------------------------------------------------------------
    def _fail(self, exc: VfdError) -> VfdError:
        """Attempt a stop (unless already stopping) and annotate ``exc`` with the outcome."""
        if self._stopping:
            return exc
        exc.stop_attempted = True
        try:
            self._send_stop("stop (after a failure)")
            exc.stop_ok = True
            note = "stop command sent and acknowledged"
            if self.stop_attempts > 1:
                note += f" (attempt {self.stop_attempts})"
        except VfdError as stop_exc:
            exc.stop_ok = False
            note = f"stop command attempted but failed: {stop_exc}"
        exc.args = (f"{exc.args[0]}; {note}",)
        log.error("%s", exc.args[0])
        return exc

    def _describe(self, address: int) -> str:
        names = [n for n, a in self.map.addresses().items() if a == address]
        return f"{names[0] if names else 'register'} 0x{address:04X}"

    def _request(self, call: Callable[[], _T], what: str) -> _T:
        """One request under the line lock; any reply (an exception response too) is a contact."""
        with self.contact.exchange():
            try:
                result = call()
            except ModbusExceptionReply as exc:
                self.contact.touch()
                name = EXCEPTION_NAMES.get(exc.exception_code, "unknown exception")
                raise VfdExceptionResponseError(
                    f"{what}: drive answered Modbus exception {exc.exception_code} ({name})",
                    exc.exception_code) from exc
            except ModbusLinkError as exc:
                raise VfdCommunicationError(f"{what}: {exc}") from exc
            self.contact.touch()
            return result

    def _read(self, address: int, count: int, what: str) -> list[int]:
        what = f"{what}: read {count} register(s) at {self._describe(address)} (unit {self.map.unit_id})"
        try:
            return self._request(lambda: self.link.read_holding_registers(self.map.unit_id, address, count),
                                 what)
        except VfdError as exc:
            raise self._fail(exc) from exc.__cause__

    def _write(self, address: int, value: int, what: str) -> None:
        what = f"{what}: write 0x{value:04X} to {self._describe(address)} (unit {self.map.unit_id})"
        try:
            self._request(lambda: self.link.write_register(self.map.unit_id, address, value), what)
        except VfdError as exc:
            raise self._fail(exc) from exc.__cause__

    def _send_stop(self, what: str) -> None:
        """The stop command, repeated on fresh links until acknowledged or ``stop_deadline_s`` has passed."""
        address, value = self.map.command, self.map.cmd_stop
        what = f"{what}: write 0x{value:04X} to {self._describe(address)} (unit {self.map.unit_id})"
        pdu = write_single_request(address, value)
        self.stop_attempts = 0

        def send() -> None:
            self.stop_attempts = self.link.execute_until(self.map.unit_id, pdu, self.stop_deadline_s)

        try:
            self._request(send, what)
        except VfdCommunicationError as exc:
            cause = exc.__cause__
            self.stop_attempts = cause.attempts if isinstance(cause, ModbusLinkError) else 0
            raise
        if self.stop_attempts > 1:
            log.warning("%s: acknowledged at attempt %d", what, self.stop_attempts)

    # commands ----------------------------------------------------------------------------------------
    def check_frequency_hz(self, frequency_hz: float) -> int:
        """Validate a drive output frequency and return its register value (nothing is sent)."""
        check_output_hz(frequency_hz, self.max_output_hz)
        return self.map.freq_to_register(frequency_hz)

    def set_frequency_hz(self, frequency_hz: float, *, verify: bool = True) -> None:
        """Write the frequency setpoint (Hz, 0..max_output_hz) and, with ``verify``, read the drive's
        frequency command back and compare."""
        value = self.check_frequency_hz(frequency_hz)
        self._write(self.map.freq_set, value, f"set frequency {frequency_hz:g} Hz")
        if verify:
            (back,) = self._read(self.map.freq_cmd, 1, "read back frequency command")
            if back != value:
                raise self._fail(VfdProtocolError(
                    f"set frequency {frequency_hz:g} Hz: drive reports command {back} "
                    f"({self.map.register_to_freq(back):g} Hz), wrote {value}"))

    def run(self, direction: str = "forward") -> None:
        """Start the motor in ``direction`` ("forward" or "reverse")."""
        codes = {"forward": self.map.cmd_run_forward, "reverse": self.map.cmd_run_reverse}
        if direction not in codes:
            raise ValueError(f"direction={direction!r}: must be 'forward' or 'reverse'")
        self._write(self.map.command, codes[direction], f"run {direction}")

    def stop(self) -> None:
        """Command a stop (the drive decelerates on its deceleration ramp), repeated on fresh links until
        acknowledged or ``stop_deadline_s`` has passed; raises :class:`VfdError` naming the attempts."""
        self._stopping = True
        try:
            self._send_stop("stop")
        finally:
            self._stopping = False

    def reset_fault(self) -> None:
        """Write the fault-reset code (the drive clears the fault only if its cause is gone)."""
        if self.map.aux_command is None:
            raise VfdError(f"reset_fault: register map {self.map.model!r} has no aux_command register")
        self._write(self.map.aux_command, self.map.aux_fault_reset, "fault reset")

    def set_ramp_times_s(self, accel_s: float, decel_s: float) -> None:
        """Acceleration and deceleration times (s, from 0 Hz to max_output_hz and back)."""
        if not self.map.has_ramp_registers:
            raise VfdError(f"set_ramp_times_s: register map {self.map.model!r} has no ramp-time registers")
        accel = self.map.ramp_time_to_register(accel_s)
        decel = self.map.ramp_time_to_register(decel_s)
        assert self.map.accel_time is not None and self.map.decel_time is not None
        self._write(self.map.accel_time, accel, f"acceleration time {accel_s:g} s")
        self._write(self.map.decel_time, decel, f"deceleration time {decel_s:g} s")

    def set_comm_timeout_s(self, timeout_s: float | None) -> None:
        """Arm the drive's own communication-loss stop: with no valid request for ``timeout_s`` (s, within
        the register's range) it faults (Delta CE10) and ramps to a stop on its deceleration ramp — what
        covers a controller that dies without a word (SIGKILL, power loss, a cut cable). ``None`` disarms
        it (a clean close: an idle drive must not fault between runs)."""
        m = self.map
        if m.comm_timeout is None or m.comm_fault_treatment is None:
            raise VfdError(f"set_comm_timeout_s: register map {m.model!r} has no communication time-out "
                           "registers")
        if timeout_s is None:
            self._write(m.comm_timeout, 0, "communication time-out off")
            return
        value = m.comm_timeout_to_register(timeout_s)
        self._write(m.comm_fault_treatment, m.comm_treatment_ramp_stop, "on communication loss: ramp to stop")
        self._write(m.comm_timeout, value, f"communication time-out {timeout_s:g} s")

    def set_ramp_rate_hz_per_s(self, rate_hz_per_s: float, *,
                               max_rate_hz_per_s: float | None = None) -> float:
        """Set both ramp times so the drive changes frequency at ``rate_hz_per_s`` (drive Hz/s) or a
        little faster (the ramp time is rounded down to the register's resolution, so the drive never
        lags a profile), but never faster than ``max_rate_hz_per_s``. Returns the rate obtained."""
        if not rate_hz_per_s > 0:
            raise ValueError(f"rate_hz_per_s={rate_hz_per_s!r}: must be > 0")
        unit = self.map.ramp_time_unit_s
        exact = self.max_output_hz / rate_hz_per_s / unit
        steps = max(1, math.floor(exact + 1e-9))
        if max_rate_hz_per_s is not None and self.max_output_hz / (steps * unit) > max_rate_hz_per_s:
            steps = math.ceil(exact - 1e-9)
        self.set_ramp_times_s(steps * unit, steps * unit)
        return self.max_output_hz / (steps * unit)

    # monitor -----------------------------------------------------------------------------------------
    def read_fault_code(self) -> int:
        (value,) = self._read(self.map.fault, 1, "read fault")
        return value & self.map.fault_code_mask

    def read_actual_frequency_hz(self) -> float:
        (value,) = self._read(self.map.freq_out, 1, "read output frequency")
        return self.map.register_to_freq(value)

    def read_status(self) -> DriveStatus:
        """Fault, status word, commanded and actual frequency (and current) in one FC03 when the map
        keeps them contiguous (Delta: 0x2100..0x2104), else one read each."""
        m = self.map
        wanted = [m.fault, m.status, m.freq_cmd, m.freq_out] + ([m.current] if m.current is not None else [])
        lo, hi = min(wanted), max(wanted)
        if hi - lo < 16:
            regs = self._read(lo, hi - lo + 1, "read status")
            values = {a: regs[a - lo] for a in wanted}
        else:
            values = {a: self._read(a, 1, "read status")[0] for a in wanted}
        fault = values[m.fault]
        return DriveStatus(
            fault_code=fault & m.fault_code_mask,
            warning_code=(fault & ~m.fault_code_mask & 0xFFFF) >> 8,
            state=self.decode_state(values[m.status]),
            direction=self.decode_direction(values[m.status]),
            freq_cmd_hz=m.register_to_freq(values[m.freq_cmd]),
            freq_out_hz=m.register_to_freq(values[m.freq_out]),
            current_a=None if m.current is None else values[m.current] * m.current_unit_a,
            status_word=values[m.status])

    def probe(self) -> str | None:
        """Heartbeat probe: one FC03 of STATUS (with FAULT when adjacent, Delta 0x2100..0x2101), no stop
        attempt on failure (the runner makes every device safe). Returns the fault text if the drive
        reports one, else None; raises :class:`VfdError` when it does not answer."""
        m = self.map
        lo = min(m.fault, m.status) if abs(m.fault - m.status) == 1 else m.status
        count = 2 if abs(m.fault - m.status) == 1 else 1
        what = f"heartbeat: read {count} register(s) at {self._describe(lo)} (unit {m.unit_id})"
        regs = self._request(lambda: self.link.read_holding_registers(m.unit_id, lo, count), what)
        if count == 2:
            fault = regs[m.fault - lo] & m.fault_code_mask
            if fault:
                return f"drive reports {self.fault_text(fault)}"
        return None

    def decode_state(self, status_word: int) -> str:
        m = self.map
        bits = status_word & m.status_run_mask
        states = {m.status_stopped: "stopped", m.status_running: "running",
                  m.status_decelerating: "decelerating", m.status_standby: "standby"}
        return states.get(bits, f"unknown(0x{bits:02X})")

    def decode_direction(self, status_word: int) -> str:
        m = self.map
        bits = status_word & m.status_dir_mask
        if bits == m.status_dir_forward:
            return "forward"
        if bits == m.status_dir_reverse:
            return "reverse"
        return "reversing"

    def fault_text(self, code: int) -> str:
        return f"fault code {code} ({self.fault_names.get(code, 'see the drive manual')})"

    def raise_if_faulted(self, status: DriveStatus, what: str) -> None:
        """Raise :class:`VfdFaultError` (after a stop attempt) if ``status`` carries a fault."""
        if status.fault_code:
            raise self._fail(VfdFaultError(f"{what}: drive reports {self.fault_text(status.fault_code)}",
                                           status.fault_code))
