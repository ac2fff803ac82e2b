"""A Modbus master (RTU or TCP) over a :mod:`drivers.transport` link that stays in step with its slaves.

Modbus RTU has no transaction id: a reply that arrives after its request timed out looks like the reply
to the next request. :class:`ModbusLink` therefore

* drains the input before every request (a late reply that already arrived is discarded);
* validates every reply against its request (unit, function code, byte count, address/value echo —
  :func:`drivers.modbus.decode_reply`) and CRC;
* after a timeout, a CRC error or a reply that does not match (out of step), discards everything until
  the line has been silent for t3.5 (3.5 character times at the line's baud rate; in practice at least
  one serial poll, ~20 ms) before the next request; then retries (``retries`` times);
* on TCP, numbers requests (MBAP transaction id) and skips replies with another id; after a timeout, a
  malformed MBAP header or a closed connection it reconnects (a stream cut mid-frame cannot be
  resynchronised);
* :meth:`ModbusLink.execute_until` (for a stop or make-safe command) retries on a **fresh link** (port
  reopened / new TCP connection, then t3.5 silence) until a deadline on the injected clock, and reports
  the number of attempts.

Every write a VFD driver sends is an absolute value, so a repeated request does no harm. A late reply to
a read of the same registers is indistinguishable from the reply to the repeated read on RTU (same
bytes, no id); it is at most one timeout old.

Thread-safe: one exchange at a time under :attr:`ModbusLink.lock` (re-entrant; drives on one RS-485 bus
share the link and so the lock).
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from typing import Protocol

from drivers.modbus import (
    MBAP_BYTES,
    ModbusExceptionReply,
    ReplyMismatch,
    decode_reply,
    mbap_adu,
    parse_mbap,
    read_request,
    rtu_adu,
    rtu_reply_length,
    rtu_silence_s,
    split_rtu,
    write_single_request,
)
from drivers.transport import SerialTransport, Transport, TransportError, TransportTimeout, open_transport

__all__ = ["LinkClock", "ModbusLink", "ModbusLinkError", "WallClock"]

log = logging.getLogger(__name__)

RECONNECT_PAUSE_S = 0.05  # between fresh-link attempts when the port cannot be opened


class LinkClock(Protocol):
    """Time source for deadlines and pauses (seconds)."""

    def monotonic(self) -> float: ...
    def sleep(self, seconds: float) -> None: ...


class WallClock:
    """The real clock (:func:`time.monotonic`, :func:`time.sleep`)."""

    def monotonic(self) -> float:
        return time.monotonic()

    def sleep(self, seconds: float) -> None:
        time.sleep(seconds)


class ModbusLinkError(OSError):
    """No valid reply: time-out, CRC error, out-of-step reply or lost connection, after every attempt.
    ``attempts``: how many requests were sent."""

    def __init__(self, message: str, attempts: int) -> None:
        super().__init__(message)
        self.attempts = attempts


class _OutOfStep(Exception):  # noqa: N818
    """A frame that cannot be the reply (wrong unit, function, CRC, length or MBAP header)."""


class ModbusLink:
    """Modbus master on ``url`` (``tcp://HOST:PORT`` → Modbus TCP; anything else
    :func:`drivers.transport.open_transport` accepts — ``serial:///dev/ttyUSB0?baud=19200``, a pty
    name, ``socket://`` — → Modbus RTU).

    timeout_s: reply timeout of one attempt (s). retries: extra attempts after a failed one (0..5).
    clock: deadlines of :meth:`execute_until` and pauses between fresh-link attempts (default: wall).
    opener: ``(url, timeout_s) -> Transport`` (default :func:`open_transport`). The port is opened at once;
    a failure raises :class:`drivers.transport.TransportError`.
    """

    def __init__(self, url: str, *, timeout_s: float = 1.0, retries: int = 1, clock: LinkClock | None = None,
                 opener: Callable[[str, float], Transport] = open_transport) -> None:
        if not 0 <= retries <= 5:
            raise ValueError(f"retries={retries!r}: must be 0..5")
        if not timeout_s > 0:
            raise ValueError(f"timeout_s={timeout_s!r}: must be > 0 s")
        self.url = url
        self.framing = "tcp" if url.lower().startswith("tcp://") else "rtu"
        self.timeout_s = float(timeout_s)
        self.retries = retries
        self.clock: LinkClock = clock if clock is not None else WallClock()
        self.lock = threading.RLock()
        self._opener = opener
        self._transport: Transport | None = None
        self._out_of_step = False
        self._tid = 0
        self._closed = False
        # counters (for tests and diagnostics)
        self.requests_sent = 0
        self.discarded_bytes = 0
        self.stale_replies = 0
        self.reconnects = 0
        self._transport = self._open()
        # a pyserial URL without a line (socket://, a pty) still gets the t3.5 of its nominal speed
        baud = self._transport.baudrate if isinstance(self._transport, SerialTransport) else 19200
        self.silence_s = rtu_silence_s(baud)

    # connection ------------------------------------------------------------------------------------------
    def _open(self) -> Transport:
        return self._opener(self.url, self.timeout_s)

    def _drop(self) -> None:
        if self._transport is not None:
            self._transport.close()
            self._transport = None

    def _live(self) -> Transport:
        if self._closed:
            raise TransportError(f"{self.url}: Modbus link is closed")
        if self._transport is None:
            self._transport = self._open()
            self.reconnects += 1
            self._out_of_step = self.framing == "rtu"  # a fresh port: wait for silence first
        return self._transport

    def close(self) -> None:
        """Close the port; idempotent."""
        with self.lock:
            self._closed = True
            self._drop()

    @property
    def closed(self) -> bool:
        return self._closed

    # one attempt -----------------------------------------------------------------------------------------
    def _discard(self, transport: Transport) -> None:
        stale = transport.read_available()
        if stale:
            self.discarded_bytes += len(stale)
            log.debug("%s: discarded %d stale byte(s) %s", self.url, len(stale), stale[:32].hex(" "))

    def _wait_silence(self, transport: Transport) -> None:
        """Discard bytes until none arrived for t3.5 (bounded by the reply timeout on a babbling line)."""
        end = time.monotonic() + self.timeout_s
        while time.monotonic() < end:
            self._discard(transport)
            try:
                byte = transport.read_exact(1, timeout_s=self.silence_s)
            except TransportTimeout:
                break
            self.discarded_bytes += len(byte)
        self._out_of_step = False

    def _attempt_rtu(self, transport: Transport, unit: int, pdu: bytes) -> bytes:
        if self._out_of_step:
            self._wait_silence(transport)
        self._discard(transport)
        transport.write(rtu_adu(unit, pdu))
        self.requests_sent += 1
        deadline = time.monotonic() + self.timeout_s

        def read(n: int) -> bytes:
            return transport.read_exact(n, timeout_s=max(deadline - time.monotonic(), 1e-3))

        head = read(3)
        if head[0] != unit:
            raise _OutOfStep(f"reply from unit {head[0]}, asked unit {unit}")
        length = rtu_reply_length(pdu[0], head)
        if length is None:
            raise _OutOfStep(f"function code 0x{head[1]:02X} in reply to 0x{pdu[0]:02X}")
        if pdu[0] == 0x03 and head[1] == 0x03 and head[2] != 2 * int.from_bytes(pdu[3:5], "big"):
            raise _OutOfStep(f"byte count {head[2]} in reply to a read of {int.from_bytes(pdu[3:5], 'big')}")
        frame = head + read(length - 3)
        parts = split_rtu(frame)
        if parts is None:
            raise _OutOfStep(f"CRC error in {frame.hex(' ')}")
        return parts[1]

    def _attempt_tcp(self, transport: Transport, unit: int, pdu: bytes) -> bytes:
        self._discard(transport)
        self._tid = self._tid % 0xFFFF + 1
        transport.write(mbap_adu(self._tid, unit, pdu))
        self.requests_sent += 1
        deadline = time.monotonic() + self.timeout_s
        while True:
            header = transport.read_exact(MBAP_BYTES, timeout_s=max(deadline - time.monotonic(), 1e-3))
            tid, protocol, length, reply_unit = parse_mbap(header)
            if protocol != 0 or not 2 <= length <= 254:
                raise _OutOfStep(f"malformed MBAP header {header.hex(' ')}")
            body = transport.read_exact(length - 1, timeout_s=max(deadline - time.monotonic(), 1e-3))
            if tid != self._tid:
                self.stale_replies += 1
                continue
            if reply_unit != unit:
                raise _OutOfStep(f"reply from unit {reply_unit}, asked unit {unit}")
            return body

    def _attempt(self, unit: int, pdu: bytes) -> list[int]:
        transport = self._live()
        try:
            reply = (self._attempt_tcp if self.framing == "tcp" else self._attempt_rtu)(transport, unit, pdu)
            return decode_reply(pdu, reply)
        except ReplyMismatch as exc:
            raise _OutOfStep(str(exc)) from exc

    def _after_failure(self, exc: BaseException) -> None:
        if isinstance(exc, _OutOfStep):
            self.stale_replies += 1
        if self.framing == "tcp":
            self._drop()  # a TCP stream cut mid-frame cannot be resynchronised: reconnect
        elif isinstance(exc, TransportError) and not isinstance(exc, TransportTimeout):
            self._drop()  # closed or broken: reconnect on the next attempt
        else:
            self._out_of_step = True  # RTU: a late reply may still come; wait for silence first

    # public ----------------------------------------------------------------------------------------------
    def execute(self, unit: int, pdu: bytes) -> list[int]:
        """Send request ``pdu`` to ``unit`` and return the registers read ([] for a write), with up to
        ``retries`` repetitions. Raises :class:`drivers.modbus.ModbusExceptionReply` when the slave
        refuses, :class:`ModbusLinkError` when no valid reply came."""
        with self.lock:
            last: BaseException | None = None
            for attempt in range(1, self.retries + 2):
                try:
                    return self._attempt(unit, pdu)
                except ModbusExceptionReply:
                    raise
                except (TransportError, _OutOfStep) as exc:
                    last = exc
                    self._after_failure(exc)
                    log.warning("%s: unit %d attempt %d failed: %s", self.url, unit, attempt, exc)
            raise ModbusLinkError(f"no valid reply after {self.retries + 1} attempt(s): "
                                  f"{type(last).__name__.lstrip('_')}: {last}", self.retries + 1)

    def execute_until(self, unit: int, pdu: bytes, deadline_s: float, *,
                      retry_exception_codes: tuple[int, ...] = (5, 6)) -> int:
        """Repeat ``pdu`` until it is acknowledged or ``deadline_s`` (s, on :attr:`clock`) has passed,
        on a fresh link (reopened port or connection, t3.5 silence) after every failure; exception
        replies in ``retry_exception_codes`` (acknowledge, busy) are retried too. Returns the number of
        attempts; raises :class:`ModbusLinkError` (or the exception reply) naming them."""
        with self.lock:
            end = self.clock.monotonic() + deadline_s
            attempts = 0
            while True:
                attempts += 1
                try:
                    self._attempt(unit, pdu)
                    return attempts
                except ModbusExceptionReply as exc:
                    if exc.exception_code not in retry_exception_codes or self.clock.monotonic() >= end:
                        raise
                    last: BaseException = exc
                except (TransportError, _OutOfStep) as exc:
                    last = exc
                    self.stale_replies += isinstance(exc, _OutOfStep)
                    self._drop()  # fresh link for the next attempt
                log.warning("%s: unit %d: attempt %d not acknowledged: %s", self.url, unit, attempts, last)
                if self._closed:  # closed by its owner: no fresh link will be opened (was a busy loop)
                    raise ModbusLinkError(f"not acknowledged: the link was closed after {attempts} "
                                          f"attempt(s): {type(last).__name__.lstrip('_')}: {last}", attempts)
                if self.clock.monotonic() >= end:
                    raise ModbusLinkError(
                        f"not acknowledged after {attempts} attempt(s) within {deadline_s:g} s on fresh "
                        f"links: {type(last).__name__.lstrip('_')}: {last}", attempts)
                if self._transport is None and not self._closed:
                    try:
                        self._live()
                    except TransportError as exc:
                        log.warning("%s: cannot reopen: %s", self.url, exc)
                        self.clock.sleep(RECONNECT_PAUSE_S)

    def read_holding_registers(self, unit: int, address: int, count: int) -> list[int]:
        return self.execute(unit, read_request(address, count))

    def write_register(self, unit: int, address: int, value: int) -> None:
        self.execute(unit, write_single_request(address, value))

    def __repr__(self) -> str:
        return f"ModbusLink({self.url!r}, {self.framing})"
