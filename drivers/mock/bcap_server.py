"""A mock DENSO RC8 controller speaking b-CAP over TCP (127.0.0.1) or a pty serial line (with CRC).

Behind it is the simulated robot body (``world.robot``) and the rig's virtual clock: a Move starts the
body's move at the current virtual time and lasts as long as the body says. In *instant* clock mode the
server advances the clock to the end of the move and replies at once; in *paced* mode the reply waits
until the move ends in (scaled) wall time, with S_EXECUTING keep-alives every WDT ms meanwhile.

Protocol behaviour (``../shared/notes/bcap.md`` §15): each reply is one write; handles are returned as
VT_UI4 and accepted as VT_I4 or VT_UI4; a request arriving while a Move executes gets E_BUSY_PROC; on a
serial line a retry (reserved field = first attempt's serial) is answered from the reply cache and
bad-CRC packets are dropped silently. Fault switches are in :class:`Faults`.

**One client at a time**, over all channels: the controller state is one arm whose cleanup when a client
goes away halts the robot, switches the motor off and drops *every* handle — two concurrent clients
(say one on TCP, one on the serial line) would pull the arm from under each other, so the mock does not
serve one client per channel. A client holds the controller from its first request until its connection
ends or it sends Service_Stop (a serial line has no connection to close: Service_Stop, which the driver
sends last, ends its session); a request of any other client meanwhile gets E_MAX_CONNECT. An open but
silent channel holds nothing, so serving ``--pty`` beside TCP does not lock TCP clients out. (A serial
client that dies without Service_Stop keeps the controller until the mock restarts.)

The mock binds loopback addresses only (127.0.0.1 by default): ``ValueError`` / a usage error otherwise.

Run on its own (own world, paced clock at real time)::

    python -m drivers.mock.bcap_server --port 5007          # tcp://127.0.0.1:5007
    python -m drivers.mock.bcap_server --port 0             # any free port; the first line printed says which
    python -m drivers.mock.bcap_server --pty                # also prints the pty slave to open
"""

from __future__ import annotations

import logging
import socket
import threading
import time
from collections import OrderedDict
from dataclasses import dataclass
from types import TracebackType
from typing import Any

from drivers.denso import hresult as hr
from drivers.denso.bcap import ROBOT_MOVE, SERVICE_STOP, Packet, PacketDecoder, encode_packet
from drivers.denso.variant import EMPTY, Variant
from drivers.mock._serve import (
    accept_loop,
    loopback_host,
    require_loopback,
    standalone_parser,
    start_standalone,
    wait_for_interrupt,
)
from drivers.mock.bcap_args import VALUE_RETURNING
from drivers.mock.bcap_channels import Channel, PtyChannel, TcpChannel, UdpChannel
from drivers.mock.bcap_state import ControllerState, RobotBodyLike

log = logging.getLogger(__name__)
CACHE_SIZE = 32


@dataclass
class Faults:
    """Fault-injection switches; counters decrement as faults fire. ``*_function`` None = any function."""

    drop_replies: int = 0            # replies executed but never sent (a retry gets the cached reply)
    drop_function: int | None = None
    delay_reply_s: float = 0.0       # wall delay before replies to delay_function
    delay_function: int | None = None
    corrupt_crc: int = 0             # serial line: replies sent with a broken CRC
    close_mid_move: bool = False     # close the connection once a Move has started (blocking or NEXT)
    move_error: int | None = None    # HRESULT every Move fails with
    busy_replies: int = 0            # requests answered E_BUSY_PROC without executing
    busy_function: int | None = None
    wrong_serial_first: bool = False  # send a copy of each reply under another serial first
    stray_keepalive: bool = False     # send an S_EXECUTING before each reply
    fragment_replies: bool = False    # opt-in: send replies byte by byte (tests client reassembly)

    def matches(self, wanted: int | None, function_id: int) -> bool:
        return wanted is None or wanted == function_id


class _Session:
    """One client connection: reads requests, executes them on the shared state, writes replies."""

    def __init__(self, server: BcapMockServer, channel: Channel) -> None:
        self.server = server
        self.channel = channel
        self._write_lock = threading.Lock()
        self._cache: OrderedDict[int, tuple[int, int, list[Variant]]] = OrderedDict()
        self._executing: tuple[int, int] | None = None  # (original serial, function) of a running Move
        self._stop = threading.Event()
        self.thread = threading.Thread(target=self._run, name=f"bcap-{channel.name}", daemon=True)

    # -------------------------------------------------------------------------------------- reading
    def _run(self) -> None:
        decoder = PacketDecoder(serial_line=self.channel.serial_line)
        try:
            while not self._stop.is_set():
                decoder.feed(self.channel.recv(0.05))
                while True:
                    try:
                        packet = decoder.next_packet()
                    except hr.BcapProtocolError as exc:
                        log.warning("%s: malformed request dropped: %s", self.channel.name, exc)
                        continue
                    if packet is None:
                        break
                    self._on_request(packet)
        except EOFError:
            log.info("%s: client gone", self.channel.name)
        finally:
            self._stop.set()
            self.server._session_ended(self)
            self.channel.close()

    def stop(self) -> None:
        self._stop.set()
        self.channel.close()

    def _drop_connection(self) -> None:
        """Fault: the controller goes away mid-move. It stops the arm first, as a controller would."""
        with self.server.lock:
            self.server.state.release_all()
        self.stop()

    def _on_request(self, packet: Packet) -> None:
        faults, function = self.server.faults, packet.code
        self.server.requests.append((packet.serial, packet.reserved, function))
        original = packet.reserved if self.channel.may_retry and packet.reserved else packet.serial
        if not self.server._claim(self):  # another client holds the controller
            self._reply(packet, hr.E_MAX_CONNECT, [EMPTY] if function in VALUE_RETURNING else [], cache=False)
            return
        if original != packet.serial:
            if original in self._cache:  # a retry of an answered request: re-send the same reply
                _fn, code, args = self._cache[original]
                self._send(packet.serial, code, args, function)
                return
            if self._executing and self._executing[0] == original:
                return  # still executing: the final reply goes out under the first serial
        injected_busy = bool(faults.busy_replies) and faults.matches(faults.busy_function, function)
        if self._executing is not None or injected_busy:
            if self._executing is None:
                faults.busy_replies -= 1
            self._reply(packet, hr.E_BUSY_PROC, [EMPTY] if function in VALUE_RETURNING else [], cache=False)
            return
        with self.server.lock:
            self.server.state.move_error = faults.move_error
            outcome = self.server.state.execute(function, list(packet.args))
        if faults.close_mid_move and function == ROBOT_MOVE and not hr.is_failure(outcome.hresult) \
                and outcome.motion_end_s is None:  # a NEXT move has started: go away before the reply
            self._drop_connection()
            return
        if outcome.motion_end_s is None or hr.is_failure(outcome.hresult):
            if function == SERVICE_STOP:  # the client is done (all a serial line can say): controller free,
                self.server._release(self)  # before the reply, on which the next client may connect at once
            self._reply(packet, outcome.hresult, outcome.args)
            return
        if self.server.instant:
            if faults.close_mid_move:
                self._drop_connection()
                return
            self.server.clock.advance_to(outcome.motion_end_s)
            self._reply(packet, outcome.hresult, outcome.args)
            return
        self._executing = (original, function)
        threading.Thread(target=self._wait_for_move, args=(packet, outcome.hresult, outcome.args),
                         name=f"bcap-move-{packet.serial}", daemon=True).start()

    def _wait_for_move(self, packet: Packet, code: int, args: list[Variant]) -> None:
        """Paced clock: keep-alives every WDT ms until the body is at rest, then the final reply."""
        state, robot = self.server.state, self.server.state.robot
        wdt_s = state.wdt_ms / 1000.0 if state.wdt_ms else None
        started = time.monotonic()
        invoke_deadline = started + state.invoke_timeout_ms / 1000.0
        next_keepalive = started + wdt_s if wdt_s else float("inf")
        try:
            while robot.is_moving(self.server.clock.now_s()):
                if self.server.faults.close_mid_move:
                    self._drop_connection()
                    return
                now = time.monotonic()
                if now >= invoke_deadline:
                    log.warning("serial %d: InvokeTimeout expired; no final reply", packet.serial)
                    return
                if now >= next_keepalive:
                    self._write(encode_packet(packet.serial, 0, hr.S_EXECUTING, [],
                                              serial_line=self.channel.serial_line))
                    next_keepalive += wdt_s or 0.0
                if self._stop.wait(min(0.01, max(0.0, next_keepalive - now))):
                    return
            self._executing = None  # before the reply: the client may send its next request at once
            self._reply(packet, code, args)
        except EOFError:
            self.stop()
        finally:
            self._executing = None

    # -------------------------------------------------------------------------------------- writing
    def _reply(self, packet: Packet, code: int, args: list[Any], *, cache: bool = True) -> None:
        if cache and self.channel.may_retry:
            original = packet.reserved or packet.serial
            self._cache[original] = (packet.code, code, list(args))
            while len(self._cache) > CACHE_SIZE:
                self._cache.popitem(last=False)
        self._send(packet.serial, code, args, packet.code)

    def _send(self, serial: int, code: int, args: list[Any], function: int) -> None:
        faults = self.server.faults
        delayed = faults.delay_reply_s and faults.matches(faults.delay_function, function)
        if delayed and self._stop.wait(faults.delay_reply_s):
            return
        if faults.drop_replies and faults.matches(faults.drop_function, function):
            faults.drop_replies -= 1
            log.info("fault: reply to serial %d dropped", serial)
            return
        serial_line = self.channel.serial_line
        data = bytearray(encode_packet(serial, 0, code, args, serial_line=serial_line))
        if serial_line and faults.corrupt_crc:
            faults.corrupt_crc -= 1
            data[-2] ^= 0x5A
        if faults.stray_keepalive:
            self._write(encode_packet(serial, 0, hr.S_EXECUTING, [], serial_line=serial_line))
        if faults.wrong_serial_first:
            self._write(encode_packet(serial % 0xFFFF + 1, 0, code, args, serial_line=serial_line))
        self._write(bytes(data))

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
        clock: the rig clock (``world.clock``); instant mode if it has ``is_instant`` true.
        full_speed_mm_s, full_accel_mm_s2: what 100 % speed / acceleration mean on this controller.
        faults: fault switches (shared, may be changed while serving).
    """

    def __init__(self, robot: RobotBodyLike, clock: Any, *, full_speed_mm_s: float = 1000.0,
                 full_accel_mm_s2: float = 5000.0, faults: Faults | None = None) -> None:
        self.clock = clock
        self.state = ControllerState(robot, clock, full_speed_mm_s=full_speed_mm_s,
                                     full_accel_mm_s2=full_accel_mm_s2)
        self.faults = faults or Faults()
        self.lock = threading.RLock()
        self.instant = bool(getattr(clock, "is_instant", False))
        self._sessions: list[_Session] = []
        self._active: _Session | None = None
        self._listener: socket.socket | None = None
        self._closing = threading.Event()
        self.port: int | None = None
        self.requests: list[tuple[int, int, int]] = []  # (serial, reserved, function ID) as received

    def serve_tcp(self, host: str = "127.0.0.1", port: int = 0) -> int:
        """Listen on ``host:port`` (a loopback address; port 0 = ephemeral); return the bound port."""
        host = require_loopback(host)
        self._listener = socket.create_server((host, port))
        self.port = self._listener.getsockname()[1]
        threading.Thread(target=accept_loop, args=(self._listener, self._closing, self._on_connection),
                         kwargs={"poll_s": 0.1}, name="bcap-accept", daemon=True).start()
        log.info("b-CAP mock listening on tcp://%s:%d", host, self.port)
        return self.port

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
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self._start_session(TcpChannel(sock))

    def _start_session(self, channel: Channel) -> None:
        session = _Session(self, channel)
        with self.lock:
            self._sessions.append(session)
        session.thread.start()

    def _claim(self, session: _Session) -> bool:
        """True if ``session`` holds the controller (taking it when free); False if another client does."""
        with self.lock:
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
        self._closing.set()
        if self._listener is not None:
            self._listener.close()
        for session in list(self._sessions):
            session.stop()
        for session in list(self._sessions):
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
    options, world = start_standalone(parser, argv)
    with BcapMockServer(world.robot, world.clock) as server:
        port = server.serve_tcp(options.host, options.port)
        print(f"b-CAP mock RC8 on tcp://{options.host}:{port}", flush=True)
        if options.pty:
            print(f"b-CAP mock RC8 on serial://{server.serve_pty()} (CRC framing)", flush=True)
        wait_for_interrupt()
        print(f"b-CAP mock RC8 stopped; requests received: {len(server.requests)}", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())


__all__ = ["BcapMockServer", "Faults"]
