"""b-CAP packet and VARIANT codec: the worked packets of ../shared/notes/bcap.md §4, plus properties."""

from __future__ import annotations

import contextlib
import struct
from datetime import datetime

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.denso.bcap import (
    Packet,
    PacketDecoder,
    crc16_ccitt,
    decode_packet,
    encode_packet,
    next_serial,
)
from drivers.denso.hresult import (
    E_TOO_MUCH_DATA,
    S_EXECUTING,
    BcapError,
    BcapProtocolError,
    name_of,
)
from drivers.denso.variant import (
    VT_ARRAY,
    VT_BOOL,
    VT_BSTR,
    VT_CY,
    VT_DATE,
    VT_EMPTY,
    VT_ERROR,
    VT_I2,
    VT_I4,
    VT_I8,
    VT_NULL,
    VT_R4,
    VT_R8,
    VT_UI1,
    VT_UI2,
    VT_UI4,
    VT_UI8,
    VT_VARIANT,
    Variant,
    decode_variant,
    encode_variant,
    to_variant,
)


def hexbytes(text: str) -> bytes:
    return bytes.fromhex(text.replace("|", " "))


# bcap.md §4, copied verbatim
SERVICE_START_TCP = hexbytes("01 | 1e 00 00 00 | 01 00 | 00 00 | 01 00 00 00 | 01 00 | 0a 00 00 00 | 08 00 "
                             "| 01 00 00 00 | 00 00 00 00 | 04")
SERVICE_START_OK = hexbytes("01 | 10 00 00 00 | 01 00 | 00 00 | 00 00 00 00 | 00 00 | 04")
SERVICE_STOP_SERIAL = hexbytes("01 12 00 00 00 01 00 01 00 02 00 00 00 00 00 89 3a 04")
TAKE_ARM = hexbytes(
    "01 4c 00 00 00 05 00 00 00 40 00 00 00 03 00 | 0a 00 00 00 13 00 01 00 00 00 01 00 00 00 | "
    "18 00 00 00 08 00 01 00 00 00 0e 00 00 00 54 00 61 00 6b 00 65 00 41 00 72 00 6d 00 | "
    "0e 00 00 00 03 20 02 00 00 00 00 00 00 00 01 00 00 00 | 04")
KEEPALIVE_5 = hexbytes("01 10 00 00 00 05 00 00 00 00 09 00 00 00 00 04")


def test_crc_check_value_and_note_example() -> None:
    assert crc16_ccitt(b"123456789") == 0x29B1
    assert crc16_ccitt(hexbytes("12 00 00 00 01 00 01 00 02 00 00 00 00 00")) == 0x3A89


def test_worked_packets_encode_byte_for_byte() -> None:
    assert encode_packet(1, 0, 1, [""]) == SERVICE_START_TCP
    assert encode_packet(1, 0, 0, []) == SERVICE_START_OK
    assert encode_packet(1, 1, 2, [], serial_line=True) == SERVICE_STOP_SERIAL
    assert encode_packet(5, 0, 64, [Variant(VT_UI4, 1), "TakeArm", [0, 1]]) == TAKE_ARM
    assert encode_packet(5, 0, S_EXECUTING, []) == KEEPALIVE_5


def test_worked_packets_decode() -> None:
    assert decode_packet(SERVICE_START_TCP) == Packet(1, 0, 1, (Variant(VT_BSTR, ""),))
    assert decode_packet(SERVICE_STOP_SERIAL, serial_line=True) == Packet(1, 1, 2, ())
    take = decode_packet(TAKE_ARM)
    assert take.code == 64 and take.serial == 5
    assert take.args == (Variant(VT_UI4, 1), Variant(VT_BSTR, "TakeArm"), Variant(VT_ARRAY | VT_I4, [0, 1]))
    keep = decode_packet(KEEPALIVE_5)
    assert keep.is_keepalive and keep.serial == 5


def test_hresult_is_signed_in_the_packet() -> None:
    packet = encode_packet(7, 0, 0x809100AA, [])
    assert packet[9:13] == bytes.fromhex("aa 00 91 80")
    assert decode_packet(packet).code == struct.unpack("<i", bytes.fromhex("aa009180"))[0]
    assert name_of(decode_packet(packet).code) == "E_BUSY_PROC"


def test_serial_wraps_to_one_never_zero() -> None:
    assert next_serial(0) == 1
    assert next_serial(1) == 2
    assert next_serial(65534) == 65535
    assert next_serial(65535) == 1


def test_serial_line_cap_503_bytes() -> None:
    text = "x" * 230  # 460 bytes of UTF-16 + headers < 503
    assert len(encode_packet(1, 1, 64, [text], serial_line=True)) <= 503
    with pytest.raises(BcapError) as info:
        encode_packet(1, 1, 64, ["x" * 250], serial_line=True)
    assert info.value.hresult == E_TOO_MUCH_DATA and "503" in str(info.value)
    assert len(encode_packet(1, 0, 64, ["x" * 250])) > 503  # TCP has no such cap


def test_decoder_resynchronises_on_soh_and_drops_bad_crc() -> None:
    good = encode_packet(3, 3, 2, [], serial_line=True)
    bad_crc = bytearray(encode_packet(4, 4, 2, [], serial_line=True))
    bad_crc[-2] ^= 0xFF
    decoder = PacketDecoder(serial_line=True)
    decoder.feed(b"\x00\xff\x01\x99\x99" + bytes(bad_crc) + b"\x04\x01" + good)
    assert decoder.packets() == [Packet(3, 3, 2, ())]
    assert decoder.crc_errors == 1
    assert decoder.skipped_bytes > 0


def test_decoder_reassembles_byte_by_byte() -> None:
    decoder = PacketDecoder()
    stream = TAKE_ARM + KEEPALIVE_5 + SERVICE_START_OK
    found = []
    for byte in stream:
        decoder.feed(bytes([byte]))
        found += decoder.packets()
    assert [p.serial for p in found] == [5, 5, 1]
    assert decoder.buffered == 0


def test_framed_packet_with_bad_argument_raises_protocol_error_and_stream_continues() -> None:
    broken = bytearray(encode_packet(9, 0, 64, ["ab"]))
    broken[15:19] = struct.pack("<I", 200)  # argument length beyond the packet
    decoder = PacketDecoder()
    decoder.feed(bytes(broken) + SERVICE_START_OK)
    with pytest.raises(BcapProtocolError, match="argument 0 length 200"):
        decoder.next_packet()
    assert decoder.next_packet() == Packet(1, 0, 0, ())


@pytest.mark.parametrize("variant, data", [
    (Variant(VT_EMPTY), "00 00 01 00 00 00"),
    (Variant(VT_I2, -2), "02 00 01 00 00 00 fe ff"),
    (Variant(VT_R4, 1.5), "04 00 01 00 00 00 00 00 c0 3f"),
    (Variant(VT_BOOL, True), "0b 00 01 00 00 00 ff ff"),
    (Variant(VT_BSTR, "Aé"), "08 00 01 00 00 00 04 00 00 00 41 00 e9 00"),
    (Variant(VT_DATE, datetime(1970, 1, 1)), "07 00 01 00 00 00" + struct.pack("<d", 25569.0).hex()),
    (Variant(VT_ARRAY | VT_BSTR, ["a", ""]), "08 20 02 00 00 00 02 00 00 00 61 00 00 00 00 00"),
    (Variant(VT_ARRAY | VT_UI1, b"\x01\x02"), "11 20 02 00 00 00 01 02"),
    (Variant(VT_ARRAY | VT_VARIANT, [Variant(VT_I4, 1), Variant(VT_BSTR, "P")]),
     "0c 20 02 00 00 00 03 00 01 00 00 00 01 00 00 00 08 00 01 00 00 00 02 00 00 00 50 00"),
])
def test_variant_bytes(variant: Variant, data: str) -> None:
    assert encode_variant(variant) == hexbytes(data)
    assert decode_variant(hexbytes(data)) == (variant, len(hexbytes(data)))


def test_reference_python_mapping() -> None:
    assert to_variant(3) == Variant(VT_I4, 3)
    assert to_variant(2.0) == Variant(VT_R8, 2.0)
    assert to_variant(True) == Variant(VT_BOOL, True)
    assert to_variant(None) == to_variant([]) == Variant(VT_EMPTY)
    assert to_variant([1.0, 2.0]).vt == VT_ARRAY | VT_R8
    assert to_variant([1, "P"]).vt == VT_ARRAY | VT_VARIANT
    assert to_variant(b"ab") == Variant(VT_ARRAY | VT_UI1, b"ab")


@pytest.mark.parametrize("bad, message", [
    (Variant(VT_I2, 40000), "outside"), (Variant(VT_UI4, -1), "outside"), (Variant(VT_BSTR, 3), "str"),
    (Variant(VT_R4, 1e300), "float32"),
])
def test_out_of_range_values_raise_value_error(bad: Variant, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        encode_variant(bad)


# ---------------------------------------------------------------------------------------------- properties
_INT_TYPES = {VT_I2: 16, VT_I4: 32, VT_ERROR: 32, VT_CY: 64, VT_I8: 64}
_UINT_TYPES = {VT_UI1: 8, VT_UI2: 16, VT_UI4: 32, VT_UI8: 64}


def _scalar(vt: int) -> st.SearchStrategy:
    if vt in _INT_TYPES:
        bits = _INT_TYPES[vt]
        return st.integers(-(1 << (bits - 1)), (1 << (bits - 1)) - 1)
    if vt in _UINT_TYPES:
        return st.integers(0, (1 << _UINT_TYPES[vt]) - 1)
    if vt == VT_R4:
        return st.floats(width=32, allow_nan=False)
    if vt == VT_R8:
        return st.floats(allow_nan=False)
    if vt == VT_BOOL:
        return st.booleans()
    if vt == VT_BSTR:
        return st.text(max_size=20)
    if vt == VT_DATE:
        return st.datetimes(min_value=datetime(1800, 1, 1), max_value=datetime(2200, 1, 1)).map(
            lambda d: d.replace(microsecond=d.microsecond // 1000 * 1000))
    raise AssertionError(vt)


_DATA_TYPES = [*_INT_TYPES, *_UINT_TYPES, VT_R4, VT_R8, VT_BOOL, VT_BSTR, VT_DATE]
_scalars = st.one_of(
    st.just(Variant(VT_EMPTY)), st.just(Variant(VT_NULL)),
    *[_scalar(vt).map(lambda v, vt=vt: Variant(vt, v)) for vt in _DATA_TYPES])
_arrays = st.one_of(
    *[st.lists(_scalar(vt), max_size=6).map(lambda v, vt=vt: Variant(VT_ARRAY | vt, v))
      for vt in _DATA_TYPES],
    st.binary(max_size=10).map(lambda b: Variant(VT_ARRAY | VT_UI1, b)))
variants = st.recursive(
    st.one_of(_scalars, _arrays),
    lambda inner: st.lists(inner, max_size=4).map(lambda items: Variant(VT_ARRAY | VT_VARIANT, items)),
    max_leaves=12)


@given(variants)
def test_variant_round_trip(variant: Variant) -> None:
    data = encode_variant(variant)
    assert decode_variant(data) == (variant, len(data))


@given(st.integers(1, 65535), st.integers(0, 65535), st.integers(-(1 << 31), (1 << 31) - 1),
       st.lists(variants, max_size=3), st.booleans())
def test_packet_round_trip(serial: int, reserved: int, code: int, args: list[Variant],
                           serial_line: bool) -> None:
    try:
        data = encode_packet(serial, reserved, code, args, serial_line=serial_line)
    except BcapError as exc:  # only the 503-byte cap may refuse
        assert serial_line and exc.hresult == E_TOO_MUCH_DATA
        return
    assert decode_packet(data, serial_line=serial_line) == Packet(serial, reserved, code, tuple(args))


@settings(max_examples=300)
@given(st.lists(st.one_of(st.binary(max_size=40), st.sampled_from([TAKE_ARM, KEEPALIVE_5, b"\x01", b"\x04"])),
                max_size=12), st.booleans())
def test_random_streams_never_hang_and_raise_only_protocol_errors(chunks: list[bytes],
                                                                  serial_line: bool) -> None:
    decoder = PacketDecoder(serial_line=serial_line)
    decoder.feed(b"".join(chunks))
    for _ in range(10_000):  # every iteration consumes bytes or returns None: the bound is never reached
        try:
            if decoder.next_packet() is None:
                break
        except BcapProtocolError:
            continue
    else:
        pytest.fail("decoder did not terminate")


@given(st.binary(max_size=200))
def test_random_variant_bytes_raise_only_protocol_errors(data: bytes) -> None:
    with contextlib.suppress(BcapProtocolError):
        decode_variant(data)


@given(st.binary(min_size=1, max_size=40), st.integers(0, 200), st.booleans())
def test_mutated_vendor_frames_decode_or_raise_a_protocol_error(noise: bytes, at: int,
                                                               serial_line: bool) -> None:
    frame = bytearray(SERVICE_STOP_SERIAL if serial_line else TAKE_ARM)
    frame[at % len(frame):at % len(frame) + len(noise)] = noise
    with contextlib.suppress(BcapProtocolError):
        decode_packet(bytes(frame), serial_line=serial_line)
