"""SCPI function generator (Keysight 33500-style command set, channel 1..2) over a byte transport.

The driver receives a :class:`drivers.transport.Transport` (serial line, ``socket://``, TCP) and never
opens a port. Every command is followed by ``SYST:ERR?``, read until ``+0,"No error"``; any error found
raises :class:`ScpiError` carrying every queued error and the command that provoked it. Queries are
checked the same way after their reply is read.

Only the generator is here; what the volts do to a shaker (displacement sensitivity, limits, safe
ramping) is :mod:`drivers.exciter.shaker`.
"""

from __future__ import annotations

import logging
import math
from typing import Any

from drivers.exciter.scpi import (
    Identity,
    ScpiReplyError,
    format_command,
    parse_bool,
    parse_error,
    parse_identity,
    parse_number,
)
from drivers.heartbeat import ContactRecord
from drivers.transport import TransportClosed

__all__ = ["GeneratorError", "ScpiError", "ScpiGenerator"]

log = logging.getLogger(__name__)

MAX_ERROR_READS = 32  # a 20-deep queue plus margin: more means the instrument never says "No error"


class GeneratorError(RuntimeError):
    """Base of the generator driver's errors (communication and protocol)."""


class ScpiError(GeneratorError):
    """The instrument queued one or more errors. ``errors`` is [(code, message), ...], ``command`` the
    program message that provoked them."""

    def __init__(self, command: str, errors: list[tuple[int, str]]) -> None:
        self.command = command
        self.errors = errors
        listed = "; ".join(f"{code},\"{msg}\"" for code, msg in errors)
        super().__init__(f"{command!r} → instrument error(s): {listed}")

    @property
    def code(self) -> int:
        return self.errors[0][0]


class ScpiGenerator:
    """A function generator channel.

    transport: a connected :class:`drivers.transport.Transport`. channel: 1 or 2. timeout_s: reply
    timeout per line. check_errors: query ``SYST:ERR?`` after every command (default; turning it off is
    for speed-critical loops only).

    Thread-safe: a command and its error check are one exchange under ``contact.lock``; ``contact``
    (:class:`drivers.heartbeat.ContactRecord`) records the wall time of every reply line and latches a
    closed link, for the shaker's heartbeat.
    """

    def __init__(self, transport: Any, *, channel: int = 1, timeout_s: float = 1.0,
                 check_errors: bool = True) -> None:
        if channel not in (1, 2):
            raise ValueError(f"channel={channel!r}: must be 1 or 2")
        if not (math.isfinite(timeout_s) and timeout_s > 0):
            raise ValueError(f"timeout_s={timeout_s!r}: must be > 0 s")
        self.transport = transport
        self.channel = channel
        self.timeout_s = timeout_s
        self.check_errors = check_errors
        self.source = f"SOUR{channel}"
        self.contact = ContactRecord()
        self.output_node = f"OUTP{channel}"

    # line level ------------------------------------------------------------------------------------------
    def _send(self, message: str) -> None:
        try:
            self.transport.write(message.encode("ascii") + b"\n")
        except OSError as exc:
            if isinstance(exc, TransportClosed):
                self.contact.fail(f"SCPI link closed sending {message!r}: {exc}")
            raise GeneratorError(f"{message!r}: cannot send: {exc}") from exc

    def _readline(self, what: str, timeout_s: float | None = None) -> str:
        timeout = self.timeout_s if timeout_s is None else timeout_s
        try:
            line = self.transport.read_until(b"\n", timeout_s=timeout)
        except OSError as exc:  # TransportError / TransportTimeout derive from OSError
            if isinstance(exc, TransportClosed):
                self.contact.fail(f"SCPI link closed awaiting the reply to {what}: {exc}")
            raise GeneratorError(f"{what}: no reply within {timeout:g} s ({exc})") from exc
        self.contact.touch()
        return line.decode("ascii", errors="replace").rstrip("\r\n")

    def drain_errors(self, command: str = "") -> list[tuple[int, str]]:
        """Read ``SYST:ERR?`` until ``0,"No error"``; return what was queued (oldest first)."""
        errors: list[tuple[int, str]] = []
        for _ in range(MAX_ERROR_READS):
            self._send("SYST:ERR?")
            reply = self._readline(f"SYST:ERR? after {command!r}")
            try:
                code, message = parse_error(reply)
            except ScpiReplyError as exc:
                raise GeneratorError(f"SYST:ERR? after {command!r}: {exc}") from exc
            if code == 0:
                return errors
            errors.append((code, message))
        raise GeneratorError(f"SYST:ERR? after {command!r}: still errors after {MAX_ERROR_READS} reads")

    def _check(self, command: str) -> None:
        if self.check_errors and (errors := self.drain_errors(command)):
            log.error("generator: %r → %s", command, errors)
            raise ScpiError(command, errors)

    def write(self, header: str, *args: float | str) -> None:
        """Send one command, then check the error queue."""
        command = format_command(header, *args)
        with self.contact.exchange():
            self._send(command)
            self._check(command)

    def query(self, header: str) -> str:
        """Send a query, read its reply line, then check the error queue."""
        if not header.endswith("?"):
            raise ValueError(f"header={header!r}: a query ends with '?'")
        command = format_command(header)
        with self.contact.exchange():
            self._send(command)
            try:
                reply = self._readline(command)
            except GeneratorError:
                self._check(command)  # an error in the queue explains the missing reply better
                raise
            self._check(command)
        return reply

    # instrument commands ----------------------------------------------------------------------------------
    def identify(self) -> Identity:
        """``*IDN?`` → manufacturer, model, serial, firmware."""
        reply = self.query("*IDN?")
        try:
            return parse_identity(reply)
        except ScpiReplyError as exc:
            raise GeneratorError(str(exc)) from exc

    def set_remote(self) -> None:
        """``SYST:REM``: older RS-232 instruments (Agilent 33120A/E3632A era) need it before remote
        commands; instruments on USB/LAN accept or ignore it."""
        self.write("SYST:REM")

    def clear_status(self) -> None:
        """``*CLS``: empty the error queue and the status registers."""
        with self.contact.exchange():
            self._send("*CLS")
            self._check("*CLS")

    def wait_complete(self) -> None:
        """``*OPC?``: returns once every pending operation is done."""
        reply = self.query("*OPC?")
        if reply.strip() != "1":
            raise GeneratorError(f"*OPC? answered {reply!r}, expected 1")

    def probe(self, timeout_s: float | None = None) -> None:
        """Heartbeat probe: one ``*OPC?`` exchange under the link lock (no error-queue read, so no error
        meant for the procedure is consumed). Bytes left over from an earlier timed-out exchange are
        discarded first. Raises :class:`GeneratorError` on no reply or a reply other than 1."""
        with self.contact.exchange():
            try:
                stale = self.transport.read_available()
            except OSError as exc:
                if isinstance(exc, TransportClosed):
                    self.contact.fail(f"SCPI link closed: {exc}")
                raise GeneratorError(f"*OPC? (heartbeat): link failed: {exc}") from exc
            if stale:
                log.warning("generator: discarded %d stale byte(s) %r before the heartbeat",
                            len(stale), stale)
            self._send("*OPC?")
            reply = self._readline("*OPC? (heartbeat)", timeout_s)
        if reply.strip() != "1":
            raise GeneratorError(f"*OPC? (heartbeat) answered {reply!r}, expected 1")

    def set_sine(self) -> None:
        self.write(f"{self.source}:FUNC", "SIN")

    def set_load_high_z(self) -> None:
        """``OUTPn:LOAD INF``: the amplifier input is high impedance, so displayed volts = real volts."""
        self.write(f"{self.output_node}:LOAD", "INF")

    def set_frequency_hz(self, frequency_hz: float) -> None:
        self.write(f"{self.source}:FREQ", frequency_hz)

    def frequency_hz(self) -> float:
        return self._number(f"{self.source}:FREQ?")

    def set_amplitude_vpp(self, amplitude_vpp: float) -> None:
        """Amplitude in volts peak-to-peak (the unit is set to VPP first by :meth:`configure_units`)."""
        self.write(f"{self.source}:VOLT", amplitude_vpp)

    def amplitude_vpp(self) -> float:
        return self._number(f"{self.source}:VOLT?")

    def configure_units(self) -> None:
        """Amplitude unit Vpp, offset 0 V."""
        self.write(f"{self.source}:VOLT:UNIT", "VPP")
        self.write(f"{self.source}:VOLT:OFFS", 0)

    def set_output(self, on: bool) -> None:
        self.write(self.output_node, "ON" if on else "OFF")

    def output(self) -> bool:
        reply = self.query(f"{self.output_node}?")
        try:
            return parse_bool(reply)
        except ScpiReplyError as exc:
            raise GeneratorError(str(exc)) from exc

    def configure_sweep(self, start_hz: float, stop_hz: float, time_s: float,
                        spacing: str = "linear") -> None:
        """Sweep range, spacing ("linear" | "log") and time; does not start it."""
        codes = {"linear": "LIN", "log": "LOG"}
        if spacing not in codes:
            raise ValueError(f"spacing={spacing!r}: must be 'linear' or 'log'")
        self.write(f"{self.source}:FREQ:STAR", start_hz)
        self.write(f"{self.source}:FREQ:STOP", stop_hz)
        self.write(f"{self.source}:SWE:SPAC", codes[spacing])
        self.write(f"{self.source}:SWE:TIME", time_s)
        self.write(f"TRIG{self.channel}:SOUR", "IMM")

    def set_sweep(self, on: bool) -> None:
        self.write(f"{self.source}:SWE:STAT", "ON" if on else "OFF")

    def _number(self, header: str) -> float:
        reply = self.query(header)
        try:
            return parse_number(reply)
        except ScpiReplyError as exc:
            raise GeneratorError(f"{header}: {exc}") from exc
