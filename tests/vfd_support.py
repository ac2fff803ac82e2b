"""Test support for the exciter/VFD tests: an independent CRC, a scripted byte peer, mock rigs."""

from __future__ import annotations

import contextlib
import socket
import threading
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

import serial

from drivers.exciter.exciter import Exciter
from drivers.exciter.limits import MotionLimits
from drivers.exciter.vfd import VfdDriver
from drivers.mock.pty_link import PtyLink
from drivers.mock.vfd_drive import DriveModel
from drivers.mock.vfd_server import VfdServer
from drivers.modbus import crc16
from drivers.modbus_link import ModbusLink
from drivers.sim.clock import VirtualClock
from drivers.sim.world import World


def crc16_modbus(data: bytes) -> bytes:
    """CRC-16/MODBUS (poly 0xA001 reflected, init 0xFFFF), low byte first — written from the spec, bit by
    bit (independent of the table-driven :func:`drivers.modbus.crc16`)."""
    crc = 0xFFFF
    for byte in data:
        crc ^= byte
        for _ in range(8):
            crc = (crc >> 1) ^ 0xA001 if crc & 1 else crc >> 1
    return bytes([crc & 0xFF, crc >> 8])


assert crc16(b"\x01\x03\x21\x00\x00\x05") == crc16_modbus(b"\x01\x03\x21\x00\x00\x05")


def rtu(hex_without_crc: str) -> bytes:
    """An RTU frame from hex digits, with its CRC appended."""
    body = bytes.fromhex(hex_without_crc)
    return body + crc16_modbus(body)


class ScriptedPeer:
    """A byte peer that expects exact request bytes and answers with scripted bytes (PyMeasure's
    ``expected_protocol`` idea, over a real serial line or socket).

    script: [(expected request, reply), ...]. ``transport="pty"`` (RTU): the peer sits on one end of a
    :class:`PtyLink` and the client opens :attr:`client_port`. ``transport="tcp"`` (Modbus TCP): the first
    two bytes of each request (the MBAP transaction id) are not compared and are copied into the reply.
    """

    def __init__(self, script: list[tuple[bytes, bytes]], *, transport: str = "pty",
                 read_timeout_s: float = 2.0) -> None:
        self.script = list(script)
        self.mbap = transport == "tcp"
        self.read_timeout_s = read_timeout_s
        self.received = bytearray()
        self.mismatch: tuple[bytes, bytes] | None = None
        self.served = 0
        self.link: PtyLink | None = None
        self._listener: socket.socket | None = None
        if self.mbap:
            self._listener = socket.create_server(("127.0.0.1", 0))
            self.port = self._listener.getsockname()[1]
        else:
            self.link = PtyLink()
            self.client_port = self.link.client_port
            self._serial = serial.serial_for_url(self.link.device_port, timeout=read_timeout_s,
                                                 write_timeout=read_timeout_s)
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _exchange(self, read: Any, write: Any) -> None:
        for expected, reply in self.script:
            n = len(expected) + (2 if self.mbap else 0)
            got = read(n)
            self.received += got
            body = got[2:] if self.mbap else got
            if body != expected:
                self.mismatch = (expected, body)
                return
            write((got[:2] if self.mbap else b"") + reply)
            self.served += 1
        self.received += read(4096, tail=True)  # anything unexpected right afterwards is recorded too

    def _run(self) -> None:
        if self._listener is None:
            def read_serial(n: int, tail: bool = False) -> bytes:
                self._serial.timeout = 0.05 if tail else self.read_timeout_s
                return self._serial.read(n)
            self._exchange(read_serial, self._serial.write)
            return
        self._listener.settimeout(5.0)
        try:
            conn, _ = self._listener.accept()
        except OSError:
            return
        with conn:
            def read_socket(n: int, tail: bool = False) -> bytes:
                conn.settimeout(0.05 if tail else self.read_timeout_s)
                data = b""
                with contextlib.suppress(OSError):
                    while len(data) < n and (chunk := conn.recv(n - len(data))):
                        data += chunk
                return data
            self._exchange(read_socket, conn.sendall)

    def close(self) -> None:
        self._thread.join(timeout=3.0)
        if self._listener is not None:
            self._listener.close()
        if self.link is not None:
            self._serial.close()
            self.link.close()


@contextlib.contextmanager
def rtu_client_for(peer: ScriptedPeer, timeout_s: float = 1.0) -> Iterator[ModbusLink]:
    """Our Modbus RTU master on the peer's line, no retries (every byte it sends is scripted)."""
    link = ModbusLink(f"serial://{peer.client_port}?baud=115200", timeout_s=timeout_s, retries=0)
    try:
        yield link
    finally:
        link.close()


EXCITER_LIMITS = MotionLimits(max_frequency_hz=32.0, max_displacement_mm=10.0, max_acceleration_m_s2=250.0,
                              max_ramp_rate_hz_per_s=2.0)


@dataclass
class VfdRig:
    world: World
    clock: VirtualClock
    drive: DriveModel
    server: VfdServer
    client: ModbusLink
    vfd: VfdDriver
    exciter: Exciter


# The reply time-out of exchanges no fault is injected into: a loaded machine may take a second to pass a
# reply through the mock's thread and the pty bridge, and that is no fault. A test of a lost or late reply
# passes its own short time-out, for the faulted exchange.
HEALTHY_TIMEOUT_S = 30.0


def connect_client(server: VfdServer, *, timeout_s: float = HEALTHY_TIMEOUT_S, retries: int = 0,
                   clock: Any = None) -> ModbusLink:
    """Our Modbus master on the mock's TCP port or RTU pty."""
    url = server.url if server.mode == "tcp" else f"serial://{server.client_port}?baud=115200"
    return ModbusLink(url, timeout_s=timeout_s, retries=retries, clock=clock)


@contextlib.contextmanager
def vfd_rig(mode: str, *, gear_ratio: float = 1.5, max_output_hz: float = 60.0, poll_interval_s: float = 0.25,
            timeout_s: float = HEALTHY_TIMEOUT_S, retries: int = 1, stop_deadline_s: float = 2.0,
            **drive_kwargs: Any) -> Iterator[VfdRig]:
    """World (instant clock) + mock drive moving world.exciter + connected driver + Exciter. The link
    repeats a request once (the station's setting); a test of one failure sets ``rig.client.retries = 0``
    after its set-up."""
    world = World(VirtualClock(), seed=1)
    drive = DriveModel(world.exciter, world.clock, gear_ratio=gear_ratio, max_output_hz=max_output_hz,
                       **drive_kwargs)
    server = VfdServer(drive, mode=mode).start()
    client = connect_client(server, timeout_s=timeout_s, retries=retries)
    vfd = VfdDriver(client, max_output_hz=max_output_hz, stop_deadline_s=stop_deadline_s)
    exciter = Exciter(vfd, clock=world.clock, limits=EXCITER_LIMITS,
                      crank_radius_mm=world.layout.crank_radius_mm, gear_ratio=gear_ratio,
                      ramp_rate_hz_per_s=2.0, poll_interval_s=poll_interval_s)
    try:
        yield VfdRig(world, world.clock, drive, server, client, vfd, exciter)
    finally:
        client.close()
        server.stop()
