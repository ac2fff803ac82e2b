"""Byte-stream transports shared by every byte-oriented driver (b-CAP, SCPI, ...).

A driver receives a :class:`Transport`; it never opens a port itself. :func:`open_transport` builds one
from a configuration address:

==========================================  ==========================================================
``tcp://HOST:PORT``                         TCP socket (:class:`TcpTransport`)
``udp://HOST:PORT``                         UDP datagrams (:class:`UdpTransport`)
``serial:///dev/ttyUSB0?baud=115200``       serial line through pyserial (:class:`SerialTransport`);
                                            query keys ``baud``, ``bytesize`` (5..8), ``parity``
                                            (N/E/O/M/S), ``stopbits`` (1, 1.5, 2)
``socket://HOST:PORT``, ``loop://``         pyserial URL handlers, passed through unchanged
``/dev/pts/3``, ``COM3``                    a bare device name (a serial line, 38400 baud by default)
==========================================  ==========================================================

Every timeout is in seconds. Raw bytes are logged at DEBUG level by the public methods (logger
``drivers.transport``). Reads keep bytes that arrived before a timeout in the transport's buffer, so a
later read (or a resynchronising decoder) still sees them.
"""

from __future__ import annotations

import abc
import contextlib
import logging
import math
import socket
import sys
import time
from types import TracebackType
from typing import Protocol, TypedDict, runtime_checkable
from urllib.parse import parse_qs, urlsplit

import serial

if sys.platform == "win32":  # pragma: no cover
    _SERIAL_ERRORS: tuple[type[Exception], ...] = (serial.SerialException, OSError)
else:  # termios errors (not OSError) escape pyserial on a hung-up tty
    from termios import error as _TermiosError  # noqa: N812

    _SERIAL_ERRORS = (serial.SerialException, OSError, _TermiosError)

log = logging.getLogger(__name__)

DEFAULT_SERIAL_BAUD = 38400
SERIAL_POLL_S = 0.02  # pyserial read timeout; reads wait in slices of this length
_PARITIES = {"N": serial.PARITY_NONE, "E": serial.PARITY_EVEN, "O": serial.PARITY_ODD,
             "M": serial.PARITY_MARK, "S": serial.PARITY_SPACE}
_STOPBITS = {"1": serial.STOPBITS_ONE, "1.5": serial.STOPBITS_ONE_POINT_FIVE, "2": serial.STOPBITS_TWO}
_BYTESIZES = {"5": serial.FIVEBITS, "6": serial.SIXBITS, "7": serial.SEVENBITS, "8": serial.EIGHTBITS}


class TransportError(OSError):
    """The link failed: cannot connect, closed by the peer, or an I/O error."""


class TransportTimeout(TransportError, TimeoutError):  # noqa: N818 (name fixed by the interface)
    """No (or not enough) bytes arrived within the timeout."""


class TransportClosed(TransportError):  # noqa: N818
    """The peer closed the connection, or the transport was used after :meth:`Transport.close`."""


@runtime_checkable
class Transport(Protocol):
    """What drivers use. Implementations: :class:`TcpTransport`, :class:`SerialTransport`."""

    url: str

    def write(self, data: bytes) -> None: ...
    def read_exact(self, n: int, timeout_s: float | None = None) -> bytes: ...
    def read_until(self, terminator: bytes, timeout_s: float | None = None,
                   max_bytes: int = 65536) -> bytes: ...
    def read_available(self) -> bytes: ...
    def close(self) -> None: ...
    @property
    def closed(self) -> bool:
        """True once closed (by :meth:`close` or a failure); thread-safe, no I/O."""
        ...
    def __enter__(self) -> Transport: ...
    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None: ...


def _check_timeout(timeout_s: float) -> float:
    if not (timeout_s > 0 and math.isfinite(timeout_s)):
        raise ValueError(f"timeout_s={timeout_s!r}: must be a positive number of seconds")
    return float(timeout_s)


class _BufferedTransport(abc.ABC):
    """Shared reading logic; subclasses provide ``_recv_some``, ``_send`` and ``_close``."""

    def __init__(self, url: str, timeout_s: float) -> None:
        self.url = url
        self.timeout_s = _check_timeout(timeout_s)
        self._buffer = bytearray()
        self._closed = False

    # subclass hooks -------------------------------------------------------------------------------
    @abc.abstractmethod
    def _recv_some(self, max_bytes: int, timeout_s: float) -> bytes:
        """Up to ``max_bytes`` bytes that arrive within ``timeout_s``; b"" on timeout."""

    @abc.abstractmethod
    def _send(self, data: bytes) -> None:
        """Write all of ``data``."""

    @abc.abstractmethod
    def _close(self) -> None:
        """Release the port or socket."""

    # public API ---------------------------------------------------------------------------------
    def _ensure_open(self) -> None:
        if self._closed:
            raise TransportClosed(f"{self.url}: transport is closed")

    def write(self, data: bytes) -> None:
        """Send all of ``data`` (raises :class:`TransportTimeout` if the line will not take it)."""
        self._ensure_open()
        log.debug("%s >> %s", self.url, bytes(data).hex(" "))
        self._send(bytes(data))

    def _fill(self, deadline: float, want: int) -> bool:
        remaining = deadline - time.monotonic()
        if remaining <= 0:
            return False
        chunk = self._recv_some(max(want, 1), remaining)
        if chunk:
            self._buffer += chunk
        return True

    def read_exact(self, n: int, timeout_s: float | None = None) -> bytes:
        """Return exactly ``n`` bytes, waiting at most ``timeout_s`` (default: the transport's) in total."""
        self._ensure_open()
        if n < 0:
            raise ValueError(f"n={n}: must be >= 0")
        timeout = self.timeout_s if timeout_s is None else _check_timeout(timeout_s)
        deadline = time.monotonic() + timeout
        while len(self._buffer) < n:
            if not self._fill(deadline, n - len(self._buffer)):
                raise TransportTimeout(f"{self.url}: {len(self._buffer)} of {n} bytes within {timeout:g} s")
        data = bytes(self._buffer[:n])
        del self._buffer[:n]
        log.debug("%s << %s", self.url, data.hex(" "))
        return data

    def read_until(self, terminator: bytes, timeout_s: float | None = None, max_bytes: int = 65536) -> bytes:
        """Return bytes up to and including ``terminator``.

        Raises :class:`TransportTimeout` if it does not arrive within ``timeout_s``, and
        :class:`TransportError` if ``max_bytes`` arrive without it (the bytes are kept buffered).
        """
        self._ensure_open()
        if not terminator:
            raise ValueError("terminator must be at least one byte")
        timeout = self.timeout_s if timeout_s is None else _check_timeout(timeout_s)
        deadline = time.monotonic() + timeout
        while True:
            index = self._buffer.find(terminator)
            if index >= 0 and index + len(terminator) <= max_bytes:
                end = index + len(terminator)
                data = bytes(self._buffer[:end])
                del self._buffer[:end]
                log.debug("%s << %s", self.url, data.hex(" "))
                return data
            if len(self._buffer) >= max_bytes:
                raise TransportError(f"{self.url}: {max_bytes} bytes without terminator {terminator!r}")
            if not self._fill(deadline, 1):
                raise TransportTimeout(
                    f"{self.url}: no terminator {terminator!r} within {timeout:g} s "
                    f"({len(self._buffer)} bytes buffered)")

    def read_available(self) -> bytes:
        """Return whatever is buffered or already waiting on the line, without blocking (maybe b"")."""
        self._ensure_open()
        while True:
            chunk = self._recv_some(65536, 0.0)
            if not chunk:
                break
            self._buffer += chunk
        data = bytes(self._buffer)
        self._buffer.clear()
        if data:
            log.debug("%s << %s", self.url, data.hex(" "))
        return data

    def close(self) -> None:
        """Close the link; idempotent."""
        if not self._closed:
            self._closed = True
            log.debug("%s closed", self.url)
            self._close()

    @property
    def closed(self) -> bool:
        return self._closed

    def __enter__(self) -> _BufferedTransport:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.url!r})"


class TcpTransport(_BufferedTransport):
    """A TCP client connection. ``timeout_s`` bounds the connect and is the default read/write timeout."""

    def __init__(self, host: str, port: int, *, timeout_s: float = 3.0,
                 connect_timeout_s: float | None = None) -> None:
        if not 0 < int(port) < 65536:
            raise ValueError(f"port={port}: must be 1..65535")
        super().__init__(f"tcp://{host}:{int(port)}", timeout_s)
        connect_timeout = self.timeout_s if connect_timeout_s is None else _check_timeout(connect_timeout_s)
        try:
            self._sock = socket.create_connection((host, int(port)), timeout=connect_timeout)
        except TimeoutError as exc:
            raise TransportTimeout(f"{self.url}: connect timed out after {connect_timeout:g} s") from exc
        except OSError as exc:
            raise TransportError(f"{self.url}: cannot connect: {exc}") from exc
        self._sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)

    def _recv_some(self, max_bytes: int, timeout_s: float) -> bytes:
        try:
            if timeout_s <= 0:
                self._sock.setblocking(False)
            else:
                self._sock.settimeout(timeout_s)
            data = self._sock.recv(max(max_bytes, 1))
        except (TimeoutError, BlockingIOError):
            return b""
        except OSError as exc:
            raise TransportError(f"{self.url}: receive failed: {exc}") from exc
        if not data:
            raise TransportClosed(f"{self.url}: connection closed by the peer")
        return data

    def _send(self, data: bytes) -> None:
        try:
            self._sock.settimeout(self.timeout_s)
            self._sock.sendall(data)
        except TimeoutError as exc:
            raise TransportTimeout(f"{self.url}: send timed out after {self.timeout_s:g} s") from exc
        except OSError as exc:
            raise TransportError(f"{self.url}: send failed: {exc}") from exc

    def _close(self) -> None:
        with contextlib.suppress(OSError):
            self._sock.shutdown(socket.SHUT_RDWR)
        self._sock.close()


class UdpTransport(_BufferedTransport):
    """A connected UDP socket: each :meth:`write` is one datagram; received datagrams are read as a stream."""

    def __init__(self, host: str, port: int, *, timeout_s: float = 3.0) -> None:
        if not 0 < int(port) < 65536:
            raise ValueError(f"port={port}: must be 1..65535")
        super().__init__(f"udp://{host}:{int(port)}", timeout_s)
        try:
            self._sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            self._sock.connect((host, int(port)))
        except OSError as exc:
            raise TransportError(f"{self.url}: cannot open: {exc}") from exc

    def _recv_some(self, max_bytes: int, timeout_s: float) -> bytes:
        try:
            if timeout_s <= 0:
                self._sock.setblocking(False)
            else:
                self._sock.settimeout(timeout_s)
            return self._sock.recv(65535)
        except (TimeoutError, BlockingIOError):
            return b""
        except OSError as exc:  # e.g. ICMP port unreachable
            raise TransportError(f"{self.url}: receive failed: {exc}") from exc

    def _send(self, data: bytes) -> None:
        try:
            self._sock.send(data)
        except OSError as exc:
            raise TransportError(f"{self.url}: send failed: {exc}") from exc

    def _close(self) -> None:
        self._sock.close()


class SerialTransport(_BufferedTransport):
    """A serial line (or any pyserial URL: ``socket://``, ``loop://``, a pty slave name).

    pyserial always gets a read timeout and a write timeout, so no call can block forever.
    """

    def __init__(self, port_url: str, *, baudrate: int = DEFAULT_SERIAL_BAUD, timeout_s: float = 3.0,
                 bytesize: int = serial.EIGHTBITS, parity: str = serial.PARITY_NONE,
                 stopbits: float = serial.STOPBITS_ONE) -> None:
        super().__init__(port_url, timeout_s)
        try:
            self._serial = serial.serial_for_url(
                port_url, baudrate=int(baudrate), bytesize=bytesize, parity=parity, stopbits=stopbits,
                timeout=min(self.timeout_s, SERIAL_POLL_S), write_timeout=self.timeout_s)
        except (serial.SerialException, ValueError) as exc:
            raise TransportError(f"{port_url}: cannot open serial line: {exc}") from exc
        self.baudrate = int(baudrate)

    def _recv_some(self, max_bytes: int, timeout_s: float) -> bytes:
        # pyserial's read timeout stays at SERIAL_POLL_S (changing it re-runs tcsetattr on every read);
        # the caller loops until its own deadline, so a read may overshoot it by at most one poll.
        try:
            waiting = self._serial.in_waiting
            if timeout_s <= 0 and not waiting:
                return b""
            return self._serial.read(max(1, min(max_bytes, waiting)) if waiting else 1)
        except _SERIAL_ERRORS as exc:
            raise TransportError(f"{self.url}: receive failed: {exc}") from exc

    def _send(self, data: bytes) -> None:
        try:
            self._serial.write(data)
            self._serial.flush()
        except serial.SerialTimeoutException as exc:
            raise TransportTimeout(f"{self.url}: write timed out after {self.timeout_s:g} s") from exc
        except _SERIAL_ERRORS as exc:
            raise TransportError(f"{self.url}: send failed: {exc}") from exc

    def _close(self) -> None:
        with contextlib.suppress(*_SERIAL_ERRORS):
            self._serial.close()


class SerialOptions(TypedDict, total=False):
    """Line settings of a ``serial://`` address (the keywords of :class:`SerialTransport`)."""

    baudrate: int
    parity: str
    stopbits: float
    bytesize: int


def _serial_options(query: str, url: str) -> SerialOptions:
    options: SerialOptions = {}
    for key, values in parse_qs(query, keep_blank_values=True, strict_parsing=False).items():
        value = values[-1]
        if key in ("baud", "baudrate"):
            if not value.isdigit() or int(value) <= 0:
                raise ValueError(f"{url}: baud={value!r} must be a positive integer")
            options["baudrate"] = int(value)
        elif key == "parity":
            if value.upper() not in _PARITIES:
                raise ValueError(f"{url}: parity={value!r} must be one of {sorted(_PARITIES)}")
            options["parity"] = _PARITIES[value.upper()]
        elif key == "stopbits":
            if value not in _STOPBITS:
                raise ValueError(f"{url}: stopbits={value!r} must be one of {sorted(_STOPBITS)}")
            options["stopbits"] = _STOPBITS[value]
        elif key == "bytesize":
            if value not in _BYTESIZES:
                raise ValueError(f"{url}: bytesize={value!r} must be one of {sorted(_BYTESIZES)}")
            options["bytesize"] = _BYTESIZES[value]
        else:
            raise ValueError(f"{url}: unknown option {key!r}; allowed: baud, parity, stopbits, bytesize")
    return options


def open_transport(url: str, timeout_s: float = 3.0) -> TcpTransport | UdpTransport | SerialTransport:
    """Open the transport named by ``url`` (see the module docstring for the forms)."""
    parts = urlsplit(url)
    scheme = parts.scheme.lower()
    if scheme == "tcp":
        if not parts.hostname or parts.port is None:
            raise ValueError(f"{url!r}: a TCP address is tcp://HOST:PORT")
        return TcpTransport(parts.hostname, parts.port, timeout_s=timeout_s)
    if scheme == "udp":
        if not parts.hostname or parts.port is None:
            raise ValueError(f"{url!r}: a UDP address is udp://HOST:PORT")
        return UdpTransport(parts.hostname, parts.port, timeout_s=timeout_s)
    if scheme == "serial":
        path = parts.netloc + parts.path if parts.netloc else parts.path
        if not path:
            raise ValueError(f"{url!r}: a serial address is serial:///dev/ttyUSB0?baud=115200")
        return SerialTransport(path, timeout_s=timeout_s, **_serial_options(parts.query, url))
    if scheme in ("socket", "loop", "rfc2217", "spy"):
        return SerialTransport(url, timeout_s=timeout_s)
    if url.startswith("/") or url.upper().startswith("COM"):
        return SerialTransport(url, timeout_s=timeout_s)
    raise ValueError(f"{url!r}: unsupported address; use tcp://HOST:PORT, udp://HOST:PORT, "
                     "serial:///DEV?baud=N, "
                     "socket://HOST:PORT, loop:// or a device path")
