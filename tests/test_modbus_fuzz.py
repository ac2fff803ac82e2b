"""Property tests of the Modbus frame parsers: the driver's reply parsing (RTU and TCP) and the mock
slave's request parsing, with random and mutated bytes. Nothing may raise anything but the documented
errors, nothing may be taken for a reply it is not, and the mock must answer a valid request afterwards."""

from __future__ import annotations

import socket
import struct
import time

import pytest
import serial
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from vfd_support import crc16_modbus, rtu

from drivers.exciter.register_map import RegisterMap
from drivers.mock.modbus_slave import ModbusSlave
from drivers.mock.vfd_drive import DriveModel
from drivers.mock.vfd_server import VfdServer
from drivers.modbus import (
    ModbusExceptionReply,
    ReplyMismatch,
    decode_reply,
    mbap_adu,
    parse_mbap,
    read_request,
    rtu_adu,
    split_rtu,
    write_single_request,
)
from drivers.modbus_link import ModbusLink, ModbusLinkError
from drivers.sim.clock import VirtualClock
from drivers.sim.world import World
from drivers.transport import TransportClosed, TransportTimeout

FUZZ = settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
LIVE = settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow,
                                                                       HealthCheck.function_scoped_fixture])


class ScriptedLine:
    """An in-memory :class:`drivers.transport.Transport`: each write makes the next scripted chunk arrive;
    a read of bytes that are not there times out at once (the bytes stay buffered, as on a real line)."""

    url = "memory://line"

    def __init__(self, chunks: list[bytes]) -> None:
        self.chunks = list(chunks)
        self.buffer = bytearray()
        self.written: list[bytes] = []
        self.closed = False

    def write(self, data: bytes) -> None:
        if self.closed:
            raise TransportClosed("closed")
        self.written.append(bytes(data))
        if self.chunks:
            self.buffer += self.chunks.pop(0)

    def read_exact(self, n: int, timeout_s: float | None = None) -> bytes:
        if len(self.buffer) < n:
            raise TransportTimeout(f"{len(self.buffer)} of {n} bytes")
        data = bytes(self.buffer[:n])
        del self.buffer[:n]
        return data

    def read_until(self, terminator: bytes, timeout_s: float | None = None, max_bytes: int = 65536) -> bytes:
        raise NotImplementedError

    def read_available(self) -> bytes:
        data = bytes(self.buffer)
        self.buffer.clear()
        return data

    def close(self) -> None:
        self.closed = True

    def __enter__(self) -> ScriptedLine:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _link(url: str, chunks: list[bytes], retries: int) -> tuple[ModbusLink, list[ScriptedLine]]:
    lines: list[ScriptedLine] = []

    def opener(_url: str, _timeout: float) -> ScriptedLine:
        lines.append(ScriptedLine(chunks if not lines else []))
        return lines[-1]

    return ModbusLink(url, timeout_s=0.01, retries=retries, opener=opener), lines


# driver side -------------------------------------------------------------------------------------------
@FUZZ
@given(count=st.integers(1, 125), address=st.integers(0, 0xFFFF), reply=st.binary(max_size=260))
def test_decode_reply_accepts_only_a_matching_reply(count: int, address: int, reply: bytes) -> None:
    request = read_request(address, count)
    try:
        registers = decode_reply(request, reply)
    except (ReplyMismatch, ModbusExceptionReply):
        return
    assert len(registers) == count and reply[:2] == bytes((3, 2 * count))


@FUZZ
@given(address=st.integers(0, 0xFFFF), value=st.integers(0, 0xFFFF), reply=st.binary(max_size=12))
def test_a_write_reply_must_echo_the_request_exactly(address: int, value: int, reply: bytes) -> None:
    request = write_single_request(address, value)
    try:
        assert decode_reply(request, reply) == [] and reply == request
    except (ReplyMismatch, ModbusExceptionReply):
        assert reply != request


@FUZZ
@given(unit=st.integers(0, 255), pdu=st.binary(min_size=1, max_size=253), flip=st.integers(0, 8 * 255))
def test_rtu_frames_round_trip_and_a_flipped_bit_is_caught(unit: int, pdu: bytes, flip: int) -> None:
    adu = rtu_adu(unit, pdu)
    assert adu[-2:] == crc16_modbus(adu[:-2])
    assert split_rtu(adu) == (unit, pdu)
    bit = flip % (8 * len(adu))
    mutated = bytearray(adu)
    mutated[bit // 8] ^= 1 << (bit % 8)
    assert split_rtu(bytes(mutated)) is None  # CRC-16 detects every single-bit error


@FUZZ
@given(tid=st.integers(0, 0xFFFF), unit=st.integers(0, 255), pdu=st.binary(min_size=1, max_size=253))
def test_mbap_round_trip(tid: int, unit: int, pdu: bytes) -> None:
    adu = mbap_adu(tid, unit, pdu)
    assert parse_mbap(adu[:7]) == (tid, 0, len(pdu) + 1, unit) and adu[7:] == pdu


@FUZZ
@given(garbage=st.binary(max_size=40), registers=st.lists(st.integers(0, 0xFFFF), min_size=1, max_size=5),
       framing=st.sampled_from(["rtu", "tcp"]))
def test_link_survives_garbage_before_the_reply(garbage: bytes, registers: list[int], framing: str) -> None:
    """Random bytes ahead of the real reply: the link returns the right registers (possibly after a retry
    on a fresh line) or raises ModbusLinkError — never another exception, never wrong registers."""
    count = len(registers)
    pdu = struct.pack(f">BB{count}H", 3, 2 * count, *registers)
    if framing == "rtu":
        url, reply, retry_reply = "serial:///dev/null", rtu_adu(1, pdu), rtu_adu(1, pdu)
    else:  # the first request has transaction id 1, a retry (after a reconnect) id 2
        url, reply, retry_reply = "tcp://127.0.0.1:1", mbap_adu(1, 1, pdu), mbap_adu(2, 1, pdu)
    link, _lines = _link(url, [garbage + reply, retry_reply], retries=1)
    try:
        got = link.read_holding_registers(1, 0x2100, count)
    except ModbusLinkError:
        assert garbage, "a clean reply must be accepted"
        return
    assert got == registers
    if not garbage:
        assert link.requests_sent == 1


# mock side ---------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def slave() -> ModbusSlave:
    world = World(VirtualClock(), seed=9)
    return ModbusSlave([DriveModel(world.exciter, world.clock),
                        DriveModel(world.rotor, world.clock, register_map=RegisterMap(unit_id=2))], "rtu")


@FUZZ
@given(unit=st.integers(0, 255), pdu=st.binary(max_size=253))
def test_slave_answers_any_pdu_with_its_code_or_an_exception(slave: ModbusSlave, unit: int,
                                                             pdu: bytes) -> None:
    reply = slave.handle(unit, pdu)
    if reply is None:
        assert unit not in (1, 2) or not pdu or (unit == 0)
        return
    assert reply[0] in (pdu[0], pdu[0] | 0x80)
    if reply[0] & 0x80:
        assert len(reply) == 2 and reply[1] in (1, 2, 3, 4, 6, 11)


@FUZZ
@given(data=st.binary(max_size=300))
def test_rtu_frame_splitter_takes_only_complete_valid_frames(data: bytes) -> None:
    buffer = bytearray(data)
    frame = VfdServer._complete_rtu_frame(buffer)
    if frame is None:
        assert buffer == data
    else:
        assert split_rtu(frame) is not None and data == frame + bytes(buffer)


@pytest.fixture(scope="module")
def live_rtu() -> VfdServer:
    world = World(VirtualClock(), seed=9)
    with VfdServer(DriveModel(world.exciter, world.clock), mode="rtu") as server:
        yield server


@LIVE
@given(junk=st.binary(min_size=1, max_size=300), value=st.integers(0, 0x7FFF))
def test_mock_rtu_answers_after_any_junk_and_a_silence(live_rtu: VfdServer, junk: bytes, value: int) -> None:
    with serial.serial_for_url(live_rtu.client_port, baudrate=115200, timeout=2.0) as port:
        port.write(junk)
        time.sleep(0.03)  # line silence: far above t3.5
        port.reset_input_buffer()  # whatever the junk provoked
        frame = rtu(f"01 06 01 09 {max(value, 1):04X}")  # acceleration time: any value >= 1 is valid
        port.write(frame)
        assert port.read(8) == frame


@pytest.fixture(scope="module")
def live_tcp() -> VfdServer:
    world = World(VirtualClock(), seed=9)
    with VfdServer(DriveModel(world.exciter, world.clock)) as server:
        yield server


@LIVE
@given(junk=st.binary(min_size=1, max_size=600))
def test_mock_tcp_survives_any_junk(live_tcp: VfdServer, junk: bytes) -> None:
    with socket.create_connection(("127.0.0.1", live_tcp.port), timeout=2.0) as sock:
        sock.sendall(junk)
    with socket.create_connection(("127.0.0.1", live_tcp.port), timeout=2.0) as sock:
        sock.sendall(mbap_adu(9, 1, read_request(0x2100, 1)))
        assert sock.recv(64) == mbap_adu(9, 1, bytes.fromhex("03 02 00 00"))
