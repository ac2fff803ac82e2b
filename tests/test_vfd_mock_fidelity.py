"""The mock drive behaves like a Modbus slave on the wire (docs/exciter.md, "Mock drive: Modbus behaviour").

Raw bytes over the real pty (RTU) and TCP socket; the expected frames are built with the test support's
independent CRC. Pauses below create line silence (a stimulus); nothing asserts on elapsed time.
"""

from __future__ import annotations

import contextlib
import os
import re
import signal
import socket
import struct
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
import serial
from vfd_support import rtu

from drivers.exciter.register_map import RegisterMap
from drivers.mock.modbus_faults import parse_fault
from drivers.mock.vfd_drive import DriveModel
from drivers.mock.vfd_server import MAX_CONNECTIONS, VfdServer
from drivers.modbus import mbap_adu
from drivers.sim.clock import VirtualClock
from drivers.sim.world import World

ROOT = Path(__file__).resolve().parents[1]
SILENCE_S = 0.05  # far above t3.5 at 115200 baud (1.75 ms)


@contextlib.contextmanager
def rtu_line(*, two_drives: bool = False) -> Iterator[tuple[serial.Serial, VfdServer]]:
    world = World(VirtualClock(), seed=5)
    drives = [DriveModel(world.exciter, world.clock, register_map=RegisterMap(unit_id=1))]
    if two_drives:
        drives.append(DriveModel(world.rotor, world.clock, register_map=RegisterMap(unit_id=2)))
    with VfdServer(drives, mode="rtu") as server:
        port = serial.serial_for_url(server.client_port, baudrate=115200, timeout=1.0)
        try:
            yield port, server
        finally:
            port.close()


def ask(port: serial.Serial, frame: bytes, reply_len: int) -> bytes:
    port.reset_input_buffer()
    port.write(frame)
    return port.read(reply_len)


@pytest.mark.parametrize(("request_hex", "reply_hex"), [
    ("01 2B 0E 01 00", "01 AB 01"),          # unknown function code (read device id) → 0x2B | 0x80, 01
    ("01 03 21 00 00 00", "01 83 03"),       # quantity 0 → 03
    ("01 03 21 00 00 7E", "01 83 03"),       # quantity 126 > 125 → 03
    ("01 03 21 00", "01 83 03"),             # short request (valid CRC) → 03, with the request's code
    ("01 10 20 00 00 02 02 00 01", "01 90 03"),  # byte count 2 for 2 registers → 03
    ("01 06 21 03 00 64", "01 86 02"),       # write to a monitor register → 02
    ("01 03 21 05 00 01", "01 83 02"),       # unmapped register → 02
])
def test_rtu_exception_replies_carry_the_request_function_code(request_hex: str, reply_hex: str) -> None:
    with rtu_line() as (port, _):
        assert ask(port, rtu(request_hex), 5) == rtu(reply_hex)


def test_rtu_write_multiple_is_supported() -> None:
    with rtu_line() as (port, server):
        assert ask(port, rtu("01 10 20 01 00 01 02 03 E8"), 8) == rtu("01 10 20 01 00 01")
        assert server.drive.regs[0x2001] == 1000


def test_rtu_broadcast_write_is_carried_out_by_every_drive_without_a_reply() -> None:
    with rtu_line(two_drives=True) as (port, server):
        port.timeout = 0.3
        assert ask(port, rtu("00 06 20 01 04 D2"), 8) == b""  # 12.34 Hz to everybody, nobody answers
        assert [d.regs[0x2001] for d in server.drives] == [1234, 1234]
        assert ask(port, rtu("00 03 21 00 00 01"), 7) == b""  # a broadcast read is not answered either
        port.timeout = 1.0
        assert ask(port, rtu("02 03 20 01 00 01"), 7) == rtu("02 03 02 04 D2")


@pytest.mark.parametrize("partial_hex", [
    "01 03 21",                                # cut short
    "01 10 20 00 00 7B F6 00 01",              # an FC16 announcing 246 data bytes that never come
    "01 06 20 01 03 E8 00 00",                 # complete length, wrong CRC
    "FF" * 300,                                # longer than any RTU frame
])
def test_rtu_slave_is_back_in_step_after_a_silence(partial_hex: str) -> None:
    """The issue saw 31 valid requests unanswered after one partial frame; a slave resynchronises at t3.5."""
    with rtu_line() as (port, server):
        port.write(bytes.fromhex(partial_hex))
        time.sleep(SILENCE_S)
        for value in range(5):
            frame = rtu(f"01 06 20 01 00 {value:02X}")
            assert ask(port, frame, 8) == frame
            time.sleep(SILENCE_S / 10)
        assert server.frames_dropped >= 1


def test_rtu_slave_ignores_other_units_and_answers_its_own() -> None:
    with rtu_line() as (port, _):
        port.timeout = 0.3
        assert ask(port, rtu("07 03 21 00 00 01"), 7) == b""
        assert ask(port, rtu("01 03 21 00 00 01"), 7) == rtu("01 03 02 00 00")


def _tcp_ask(sock: socket.socket, tid: int, unit: int, pdu: bytes) -> bytes:
    sock.sendall(struct.pack(">HHHB", tid, 0, len(pdu) + 1, unit) + pdu)
    header = sock.recv(7, socket.MSG_WAITALL)
    length = struct.unpack(">H", header[4:6])[0]
    assert header[:2] == struct.pack(">H", tid) and header[6] == unit
    return sock.recv(length - 1, socket.MSG_WAITALL)


def test_tcp_exceptions_unit_ids_and_a_skipped_foreign_protocol() -> None:
    world = World(VirtualClock(), seed=5)
    with VfdServer(DriveModel(world.exciter, world.clock)) as server, \
            socket.create_connection(("127.0.0.1", server.port), timeout=2.0) as sock:
        assert _tcp_ask(sock, 1, 1, bytes.fromhex("2B 0E 01 00")) == bytes.fromhex("AB 01")
        assert _tcp_ask(sock, 2, 1, bytes.fromhex("03 21 00 00 00")) == bytes.fromhex("83 03")
        assert _tcp_ask(sock, 3, 1, bytes.fromhex("03 21")) == bytes.fromhex("83 03")
        assert _tcp_ask(sock, 4, 9, bytes.fromhex("03 21 00 00 01")) == bytes.fromhex("83 0B")
        assert _tcp_ask(sock, 5, 0xFF, bytes.fromhex("03 21 00 00 01")) == bytes.fromhex("03 02 00 00")
        sock.sendall(struct.pack(">HHHB", 6, 7, 6, 1) + bytes.fromhex("03 21 00 00 01"))  # protocol id 7
        assert _tcp_ask(sock, 7, 1, bytes.fromhex("06 20 01 00 0A")) == bytes.fromhex("06 20 01 00 0A")


def test_tcp_connection_threads_are_reaped_and_capped() -> None:
    world = World(VirtualClock(), seed=5)
    with VfdServer(DriveModel(world.exciter, world.clock)) as server:
        for i in range(3 * MAX_CONNECTIONS):
            with socket.create_connection(("127.0.0.1", server.port), timeout=2.0) as sock:
                assert _tcp_ask(sock, i, 1, bytes.fromhex("03 21 00 00 01")) == bytes.fromhex("03 02 00 00")
            deadline = time.monotonic() + 10.0  # the server notices the close
            while server.connection_threads and time.monotonic() < deadline:
                time.sleep(0.01)
            assert server.connection_threads == 0
        assert server.connections_tracked <= 1  # 24 finished connections: all but the last reaped
        held = [socket.create_connection(("127.0.0.1", server.port), timeout=2.0)
                for _ in range(MAX_CONNECTIONS + 1)]
        try:
            for sock in held[:MAX_CONNECTIONS]:
                assert _tcp_ask(sock, 1, 1, bytes.fromhex("03 21 00 00 01")) == bytes.fromhex("03 02 00 00")
            assert held[-1].recv(7) == b""  # one too many: closed by the server
            assert server.connection_threads <= MAX_CONNECTIONS
        finally:
            for sock in held:
                sock.close()


def test_fault_options_are_parsed_with_clear_errors() -> None:
    assert parse_fault("late:0.5").value == 0.5
    assert parse_fault("busy:3").every == 3
    assert parse_fault("disconnect:20").every == 20
    assert parse_fault("trip:65").value == 65
    with pytest.raises(ValueError, match=r"unknown kind 'slow'; allowed: late, no_reply"):
        parse_fault("slow")
    with pytest.raises(ValueError, match="whole number"):
        parse_fault("busy:0.5")
    with pytest.raises(ValueError, match="0 < PARAM <= 60 s"):
        parse_fault("late:-1")


def test_rig_mock_rotor_answers_its_configured_unit_and_injects_cli_faults() -> None:
    """`rig mock rotor` defaults to unit 2 as in rig/data/sim.toml; --fault busy:2 refuses every second
    request."""
    env = {**os.environ, "PYTHONPATH": str(ROOT), "PYTHONUNBUFFERED": "1"}
    command = [sys.executable, "-m", "rig.cli", "mock", "rotor", "--port", "0", "--fault", "busy:2"]
    proc = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True, env=env)
    try:
        assert proc.stdout is not None
        line = proc.stdout.readline()
        match = re.search(r"unit 2\) serving Modbus TCP at tcp://127\.0\.0\.1:(\d+); faults: busy:2", line)
        assert match, line
        with socket.create_connection(("127.0.0.1", int(match.group(1))), timeout=5.0) as sock:
            assert _tcp_ask(sock, 1, 2, bytes.fromhex("03 21 00 00 01")) == bytes.fromhex("03 02 00 00")
            assert _tcp_ask(sock, 2, 2, bytes.fromhex("03 21 00 00 01")) == bytes.fromhex("83 06")
            assert _tcp_ask(sock, 3, 1, bytes.fromhex("03 21 00 00 01")) == bytes.fromhex("83 0B")
    finally:
        proc.send_signal(signal.SIGINT)
        proc.wait(timeout=20)
    assert proc.returncode == 0


def test_cli_faults_disconnect_every_n_requests_and_trip_when_running() -> None:
    world = World(VirtualClock(), seed=5)
    faults = [parse_fault("disconnect:3"), parse_fault("trip:65")]
    with VfdServer(DriveModel(world.exciter, world.clock), faults=faults) as server:
        read = bytes.fromhex("03 21 00 00 01")
        with socket.create_connection(("127.0.0.1", server.port), timeout=2.0) as sock:
            assert _tcp_ask(sock, 1, 1, read) == bytes.fromhex("03 02 00 00")
            assert _tcp_ask(sock, 2, 1, read) == bytes.fromhex("03 02 00 00")
            sock.sendall(mbap_adu(3, 1, read))
            assert sock.recv(16) == b""  # the third request: the connection drops
        with socket.create_connection(("127.0.0.1", server.port), timeout=2.0) as sock:
            assert _tcp_ask(sock, 4, 1, bytes.fromhex("06 20 01 03 E8")) == bytes.fromhex("06 20 01 03 E8")
            assert _tcp_ask(sock, 5, 1, bytes.fromhex("06 20 00 00 12")) == bytes.fromhex("06 20 00 00 12")
            sock.sendall(mbap_adu(6, 1, read))
            assert sock.recv(16) == b""
        with socket.create_connection(("127.0.0.1", server.port), timeout=2.0) as sock:
            assert _tcp_ask(sock, 7, 1, read) == bytes.fromhex("03 02 00 41")  # tripped: fault 65 (0x41)
        assert server.drive.fault_code == 65 and not server.drive.running
