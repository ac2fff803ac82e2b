"""The mock RC8's own codec (``drivers/mock/bcap_wire.py``): the worked vendor frames of bcap.md §4 byte for
byte, round trips, any bytes → a clean :class:`WireError`, and agreement with the driver's independent
codec in both directions (the two ends never share encoding code)."""

from __future__ import annotations

import contextlib
import math

from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.denso import bcap as driver
from drivers.denso.variant import Variant
from drivers.mock import bcap_wire as w

SERVICE_START_TCP = bytes.fromhex("01 1e 00 00 00 01 00 00 00 01 00 00 00 01 00 0a 00 00 00 08 00 01 00 00 00"
                                  " 00 00 00 00 04")
SERVICE_START_OK = bytes.fromhex("01 10 00 00 00 01 00 00 00 00 00 00 00 00 00 04")
SERVICE_STOP_SERIAL = bytes.fromhex("01 12 00 00 00 01 00 01 00 02 00 00 00 00 00 89 3a 04")
TAKE_ARM = bytes.fromhex(
    "01 4c 00 00 00 05 00 00 00 40 00 00 00 03 00 0a 00 00 00 13 00 01 00 00 00 01 00 00 00 "
    "18 00 00 00 08 00 01 00 00 00 0e 00 00 00 54 00 61 00 6b 00 65 00 41 00 72 00 6d 00 "
    "0e 00 00 00 03 20 02 00 00 00 00 00 00 00 01 00 00 00 04")
KEEPALIVE_5 = bytes.fromhex("01 10 00 00 00 05 00 00 00 00 09 00 00 00 00 04")


def test_crc_check_value() -> None:
    assert w.crc16(b"123456789") == 0x29B1


def test_vendor_frames_decode_and_encode_byte_for_byte() -> None:
    assert w.parse(SERVICE_START_TCP) == w.Packet(1, 0, 1, (w.Value(w.BSTR, ""),))
    assert w.build(1, 0, 1, [w.Value(w.BSTR, "")]) == SERVICE_START_TCP
    assert w.build(1, 0, w.S_OK) == SERVICE_START_OK
    assert w.parse(SERVICE_STOP_SERIAL, serial_line=True) == w.Packet(1, 1, 2, ())
    assert w.build(1, 1, 2, serial_line=True) == SERVICE_STOP_SERIAL
    take_arm = w.Packet(5, 0, 64, (w.Value(w.UI4, 1), w.Value(w.BSTR, "TakeArm"),
                                   w.Value(w.ARRAY | w.I4, [0, 1])))
    assert w.parse(TAKE_ARM) == take_arm
    assert w.build(5, 0, 64, take_arm.args) == TAKE_ARM
    assert w.build(5, 0, w.S_EXECUTING) == KEEPALIVE_5
    assert w.build(1, 0, w.E_BUSY_PROC)[9:13] == bytes.fromhex("aa 00 91 80")  # signed in the packet


def test_framer_resynchronises_drops_bad_crc_and_raises_on_a_malformed_packet() -> None:
    framer = w.Framer(serial_line=True)
    bad_crc = bytearray(SERVICE_STOP_SERIAL)
    bad_crc[-2] ^= 0xFF
    framer.feed(b"\x00\x07junk" + bytes(bad_crc) + SERVICE_STOP_SERIAL)
    assert framer.next() == w.Packet(1, 1, 2, ())
    assert framer.crc_errors == 1 and framer.next() is None
    tcp = w.Framer()
    bad_eot = bytearray(SERVICE_START_TCP)
    bad_eot[-1] = 0x05
    tcp.feed(bytes(bad_eot))
    try:
        tcp.next()
    except w.WireError:
        pass
    else:
        raise AssertionError("a framed packet without EOT must raise WireError")


def _values(depth: int = 2) -> st.SearchStrategy[w.Value]:
    finite = st.floats(allow_nan=False, width=64)
    scalars = st.one_of(
        st.just(w.EMPTY), st.builds(w.Value, st.just(w.I2), st.integers(-2**15, 2**15 - 1)),
        st.builds(w.Value, st.just(w.I4), st.integers(-2**31, 2**31 - 1)),
        st.builds(w.Value, st.just(w.UI4), st.integers(0, 2**32 - 1)),
        st.builds(w.Value, st.just(w.R4), st.floats(width=32, allow_nan=False)),
        st.builds(w.Value, st.just(w.R8), finite), st.builds(w.Value, st.just(w.BOOL), st.booleans()),
        st.builds(w.Value, st.just(w.BSTR), st.text(max_size=20)),
        st.builds(w.Value, st.just(w.ARRAY | w.R8), st.lists(finite, max_size=8)),
        st.builds(w.Value, st.just(w.ARRAY | w.UI1), st.binary(max_size=20)),
        st.builds(w.Value, st.just(w.ARRAY | w.BSTR), st.lists(st.text(max_size=5), max_size=4)))
    if depth == 0:
        return scalars
    return st.one_of(scalars, st.builds(w.Value, st.just(w.ARRAY | w.VARIANT),
                                        st.lists(_values(depth - 1), max_size=4)))


@settings(max_examples=200, deadline=None)
@given(st.integers(0, 65535), st.integers(0, 65535), st.integers(-2**31, 2**31 - 1),
       st.lists(_values(), max_size=5), st.booleans())
def test_packet_round_trip(serial: int, reserved: int, code: int, args: list[w.Value],
                           serial_line: bool) -> None:
    data = w.build(serial, reserved, code, args, serial_line=serial_line)
    assert w.parse(data, serial_line=serial_line) == w.Packet(serial, reserved, code, tuple(args))
    framer = w.Framer(serial_line=serial_line, max_length=len(data))
    for i in range(len(data)):  # byte by byte
        framer.feed(data[i:i + 1])
    assert framer.next() == w.Packet(serial, reserved, code, tuple(args))


def _same(mock: w.Value, other: Variant) -> bool:
    if mock.vt != other.vt:
        return False
    if mock.vt == w.ARRAY | w.VARIANT:
        return len(mock.value) == len(other.value) and all(map(_same, mock.value, other.value))
    if isinstance(mock.value, float):
        return mock.value == other.value or (math.isnan(mock.value) and math.isnan(other.value))
    return mock.value == other.value


@settings(max_examples=200, deadline=None)
@given(st.lists(_values(), max_size=5), st.booleans())
def test_the_two_codecs_agree_both_ways(args: list[w.Value], serial_line: bool) -> None:
    data = w.build(7, 0, 64, args, serial_line=serial_line)
    decoded = driver.decode_packet(data, serial_line=serial_line)
    assert len(decoded.args) == len(args) and all(map(_same, args, decoded.args))
    again = driver.encode_packet(7, 0, 64, decoded.args, serial_line=serial_line, max_length=len(data))
    assert again == data


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=300), st.booleans())
def test_any_bytes_are_a_packet_or_a_wire_error(data: bytes, serial_line: bool) -> None:
    with contextlib.suppress(w.WireError):
        w.parse(data, serial_line=serial_line)
    with contextlib.suppress(w.WireError):
        w.read_value(data)


@settings(max_examples=200, deadline=None)
@given(st.lists(st.binary(max_size=80), max_size=10), st.booleans())
def test_random_streams_end_in_packets_or_wire_errors(chunks: list[bytes], serial_line: bool) -> None:
    framer = w.Framer(serial_line=serial_line)
    for chunk in chunks:
        framer.feed(chunk)
        for _ in range(len(chunk) + 2):  # each step consumes bytes: the loop always ends
            try:
                if framer.next() is None:
                    break
            except w.WireError:
                pass


@settings(max_examples=200, deadline=None)
@given(st.binary(min_size=1, max_size=40), st.integers(0, 200))
def test_mutated_vendor_frames_never_raise_anything_else(noise: bytes, at: int) -> None:
    data = bytearray(TAKE_ARM)
    position = at % len(data)
    data[position:position + len(noise)] = noise
    with contextlib.suppress(w.WireError):
        w.parse(bytes(data))
