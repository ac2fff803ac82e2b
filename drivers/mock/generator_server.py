"""Mock SCPI function generator: LF-terminated lines over TCP (``socket://``/``tcp://``) or a pty.

The instrument is :class:`drivers.mock.generator_instrument.GeneratorInstrument` (Keysight 33521B-like,
IEEE 488.2 status model, short/long headers, ``;``-joined commands, moving the twin's shaker). This module
only carries bytes:

* TCP on ``127.0.0.1`` (port 0 = ephemeral): clients use ``socket://127.0.0.1:N`` (pyserial) or
  ``tcp://127.0.0.1:N`` (:mod:`drivers.transport`), or VISA ``TCPIP::127.0.0.1::N::SOCKET``; at most
  :data:`MAX_CONNECTIONS` at once (more are closed at once), finished connection threads are reaped;
* a serial line: a :class:`~drivers.mock.pty_link.PtyLink` whose :attr:`GeneratorServer.client_port`
  the driver opens like a USB-serial adapter.

Input is bounded: a line longer than :data:`MAX_LINE` bytes is discarded up to its terminator with
−223 "Too much data" queued once.

Fault injection (:meth:`GeneratorServer.inject`, or ``--fault KIND[:PARAM]`` on the command line,
repeatable), each until :meth:`clear_faults` or for ``count`` replies/messages:

==============  ===========  =====================================================================
kind            PARAM        effect
==============  ===========  =====================================================================
``late``        s (2)        every reply is sent PARAM s late (later lines are executed meanwhile)
``no_reply``    –            commands execute, replies are swallowed
``busy``        s (1)        each program message is executed PARAM s after it is read (input waits)
``disconnect``  N (0)        a connection is closed after N program messages (0: at once, and new
                             connections are refused)
``error``       code (-310)  the error is queued once after the next program message
``twice``       –            every reply is sent twice
``drop``        N (1)        the last N bytes of every reply (terminator first) are lost
==============  ===========  =====================================================================

Run standalone (its own world with a paced clock)::

    python -m drivers.mock.generator_server --port 5025       # TCP on 127.0.0.1:5025
    python -m drivers.mock.generator_server --pty             # serial on a new pty; prints the port
    rig mock generator --fault late:1.5 --fault error:-310
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import os
import select
import socket
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from types import TracebackType

from drivers.mock._serve import (
    accept_loop,
    require_loopback,
    standalone_parser,
    start_standalone,
    wait_for_interrupt,
)
from drivers.mock.generator_instrument import GeneratorInstrument
from drivers.mock.pty_link import PtyLink

__all__ = ["FAULT_KINDS", "Fault", "GeneratorServer", "LineAssembler", "main", "parse_fault"]

log = logging.getLogger(__name__)
MAX_LINE = 4096
MAX_CONNECTIONS = 16
POLL_S = 0.05
SEND_TIMEOUT_S = 5.0
FAULT_KINDS: dict[str, float | None] = {"late": 2.0, "no_reply": None, "busy": 1.0, "disconnect": 0.0,
                                         "error": -310.0, "twice": None, "drop": 1.0}


@dataclass
class Fault:
    """One injected fault: ``kind`` (a key of :data:`FAULT_KINDS`), its parameter, and how many more
    replies/messages it affects (``None``: until cleared; ``error`` defaults to once)."""

    kind: str
    param: float | None = None
    count: int | None = None

    def __post_init__(self) -> None:
        if self.kind not in FAULT_KINDS:
            raise ValueError(f"fault kind {self.kind!r}: must be one of {', '.join(FAULT_KINDS)}")
        if self.param is None:
            self.param = FAULT_KINDS[self.kind]
        if self.param is not None and self.kind in ("late", "busy", "disconnect", "drop") and self.param < 0:
            raise ValueError(f"fault {self.kind}:{self.param!r}: the parameter must be >= 0")
        if self.count is not None and self.count < 1:
            raise ValueError(f"fault count={self.count!r}: must be >= 1 or None")
        if self.kind == "error" and self.count is None:
            self.count = 1  # an error is pushed once (inject again for another)


def parse_fault(text: str) -> Fault:
    """``KIND[:PARAM]`` (``late:1.5``, ``no_reply``, ``disconnect:3``, ``error:-222``) → :class:`Fault`."""
    kind, _, param = text.strip().partition(":")
    kind = kind.strip().lower().replace("-", "_")
    if kind not in FAULT_KINDS:
        raise ValueError(f"--fault {text!r}: KIND must be one of {', '.join(FAULT_KINDS)}")
    if param and FAULT_KINDS[kind] is None:
        raise ValueError(f"--fault {text!r}: {kind} takes no parameter")
    try:
        value = float(param) if param else None
    except ValueError:
        raise ValueError(f"--fault {text!r}: PARAM must be a number") from None
    return Fault(kind, value)


class LineAssembler:
    """Bytes → LF-terminated lines (``\\r`` before the LF dropped) with at most ``max_line`` bytes
    buffered; an over-long line is discarded up to its LF and reported once through ``on_overflow``."""

    def __init__(self, on_overflow: Callable[[], None], max_line: int = MAX_LINE) -> None:
        self.on_overflow = on_overflow
        self.max_line = max_line
        self._buffer = bytearray()
        self._discarding = False

    def feed(self, data: bytes) -> list[str]:
        lines = []
        *complete, tail = data.split(b"\n")
        for piece in complete:
            if self._discarding:  # the over-long line ends here
                self._discarding = False
            else:
                self._buffer += piece
                if len(self._buffer) > self.max_line:
                    self.on_overflow()
                else:
                    lines.append(bytes(self._buffer).rstrip(b"\r").decode("ascii", errors="replace"))
            self._buffer.clear()
        if not self._discarding:
            self._buffer += tail
            if len(self._buffer) > self.max_line:
                self.on_overflow()
                self._buffer.clear()
                self._discarding = True
        return lines


class _Session:
    """One client (a TCP connection or the pty): lines in, replies out through ``send``, with the faults
    applied. ``closed`` turns true when a ``disconnect`` fault ends it."""

    def __init__(self, server: GeneratorServer, send: Callable[[bytes], None]) -> None:
        self.server = server
        self.send = send
        self.lines = LineAssembler(lambda: server.instrument.push_error(-223, "Too much data"))
        self.handled = 0
        self.closed = False
        self._late: list[tuple[float, bytes]] = []

    def feed(self, data: bytes) -> None:
        for line in self.lines.feed(data):
            if self.closed or self.server.stopped:
                return
            self._handle(line)

    def _handle(self, line: str) -> None:
        server = self.server
        if (busy := server.take_fault("busy")) is not None:
            server.wait(busy.param or 0.0)
        try:
            reply = server.instrument.handle_line(line)
        except Exception:  # a bug in the instrument must not end the connection: log and queue it
            log.exception("generator mock: %r raised", line[:200])
            server.instrument.push_error(-300, "Device-specific error")
            reply = None
        self.handled += 1
        if (error := server.take_fault("error")) is not None:
            server.instrument.push_error(int(error.param or -310))
        if reply is not None:
            self._reply(reply.encode("ascii", errors="replace") + b"\n")
        limit = server.fault_param("disconnect")
        if limit is not None and self.handled >= limit:
            self.closed = True

    def _reply(self, out: bytes) -> None:
        server = self.server
        if server.take_fault("no_reply") is not None:
            return
        if (drop := server.take_fault("drop")) is not None:
            out = out[: max(len(out) - int(drop.param or 1), 0)]
        if server.take_fault("twice") is not None:
            out = out + out
        if (late := server.take_fault("late")) is not None:
            self._late.append((time.monotonic() + (late.param or 0.0), out))
            return
        if self._late:  # keep the order: an on-time reply waits behind a late one
            self._late.append((self._late[-1][0], out))
            return
        self.send(out)

    def next_due_s(self) -> float:
        """Seconds until the next late reply is due (``POLL_S`` when none is waiting)."""
        if not self._late:
            return POLL_S
        return min(max(self._late[0][0] - time.monotonic(), 0.0), POLL_S)

    def flush_due(self) -> None:
        now = time.monotonic()
        while self._late and self._late[0][0] <= now:
            self.send(self._late.pop(0)[1])


class GeneratorServer:
    """Serve a :class:`GeneratorInstrument` in background threads. mode: "tcp" or "pty". host: a loopback
    address only (ValueError otherwise: a mock is never reachable from the network). faults: injected
    from the start (see the module's table)."""

    def __init__(self, instrument: GeneratorInstrument, *, mode: str = "tcp", host: str = "127.0.0.1",
                 port: int = 0, faults: list[Fault] | None = None) -> None:
        if mode not in ("tcp", "pty"):
            raise ValueError(f"mode={mode!r}: must be 'tcp' or 'pty'")
        self.instrument = instrument
        self.mode = mode
        self.host = require_loopback(host)
        self.port = port
        self.link: PtyLink | None = None
        self.faults: list[Fault] = list(faults or [])
        self._fault_lock = threading.Lock()
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []  # accept loop or pty loop
        self._conn_threads: set[threading.Thread] = set()
        self._listener: socket.socket | None = None
        self._conns: set[socket.socket] = set()
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

    @property
    def stopped(self) -> bool:
        return self._stop.is_set()

    @property
    def connection_threads(self) -> int:
        """Connection threads alive now (finished ones are reaped)."""
        with self._fault_lock:
            return len(self._conn_threads)

    def wait(self, seconds: float) -> None:
        """Sleep up to ``seconds`` wall seconds, returning early when the server stops."""
        self._stop.wait(seconds)

    def start(self) -> GeneratorServer:
        if self.mode == "tcp":
            self._listener = socket.create_server((self.host, self.port))
            self.port = self._listener.getsockname()[1]
            self._spawn(accept_loop, self._listener, self._stop, self._on_connection)
        else:
            self.link = PtyLink()
            self._fd = os.open(self.link.device_port, os.O_RDWR | os.O_NOCTTY)
            self._spawn(self._pty_loop)
        return self

    def _spawn(self, target: Callable[..., object], *args: object) -> None:
        thread = threading.Thread(target=target, args=args, daemon=True, name=f"scpi-mock {target.__name__}")
        thread.start()
        self._threads.append(thread)

    def stop(self) -> None:
        """Stop every thread, close sockets and the pty; idempotent."""
        self._stop.set()
        if self._listener is not None:
            with contextlib.suppress(OSError):
                self._listener.close()
        with self._fault_lock:
            conns, threads = list(self._conns), list(self._conn_threads)
        for conn in conns:
            with contextlib.suppress(OSError):
                conn.shutdown(socket.SHUT_RDWR)
        for thread in self._threads + threads:
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
    def inject(self, kind: str, param: float | None = None, count: int | None = None) -> None:
        """Add a fault (see the module's table); ``count`` replies/messages, or until :meth:`clear_faults`.
        ``disconnect`` without a parameter also drops the current connections (and unplugs the pty)."""
        fault = Fault(kind, param, count)
        with self._fault_lock:
            self.faults.append(fault)
            conns = list(self._conns)
        if kind == "disconnect" and not fault.param:
            if self.link is not None:
                self.link.unplug()
            for conn in conns:
                with contextlib.suppress(OSError):
                    conn.shutdown(socket.SHUT_RDWR)

    def clear_faults(self) -> None:
        with self._fault_lock:
            self.faults.clear()
        if self.link is not None:
            self.link.plug()

    def take_fault(self, kind: str) -> Fault | None:
        """The first active fault of ``kind``, counting one use of it (removed when used up)."""
        with self._fault_lock:
            for fault in self.faults:
                if fault.kind == kind:
                    if fault.count is not None:
                        fault.count -= 1
                        if fault.count <= 0:
                            self.faults.remove(fault)
                    return fault
        return None

    def fault_param(self, kind: str) -> float | None:
        """The parameter of the first active fault of ``kind`` without using it up (None: none active)."""
        with self._fault_lock:
            return next((f.param for f in self.faults if f.kind == kind), None)

    @property
    def requests_received(self) -> int:
        """Program messages received so far (every line, including those the history no longer keeps)."""
        return self.instrument.lines_received

    # byte handling ---------------------------------------------------------------------------------------
    def _on_connection(self, conn: socket.socket) -> None:
        with self._fault_lock:
            refuse = len(self._conn_threads) >= MAX_CONNECTIONS
            thread = threading.Thread(target=self._conn_loop, args=(conn,), daemon=True,
                                      name="scpi-mock connection")
            if not refuse:
                self._conns.add(conn)
                self._conn_threads.add(thread)
        if refuse or self.fault_param("disconnect") == 0:
            if refuse:
                log.warning("generator mock: %d connections open, refusing another", MAX_CONNECTIONS)
            self._forget(conn, thread)
            conn.close()
            return
        thread.start()

    def _forget(self, conn: socket.socket, thread: threading.Thread) -> None:
        with self._fault_lock:
            self._conns.discard(conn)
            self._conn_threads.discard(thread)

    def _conn_loop(self, conn: socket.socket) -> None:
        def send(out: bytes) -> None:
            conn.settimeout(SEND_TIMEOUT_S)  # a client that never reads loses its replies, not the server
            try:
                conn.sendall(out)
            except OSError:
                session.closed = True
            finally:
                with contextlib.suppress(OSError):
                    conn.settimeout(POLL_S)

        session = _Session(self, send)
        try:
            with conn:
                conn.settimeout(POLL_S)
                while not self._stop.is_set() and not session.closed:
                    conn.settimeout(session.next_due_s() or 1e-3)
                    try:
                        data = conn.recv(4096)
                    except TimeoutError:
                        data = None
                    except OSError:
                        break
                    if data == b"":
                        break
                    if data:
                        session.feed(data)
                    session.flush_due()
        finally:
            self._forget(conn, threading.current_thread())

    def _pty_loop(self) -> None:
        # No terminal set-up here: the PtyLink put the line in raw mode before its names existed. This
        # thread once called tty.setraw, whose default TCSAFLUSH discarded whatever the client had
        # already sent when a loaded machine scheduled the thread late (a lost first command).
        assert self._fd is not None
        fd = self._fd

        def send(out: bytes) -> None:
            with contextlib.suppress(OSError):
                os.write(fd, out)

        session = _Session(self, send)
        while not self._stop.is_set():
            readable, _, _ = select.select([fd], [], [], session.next_due_s())
            if readable:
                try:
                    data = os.read(fd, 4096)
                except OSError:
                    return
                session.feed(data)
            session.flush_due()
            if session.closed and self.link is not None:  # disconnect:N on a serial line: pull the cable
                self.link.unplug()
                session.closed = False


def main(argv: list[str] | None = None, prog: str | None = None) -> int:
    """Serve until Ctrl-C or SIGTERM; ``prog`` names the command in help and errors."""
    parser = standalone_parser("generator_server", "Mock SCPI function generator driving the twin's shaker.",
                               default_port=5025, prog=prog)
    parser.add_argument("--pty", action="store_true", help="serve on a new pty pair instead of TCP")
    parser.add_argument("--fault", action="append", default=[], type=_fault_arg, metavar="KIND[:PARAM]",
                        help="inject a fault (repeatable): " + ", ".join(
                            f"{k}" + (f"[:{v:g}]" if v is not None else "") for k, v in FAULT_KINDS.items()))
    args, world = start_standalone(parser, argv)
    instrument = GeneratorInstrument(world.shaker, world.clock)
    with GeneratorServer(instrument, mode="pty" if args.pty else "tcp", port=args.port,
                         faults=args.fault) as server:
        print(f"mock SCPI generator serving at {server.url} (socket://127.0.0.1:{server.port} for pyserial)"
              if server.mode == "tcp" else f"mock SCPI generator serving on {server.url}", flush=True)
        for fault in args.fault:
            print(f"fault injected: {fault.kind}" + (f":{fault.param:g}" if fault.param is not None else ""),
                  flush=True)
        wait_for_interrupt()
        print(f"mock SCPI generator stopped; requests received: {server.requests_received}", flush=True)
    return 0


def _fault_arg(text: str) -> Fault:
    try:
        return parse_fault(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from exc


if __name__ == "__main__":
    raise SystemExit(main())
