"""Mock SCPI function generator: LF-terminated lines over TCP (``socket://``/``tcp://``) or a pty.

The instrument is :class:`drivers.mock.generator_instrument.GeneratorInstrument` (Keysight 33521B-like,
20-deep error queue with -350 overflow, short/long headers, ``;``-joined commands, moving the twin's
shaker). This module only carries bytes:

* TCP on ``127.0.0.1`` (port 0 = ephemeral): clients use ``socket://127.0.0.1:N`` (pyserial) or
  ``tcp://127.0.0.1:N`` (:mod:`drivers.transport`);
* a serial line: a :class:`~drivers.mock.pty_link.PtyLink` whose :attr:`GeneratorServer.client_port`
  the driver opens like a USB-serial adapter.

Fault injection: :meth:`GeneratorServer.inject` ``"no_reply"`` (replies are swallowed) or
``"disconnect"`` (TCP: the connection is closed; pty: the cable is pulled) until :meth:`clear_faults`.

Run standalone (its own world with a paced clock)::

    python -m drivers.mock.generator_server --port 5025       # TCP on 127.0.0.1:5025
    python -m drivers.mock.generator_server --pty             # serial on a new pty; prints the port
"""

from __future__ import annotations

import contextlib
import logging
import os
import select
import socket
import threading
from types import TracebackType
from typing import Any

from drivers.mock._serve import (
    accept_loop,
    require_loopback,
    standalone_parser,
    start_standalone,
    wait_for_interrupt,
)
from drivers.mock.generator_instrument import GeneratorInstrument
from drivers.mock.pty_link import PtyLink

__all__ = ["GeneratorServer", "main"]

log = logging.getLogger(__name__)
HOUSEKEEPING_S = 0.02
MAX_LINE = 4096


class GeneratorServer:
    """Serve a :class:`GeneratorInstrument` in background threads. mode: "tcp" or "pty". host: a loopback
    address only (ValueError otherwise: a mock is never reachable from the network)."""

    def __init__(self, instrument: GeneratorInstrument, *, mode: str = "tcp", host: str = "127.0.0.1",
                 port: int = 0) -> None:
        if mode not in ("tcp", "pty"):
            raise ValueError(f"mode={mode!r}: must be 'tcp' or 'pty'")
        self.instrument = instrument
        self.mode = mode
        self.host = require_loopback(host)
        self.port = port
        self.link: PtyLink | None = None
        self.fault: str | None = None
        self.requests_received = 0  # command lines received
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self._listener: socket.socket | None = None
        self._conns: list[socket.socket] = []
        self._fd: int | None = None

    @property
    def url(self) -> str:
        """Address for :func:`drivers.transport.open_transport`."""
        if self.mode == "tcp":
            return f"tcp://{self.host}:{self.port}"
        assert self.link is not None
        return self.link.client_port

    @property
    def client_port(self) -> str:
        if self.link is None:
            raise RuntimeError("client_port: the server is not in pty mode")
        return self.link.client_port

    def start(self) -> GeneratorServer:
        if self.mode == "tcp":
            self._listener = socket.create_server((self.host, self.port))
            self.port = self._listener.getsockname()[1]
            self._spawn(accept_loop, self._listener, self._stop, self._on_connection)
        else:
            self.link = PtyLink()
            self._fd = os.open(self.link.device_port, os.O_RDWR | os.O_NOCTTY)
            self._spawn(self._pty_loop)
        self._spawn(self._housekeeping)
        return self

    def _spawn(self, target: Any, *args: Any) -> None:
        thread = threading.Thread(target=target, args=args, daemon=True, name=f"scpi-mock {target.__name__}")
        thread.start()
        self._threads.append(thread)

    def stop(self) -> None:
        """Stop every thread, close sockets and the pty; idempotent."""
        self._stop.set()
        if self._listener is not None:
            with contextlib.suppress(OSError):
                self._listener.close()
        for conn in list(self._conns):
            with contextlib.suppress(OSError):
                conn.shutdown(socket.SHUT_RDWR)
        for thread in self._threads:
            thread.join(timeout=2.0)
        if self._fd is not None:
            with contextlib.suppress(OSError):
                os.close(self._fd)
            self._fd = None
        if self.link is not None:
            self.link.close()

    def __enter__(self) -> GeneratorServer:
        return self.start()

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.stop()

    # faults ---------------------------------------------------------------------------------------------
    def inject(self, fault: str) -> None:
        if fault not in ("no_reply", "disconnect"):
            raise ValueError(f"fault={fault!r}: must be 'no_reply' or 'disconnect'")
        self.fault = fault
        if fault == "disconnect":
            if self.link is not None:
                self.link.unplug()
            for conn in list(self._conns):
                with contextlib.suppress(OSError):
                    conn.shutdown(socket.SHUT_RDWR)

    def clear_faults(self) -> None:
        self.fault = None
        if self.link is not None:
            self.link.plug()

    # byte handling ---------------------------------------------------------------------------------------
    def _lines(self, buffer: bytearray, data: bytes) -> list[str]:
        buffer += data
        lines = []
        while (i := buffer.find(b"\n")) >= 0:
            raw = bytes(buffer[:i]).rstrip(b"\r")
            del buffer[: i + 1]
            lines.append(raw.decode("ascii", errors="replace"))
        if len(buffer) > MAX_LINE:
            buffer.clear()
            self.instrument.push_error(-223, "Too much data")
        return lines

    def _respond(self, line: str) -> bytes:
        self.requests_received += 1
        reply = self.instrument.handle_line(line)
        if reply is None or self.fault is not None:
            return b""
        return reply.encode("ascii") + b"\n"

    def _on_connection(self, conn: socket.socket) -> None:
        if self.fault == "disconnect":
            conn.close()
            return
        self._conns.append(conn)
        self._spawn(self._conn_loop, conn)

    def _conn_loop(self, conn: socket.socket) -> None:
        buffer = bytearray()
        conn.settimeout(0.05)
        with conn:
            while not self._stop.is_set():
                try:
                    data = conn.recv(4096)
                except TimeoutError:
                    continue
                except OSError:
                    break
                if not data:
                    break
                for line in self._lines(buffer, data):
                    if out := self._respond(line):
                        with contextlib.suppress(OSError):
                            conn.sendall(out)
        with contextlib.suppress(ValueError):
            self._conns.remove(conn)

    def _pty_loop(self) -> None:
        assert self._fd is not None
        import tty

        tty.setraw(self._fd)
        buffer = bytearray()
        while not self._stop.is_set():
            readable, _, _ = select.select([self._fd], [], [], 0.05)
            if not readable:
                continue
            try:
                data = os.read(self._fd, 4096)
            except OSError:
                return
            for line in self._lines(buffer, data):
                if out := self._respond(line):
                    with contextlib.suppress(OSError):
                        os.write(self._fd, out)

    def _housekeeping(self) -> None:
        while not self._stop.wait(HOUSEKEEPING_S):
            self.instrument.advance(self.instrument.clock.now_s())


def main(argv: list[str] | None = None, prog: str | None = None) -> int:
    """Serve until Ctrl-C or SIGTERM; ``prog`` names the command in help and errors."""
    parser = standalone_parser("generator_server", "Mock SCPI function generator driving the twin's shaker.",
                               default_port=5025, prog=prog)
    parser.add_argument("--pty", action="store_true", help="serve on a new pty pair instead of TCP")
    args, world = start_standalone(parser, argv)
    instrument = GeneratorInstrument(world.shaker, world.clock)
    with GeneratorServer(instrument, mode="pty" if args.pty else "tcp", port=args.port) as server:
        print(f"mock SCPI generator serving at {server.url} (socket://127.0.0.1:{server.port} for pyserial)"
              if server.mode == "tcp" else f"mock SCPI generator serving on {server.url}", flush=True)
        wait_for_interrupt()
        print(f"mock SCPI generator stopped; requests received: {server.requests_received}", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
