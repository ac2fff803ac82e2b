"""Mock VFD: a Modbus slave speaking Modbus TCP or Modbus RTU, backed by :class:`DriveModel` (the twin).

* Modbus TCP on ``127.0.0.1`` (port 0 = ephemeral), one thread per connection (at most
  :data:`MAX_CONNECTIONS`; finished threads are reaped);
* Modbus RTU on a serial line: by default a :class:`~drivers.mock.pty_link.PtyLink` is created and the
  server opens its device end, so a client opens :attr:`VfdServer.client_port` (``/dev/pts/N``) exactly
  like a USB–RS485 adapter; or a given device path.

How the slave behaves, and the source of each behaviour, is the table in ``docs/exciter.md`` ("Mock
drive: Modbus behaviour"). In short: an RTU frame ends when its length (known from the function code)
is complete with a valid CRC, or at t3.5 of silence; a frame with a CRC error is dropped, and after any
partial frame the slave is back in step at the next silence (where a dropped buffer still holds a
whole valid request — a silence the pty lost under load — that request is served). Exception replies
carry the request's function code | 0x80. Broadcast writes (unit 0) on RTU are carried out by every
drive without a reply.
A unit id not on the line gets no reply on RTU and exception 0x0B (gateway target failed to respond) on
TCP.

Fault injection (:meth:`VfdServer.inject`, or ``--fault KIND[:PARAM]`` on the command line, see
:data:`drivers.mock.modbus_faults.FAULT_KINDS`) applies to requests addressed to a drive of this server.

Run standalone (its own world with a paced clock)::

    python -m drivers.mock.vfd_server --port 5020            # Modbus TCP on 127.0.0.1:5020
    python -m drivers.mock.vfd_server --rtu                  # RTU on a new pty; prints the port name
    python -m drivers.mock.vfd_server --rtu --fault late:0.5 --fault busy:10
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import select
import socket
import threading
from collections.abc import Callable
from types import TracebackType

import serial

from drivers.mock._serve import (
    accept_loop,
    require_loopback,
    standalone_parser,
    start_standalone,
    wait_for_interrupt,
)
from drivers.mock.modbus_faults import FAULT_KINDS, Fault, FaultPlan, parse_fault
from drivers.mock.modbus_slave import ModbusSlave
from drivers.mock.pty_link import PtyLink
from drivers.mock.vfd_drive import DriveModel
from drivers.modbus import (
    BROADCAST,
    MBAP_BYTES,
    ExceptionCode,
    exception_pdu,
    mbap_adu,
    parse_mbap,
    request_pdu_length,
    rtu_adu,
    rtu_silence_s,
    split_rtu,
)

__all__ = ["MAX_CONNECTIONS", "VfdServer", "main"]

log = logging.getLogger(__name__)

HOUSEKEEPING_S = 0.02   # wall seconds between checks for trips that happen while nobody asks
MAX_CONNECTIONS = 8     # concurrent Modbus TCP clients (our choice; drive Ethernet cards allow a few)
MAX_RTU_ADU = 256       # Serial Line §2.5.1
IDLE_POLL_S = 0.1       # how often an idle reader looks at the stop flag


class VfdServer:
    """Serve one :class:`DriveModel`, or several with distinct unit ids sharing one line (an RS-485 bus
    with the exciter and the rotor drives), in background threads.

    mode: "tcp" or "rtu". host/port: TCP bind address (a loopback address only, ValueError otherwise;
    port 0 picks one). serial_port: RTU device path to open; None creates a pty pair (see
    :attr:`client_port`). baudrate: RTU line speed; it sets t3.5 (a pty carries bytes at any speed).
    faults: faults active from the start (the command line's ``--fault``).
    """

    def __init__(self, drive: DriveModel | list[DriveModel], *, mode: str = "tcp", host: str = "127.0.0.1",
                 port: int = 0, serial_port: str | None = None, baudrate: int = 115200,
                 faults: list[Fault] | None = None) -> None:
        if mode not in ("tcp", "rtu"):
            raise ValueError(f"mode={mode!r}: must be 'tcp' or 'rtu'")
        self.drives = list(drive) if isinstance(drive, list) else [drive]
        units = [d.map.unit_id for d in self.drives]
        if not self.drives or len(set(units)) != len(units):
            raise ValueError(f"drives need distinct unit ids on one line, got {units}")
        self.drive = self.drives[0]
        self.mode = mode
        self.host = require_loopback(host)
        self.port = port
        self.baudrate = baudrate
        self.silence_s = rtu_silence_s(baudrate)
        self.link: PtyLink | None = None
        self.slave = ModbusSlave(self.drives, mode)
        self._serial_port = serial_port
        self._plan = FaultPlan()
        for fault in faults or []:
            self._plan.add(fault)
        self._stopped = threading.Event()
        self._thread: threading.Thread | None = None  # the serving thread (liveness)
        self._threads: list[threading.Thread] = []
        self._connections: dict[threading.Thread, socket.socket] = {}
        self._conn_lock = threading.Lock()
        self._listener: socket.socket | None = None
        self._serial: serial.Serial | None = None
        self._write_lock = threading.Lock()
        self._last_reply: bytes | None = None
        self.replies_sent = 0
        self.requests_received = 0  # request frames that reached the server (any unit id)
        self.frames_dropped = 0  # RTU frames discarded (CRC error, overlong, cut by silence)

    # addresses ------------------------------------------------------------------------------------------
    @property
    def client_port(self) -> str:
        """RTU: the serial port a client opens (the pty's other end)."""
        if self.link is not None:
            return self.link.client_port
        if self._serial_port is None:
            raise RuntimeError("client_port: the server is not started in RTU mode")
        return self._serial_port

    @property
    def url(self) -> str:
        return f"tcp://{self.host}:{self.port}" if self.mode == "tcp" else self.client_port

    @property
    def serving(self) -> bool:
        """The serving thread (TCP accept loop or RTU loop) is alive: False before :meth:`start` and once
        it died or stopped."""
        return self._thread is not None and self._thread.is_alive()

    @property
    def connection_threads(self) -> int:
        """TCP connection threads still alive."""
        with self._conn_lock:
            return sum(t.is_alive() for t in self._connections)

    @property
    def connections_tracked(self) -> int:
        """TCP connection threads the server still holds (finished ones are reaped at the next accept)."""
        with self._conn_lock:
            return len(self._connections)

    # lifecycle ------------------------------------------------------------------------------------------
    def start(self) -> VfdServer:
        if self.mode == "tcp":
            self._listener = socket.create_server((self.host, self.port))
            self.port = self._listener.getsockname()[1]
            self._thread = self._spawn(self._accept, f"vfd-mock tcp :{self.port}")
        else:
            if self._serial_port is None:
                self.link = PtyLink()
            port = self.link.device_port if self.link is not None else self._serial_port
            self._serial = serial.serial_for_url(port, baudrate=self.baudrate, timeout=0, write_timeout=2.0)
            self._thread = self._spawn(self._serve_rtu, f"vfd-mock rtu {port}")
        self._spawn(self._housekeeping, "vfd-mock housekeeping")
        return self

    def _spawn(self, target: Callable[[], object], name: str) -> threading.Thread:
        thread = threading.Thread(target=target, name=name, daemon=True)
        self._threads.append(thread)
        thread.start()
        return thread

    def _housekeeping(self) -> None:
        while not self._stopped.wait(HOUSEKEEPING_S):
            for drive in self.drives:
                drive.advance(drive.clock.now_s())

    def stop(self) -> None:
        """Shut the server down and close the pty link; idempotent."""
        self._stopped.set()
        if self._listener is not None:
            with contextlib.suppress(OSError):
                self._listener.close()
        with self._conn_lock:
            for conn in self._connections.values():
                with contextlib.suppress(OSError):
                    conn.shutdown(socket.SHUT_RDWR)
            threads = [*self._threads, *self._connections]
        for thread in threads:
            if thread is not threading.current_thread():
                thread.join(timeout=5.0)
        if self._serial is not None:
            with contextlib.suppress(OSError, serial.SerialException):
                self._serial.close()
        if self.link is not None:
            self.link.close()

    def __enter__(self) -> VfdServer:
        return self.start()

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.stop()

    # fault injection ------------------------------------------------------------------------------------
    def inject(self, fault: str, value: float | None = None, *, count: int | None = 1, every: int = 1,
               exception_code: int = 6) -> None:
        """Apply ``fault`` (a kind of :data:`~drivers.mock.modbus_faults.FAULTS`) to the next ``count``
        requests it is due for (``None``: until :meth:`clear_faults`), every ``every``-th request.
        ``value``: see :data:`FAULT_KINDS` ("late": seconds, default 1; "trip": fault code; "drop": bytes;
        "disconnect": seconds an RTU cable stays pulled, default until :meth:`clear_faults`).
        ``exception_code`` is the code of kind "exception"."""
        if fault == "exception":
            if exception_code not in {int(c) for c in ExceptionCode}:
                raise ValueError(f"exception_code={exception_code!r}: must be one of "
                                 f"{sorted(int(c) for c in ExceptionCode)}")
            value = exception_code
        elif value is None and fault in ("late", "trip", "drop"):
            value = FAULT_KINDS[fault][1]
        self._plan.add(Fault(fault, value, every=every, count=count))

    def clear_faults(self) -> None:
        self._plan.clear()
        if self.link is not None:
            self.link.plug()

    def _respond(self, unit: int, pdu: bytes) -> tuple[bytes | None, dict[str, Fault]]:
        """The reply PDU to one request addressed to this line, and the faults due for it."""
        due = self._plan.next_request()
        running = [d for d in self.drives if d.running and not d.fault_code]
        if running and (code := self._plan.take_trip()) is not None:
            for drive in running:
                drive.trip(code)
        if "busy" in due or "exception" in due:
            busy = int(ExceptionCode.SERVER_DEVICE_BUSY)
            code = int(due["exception"].value or busy) if "exception" in due else busy
            if unit == BROADCAST and self.mode == "rtu":
                return None, due
            return exception_pdu(pdu[0] if pdu else 0, code), due
        return self.slave.handle(unit, pdu), due

    def _outgoing(self, adu: bytes, due: dict[str, Fault]) -> list[bytes]:
        """The byte strings actually sent for reply ``adu`` (faults applied); [] for none."""
        previous, self._last_reply = self._last_reply, adu
        if "no_reply" in due:
            return []
        if "previous" in due and previous is not None:
            adu = previous
        if "bad_crc" in due:
            adu = (adu[:-2] + bytes([adu[-2] ^ 0xFF, adu[-1]])) if self.mode == "rtu" else \
                adu[:2] + b"\xff\xff" + adu[4:]
        if "drop" in due:
            k = max(1, int(due["drop"].value or 1))
            mid = len(adu) // 2
            adu = adu[:max(1, mid - k // 2)] + adu[max(1, mid - k // 2) + k:]
        return [adu, adu] if "twice" in due else [adu]

    def _delay(self, due: dict[str, Fault]) -> None:
        if "late" in due:
            self._stopped.wait(float(due["late"].value or 1.0))

    # Modbus TCP -----------------------------------------------------------------------------------------
    def _accept(self) -> None:
        assert self._listener is not None
        accept_loop(self._listener, self._stopped, self._on_connection)

    def _on_connection(self, conn: socket.socket) -> None:
        with self._conn_lock:
            for thread in [t for t in self._connections if not t.is_alive()]:
                thread.join()
                del self._connections[thread]  # reap finished connection threads
            if len(self._connections) >= MAX_CONNECTIONS:
                log.warning("refusing a Modbus TCP connection: %d clients already", MAX_CONNECTIONS)
                conn.close()
                return
            thread = threading.Thread(target=self._serve_connection, args=(conn,), daemon=True,
                                      name=f"vfd-mock tcp client {len(self._connections) + 1}")
            self._connections[thread] = conn
        thread.start()

    def _serve_connection(self, conn: socket.socket) -> None:
        buffer = bytearray()
        conn.settimeout(IDLE_POLL_S)
        with contextlib.suppress(OSError), conn:
            while not self._stopped.is_set():
                try:
                    chunk = conn.recv(4096)
                except TimeoutError:
                    continue
                if not chunk:
                    return
                buffer += chunk
                while len(buffer) >= MBAP_BYTES:
                    tid, protocol, length, unit = parse_mbap(bytes(buffer[:MBAP_BYTES]))
                    if not 2 <= length <= 254:
                        return  # cannot find the next frame in the stream: close (our choice)
                    if len(buffer) < MBAP_BYTES - 1 + length:
                        break
                    pdu = bytes(buffer[MBAP_BYTES:MBAP_BYTES - 1 + length])
                    del buffer[:MBAP_BYTES - 1 + length]
                    if protocol != 0:
                        continue  # not Modbus: discarded (TCP guide §4.4.1.2)
                    if not self._tcp_request(conn, tid, unit, pdu):
                        return

    def _tcp_request(self, conn: socket.socket, tid: int, unit: int, pdu: bytes) -> bool:
        """Answer one request; False when the connection is to be closed."""
        self.requests_received += 1
        reply, due = self._respond(unit, pdu)
        if "disconnect" in due:
            return False
        if reply is None:
            return True
        self._delay(due)
        for data in self._outgoing(mbap_adu(tid, unit, reply), due):
            conn.sendall(data)
            self.replies_sent += 1
        return True

    # Modbus RTU -----------------------------------------------------------------------------------------
    def _serve_rtu(self) -> None:
        assert self._serial is not None
        fd = self._serial.fileno()
        buffer = bytearray()
        overlong = False  # more than an RTU frame arrived without a silence: only the tail is kept
        while not self._stopped.is_set():
            ready, _, _ = select.select([fd], [], [], self.silence_s if buffer else IDLE_POLL_S)
            if not ready:
                if buffer:
                    self._rtu_frame_at_silence(bytes(buffer), overlong)
                buffer.clear()
                overlong = False
                continue
            try:
                chunk = self._serial.read(max(1, self._serial.in_waiting))
            except (OSError, serial.SerialException):
                if self._stopped.wait(IDLE_POLL_S):
                    return
                continue
            if not chunk:
                self._stopped.wait(self.silence_s)
                continue
            buffer += chunk
            while not overlong and (frame := self._complete_rtu_frame(buffer)) is not None:
                self._rtu_request(frame)
            if len(buffer) > MAX_RTU_ADU:
                del buffer[:-MAX_RTU_ADU]
                overlong = True

    @staticmethod
    def _complete_rtu_frame(buffer: bytearray) -> bytes | None:
        """A frame complete by the length its function code implies, with a valid CRC (removed from
        ``buffer``); else None (the frame will end at the next silence)."""
        if len(buffer) < 2:
            return None
        n = request_pdu_length(bytes(buffer[1:7]))
        if not n or len(buffer) < n + 3:
            return None
        frame = bytes(buffer[:n + 3])
        if split_rtu(frame) is None:
            return None
        del buffer[:n + 3]
        return frame

    def _rtu_frame_at_silence(self, data: bytes, overlong: bool) -> None:
        if not overlong and split_rtu(data) is not None:
            self._rtu_request(data)
            return
        self.frames_dropped += 1  # CRC error, a partial or an overlong frame: the slave ignores it ...
        for frame in self._hunt_rtu_frames(data):
            self._rtu_request(frame)  # ... but not a valid frame that a loaded pty ran into it

    def _hunt_rtu_frames(self, data: bytes) -> list[bytes]:
        """Valid request frames (by length and CRC) addressed to this line inside ``data``. Our choice: a
        pty carries no byte timing, so on a loaded machine the silence before a request can be lost
        between the client's write and this thread's read; a UART-fed slave would have seen it."""
        frames, i = [], 0
        while i + 4 <= len(data):
            n = request_pdu_length(data[i + 1:i + 7]) if self.slave.addressed(data[i]) else None
            if n and i + n + 3 <= len(data) and split_rtu(data[i:i + n + 3]) is not None:
                frames.append(data[i:i + n + 3])
                i += n + 3
            else:
                i += 1
        return frames

    def _rtu_request(self, frame: bytes) -> None:
        parts = split_rtu(frame)
        assert parts is not None
        unit, pdu = parts
        self.requests_received += 1
        if not self.slave.addressed(unit) or (self.link is not None and not self.link.plugged):
            return
        reply, due = self._respond(unit, pdu)
        if "disconnect" in due and self.link is not None:
            fault = due["disconnect"]
            self.link.unplug()
            if fault.value is not None:
                timer = threading.Timer(float(fault.value), self.link.plug)
                timer.daemon = True
                timer.start()
            return
        if reply is None:
            return
        self._delay(due)
        port = self._serial
        assert port is not None  # RTU requests come only from the serial line (_serve_rtu)
        for data in self._outgoing(rtu_adu(unit, reply), due):
            with self._write_lock:
                port.write(data)
            self.replies_sent += 1


def _parser(prog: str | None) -> argparse.ArgumentParser:
    parser = standalone_parser("vfd_server", "Mock VFD (Delta-style register map) on Modbus TCP or RTU.",
                               default_port=5020, prog=prog)
    parser.add_argument("--rtu", action="store_true", help="Modbus RTU on a new pty pair, not TCP")
    parser.add_argument("--serial", default=None, help="RTU on this serial device instead of a pty")
    parser.add_argument("--baud", type=int, default=115200, help="RTU line speed (sets t3.5)")
    parser.add_argument("--body", choices=("exciter", "rotor"), default="exciter", help="twin body to move")
    parser.add_argument("--unit", type=int, default=None,
                        help="Modbus unit id 1..247 (default: 1 for the exciter, 2 for the rotor, as in "
                             "rig/data/sim.toml)")
    parser.add_argument("--gear-ratio", type=float, default=1.0, help="drive Hz per body Hz")
    parser.add_argument("--max-output-hz", type=float, default=50.0)
    parser.add_argument("--watchdog-s", type=float, default=None)
    kinds = "; ".join(f"{k}: {text} (default {d:g})" for k, (text, d) in FAULT_KINDS.items())
    parser.add_argument("--fault", action="append", default=[], metavar="KIND[:PARAM]",
                        help=f"inject a fault (repeatable). {kinds}")
    return parser


DEFAULT_UNITS = {"exciter": 1, "rotor": 2}


def main(argv: list[str] | None = None, prog: str | None = None) -> int:
    """Serve until Ctrl-C or SIGTERM; ``prog`` names the command in help and errors."""
    from dataclasses import replace

    from drivers.exciter.register_map import DELTA_MAP

    parser = _parser(prog)
    args, world = start_standalone(parser, argv)
    try:
        faults = [parse_fault(text) for text in args.fault]
        regs = replace(DELTA_MAP, unit_id=DEFAULT_UNITS[args.body] if args.unit is None else args.unit)
    except ValueError as exc:
        parser.error(str(exc))
    body = {"exciter": world.exciter, "rotor": world.rotor}[args.body]  # the --body choices
    drive = DriveModel(body, world.clock, register_map=regs, gear_ratio=args.gear_ratio,
                       max_output_hz=args.max_output_hz, watchdog_s=args.watchdog_s)
    mode = "rtu" if (args.rtu or args.serial) else "tcp"
    with VfdServer(drive, mode=mode, port=args.port, serial_port=args.serial, baudrate=args.baud,
                   faults=faults) as server:
        note = f"; faults: {', '.join(args.fault)}" if args.fault else ""
        with contextlib.suppress(KeyboardInterrupt):  # a Ctrl-C right after the line is a clean stop too
            print(f"mock VFD ({args.body}, unit {regs.unit_id}) serving Modbus {mode.upper()} at "
                  f"{server.url}{note}", flush=True)
            wait_for_interrupt()
        print(f"mock VFD ({args.body}) stopped; requests received: {server.requests_received}", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
