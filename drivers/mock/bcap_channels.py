"""Byte pipes from the mock RC8 to one client: a TCP socket, or the master side of a pty pair."""

from __future__ import annotations

import abc
import contextlib
import os
import pty
import select
import socket
import tty


class Channel(abc.ABC):
    """A byte pipe to one client: a TCP socket, a pty master or a UDP socket. ``name`` says which."""

    name: str
    serial_line = False  # CRC framing
    may_retry = False    # clients may re-send (serial line, UDP): keep a reply cache

    @abc.abstractmethod
    def recv(self, timeout_s: float) -> bytes:
        """What arrived within ``timeout_s`` (s): b"" on timeout; EOFError when the channel is closed."""

    @abc.abstractmethod
    def send(self, data: bytes) -> None:
        """Write all of ``data``; EOFError when the client is gone."""

    @abc.abstractmethod
    def close(self) -> None:
        """Release the channel (idempotent)."""

    def peer_closed(self) -> bool:
        """True when the client has closed its end and nothing it sent is left unread (a connection's end
        seen without waiting for the thread that reads it); False when unknown (no connection to end)."""
        return False


class TcpChannel(Channel):
    def __init__(self, sock: socket.socket) -> None:
        self.sock = sock
        host, port = sock.getpeername()[:2]
        self.name = f"tcp:{host}:{port}"

    def recv(self, timeout_s: float) -> bytes:
        try:
            self.sock.settimeout(timeout_s)  # EBADF when the server closed the socket meanwhile
            data = self.sock.recv(65536)
        except TimeoutError:
            return b""
        except OSError as exc:
            raise EOFError(str(exc)) from exc
        if not data:
            raise EOFError("client closed")
        return data

    def send(self, data: bytes) -> None:
        try:
            self.sock.sendall(data)
        except OSError as exc:
            raise EOFError(str(exc)) from exc

    def peer_closed(self) -> bool:
        try:
            readable, _, _ = select.select([self.sock], [], [], 0)
            # readable: data or the end; peeked, so the session's own reader still gets what it holds
            return bool(readable) and self.sock.recv(1, socket.MSG_PEEK | socket.MSG_DONTWAIT) == b""
        except (OSError, ValueError):  # reset, or the socket closed here meanwhile (fd -1)
            return True

    def close(self) -> None:
        with contextlib.suppress(OSError):
            self.sock.shutdown(socket.SHUT_RDWR)
        self.sock.close()


class PtyChannel(Channel):
    """Server end of a pty pair; the client opens :attr:`slave_name` with pyserial."""

    serial_line = True
    may_retry = True

    def __init__(self) -> None:
        self.master_fd, self._slave_fd = pty.openpty()
        tty.setraw(self._slave_fd)  # no echo, no cooking, before the client configures the line
        self.slave_name = os.ttyname(self._slave_fd)
        self.name = f"pty:{self.slave_name}"
        self._closed = False

    def recv(self, timeout_s: float) -> bytes:
        if self._closed:
            raise EOFError("pty closed")
        ready, _, _ = select.select([self.master_fd], [], [], timeout_s)
        if not ready:
            return b""
        try:
            return os.read(self.master_fd, 4096)
        except OSError as exc:
            raise EOFError(str(exc)) from exc

    def send(self, data: bytes) -> None:
        view = memoryview(data)
        while view:
            try:
                written = os.write(self.master_fd, view)
            except OSError as exc:
                raise EOFError(str(exc)) from exc
            view = view[written:]

    def close(self) -> None:
        if not self._closed:
            self._closed = True
            for fd in (self.master_fd, self._slave_fd):
                with contextlib.suppress(OSError):
                    os.close(fd)


class UdpChannel(Channel):
    """A bound UDP socket; answers the address of the last datagram (one client at a time)."""

    may_retry = True

    def __init__(self, host: str, port: int) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind((host, port))
        self.port: int = self.sock.getsockname()[1]
        self.name = f"udp:{host}:{self.port}"
        self.peer: tuple[str, int] | None = None

    def recv(self, timeout_s: float) -> bytes:
        self.sock.settimeout(timeout_s)
        try:
            data, self.peer = self.sock.recvfrom(65535)
        except TimeoutError:
            return b""
        except OSError as exc:
            raise EOFError(str(exc)) from exc
        return data

    def send(self, data: bytes) -> None:
        if self.peer is not None:
            try:
                self.sock.sendto(data, self.peer)
            except OSError as exc:
                raise EOFError(str(exc)) from exc

    def close(self) -> None:
        self.sock.close()
