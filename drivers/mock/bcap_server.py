"""A mock DENSO RC8 controller speaking b-CAP over TCP (127.0.0.1), UDP or a pty serial line (with CRC).

Behind it is the simulated robot body (``world.robot``) and the rig's virtual clock: a Move starts the
body's move at the current virtual time and lasts as long as the body says. In *instant* clock mode the
server advances the clock to the end of the move and replies at once; in *paced* mode the reply waits
until the move ends in (scaled) wall time, with S_EXECUTING keep-alives every WDT ms meanwhile.

The mock speaks through its own codec (``bcap_wire.py``), never the driver's. Behaviour, each with its
source (vendor documentation, DENSO's reference server in DENSORobot/orin_bcap, or our choice), is tabled
in ``docs/bcap_mock.md``; in short:

* one reply per write; handles returned as VT_UI4, accepted as VT_I4 or VT_UI4; at most 1,000 objects
  (E_MAX_OBJECT); Service_Start sets WDT and InvokeTimeout, to their defaults when absent (values below
  80 ms: E_INVALIDARG), and a new client starts from the defaults;
* a blocking call is executed while the connection is not read: requests sent meanwhile wait their turn
  (reference server); only after InvokeTimeout expired with the call still running does a request get
  E_BUSY_PROC; a closed connection is noticed at once, and ends the session (the arm stops);
* a framed but malformed packet closes a TCP connection (reference server); on a serial line or UDP it
  is dropped; a bad CRC is dropped silently; a serial/UDP retry is answered from the reply cache.
* fault injection (:class:`Faults`, and ``--fault KIND[:PARAM]`` on the command line, see
  :func:`parse_fault`).

**One client at a time**, over all channels: the controller state is one arm whose cleanup when a client
goes away halts the robot, switches the motor off and drops *every* handle — two concurrent clients
(say one on TCP, one on the serial line) would pull the arm from under each other. A client holds the
controller from its first request until its connection ends or it sends Service_Stop (a serial line has
no connection to close: Service_Stop ends its session); a request of any other client meanwhile gets
E_MAX_CONNECT. An open but silent channel holds nothing. (A serial client that dies without Service_Stop
keeps the controller until the mock restarts.) Histories are bounded (the newest 10,000 requests).

The mock binds loopback addresses only (127.0.0.1 by default): ``ValueError`` / a usage error otherwise.

Run on its own (own world, paced clock at real time)::

    python -m drivers.mock.bcap_server --port 5007          # tcp://127.0.0.1:5007
    python -m drivers.mock.bcap_server --port 0             # any free port; the first line printed says which
    python -m drivers.mock.bcap_server --pty                # also prints the pty slave to open
    python -m drivers.mock.bcap_server --fault delay:2.5 --fault disconnect-after:40
"""

from __future__ import annotations

import argparse
import importlib
import logging
import socket
import threading
import time
from collections import OrderedDict
from dataclasses import dataclass
from types import TracebackType

from drivers.clock import Clock
from drivers.mock import bcap_wire as w
from drivers.mock._serve import (
    accept_loop,
    loopback_host,
    require_loopback,
    standalone_parser,
    start_standalone,
    wait_for_interrupt,
)
from drivers.mock.bcap_channels import Channel, PtyChannel, TcpChannel, UdpChannel
from drivers.mock.bcap_state import ControllerState, History, RobotBodyLike
from drivers.sim.clock import VirtualClock

log = logging.getLogger(__name__)
CACHE_SIZE = 32
MAX_REQUESTS_KEPT = 10_000
QUEUE_LIMIT_BYTES = 1 << 20  # requests queued during a blocking call, beyond which reading pauses
SERVICE_STOP, ROBOT_MOVE = 2, 72
ALL = 10**9  # "every time" for a fault counter
CLIENT_WDT_FACTOR = 4  # client watchdog: silence longer than 4 × WDT (1.6 s at the driver's 400 ms) ends it


@dataclass
class Faults:
    """Fault-injection switches; counters decrement as faults fire. ``*_function`` None = any function."""

    drop_replies: int = 0            # replies executed but never sent (a retry gets the cached reply)
    drop_function: int | None = None
    delay_reply_s: float = 0.0       # wall delay before replies to delay_function (a late reply)
    delay_function: int | None = None
    corrupt_crc: int = 0             # serial line: replies sent with a broken CRC
    close_mid_move: bool = False     # close the connection once a Move has started (blocking or NEXT)
    move_error: int | None = None    # HRESULT every Move fails with
    busy_replies: int = 0            # requests answered E_BUSY_PROC without executing
    busy_function: int | None = None
    wrong_serial_first: bool = False  # first a copy of each reply under the previous serial (a late reply)
    stray_keepalive: bool = False     # send an S_EXECUTING before each reply
    fragment_replies: bool = False    # opt-in: send replies byte by byte (tests client reassembly)
    duplicate_replies: int = 0       # replies sent twice
    stale_replies: int = 0           # replies replaced by the previous reply (answer the previous request)
    drop_reply_bytes: int = 0        # replies with 3 bytes lost from their middle
    disconnect_after: int | None = None  # close each connection when it sends request number N + 1

    def matches(self, wanted: int | None, function_id: int) -> bool:
        return wanted is None or wanted == function_id


FAULT_KINDS = {  # --fault KIND[:PARAM] → (Faults fields set, default PARAM, help)
    "delay": ("delay_reply_s", 5.0, "a late reply: every reply waits PARAM s (default 5)"),
    "no-reply": ("drop_replies", ALL, "the next PARAM replies are not sent (default all)"),
    "busy": ("busy_replies", ALL, "the next PARAM requests get E_BUSY_PROC (default all)"),
    "move-error": ("move_error", 0x8350A005, "every Move fails with HRESULT PARAM (default 0x8350A005)"),
    "disconnect-after": ("disconnect_after", 20, "close each connection at request PARAM + 1 (default 20)"),
    "corrupt-crc": ("corrupt_crc", ALL, "serial line: the next PARAM replies have a bad CRC"),
    "duplicate": ("duplicate_replies", ALL, "the next PARAM replies are sent twice"),
    "stale": ("stale_replies", ALL, "the next PARAM requests are answered with the previous reply"),
    "drop-bytes": ("drop_reply_bytes", ALL, "the next PARAM replies lose 3 bytes"),
}


def parse_fault(text: str) -> tuple[str, int | float]:
    """``KIND[:PARAM]`` → (Faults field, value); argparse-style ``ValueError`` naming the allowed kinds."""
    kind, _, param = text.partition(":")
    if kind not in FAULT_KINDS:
        raise ValueError(f"fault {kind!r}: expected one of {', '.join(sorted(FAULT_KINDS))}")
    name, default, _help = FAULT_KINDS[kind]
    if not param:
        return name, default
    try:
        value: int | float = float(param) if isinstance(default, float) else int(param, 0)
    except ValueError:
        raise ValueError(f"fault {kind}:{param}: PARAM must be a {type(default).__name__}") from None
    if value < 0 and kind != "move-error":
        raise ValueError(f"fault {kind}:{param}: PARAM must be >= 0")
    return name, value


def _fault_arg(text: str) -> tuple[str, int | float]:
    try:
        return parse_fault(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from exc


class _Session:
    """One client connection: reads requests, executes them on the shared state one at a time (a
    blocking call is waited for in this thread, so later requests queue in the connection), writes replies."""

    def __init__(self, server: BcapMockServer, channel: Channel) -> None:
        self.server = server
        self.channel = channel
        self._write_lock = threading.Lock()
        self._cache: OrderedDict[int, tuple[int, list[w.Value]]] = OrderedDict()
        self._running_until_rest = False  # a blocking call whose InvokeTimeout expired still runs
        self._previous_reply: bytes | None = None  # for the "stale" fault
        self._stop = threading.Event()
        self.request_count = 0
        self.framer = w.Framer(serial_line=channel.serial_line,
                               max_length=w.MAX_SERIAL_LINE if channel.may_retry else None)
        self.thread = threading.Thread(target=self._run, name=f"bcap-{channel.name}", daemon=True)

    # -------------------------------------------------------------------------------------- reading
    def _run(self) -> None:
        framer = self.framer
        last_packet = time.monotonic()
        try:
            while not self._stop.is_set():
                data = self.channel.recv(0.05)
                if data:
                    last_packet = time.monotonic()
                elif self._client_silent_too_long(last_packet):
                    return
                framer.feed(data)
                while not self._stop.is_set():
                    try:
                        packet = framer.next()
                    except w.WireError as exc:
                        if self.channel.may_retry:  # serial line / UDP: nothing to close (our choice)
                            log.warning("%s: malformed request dropped: %s", self.channel.name, exc)
                            continue
                        log.warning("%s: malformed request, connection closed: %s", self.channel.name, exc)
                        return
                    if packet is None:
                        break
                    self._on_request(packet)
                    last_packet = time.monotonic()  # a blocking call waited for in here is no silence
        except EOFError:
            log.info("%s: client gone", self.channel.name)
        finally:
            self._stop.set()
            self.server._session_ended(self)
            self.channel.close()

    def stop(self) -> None:
        self._stop.set()
        self.channel.close()

    def _client_silent_too_long(self, last_packet: float) -> bool:
        """Client watchdog (:attr:`BcapMockServer.client_watchdog`): the client holding the controller sent
        nothing for ``CLIENT_WDT_FACTOR`` × WDT wall seconds since its last request was answered (a
        blocking call is waited for in this thread, so it never counts) → it is presumed dead: halt, motor
        off, handles dropped, session ended (as when its connection closes)."""
        wdt_ms = self.server.state.wdt_ms
        if not (self.server.client_watchdog and wdt_ms and self.server._active is self):
            return False
        silent_s = time.monotonic() - last_packet
        if silent_s <= CLIENT_WDT_FACTOR * wdt_ms / 1000.0:
            return False
        log.warning("%s: client silent for %.2f s (> %d × WDT %d ms): halting the arm, motor off, session "
                    "ended", self.channel.name, silent_s, CLIENT_WDT_FACTOR, wdt_ms)
        return True

    def _drop_connection(self) -> None:
        """The controller goes away (fault), or the client did during a blocking call: the arm is stopped
        first, as a controller would — unless a new client already holds it (its session was ended and the
        arm stopped when that client took over: :meth:`BcapMockServer._claim`)."""
        with self.server.lock:
            if self.server._active in (self, None):
                self.server.state.release_all()
        self.stop()

    def _bare(self, packet: w.Packet, code: int) -> None:
        """A refusal before execution: reply without arguments (reference server), never cached."""
        self._send(packet.serial, code, [], packet.code)

    def _on_request(self, packet: w.Packet) -> None:
        faults, function = self.server.faults, packet.code
        self.server.requests.append((packet.serial, packet.reserved, function))
        self.request_count += 1
        if faults.disconnect_after is not None and self.request_count > faults.disconnect_after:
            log.info("fault: connection closed at request %d", self.request_count)
            self._drop_connection()
            return
        original = packet.reserved if self.channel.may_retry and packet.reserved else packet.serial
        if not self.server._claim(self):  # another client holds the controller
            self._bare(packet, w.E_MAX_CONNECT)
            return
        if original != packet.serial and original in self._cache:  # a retry: re-send the same reply
            code, args = self._cache[original]
            self._send(packet.serial, code, args, function)
            return
        if self._running_until_rest and self.server.state.robot.is_moving(self.server.clock.now_s()):
            self._bare(packet, w.E_BUSY_PROC)  # the call whose InvokeTimeout expired still runs
            return
        self._running_until_rest = False
        if faults.busy_replies and faults.matches(faults.busy_function, function):
            faults.busy_replies -= 1
            self._bare(packet, w.E_BUSY_PROC)
            return
        self._execute(packet, function)

    def _execute(self, packet: w.Packet, function: int) -> None:
        faults = self.server.faults
        with self.server.lock:
            self.server.state.move_error = faults.move_error
            outcome = self.server.state.execute(function, list(packet.args))
        moving = function == ROBOT_MOVE and not w.failed(outcome.hresult)
        if faults.close_mid_move and moving:  # go away once the move has started, before any reply
            self._drop_connection()
            return
        if outcome.motion_end_s is not None and not w.failed(outcome.hresult):
            if self.server.instant_clock is not None:
                self.server.instant_clock.advance_to(outcome.motion_end_s)
            elif not self._wait_for_rest(packet):
                return
        if function == SERVICE_STOP:  # the client is done (all a serial line can say): controller free,
            self.server._release(self)  # before the reply, on which the next client may connect at once
        self._reply(packet, outcome.hresult, outcome.args)

    def _wait_for_rest(self, packet: w.Packet) -> bool:
        """Paced clock, blocking call: keep-alives every WDT ms until the body is at rest. False when no
        final reply is to be sent (InvokeTimeout expired, or the client went away: the arm is stopped)."""
        state, robot = self.server.state, self.server.state.robot
        wdt_s = state.wdt_ms / 1000.0 if state.wdt_ms else None
        started = time.monotonic()
        invoke_deadline = started + state.invoke_timeout_ms / 1000.0
        next_keepalive = started + wdt_s if wdt_s else float("inf")
        while robot.is_moving(self.server.clock.now_s()):
            now = time.monotonic()
            if now >= invoke_deadline:
                log.warning("serial %d: InvokeTimeout expired; no final reply", packet.serial)
                self._running_until_rest = True
                return False
            if now >= next_keepalive:
                self._write(w.build(packet.serial, 0, w.S_EXECUTING, serial_line=self.channel.serial_line))
                next_keepalive += wdt_s or 0.0
            if self._stop.is_set():
                return False
            wait_s = min(0.01, max(0.001, next_keepalive - now))
            if len(self.framer.buffer) >= QUEUE_LIMIT_BYTES:  # the rest waits in the socket
                self._stop.wait(wait_s)
                continue
            try:  # requests sent meanwhile queue here; a closed connection is seen at once
                self.framer.feed(self.channel.recv(wait_s))
            except EOFError:
                log.info("%s: client gone during a blocking call; the arm is stopped", self.channel.name)
                self._drop_connection()
                return False
        return True

    # -------------------------------------------------------------------------------------- writing
    def _reply(self, packet: w.Packet, code: int, args: list[w.Value]) -> None:
        if self.channel.may_retry:
            self._cache[packet.reserved or packet.serial] = (code, list(args))
            while len(self._cache) > CACHE_SIZE:
                self._cache.popitem(last=False)
        self._send(packet.serial, code, args, packet.code)

    def _send(self, serial: int, code: int, args: list[w.Value], function: int) -> None:
        faults = self.server.faults
        delayed = faults.delay_reply_s and faults.matches(faults.delay_function, function)
        if delayed and self._stop.wait(faults.delay_reply_s):
            return
        if faults.drop_replies and faults.matches(faults.drop_function, function):
            faults.drop_replies -= 1
            log.info("fault: reply to serial %d dropped", serial)
            return
        serial_line = self.channel.serial_line
        data = bytearray(w.build(serial, 0, code, args, serial_line=serial_line))
        if serial_line and faults.corrupt_crc:
            faults.corrupt_crc -= 1
            data[-2] ^= 0x5A
        if faults.stray_keepalive:
            self._write(w.build(serial, 0, w.S_EXECUTING, serial_line=serial_line))
        if faults.wrong_serial_first:
            # the previous request's serial, which the client has used up: the next serial (a retry's) would
            # let a client that timed out on a loaded machine take the copy for its retry's reply
            self._write(w.build((serial - 2) % 0xFFFF + 1, 0, code, args, serial_line=serial_line))
        self._write_faulty(bytes(data))

    def _write_faulty(self, data: bytes) -> None:
        """Write one reply through the stale / drop-bytes / duplicate faults."""
        faults = self.server.faults
        if faults.stale_replies:
            faults.stale_replies -= 1
            data, self._previous_reply = self._previous_reply or b"", data
        else:
            self._previous_reply = data
        if faults.drop_reply_bytes and len(data) > 8:
            faults.drop_reply_bytes -= 1
            middle = len(data) // 2
            data = data[:middle - 1] + data[middle + 2:]
        copies = 1
        if faults.duplicate_replies:
            faults.duplicate_replies -= 1
            copies = 2
        for _ in range(copies):
            if data:
                self._write(data)

    def _write(self, data: bytes) -> None:
        with self._write_lock:
            if self.server.faults.fragment_replies:
                for i in range(len(data)):
                    self.channel.send(data[i:i + 1])
            else:
                self.channel.send(data)  # one write per packet


class BcapMockServer:
    """The mock controller. Serve it over TCP (:meth:`serve_tcp`) and/or a pty (:meth:`serve_pty`).

    Args:
        robot: the simulated robot body (``world.robot``).
        clock: the rig clock (``world.clock``); an instant :class:`VirtualClock` is advanced to a Move's end.
        full_speed_mm_s, full_accel_mm_s2: what 100 % speed / acceleration mean on this controller.
        faults: fault switches (shared, may be changed while serving).
        client_watchdog: a client that set a WDT in Service_Start and then sends nothing for
            ``CLIENT_WDT_FACTOR`` × WDT (no call of its executing) is presumed dead: the arm is halted and
            released (what a controller must do when its client loses power without closing the
            connection). On in the stand-alone mock; off by default (in-process mocks die with the client).
    """

    def __init__(self, robot: RobotBodyLike, clock: Clock, *, full_speed_mm_s: float = 1000.0,
                 full_accel_mm_s2: float = 5000.0, faults: Faults | None = None,
                 client_watchdog: bool = False) -> None:
        # SciPy's Rotation turns the simulated arm (drivers.sim.bodies imports it at its first use): loaded
        # here, not by the first Move, whose reply would wait for the import (≈ 0.5 CPU-s)
        importlib.import_module("scipy.spatial.transform")
        self.clock = clock
        self.state = ControllerState(robot, clock, full_speed_mm_s=full_speed_mm_s,
                                     full_accel_mm_s2=full_accel_mm_s2)
        self.faults = faults or Faults()
        self.client_watchdog = client_watchdog
        self.lock = threading.RLock()
        # an instant virtual clock is advanced to a blocking move's end; any other clock is waited on
        self.instant_clock = clock if isinstance(clock, VirtualClock) and clock.is_instant else None
        self._sessions: list[_Session] = []
        self._active: _Session | None = None
        self._listener: socket.socket | None = None
        self._closing = threading.Event()
        self.port: int | None = None
        # (serial, reserved, function ID) as received, the newest MAX_REQUESTS_KEPT
        self.requests: History[tuple[int, int, int]] = History(MAX_REQUESTS_KEPT)

    def serve_tcp(self, host: str = "127.0.0.1", port: int = 0) -> int:
        """Listen on ``host:port`` (a loopback address; port 0 = ephemeral); return the bound port."""
        host = require_loopback(host)
        self._listener = socket.create_server((host, port))
        bound_port: int = self._listener.getsockname()[1]
        self.port = bound_port
        threading.Thread(target=accept_loop, args=(self._listener, self._closing, self._on_connection),
                         kwargs={"poll_s": 0.1}, name="bcap-accept", daemon=True).start()
        log.info("b-CAP mock listening on tcp://%s:%d", host, bound_port)
        return bound_port

    def serve_udp(self, host: str = "127.0.0.1", port: int = 0) -> int:
        """Serve b-CAP over UDP (503-byte packets, retry cache) on loopback ``host``; return the port."""
        channel = UdpChannel(require_loopback(host), port)
        self._start_session(channel)
        return channel.port

    def serve_pty(self) -> str:
        """Open a pty pair, serve its master with serial framing; return the slave name for the client."""
        channel = PtyChannel()
        self._start_session(channel)
        return channel.slave_name

    def _on_connection(self, sock: socket.socket) -> None:
        try:
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            channel = TcpChannel(sock)
        except OSError as exc:  # reset before it was served: the accept loop must live on
            log.info("connection gone before it was served: %s", exc)
            sock.close()
            return
        self._start_session(channel)

    def _start_session(self, channel: Channel) -> None:
        session = _Session(self, channel)
        with self.lock:  # listed and started together: close() never sees an unstarted session
            if self._closing.is_set():
                channel.close()
                return
            self._sessions.append(session)
            session.thread.start()

    @property
    def held_by(self) -> str | None:
        """The channel name of the client holding the controller, or None when it is free."""
        with self.lock:
            return self._active.channel.name if self._active is not None else None

    def _claim(self, session: _Session) -> bool:
        """True if ``session`` holds the controller (taking it when free); False if another client does.
        A holder whose client closed its connection is ended here, at once (arm stopped, handles dropped)
        rather than when its own thread next reads: a client reconnecting at once (a make-safe on a fresh
        link) is never refused for the session it has just closed, however late that thread runs."""
        with self.lock:
            holder = self._active
            if holder is not None and holder is not session and holder.channel.peer_closed():
                log.info("%s: client gone; session ended for %s", holder.channel.name, session.channel.name)
                self.state.release_all()
                self._active = None
            if self._active is None:
                self._active = session
                log.info("%s: holds the controller", session.channel.name)
            return self._active is session

    def _release(self, session: _Session) -> bool:
        """Free the controller if ``session`` held it; True if it did."""
        with self.lock:
            if self._active is not session:
                return False
            self._active = None
        log.info("%s: controller free", session.channel.name)
        return True

    def _session_ended(self, session: _Session) -> None:
        """A client went away: if it held the controller, the arm is stopped and its handles dropped."""
        with self.lock:
            if self._active is session:
                self.state.release_all()
                self._active = None
            if session in self._sessions:
                self._sessions.remove(session)

    def close(self) -> None:
        with self.lock:
            self._closing.set()
            sessions = list(self._sessions)
        if self._listener is not None:
            self._listener.close()
        for session in sessions:
            session.stop()
        for session in sessions:
            if session.thread is not threading.current_thread():
                session.thread.join(timeout=1.0)

    def __enter__(self) -> BcapMockServer:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()


def main(argv: list[str] | None = None, prog: str | None = None) -> int:
    """Serve until Ctrl-C or SIGTERM; ``prog`` names the command in help and errors."""
    parser = standalone_parser("bcap_server", "Mock DENSO RC8 controller (b-CAP) on the simulated robot.",
                               default_port=5007, prog=prog)
    parser.add_argument("--host", default="127.0.0.1", type=loopback_host,
                        help="loopback address to bind (default 127.0.0.1; other addresses are refused)")
    parser.add_argument("--pty", action="store_true", help="also serve a pty serial line (CRC framing)")
    kinds = "; ".join(f"{kind}: {text}" for kind, (_f, _d, text) in FAULT_KINDS.items())
    parser.add_argument("--fault", action="append", default=[], type=_fault_arg, metavar="KIND[:PARAM]",
                        help=f"inject a fault (repeatable). {kinds}")
    options, world = start_standalone(parser, argv)
    faults = Faults()
    for name, value in options.fault:
        setattr(faults, name, value)
    with BcapMockServer(world.robot, world.clock, faults=faults, client_watchdog=True) as server:
        port = server.serve_tcp(options.host, options.port)
        print(f"b-CAP mock RC8 on tcp://{options.host}:{port}", flush=True)
        if options.pty:
            print(f"b-CAP mock RC8 on serial://{server.serve_pty()} (CRC framing)", flush=True)
        wait_for_interrupt()
        print(f"b-CAP mock RC8 stopped; requests received: {len(server.requests)}", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())


__all__ = ["FAULT_KINDS", "BcapMockServer", "Faults", "parse_fault"]
