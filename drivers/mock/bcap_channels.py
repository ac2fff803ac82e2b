"""Byte pipes from the mock RC8 to one client: a TCP socket, or the master side of a pty pair."""

from __future__ import annotations

import contextlib
import os
import pty
import select
import socket
import tty


class Channel:
    """A byte pipe to one client: a TCP socket or a pty master."""

    serial_line = False

    def recv(self, timeout_s: float) -> bytes:  # b"" on timeout; EOFError when closed
        raise NotImplementedError

    def send(self, data: bytes) -> None:
        raise NotImplementedError

    def close(self) -> None:
        raise NotImplementedError


class TcpChannel(Channel):
    def __init__(self, sock: socket.socket) -> None:
        self.sock = sock
        host, port = sock.getpeername()[:2]
        self.name = f"tcp:{host}:{port}"

    def recv(self, timeout_s: float) -> bytes:
        self.sock.settimeout(timeout_s)
        try:
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

    def close(self) -> None:
        with contextlib.suppress(OSError):
            self.sock.shutdown(socket.SHUT_RDWR)
        self.sock.close()


class PtyChannel(Channel):
    """Server end of a pty pair; the client opens :attr:`slave_name` with pyserial."""

    serial_line = True

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
