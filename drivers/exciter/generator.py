"""SCPI function generator (Keysight 33500-style command set, channel 1..2) over a byte transport.

The driver receives a :class:`drivers.transport.Transport` (serial line, ``socket://``, TCP) and never
opens a port itself (a ``reopen`` callable may give it a fresh one). Every command is followed by
``SYST:ERR?``, read until ``+0,"No error"``; any error found raises :class:`ScpiError` carrying every
queued error and the command that provoked it. Queries are checked the same way after their reply is read.

A text line has no transaction id, so a late reply would be taken for the next one. A timeout, a reply
that does not parse as what was asked, or bytes waiting before a request mark the link out of step: the
driver drains it, resynchronises on a marker query and repeats the exchange (:meth:`ScpiGenerator.
resynchronise`); a closed link is replaced. :meth:`ScpiGenerator.output_off` (make safe) goes on, on
fresh links, until its deadline and reports what it achieved.

Only the generator is here; what the volts do to a shaker (displacement sensitivity, limits, safe
ramping) is :mod:`drivers.exciter.shaker`.
"""

from __future__ import annotations

import contextlib
import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import TypeVar

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
from drivers.transport import Transport, TransportClosed

T = TypeVar("T")

__all__ = ["GeneratorError", "LinkError", "SafeOffOutcome", "ScpiError", "ScpiGenerator", "SweepSettings"]

log = logging.getLogger(__name__)

MAX_ERROR_READS = 32  # a 20-deep queue plus margin: more means the instrument never says "No error"
MAX_RESYNC_LINES = 64  # stale lines skipped while waiting for the resynchronisation token
SAFE_OFF_PAUSE_S = 0.05  # between make-safe rounds on fresh links (wall seconds)


class GeneratorError(RuntimeError):
    """Base of the generator driver's errors (communication and protocol)."""


class LinkError(GeneratorError):
    """The link failed or lost step: no reply in time, a reply that does not fit the request (a late
    answer to an earlier one, a truncated line), or a closed link."""


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


@dataclass(frozen=True)
class SweepSettings:
    """A generator sweep as configured: start/stop (Hz), time (s), spacing "linear" | "log"."""

    start_hz: float
    stop_hz: float
    time_s: float
    spacing: str


@dataclass(frozen=True)
class SafeOffOutcome:
    """What :meth:`ScpiGenerator.output_off` achieved: ``output_off`` is True only when ``OUTPn?`` read
    OFF; ``attempts`` rounds, ``reconnects`` fresh links opened, ``errors`` met on the way."""

    output_off: bool
    attempts: int
    reconnects: int
    errors: tuple[str, ...]

    def describe(self) -> str:
        state = "output OFF confirmed" if self.output_off else "output OFF NOT confirmed"
        detail = f" (last error: {self.errors[-1]})" if self.errors else ""
        return f"{state} after {self.attempts} attempt(s), {self.reconnects} reconnect(s){detail}"


# output channels of the models whose count we know (Keysight 33500 series); others: trust the configuration
KNOWN_CHANNELS = {"33511B": 1, "33521A": 1, "33521B": 1, "33512B": 2, "33522A": 2, "33522B": 2}


class ScpiGenerator:
    """A function generator channel.

    transport: a connected :class:`drivers.transport.Transport`. channel: 1 or 2. timeout_s: reply
    timeout per line. check_errors: query ``SYST:ERR?`` after every command (default; turning it off is
    for speed-critical loops only). reopen: makes a fresh transport to the same instrument (used after a
    closed link and by :meth:`output_off`); None: no reconnection. retries: further attempts of an
    exchange after a link error, each after :meth:`resynchronise` (commands are absolute settings, so
    repeating one is harmless). settle_s: the silence that ends a drain.

    Thread-safe: a command and its error check are one exchange under ``contact.lock``; ``contact``
    (:class:`drivers.heartbeat.ContactRecord`) records the wall time of every reply line and latches a
    closed link, for the shaker's heartbeat.
    """

    def __init__(self, transport: Transport, *, channel: int = 1, timeout_s: float = 1.0,
                 check_errors: bool = True, reopen: Callable[[], Transport] | None = None,
                 retries: int = 1, settle_s: float = 0.05) -> None:
        if channel not in (1, 2):
            raise ValueError(f"channel={channel!r}: must be 1 or 2")
        if not (math.isfinite(timeout_s) and timeout_s > 0):
            raise ValueError(f"timeout_s={timeout_s!r}: must be > 0 s")
        if retries < 0:
            raise ValueError(f"retries={retries!r}: must be >= 0")
        if not (math.isfinite(settle_s) and settle_s > 0):
            raise ValueError(f"settle_s={settle_s!r}: must be > 0 s")
        self.transport = transport
        self.channel = channel
        self.timeout_s = timeout_s
        self.check_errors = check_errors
        self.reopen = reopen
        self.retries = retries
        self.settle_s = settle_s
        self.source = f"SOUR{channel}"
        self.contact = ContactRecord()
        self.output_node = f"OUTP{channel}"
        self.resyncs = 0
        self._token = 0
        self._link_closed = False  # the transport reported itself closed: only a fresh link helps

    # line level ------------------------------------------------------------------------------------------
    def _send(self, message: str) -> None:
        try:
            self.transport.write(message.encode("ascii") + b"\n")
        except OSError as exc:
            if isinstance(exc, TransportClosed):
                self._closed_link(f"SCPI link closed sending {message!r}: {exc}")
            raise LinkError(f"{message!r}: cannot send: {exc}") from exc

    def _readline(self, what: str, timeout_s: float | None = None) -> str:
        timeout = self.timeout_s if timeout_s is None else timeout_s
        try:
            line = self.transport.read_until(b"\n", timeout_s=timeout)
        except OSError as exc:  # TransportError / TransportTimeout derive from OSError
            if isinstance(exc, TransportClosed):
                self._closed_link(f"SCPI link closed awaiting the reply to {what}: {exc}")
            raise LinkError(f"{what}: no reply within {timeout:g} s ({exc})") from exc
        self.contact.touch()
        return line.decode("ascii", errors="replace").rstrip("\r\n")

    def _stale(self) -> bytes:
        """Bytes already waiting before a request (a late reply): the link is out of step if any."""
        try:
            return self.transport.read_available()
        except OSError as exc:
            if isinstance(exc, TransportClosed):
                self._closed_link(f"SCPI link closed: {exc}")
            raise LinkError(f"link failed: {exc}") from exc

    def _closed_link(self, reason: str) -> None:
        self._link_closed = True
        self.contact.fail(reason)

    def drain_errors(self, command: str = "") -> list[tuple[int, str]]:
        """Read ``SYST:ERR?`` until ``0,"No error"``; return what was queued (oldest first). A reply that
        is not an error entry means the link is out of step (:class:`LinkError`)."""
        errors: list[tuple[int, str]] = []
        for _ in range(MAX_ERROR_READS):
            self._send("SYST:ERR?")
            reply = self._readline(f"SYST:ERR? after {command!r}")
            try:
                code, message = parse_error(reply)
            except ScpiReplyError as exc:
                raise LinkError(f"SYST:ERR? after {command!r}: out of step: {exc}") from exc
            if code == 0:
                return errors
            errors.append((code, message))
        raise GeneratorError(f"SYST:ERR? after {command!r}: still errors after {MAX_ERROR_READS} reads")

    def _check(self, command: str) -> None:
        if self.check_errors and (errors := self.drain_errors(command)):
            log.error("generator: %r → %s", command, errors)
            raise ScpiError(command, errors)

    # link recovery ---------------------------------------------------------------------------------------
    def _drain_until_silent(self) -> int:
        """Discard input until ``settle_s`` passes without a byte (at most 2 × ``timeout_s``); returns the
        number of bytes discarded."""
        t_end = time.monotonic() + 2.0 * self.timeout_s
        discarded, quiet_since = 0, time.monotonic()
        while time.monotonic() - quiet_since < self.settle_s:
            if time.monotonic() > t_end:
                raise LinkError(f"input never fell silent for {self.settle_s:g} s within "
                                f"{2.0 * self.timeout_s:g} s ({discarded} bytes discarded)")
            if data := self._stale():
                discarded += len(data)
                quiet_since = time.monotonic()
            time.sleep(self.settle_s / 5.0)
        return discarded

    def resynchronise(self) -> None:
        """Bring the link back in step: drain the input until it falls silent, then send a marker query
        (``*ESE k;*ESE?;*ESE 0`` with a fresh k in 1..255; IEEE 488.2 mandatory, the driver uses no
        service requests) and skip every line until the one that answers k. Raises :class:`LinkError`."""
        with self.contact.exchange():
            discarded = self._drain_until_silent()
            self._token = self._token % 255 + 1
            token = str(self._token)
            self._send(f"*ESE {token};*ESE?;*ESE 0")
            t_end = time.monotonic() + self.timeout_s
            for _ in range(MAX_RESYNC_LINES):
                remaining = t_end - time.monotonic()
                if remaining <= 0:
                    break
                line = self._readline("*ESE? (resynchronisation)", remaining)
                if line.strip().lstrip("+") == token:
                    self.resyncs += 1
                    log.warning("generator: link resynchronised (%d stale byte(s) discarded)", discarded)
                    return
            raise LinkError(f"resynchronisation: no reply {token} to *ESE? within {self.timeout_s:g} s")

    def reconnect(self) -> None:
        """Close the transport and open a fresh one with ``reopen``, then resynchronise."""
        with self.contact.exchange():
            self._fresh_link()
            self.resynchronise()

    def close(self) -> None:
        """Close the current transport (idempotent)."""
        with contextlib.suppress(OSError):
            self.transport.close()

    def _fresh_link(self) -> None:
        if self.reopen is None:
            raise LinkError("no fresh link: the generator was built without reopen")
        with contextlib.suppress(OSError):
            self.transport.close()
        try:
            self.transport = self.reopen()
        except OSError as exc:
            raise LinkError(f"cannot open a fresh link: {exc}") from exc
        self._link_closed = False

    def _recover(self) -> None:
        if self._link_closed:
            self.reconnect()
            return
        try:
            self.resynchronise()
        except LinkError:
            if self.reopen is None:
                raise
            self.reconnect()

    def _attempt(self, command: str, parse: Callable[[str], T] | None) -> T | None:
        if stale := self._stale():
            log.warning("generator: %d stale byte(s) %r before %r", len(stale), stale[:80], command)
            self.resynchronise()
        self._send(command)
        if parse is None:
            self._check(command)
            return None
        try:
            reply = self._readline(command)
        except LinkError:
            self._check(command)  # an error in the queue explains the missing reply better
            raise
        try:
            value = parse(reply)
        except ScpiReplyError as exc:
            raise LinkError(f"{command}: out of step: {exc}") from exc
        self._check(command)
        return value

    def _transact(self, command: str, parse: Callable[[str], T] | None,
                  retries: int | None = None) -> T | None:
        """One exchange with up to ``retries`` (default :attr:`retries`) further attempts, each after
        recovering the link."""
        last = self.retries if retries is None else retries
        with self.contact.exchange():
            for attempt in range(last + 1):
                try:
                    return self._attempt(command, parse)
                except LinkError as exc:
                    if attempt == last:
                        raise
                    log.warning("generator: %s; recovering the link and retrying %r", exc, command)
                    try:
                        self._recover()
                    except LinkError as recover_exc:
                        raise LinkError(f"{exc}; recovery failed: {recover_exc}") from recover_exc
        raise AssertionError("unreachable")

    def write(self, header: str, *args: float | str) -> None:
        """Send one command, then check the error queue."""
        self._transact(format_command(header, *args), None)

    def query(self, header: str) -> str:
        """Send a query, read its reply line, then check the error queue."""
        if not header.endswith("?"):
            raise ValueError(f"header={header!r}: a query ends with '?'")
        reply = self._transact(format_command(header), str)
        assert reply is not None
        return reply

    def _ask(self, header: str, parse: Callable[[str], T]) -> T:
        """A query whose reply must parse (a reply that does not is an out-of-step link: recovered)."""
        if not header.endswith("?"):
            raise ValueError(f"header={header!r}: a query ends with '?'")
        value = self._transact(format_command(header), parse)
        assert value is not None
        return value

    # instrument commands ----------------------------------------------------------------------------------
    def identify(self) -> Identity:
        """``*IDN?`` → manufacturer, model, serial, firmware."""
        return self._ask("*IDN?", parse_identity)

    def set_remote(self) -> None:
        """``SYST:REM``: older RS-232 instruments (Agilent 33120A/E3632A era) need it before remote
        commands; instruments on USB/LAN accept or ignore it."""
        self.write("SYST:REM")

    def clear_status(self) -> None:
        """``*CLS``: empty the error queue and the status registers."""
        self.write("*CLS")

    def wait_complete(self) -> None:
        """``*OPC?``: returns once every pending operation is done."""
        self._ask("*OPC?", _parse_one)

    def probe(self, timeout_s: float | None = None) -> None:
        """Heartbeat probe: one ``*OPC?`` exchange under the link lock (no error-queue read, so no error
        meant for the procedure is consumed). Bytes left over from an earlier timed-out exchange mean the
        link is out of step: it is resynchronised instead. Raises :class:`LinkError` on no reply or a
        reply other than 1."""
        with self.contact.exchange():
            if self._stale():
                self.resynchronise()
                return
            self._send("*OPC?")
            reply = self._readline("*OPC? (heartbeat)", timeout_s)
        if reply.strip() != "1":
            raise LinkError(f"*OPC? (heartbeat) answered {reply!r}, expected 1")

    def set_sine(self) -> None:
        self.write(f"{self.source}:FUNC", "SIN")

    def set_load_high_z(self) -> None:
        """``OUTPn:LOAD INF``: the amplifier input is high impedance, so displayed volts = real volts."""
        self.write(f"{self.output_node}:LOAD", "INF")

    def _source_of(self, channel: int | None) -> str:
        """``SOURn`` of ``channel`` (None: this driver's channel); ValueError outside 1..2."""
        if channel is None:
            return self.source
        if channel not in (1, 2):
            raise ValueError(f"channel={channel!r}: must be 1 or 2")
        return f"SOUR{channel}"

    def set_frequency_hz(self, frequency_hz: float, *, channel: int | None = None) -> None:
        """``SOURn:FREQ``; ``channel`` another channel of the instrument (e.g. a fiducial's)."""
        self.write(f"{self._source_of(channel)}:FREQ", frequency_hz)

    def frequency_hz(self, *, channel: int | None = None) -> float:
        return self._ask(f"{self._source_of(channel)}:FREQ?", parse_number)

    def set_amplitude_vpp(self, amplitude_vpp: float) -> None:
        """Amplitude in volts peak-to-peak (the unit is set to VPP first by :meth:`configure_units`)."""
        self.write(f"{self.source}:VOLT", amplitude_vpp)

    def amplitude_vpp(self) -> float:
        return self._ask(f"{self.source}:VOLT?", parse_number)

    def configure_units(self) -> None:
        """Amplitude unit Vpp, offset 0 V."""
        self.write(f"{self.source}:VOLT:UNIT", "VPP")
        self.write(f"{self.source}:VOLT:OFFS", 0)

    def set_output(self, on: bool) -> None:
        self.write(self.output_node, "ON" if on else "OFF")

    def output(self, *, channel: int | None = None) -> bool:
        node = self.output_node if channel is None else "OUTP" + self._source_of(channel)[4:]
        return self._ask(f"{node}?", parse_bool)

    def configure_sweep(self, start_hz: float, stop_hz: float, time_s: float,
                        spacing: str = "linear") -> None:
        """Sweep range, spacing ("linear" | "log") and time; does not start it."""
        if spacing not in _SPACING_CODES:
            raise ValueError(f"spacing={spacing!r}: must be 'linear' or 'log'")
        self.write(f"{self.source}:FREQ:STAR", start_hz)
        self.write(f"{self.source}:FREQ:STOP", stop_hz)
        self.write(f"{self.source}:SWE:SPAC", _SPACING_CODES[spacing])
        self.write(f"{self.source}:SWE:TIME", time_s)
        self.write(f"TRIG{self.channel}:SOUR", "IMM")

    def set_sync(self, on: bool) -> None:
        """``OUTPn:SYNC ON|OFF``: the Sync connector (it drives a timing fiducial LED when one is wired)."""
        self.write(f"{self.output_node}:SYNC", "ON" if on else "OFF")

    def set_sync_source(self, channel: int) -> None:
        """``OUTP:SYNC:SOUR CHn``: the channel the (one) Sync connector follows — two-channel models only
        (a one-channel instrument answers −113, raised as :class:`ScpiError`)."""
        self.write("OUTP:SYNC:SOUR", "CH" + self._source_of(channel)[4:])

    def sync_source(self) -> int:
        """``OUTP:SYNC:SOUR?`` → 1 or 2."""
        return self._ask("OUTP:SYNC:SOUR?", lambda r: int(r.strip().upper().removeprefix("CH")))

    def sync_enabled(self) -> bool:
        """``OUTPn:SYNC?``."""
        return self._ask(f"{self.output_node}:SYNC?", parse_bool)

    def synchronize_phase(self) -> None:
        """``SOURn:PHAS:SYNC``: the waveform (and its sync edges) restarts at phase 0 when executed."""
        self.write(f"{self.source}:PHAS:SYNC")

    def synchronize_phase_bracketed(self, now_s: Callable[[], float]) -> tuple[float, float]:
        """``SOURn:PHAS:SYNC;*OPC?`` in one message: the restart happens between ``now_s()`` read just before
        the exchange and ``now_s()`` read as its reply arrives — one round trip, the error queue read after
        it. Returns (t_sent_s, t_confirmed_s) on that clock."""
        confirmed: list[float] = []

        def stamp(reply: str) -> bool:
            confirmed.append(now_s())
            return _parse_one(reply)

        t_sent = now_s()
        self._transact(f"{self.source}:PHAS:SYNC;*OPC?", stamp)
        return t_sent, confirmed[-1]

    def set_sweep(self, on: bool) -> None:
        self.write(f"{self.source}:SWE:STAT", "ON" if on else "OFF")

    def sweep_enabled(self) -> bool:
        """``SOURn:SWE:STAT?``."""
        return self._ask(f"{self.source}:SWE:STAT?", parse_bool)

    def sweep_settings(self) -> SweepSettings:
        """The configured sweep (start, stop, time, spacing), read back from the instrument."""
        return SweepSettings(self._ask(f"{self.source}:FREQ:STAR?", parse_number),
                             self._ask(f"{self.source}:FREQ:STOP?", parse_number),
                             self._ask(f"{self.source}:SWE:TIME?", parse_number),
                             self._ask(f"{self.source}:SWE:SPAC?", _parse_spacing))

    def output_off(self, *, min_amplitude_vpp: float | None = None,
                   deadline_s: float = 5.0) -> SafeOffOutcome:
        """Make safe: amplitude to ``min_amplitude_vpp`` (if given), output OFF, and ``OUTPn?`` read back
        OFF. A round that fails is repeated on a fresh link (``reopen``) until ``deadline_s`` wall seconds
        have passed; never raises a link error: the outcome says what was achieved."""
        t_end = time.monotonic() + deadline_s
        attempts = reconnects = 0
        errors: list[str] = []
        while True:
            attempts += 1
            try:
                if self._output_off_round(min_amplitude_vpp, errors):
                    return SafeOffOutcome(True, attempts, reconnects, tuple(errors))
            except GeneratorError as exc:
                errors.append(str(exc))
            remaining = t_end - time.monotonic()
            if remaining <= 0:
                outcome = SafeOffOutcome(False, attempts, reconnects, tuple(errors))
                log.error("generator: make safe failed: %s", outcome.describe())
                return outcome
            # a pause between rounds: an instrument that takes each connection and drops it at once
            # was otherwise reconnected thousands of times a second (10341 times in a 3 s deadline)
            time.sleep(min(SAFE_OFF_PAUSE_S, remaining))
            try:
                if self.reopen is None:
                    self.resynchronise()
                else:
                    self._fresh_link()
                    reconnects += 1
            except GeneratorError as exc:
                errors.append(f"reconnect: {exc}")
                time.sleep(min(0.1, max(t_end - time.monotonic(), 0.0)))

    def _output_off_round(self, min_amplitude_vpp: float | None, errors: list[str]) -> bool:
        """One make-safe round without link recovery (the caller's loop recovers): a failed amplitude
        step never keeps ``OUTPn OFF`` from being sent."""
        with self.contact.exchange():
            if min_amplitude_vpp is not None:
                try:
                    self._transact(format_command(f"{self.source}:VOLT", min_amplitude_vpp), None, retries=0)
                except GeneratorError as exc:
                    errors.append(str(exc))
            self._transact(format_command(self.output_node, "OFF"), None, retries=0)
            if self._transact(format_command(f"{self.output_node}?"), parse_bool, retries=0):
                errors.append(f"{self.output_node}? still reads ON after {self.output_node} OFF")
                return False
            return True


_SPACING_CODES = {"linear": "LIN", "log": "LOG"}


def _parse_spacing(reply: str) -> str:
    """``LIN``/``LINEAR``/``LOG``/``LOGARITHMIC`` → "linear" | "log"."""
    code = reply.strip().upper()[:3]
    for name, short in _SPACING_CODES.items():
        if code == short:
            return name
    raise ScpiReplyError(f"reply {reply!r}: not a sweep spacing (LIN/LOG)")


def _parse_one(reply: str) -> bool:
    """The ``*OPC?`` reply: exactly 1."""
    if reply.strip() != "1":
        raise ScpiReplyError(f"reply {reply!r}: *OPC? must answer 1")
    return True
