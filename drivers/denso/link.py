"""One b-CAP request/reply exchange over a transport (``../shared/notes/bcap.md`` §2, §10, §16).

:class:`BcapLink` numbers requests (1..65535, wrapping to 1), writes each packet in one write, and waits
for the reply with the same serial: replies with other serials are discarded, and each S_EXECUTING
keep-alive is skipped and restarts the receive timeout. TCP never re-sends. On a serial line or UDP
a call may be attempted ``retries`` times (1..7): every attempt gets a new serial and carries the first
attempt's serial in the reserved field, so the controller answers a duplicate from its cache instead of
executing twice.

Recovery (a link out of step — a late reply, a duplicated reply, the reply to an earlier request, lost
bytes): replies with another serial are discarded; after a timeout the input is **drained** (every byte
already received or arriving before ``drain_quiet_s`` of silence is discarded and the decoder starts
afresh), so the next call does not read the stale bytes. An idempotent call (a read, a halt) may be
attempted again on TCP too, as a new request (``idempotent=True``: :data:`IDEMPOTENT_TCP_ATTEMPTS`).
:meth:`BcapLink.reconnect` replaces the transport by a fresh one (``reopen``; by default the same address).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Sequence

from drivers.denso.bcap import (
    SERIAL_MAX_PACKET,
    TCP_MAX_PACKET,
    Packet,
    PacketDecoder,
    encode_packet,
    function_name,
    next_serial,
)
from drivers.denso.hresult import (
    BcapConnectionError,
    BcapError,
    BcapTimeoutError,
    is_failure,
)
from drivers.denso.variant import Variant
from drivers.heartbeat import ContactRecord
from drivers.transport import (
    Transport,
    TransportClosed,
    TransportError,
    TransportTimeout,
    open_transport,
)

log = logging.getLogger(__name__)

MAX_ATTEMPTS = 7
IDEMPOTENT_TCP_ATTEMPTS = 2  # a read or a halt is asked again once on TCP (a new request, never a re-send)
DRAIN_LIMIT_BYTES = 1 << 20  # a line that never falls silent is not drained for ever


class BcapLink:
    """Request/reply engine. Thread-safe: one call at a time (``contact.lock``).

    ``contact`` (:class:`drivers.heartbeat.ContactRecord`) records the wall time of every packet received
    — replies, keep-alives, even discarded replies prove the controller alive — and latches a closed or
    broken link; the arm's heartbeat reads it without touching the line.

    Args:
        transport: an open :class:`drivers.transport.Transport`.
        serial_line: True on RS-232C (CRC framing, 503-byte cap, retries allowed).
        datagram: True on UDP (503-byte cap, retries allowed, no CRC).
        retries: attempts per call on a serial line, 1..7 (TCP always makes exactly one).
        timeout_s: receive timeout per attempt, restarted by each keep-alive; must exceed the WDT.
        invoke_timeout_s: cap on one call's total duration even while keep-alives arrive.
        drain_quiet_s: silence (s) that ends the drain after a timeout.
        reopen: opens a fresh transport for :meth:`reconnect` (default: ``open_transport`` of the
            transport's ``url`` with ``timeout_s``; a serial line's ``url`` is only its device, so pass the
            configured address there to keep its line settings).
    """

    def __init__(self, transport: Transport, *, serial_line: bool = False, datagram: bool = False,
                 retries: int = 3, timeout_s: float = 3.0, invoke_timeout_s: float = 180.0,
                 drain_quiet_s: float = 0.05, reopen: Callable[[], Transport] | None = None) -> None:
        if not 1 <= retries <= MAX_ATTEMPTS:
            raise ValueError(f"retries={retries}: must be 1..{MAX_ATTEMPTS} attempts")
        if not timeout_s > 0:
            raise ValueError(f"timeout_s={timeout_s}: must be > 0 seconds")
        if not invoke_timeout_s >= timeout_s:
            raise ValueError(f"invoke_timeout_s={invoke_timeout_s}: must be >= timeout_s={timeout_s}")
        self.transport = transport
        self.serial_line = serial_line
        self.datagram = datagram
        self.may_retry = serial_line or datagram
        self.attempts = retries if self.may_retry else 1
        self.timeout_s = float(timeout_s)
        self.invoke_timeout_s = float(invoke_timeout_s)
        self.max_length = SERIAL_MAX_PACKET if self.may_retry else TCP_MAX_PACKET
        self._decoder = PacketDecoder(serial_line=serial_line, max_length=self.max_length)
        self._serial = 0
        self.contact = ContactRecord()
        self._lock = self.contact.lock
        self.keepalives_seen = 0
        self.discarded_replies = 0
        self.drained_bytes = 0
        self.reconnects = 0
        self.drain_quiet_s = float(drain_quiet_s)
        self._reopen = reopen or (lambda: open_transport(transport.url, self.timeout_s))

    def drain(self) -> int:
        """Discard what is buffered and what arrives until ``drain_quiet_s`` of silence; return the count.
        A closed transport drains nothing."""
        dropped = self._decoder.buffered
        self._decoder = PacketDecoder(serial_line=self.serial_line, max_length=self.max_length)
        while dropped < DRAIN_LIMIT_BYTES:
            try:
                dropped += len(self.transport.read_exact(1, self.drain_quiet_s))
                dropped += len(self.transport.read_available())
            except TransportError:  # silence (timeout), or the link is gone: nothing more to drain
                break
        if dropped:
            log.info("%s: drained %d stale bytes", self.transport.url, dropped)
        self.drained_bytes += dropped
        return dropped

    def reconnect(self) -> None:
        """Close the transport and open a fresh one (same serial numbering; the caller starts a new
        b-CAP session on it). Raises ``TransportError`` when the controller cannot be reached."""
        with self._lock:
            try:
                self.transport.close()
            except OSError as exc:
                log.warning("closing the old b-CAP transport: %s", exc)
            self.transport = self._reopen()
            self._decoder = PacketDecoder(serial_line=self.serial_line, max_length=self.max_length)
            self.reconnects += 1

    @property
    def last_serial(self) -> int:
        return self._serial

    def call(self, function_id: int, args: Sequence[object] = (), *, timeout_s: float | None = None,
             attempts: int | None = None, idempotent: bool = False) -> list[Variant]:
        """Send one request and return the reply's arguments; a failure HRESULT raises :class:`BcapError`.
        ``attempts`` (1..``retries``) caps the attempts of this call (the heartbeat probe makes one);
        ``idempotent`` lets a read or a halt be asked again on TCP after a timeout and a drain."""
        name = function_name(function_id)
        timeout = self.timeout_s if timeout_s is None else float(timeout_s)
        allowed = max(self.attempts, IDEMPOTENT_TCP_ATTEMPTS) if idempotent else self.attempts
        n_attempts = allowed if attempts is None else max(1, min(int(attempts), allowed))
        with self.contact.exchange():
            sent: set[int] = set()
            first = 0
            for attempt in range(n_attempts):
                self._serial = next_serial(self._serial)
                serial = self._serial
                first = first or serial
                reserved = first if self.may_retry else 0  # TCP: each attempt is a new request
                packet = encode_packet(serial, reserved, function_id, args, serial_line=self.serial_line,
                                       max_length=self.max_length)
                sent.add(serial)
                try:
                    self.transport.write(packet)
                    reply = self._await(sent, timeout, name)
                except TransportTimeout:
                    log.warning("%s: no reply to serial %d (attempt %d of %d)", name, serial, attempt + 1,
                                n_attempts)
                    self.drain()
                    if not self.may_retry:
                        sent.clear()  # TCP: a late reply to the abandoned request is stale, not an answer
                    continue
                except TransportError as exc:
                    kind = "closed" if isinstance(exc, TransportClosed) else "failed"
                    self.contact.fail(f"b-CAP link {kind} during {name}: {exc}")
                    raise BcapConnectionError(f"link {kind} during the call: {exc}", function=name) from exc
                if is_failure(reply.code):
                    raise BcapError(reply.code, function=name)
                return list(reply.args)
            raise BcapTimeoutError(
                f"no reply within {timeout:g} s after {n_attempts} attempt(s)", function=name)

    def _await(self, serials: set[int], timeout_s: float, name: str) -> Packet:
        """Read packets until the reply to one of ``serials``; keep-alives restart the timeout."""
        call_deadline = time.monotonic() + self.invoke_timeout_s
        deadline = time.monotonic() + timeout_s
        while True:
            packet = self._decoder.next_packet()
            if packet is None:
                remaining = min(deadline, call_deadline) - time.monotonic()
                if remaining <= 0:
                    if time.monotonic() >= call_deadline:
                        raise BcapTimeoutError(f"call still executing after {self.invoke_timeout_s:g} s",
                                               function=name)
                    raise TransportTimeout(f"{self.transport.url}: no reply within {timeout_s:g} s")
                self._decoder.feed(self.transport.read_exact(1, remaining))
                self._decoder.feed(self.transport.read_available())
                continue
            self.contact.touch()
            if packet.serial not in serials:
                self.discarded_replies += 1
                log.debug("%s: discarded a reply with serial %d", name, packet.serial)
                continue
            if packet.is_keepalive:
                self.keepalives_seen += 1
                deadline = time.monotonic() + timeout_s
                continue
            return packet
