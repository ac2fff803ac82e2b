"""Mock VFD: a pymodbus server (SimDevice action API) speaking Modbus TCP or RTU, moving the twin.

The drive's behaviour is :class:`drivers.mock.vfd_drive.DriveModel`; this module serves it

* over Modbus TCP on ``127.0.0.1`` (port 0 = ephemeral), or
* over Modbus RTU on a serial line: by default a :class:`~drivers.mock.pty_link.PtyLink` is created and
  the server opens its device end, so a client opens :attr:`VfdServer.client_port` (``/dev/pts/N``)
  exactly like a USB–RS485 adapter; or a given device path.

Fault injection (:meth:`VfdServer.inject`), each for the next ``count`` replies or until
:meth:`VfdServer.clear_faults` (``count=None``):

* ``"no_reply"`` — the request is executed but the reply is not sent;
* ``"bad_crc"`` — the reply's CRC is corrupted (RTU); on TCP the MBAP protocol id is corrupted;
* ``"exception"`` — the request is refused with Modbus exception ``exception_code`` (default 6, busy);
* ``"disconnect"`` — TCP: the connection is closed instead of replying; RTU: the cable is pulled
  (everything is lost until :meth:`clear_faults`).

On RTU the drive stays silent for requests to other unit ids, like a slave on a shared RS-485 bus.

Drive faults (overload, overspeed, watchdog) are :class:`DriveModel` parameters or ``server.drive.trip``.

Run standalone (its own world with a paced clock)::

    python -m drivers.mock.vfd_server --port 5020            # Modbus TCP on 127.0.0.1:5020
    python -m drivers.mock.vfd_server --rtu                  # RTU on a new pty; prints the port name
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import threading
from types import TracebackType

from pymodbus.constants import ExcCodes
from pymodbus.framer import FramerType
from pymodbus.server import ModbusSerialServer, ModbusTcpServer

from drivers.mock._serve import require_loopback, standalone_parser, start_standalone, wait_for_interrupt
from drivers.mock.pty_link import PtyLink
from drivers.mock.vfd_drive import DriveModel

__all__ = ["FAULTS", "VfdServer", "main"]

log = logging.getLogger(__name__)

FAULTS = ("no_reply", "bad_crc", "exception", "disconnect")
HOUSEKEEPING_S = 0.02  # wall seconds between checks for trips that happen while nobody asks


class VfdServer:
    """Serve one :class:`DriveModel`, or several with distinct unit ids sharing one line (an RS-485
    bus with the exciter and the rotor drives), in a background thread (its own asyncio loop).

    mode: "tcp" or "rtu". host/port: TCP bind address (a loopback address only, ValueError otherwise;
    port 0 picks one).
    serial_port: RTU device path to open; None creates a pty pair (see :attr:`client_port`).
    baudrate: RTU line speed (a pty ignores it, but pymodbus times frames with it).
    """

    def __init__(self, drive: DriveModel | list[DriveModel], *, mode: str = "tcp", host: str = "127.0.0.1",
                 port: int = 0,
                 serial_port: str | None = None, baudrate: int = 115200) -> None:
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
        self.link: PtyLink | None = None
        self._serial_port = serial_port
        self._fault: tuple[str, int | None, int] | None = None  # (kind, remaining or None, exception code)
        self._fault_lock = threading.Lock()
        self._loop: asyncio.AbstractEventLoop | None = None
        self._server: ModbusTcpServer | ModbusSerialServer | None = None
        self._thread: threading.Thread | None = None
        self._ready = threading.Event()
        self._error: BaseException | None = None
        self.replies_sent = 0
        self.requests_received = 0  # request frames that reached the server (any unit id)

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

    # lifecycle ------------------------------------------------------------------------------------------
    def start(self, timeout_s: float = 5.0) -> VfdServer:
        if self.mode == "rtu" and self._serial_port is None:
            self.link = PtyLink()
        self._thread = threading.Thread(target=self._run, name=f"vfd-mock {self.mode}", daemon=True)
        self._thread.start()
        if not self._ready.wait(timeout_s):
            raise RuntimeError(f"VFD mock did not start within {timeout_s} s")
        if self._error is not None:
            raise RuntimeError(f"VFD mock failed to start: {self._error}") from self._error
        return self

    def _run(self) -> None:
        loop = asyncio.new_event_loop()
        self._loop = loop
        asyncio.set_event_loop(loop)
        try:
            loop.run_until_complete(self._serve())
        except BaseException as exc:  # reported to start()
            self._error = exc
            self._ready.set()
        finally:
            loop.close()

    async def _serve(self) -> None:
        device = [d.sim_device() for d in self.drives]
        if self.mode == "tcp":
            server: ModbusTcpServer | ModbusSerialServer = ModbusTcpServer(
                device, address=(self.host, self.port), trace_packet=self._trace_packet)
        else:
            port = self.link.device_port if self.link is not None else self._serial_port
            server = ModbusSerialServer(device, port=port or "", framer=FramerType.RTU,
                                        baudrate=self.baudrate, trace_packet=self._trace_packet,
                                        reconnect_delay=0.1)
        self._server = server
        await server.serve_forever(background=True)
        if self.mode == "tcp":
            self.port = server.transport.sockets[0].getsockname()[1]  # type: ignore[union-attr]
        self._stop_event = asyncio.Event()
        self._ready.set()
        while not self._stop_event.is_set():
            for drive in self.drives:
                drive.advance(drive.clock.now_s())
            with contextlib.suppress(asyncio.TimeoutError):
                await asyncio.wait_for(self._stop_event.wait(), HOUSEKEEPING_S)
        await server.shutdown()

    def stop(self) -> None:
        """Shut the server down and close the pty link; idempotent."""
        if self._loop is not None and self._thread is not None and self._thread.is_alive():
            self._loop.call_soon_threadsafe(self._stop_event.set)
            self._thread.join(timeout=5.0)
        if self.link is not None:
            self.link.close()

    def __enter__(self) -> VfdServer:
        return self.start()

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.stop()

    # fault injection ------------------------------------------------------------------------------------
    def inject(self, fault: str, *, count: int | None = 1, exception_code: int = 6) -> None:
        """Make the next ``count`` replies faulty (``None``: until :meth:`clear_faults`)."""
        if fault not in FAULTS:
            raise ValueError(f"fault={fault!r}: must be one of {FAULTS}")
        if count is not None and count < 1:
            raise ValueError(f"count={count!r}: must be >= 1 or None")
        if exception_code not in {int(c) for c in ExcCodes}:
            allowed = sorted(int(c) for c in ExcCodes)
            raise ValueError(f"exception_code={exception_code!r}: must be one of {allowed}")
        with self._fault_lock:
            self._fault = (fault, count, exception_code)
        if fault == "exception":
            self._force_exception(exception_code)

    def _force_exception(self, code: int | None) -> None:
        for drive in self.drives:
            drive.forced_exception = code

    def clear_faults(self) -> None:
        with self._fault_lock:
            self._fault = None
        self._force_exception(None)
        if self.link is not None:
            self.link.plug()

    def _consume(self, kinds: tuple[str, ...]) -> str | None:
        with self._fault_lock:
            if self._fault is None or self._fault[0] not in kinds:
                return None
            kind, remaining, code = self._fault
            if remaining is not None:
                self._fault = None if remaining <= 1 else (kind, remaining - 1, code)
                if self._fault is None and kind == "exception":
                    self._force_exception(None)
            return kind

    def _trace_packet(self, sending: bool, data: bytes) -> bytes:
        """pymodbus packet hook: alters outgoing replies according to the injected fault."""
        if not sending:
            self.requests_received += 1
            return data
        if self.mode == "rtu" and data and data[0] not in {d.map.unit_id for d in self.drives}:
            return b""  # an RS-485 slave never answers for another unit id (pymodbus would send exception 4)
        kind = self._consume(("no_reply", "bad_crc", "disconnect", "exception"))
        if kind == "no_reply":
            return b""
        if kind == "bad_crc":
            if self.mode == "rtu":
                return data[:-2] + bytes([data[-2] ^ 0xFF, data[-1]])
            return data[:2] + b"\xff\xff" + data[4:]
        if kind == "disconnect":
            if self.mode == "tcp" and self._server is not None:
                for conn in list(self._server.active_connections.values()):
                    self._loop.call_soon(conn.close)  # type: ignore[union-attr]
            elif self.link is not None:
                self.link.unplug()
            return b""
        self.replies_sent += 1
        return data


def main(argv: list[str] | None = None, prog: str | None = None) -> int:
    """Serve until Ctrl-C or SIGTERM; ``prog`` names the command in help and errors."""
    parser = standalone_parser("vfd_server", "Mock VFD (Delta-style register map) on Modbus TCP or RTU.",
                               default_port=5020, prog=prog)
    parser.add_argument("--rtu", action="store_true", help="Modbus RTU on a new pty pair, not TCP")
    parser.add_argument("--serial", default=None, help="RTU on this serial device instead of a pty")
    parser.add_argument("--body", choices=("exciter", "rotor"), default="exciter", help="twin body to move")
    parser.add_argument("--gear-ratio", type=float, default=1.0, help="drive Hz per body Hz")
    parser.add_argument("--max-output-hz", type=float, default=50.0)
    parser.add_argument("--watchdog-s", type=float, default=None)
    args, world = start_standalone(parser, argv)
    drive = DriveModel(getattr(world, args.body), world.clock, gear_ratio=args.gear_ratio,
                       max_output_hz=args.max_output_hz, watchdog_s=args.watchdog_s)
    mode = "rtu" if (args.rtu or args.serial) else "tcp"
    with VfdServer(drive, mode=mode, port=args.port, serial_port=args.serial) as server:
        print(f"mock VFD ({args.body}) serving Modbus {mode.upper()} at {server.url}", flush=True)
        wait_for_interrupt()
        print(f"mock VFD ({args.body}) stopped; requests received: {server.requests_received}", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
