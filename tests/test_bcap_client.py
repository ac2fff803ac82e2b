"""Byte-level tests of the b-CAP client: each command's request bytes against a scripted transport, and
the link rules of ../shared/notes/bcap.md §2, §10, §16 (keep-alives, stray serials, retries, timeouts)."""

from __future__ import annotations

import contextlib
import struct
import time
from collections import deque

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.denso.client import BcapClient, pose_string, service_option
from drivers.denso.hresult import BcapConnectionError, BcapError, BcapProtocolError, BcapTimeoutError
from drivers.transport import TransportClosed, TransportTimeout


# --- an independent little encoder (struct only), so the expected bytes do not come from the codec --------
def var(vt: int, data: bytes, count: int = 1) -> bytes:
    body = struct.pack("<HI", vt, count) + data
    return struct.pack("<I", len(body)) + body


def bstr(text: str) -> bytes:
    raw = text.encode("utf-16-le")
    return var(8, struct.pack("<I", len(raw)) + raw)


def ui4(value: int) -> bytes:
    return var(19, struct.pack("<I", value))


def i4(value: int) -> bytes:
    return var(3, struct.pack("<i", value))


def empty() -> bytes:
    return var(0, b"")


def i4_array(*values: int) -> bytes:
    return var(0x2003, struct.pack(f"<{len(values)}i", *values), len(values))


def r4_array(*values: float) -> bytes:
    return var(0x2004, struct.pack(f"<{len(values)}f", *values), len(values))


def r8_array(*values: float) -> bytes:
    return var(0x2005, struct.pack(f"<{len(values)}d", *values), len(values))


def crc(data: bytes) -> int:
    value = 0xFFFF
    for byte in data:
        value ^= byte << 8
        for _ in range(8):
            value = ((value << 1) ^ 0x1021) & 0xFFFF if value & 0x8000 else (value << 1) & 0xFFFF
    return value


def packet(serial: int, code: int, *args: bytes, reserved: int = 0, serial_line: bool = False) -> bytes:
    body = b"".join(args)
    length = 15 + len(body) + (3 if serial_line else 1)
    head = struct.pack("<IHHiH", length, serial, reserved, code - (1 << 32) if code >= 1 << 31 else code,
                       len(args)) + body
    tail = struct.pack("<H", crc(head)) + b"\x04" if serial_line else b"\x04"
    return b"\x01" + head + tail


class ScriptedTransport:
    """Replays (expected request, reply bytes) pairs; an empty reply means the controller stays silent."""

    url = "scripted://"

    def __init__(self, script: list[tuple[bytes, bytes]]) -> None:
        self.script = deque(script)
        self.inbox = bytearray()
        self.writes: list[bytes] = []

    def write(self, data: bytes) -> None:
        self.writes.append(bytes(data))
        assert self.script, f"unexpected write {data.hex(' ')}"
        expected, reply = self.script.popleft()
        assert data.hex(" ") == expected.hex(" ")
        self.inbox += reply

    def read_exact(self, n: int, timeout_s: float | None = None) -> bytes:
        if len(self.inbox) < n:
            raise TransportTimeout("scripted: no more reply bytes")
        data = bytes(self.inbox[:n])
        del self.inbox[:n]
        return data

    def read_available(self) -> bytes:
        data = bytes(self.inbox)
        self.inbox.clear()
        return data

    def read_until(self, terminator: bytes, timeout_s: float | None = None, max_bytes: int = 65536) -> bytes:
        raise AssertionError("b-CAP frames by length: the client never reads up to a terminator")

    def close(self) -> None:
        pass

    def done(self) -> None:
        assert not self.script, f"{len(self.script)} exchanges not used"
        assert not self.inbox, "reply bytes left unread"


OK = 0


def reply(serial: int, *args: bytes, code: int = OK, serial_line: bool = False) -> bytes:
    return packet(serial, code, *args, serial_line=serial_line)


def test_rc8_session_request_bytes() -> None:
    """The RC8 sequence of bcap.md §11, byte for byte, with the handles the controller returns (UI4)."""
    script = [
        (packet(1, 1, bstr(",WDT=400,InvokeTimeout=180000")), reply(1)),
        (packet(2, 3, bstr("rig"), bstr("CaoProv.DENSO.VRC"), bstr("localhost"), bstr("")), reply(2, ui4(7))),
        (packet(3, 17, ui4(7), bstr("GetCurErrorCount"), empty()), reply(3, i4(0))),
        (packet(4, 7, ui4(7), bstr("Arm"), bstr("")), reply(4, ui4(9))),
        (packet(5, 64, ui4(9), bstr("TakeArm"), i4_array(0, 1)), reply(5, empty())),
        (packet(6, 64, ui4(9), bstr("Motor"), i4_array(1, 0)), reply(6, empty())),
        (packet(7, 64, ui4(9), bstr("ExtSpeed"), r4_array(50.0, -2.0, -2.0)), reply(7, empty())),
        (packet(8, 72, ui4(9), i4(1), bstr("@P P(300,-250.5,350,180,0,-90,5)"), bstr("SPEED=20")), reply(8)),
        (packet(9, 72, ui4(9), i4(2), bstr("@P P(300,0,350,180,0,-90,-1)"), bstr("")), reply(9)),
        (packet(10, 64, ui4(9), bstr("CurPos"), empty()),
         reply(10, r8_array(300.0, 0.0, 350.0, 180.0, 0.0, -90.0, 5.0))),
        (packet(11, 70, ui4(9), bstr("")), reply(11)),
        (packet(12, 64, ui4(9), bstr("Motor"), i4_array(0, 0)), reply(12, empty())),
        (packet(13, 64, ui4(9), bstr("GiveArm"), empty()), reply(13, empty())),
        (packet(14, 84, ui4(9)), reply(14)),
        (packet(15, 4, ui4(7)), reply(15)),
        (packet(16, 2), reply(16)),
    ]
    link = ScriptedTransport(script)
    with BcapClient(link, timeout_s=1.0) as client:
        client.open_robot(ext_speed_percent=50.0)
        client.move([300, -250.5, 350, 180, 0, -90], speed_percent=20, fig=5)
        client.move([300, 0, 350, 180, 0, -90], linear=True)
        assert client.cur_pos() == [300.0, 0.0, 350.0, 180.0, 0.0, -90.0, 5.0]
        client.halt()
    link.done()


def test_rc7m_connect_sends_four_empty_strings_and_handles_echo_their_type() -> None:
    script = [
        (packet(1, 3, bstr(""), bstr(""), bstr(""), bstr("")), reply(1, i4(3))),
        (packet(2, 7, i4(3), bstr(""), bstr("")), reply(2, i4(4))),
        (packet(3, 64, i4(4), bstr("Motor"), var(2, struct.pack("<h", 1))), reply(3, empty())),
    ]
    link = ScriptedTransport(script)
    client = BcapClient(link, rc7m=True)
    client.controller_connect()
    client.controller_get_robot("")
    client.take_arm()  # RC7M: no TakeArm on the wire
    client.motor(True)
    link.done()


def test_error_queue_commands() -> None:
    script = [
        (packet(1, 3, bstr("rig"), bstr("CaoProv.DENSO.VRC"), bstr("localhost"), bstr("")), reply(1, ui4(1))),
        (packet(2, 17, ui4(1), bstr("GetCurErrorInfo"), i4(0)),
         reply(2, var(0x200C, struct.pack("<HIi", 3, 1, -2091868159)
                      + struct.pack("<HII", 8, 1, 4) + "ab".encode("utf-16-le"), 2))),
        (packet(3, 17, ui4(1), bstr("GetErrorDescription"), i4(-2091868159)), reply(3, bstr("reach"))),
        (packet(4, 17, ui4(1), bstr("ClearError"), empty()), reply(4, empty())),
    ]
    link = ScriptedTransport(script)
    client = BcapClient(link)
    client.controller_connect()
    assert client.error_info(0) == [-2091868159, "ab"]
    assert client.error_description(0x8350A001) == "reach"
    client.clear_error()
    link.done()


def test_controller_error_carries_code_name_and_controller_description() -> None:
    script = [
        (packet(1, 3, bstr("rig"), bstr("CaoProv.DENSO.VRC"), bstr("localhost"), bstr("")), reply(1, ui4(1))),
        (packet(2, 7, ui4(1), bstr("Arm"), bstr("")), reply(2, ui4(2))),
        (packet(3, 72, ui4(2), i4(1), bstr("@P P(0,0,0,0,0,0,-1)"), bstr("")), reply(3, code=0x84204041)),
        (packet(4, 17, ui4(1), bstr("GetErrorDescription"), i4(0x84204041 - (1 << 32))),
         reply(4, bstr("Out of range"))),
    ]
    link = ScriptedTransport(script)
    client = BcapClient(link)
    client.controller_connect()
    client.controller_get_robot()
    with pytest.raises(BcapError) as info:
        client.move([0, 0, 0, 0, 0, 0])
    assert info.value.hresult == 0x84204041
    assert info.value.description == "Out of range"
    assert "Robot_Move" in str(info.value) and "0x84204041" in str(info.value)
    link.done()


def test_keepalives_and_stray_serials_are_skipped() -> None:
    keepalive = packet(1, 0x900)
    stray = reply(7, i4(5))
    link = ScriptedTransport([(packet(1, 2), keepalive + stray + keepalive + reply(1))])
    client = BcapClient(link)
    client.service_stop()
    assert client.link.keepalives_seen == 2
    assert client.link.discarded_replies == 1
    link.done()


def test_tcp_never_resends() -> None:
    link = ScriptedTransport([(packet(1, 2), b"")])
    client = BcapClient(link, retries=5, timeout_s=0.05)
    with pytest.raises(BcapTimeoutError, match="1 attempt"):
        client.service_stop()
    assert len(link.writes) == 1


def test_serial_retries_carry_first_serial_in_reserved() -> None:
    script = [
        (packet(1, 2, reserved=1, serial_line=True), b""),
        (packet(2, 2, reserved=1, serial_line=True), b""),
        (packet(3, 2, reserved=1, serial_line=True), reply(3, serial_line=True)),
        (packet(4, 2, reserved=4, serial_line=True), reply(4, serial_line=True)),
    ]
    link = ScriptedTransport(script)
    client = BcapClient(link, serial_line=True, retries=3, timeout_s=0.05)
    client.service_stop()
    client.service_stop()
    link.done()


def test_serial_gives_up_after_all_attempts() -> None:
    script = [(packet(n, 2, reserved=1, serial_line=True), b"") for n in (1, 2)]
    client = BcapClient(ScriptedTransport(script), serial_line=True, retries=2, timeout_s=0.02)
    with pytest.raises(BcapTimeoutError, match="after 2 attempt"):
        client.service_stop()


def test_serial_wraps_after_65535() -> None:
    link = ScriptedTransport([(packet(65535, 2), reply(65535)), (packet(1, 2), reply(1))])
    client = BcapClient(link)
    client.link._serial = 65534
    client.service_stop()
    client.service_stop()
    link.done()


def test_closed_link_is_a_connection_error() -> None:
    class Closed(ScriptedTransport):
        def read_exact(self, n: int, timeout_s: float | None = None) -> bytes:
            raise TransportClosed("peer closed")

    client = BcapClient(Closed([(packet(1, 2), b"")]))
    with pytest.raises(BcapConnectionError, match="closed"):
        client.service_stop()


def test_keepalive_restarts_the_timeout() -> None:
    """Keep-alives every 30 ms keep a 100 ms receive timeout alive for 0.3 s (bcap.md §10 client rule)."""

    class Slow(ScriptedTransport):  # ten keep-alives, each after ≥ 30 ms, then the reply: ≥ 0.3 s in all
        def __init__(self) -> None:
            super().__init__([(packet(1, 2), b"")])
            self.keepalives = 0

        def read_exact(self, n: int, timeout_s: float | None = None) -> bytes:
            if not self.inbox:
                time.sleep(0.03)
                self.inbox += reply(1) if self.keepalives == 10 else packet(1, 0x900)
                self.keepalives += 1
            return super().read_exact(n, timeout_s)

    link = Slow()
    client = BcapClient(link, timeout_s=0.1)
    t0 = time.monotonic()
    client.service_stop()
    assert time.monotonic() - t0 >= 0.3  # the call outlived its 0.1 s receive timeout three times over
    assert client.link.keepalives_seen == 10


@pytest.mark.parametrize("kwargs, message", [
    ({"wdt_ms": 50, "invoke_timeout_ms": None}, "wdt_ms=50"),
    ({"wdt_ms": None, "invoke_timeout_ms": 0}, "invoke_timeout_ms=0"),
])
def test_service_option_validation(kwargs: dict, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        service_option(**kwargs)
    assert service_option(400, 180000) == ",WDT=400,InvokeTimeout=180000"
    assert service_option(None, None) == ""


def test_pose_strings() -> None:
    assert pose_string([300, -250, 350, 0, 0, 20], 0) == "@P P(300,-250,350,0,0,20,0)"
    assert pose_string([0.12345, -0.0, 1e-7, 1, 2, 3]) == "@P P(0.1235,0,0,1,2,3,-1)"
    with pytest.raises(ValueError, match="6"):
        pose_string([1, 2, 3])
    with pytest.raises(ValueError, match="finite"):
        pose_string([float("nan"), 0, 0, 0, 0, 0])


def test_wdt_must_fit_the_receive_timeout() -> None:
    client = BcapClient(ScriptedTransport([]), timeout_s=0.5)
    with pytest.raises(ValueError, match=r"1\.5 × WDT"):
        client.service_start(wdt_ms=400)


@settings(max_examples=150, deadline=None)
@given(st.binary(max_size=300), st.booleans())
def test_random_reply_bytes_end_in_a_bcap_error(noise: bytes, serial_line: bool) -> None:
    """Whatever the controller sends back, a call ends (no hang) in a reply or a typed b-CAP error."""
    request = packet(1, 2, reserved=1 if serial_line else 0, serial_line=serial_line)
    link = ScriptedTransport([(request, noise)])
    client = BcapClient(link, serial_line=serial_line, retries=1, timeout_s=0.01)
    with contextlib.suppress(BcapError, BcapProtocolError):
        client.service_stop()


def test_failing_error_description_does_not_recurse() -> None:
    script = [
        (packet(1, 3, bstr("rig"), bstr("CaoProv.DENSO.VRC"), bstr("localhost"), bstr("")), reply(1, ui4(1))),
        (packet(2, 17, ui4(1), bstr("Foo"), empty()), reply(2, empty(), code=0x83000001)),
        (packet(3, 17, ui4(1), bstr("GetErrorDescription"), i4(0x83000001 - (1 << 32))),
         reply(3, empty(), code=0x83000002)),
    ]
    link = ScriptedTransport(script)
    client = BcapClient(link)
    client.controller_connect()
    with pytest.raises(BcapError) as info:
        client.controller_execute("Foo")
    assert info.value.hresult == 0x83000001 and "no description" in info.value.description
    link.done()
