"""Replay of DENSO's own Python b-CAP client (``bcapclient.py``, DENSORobot/orin_bcap) against the mock RC8.

DENSO's client is not on PyPI, so its packets are written out here byte for byte, from its marshalling
rules (``BCAPClient._serialize``: header ``<bIHhiH`` with the reserved field 0 and the serial starting at
1, a uint32 length before each top-level argument; ``None`` → VT_EMPTY with count 1 and no data; a Python
``int`` — which is how it returns a VT_UI4 handle to the caller — → VT_I4; ``c_uint`` → VT_UI4; ``str`` →
VT_BSTR with a uint32 byte count and UTF-16LE; a list of ints → VT_I4 array; ``c_float`` → VT_R4). The
mock must answer each exactly as the reference server would, and the driver's codec must decode the
replies (the client and the mock use different codecs, so neither can hide the other's mistake).
"""

from __future__ import annotations

import socket

import pytest

from drivers.denso.bcap import decode_packet
from drivers.denso.variant import VT_ARRAY, VT_R8, VT_UI4
from drivers.mock.bcap_server import BcapMockServer
from drivers.sim.clock import VirtualClock
from drivers.sim.world import World


def hx(text: str) -> bytes:
    return bytes.fromhex(text.replace("|", " "))


# (request as bcapclient.py sends it, exact reply expected or None when only decoded)
SESSION = [
    # service_start("")
    (hx("01 1e 00 00 00 01 00 00 00 01 00 00 00 01 00 | 0a 00 00 00 08 00 01 00 00 00 00 00 00 00 | 04"),
     hx("01 10 00 00 00 01 00 00 00 00 00 00 00 00 00 04")),
    # controller_connect("", "CaoProv.DENSO.VRC", "localhost", "") → handle 1 as VT_UI4
    (hx("01 7c 00 00 00 02 00 00 00 03 00 00 00 04 00 | 0a 00 00 00 08 00 01 00 00 00 00 00 00 00 | "
        "2c 00 00 00 08 00 01 00 00 00 22 00 00 00 43 00 61 00 6f 00 50 00 72 00 6f 00 76 00 2e 00 44 00 "
        "45 00 4e 00 53 00 4f 00 2e 00 56 00 52 00 43 00 | 1c 00 00 00 08 00 01 00 00 00 12 00 00 00 6c 00 "
        "6f 00 63 00 61 00 6c 00 68 00 6f 00 73 00 74 00 | 0a 00 00 00 08 00 01 00 00 00 00 00 00 00 | 04"),
     hx("01 1e 00 00 00 02 00 00 00 00 00 00 00 01 00 | 0a 00 00 00 13 00 01 00 00 00 01 00 00 00 | 04")),
    # controller_getrobot(1, "Arm") — the handle echoed as VT_I4 → handle 2
    (hx("01 40 00 00 00 03 00 00 00 07 00 00 00 03 00 | 0a 00 00 00 03 00 01 00 00 00 01 00 00 00 | "
        "10 00 00 00 08 00 01 00 00 00 06 00 00 00 41 00 72 00 6d 00 | "
        "0a 00 00 00 08 00 01 00 00 00 00 00 00 00 | 04"),
     hx("01 1e 00 00 00 03 00 00 00 00 00 00 00 01 00 | 0a 00 00 00 13 00 01 00 00 00 02 00 00 00 | 04")),
    # robot_execute(2, "TakeArm", [0, 1]) → S_OK with one EMPTY
    (hx("01 4c 00 00 00 04 00 00 00 40 00 00 00 03 00 | 0a 00 00 00 03 00 01 00 00 00 02 00 00 00 | "
        "18 00 00 00 08 00 01 00 00 00 0e 00 00 00 54 00 61 00 6b 00 65 00 41 00 72 00 6d 00 | "
        "0e 00 00 00 03 20 02 00 00 00 00 00 00 00 01 00 00 00 | 04"),
     hx("01 1a 00 00 00 04 00 00 00 00 00 00 00 01 00 | 06 00 00 00 00 00 01 00 00 00 | 04")),
    # robot_execute(2, "Motor", [1, 0])
    (hx("01 48 00 00 00 05 00 00 00 40 00 00 00 03 00 | 0a 00 00 00 03 00 01 00 00 00 02 00 00 00 | "
        "14 00 00 00 08 00 01 00 00 00 0a 00 00 00 4d 00 6f 00 74 00 6f 00 72 00 | "
        "0e 00 00 00 03 20 02 00 00 00 01 00 00 00 00 00 00 00 | 04"),
     hx("01 1a 00 00 00 05 00 00 00 00 00 00 00 01 00 | 06 00 00 00 00 00 01 00 00 00 | 04")),
    # robot_execute(2, "CurPos") — the empty parameter: VT_EMPTY, count 1, argument length 6
    (hx("01 42 00 00 00 06 00 00 00 40 00 00 00 03 00 | 0a 00 00 00 03 00 01 00 00 00 02 00 00 00 | "
        "16 00 00 00 08 00 01 00 00 00 0c 00 00 00 43 00 75 00 72 00 50 00 6f 00 73 00 | "
        "06 00 00 00 00 00 01 00 00 00 | 04"), None),
    # robot_speed(2, -1, 50.0) — c_float(speed) → VT_R4
    (hx("01 3a 00 00 00 07 00 00 00 4a 00 00 00 03 00 | 0a 00 00 00 03 00 01 00 00 00 02 00 00 00 | "
        "0a 00 00 00 03 00 01 00 00 00 ff ff ff ff | 0a 00 00 00 04 00 01 00 00 00 00 00 48 42 | 04"),
     hx("01 10 00 00 00 07 00 00 00 00 00 00 00 00 00 04")),
    # robot_move(2, 1, "@P P(300,0,350,180,0,180,5)")
    (hx("01 7e 00 00 00 08 00 00 00 48 00 00 00 04 00 | 0a 00 00 00 03 00 01 00 00 00 02 00 00 00 | "
        "0a 00 00 00 03 00 01 00 00 00 01 00 00 00 | 40 00 00 00 08 00 01 00 00 00 36 00 00 00 40 00 50 00 "
        "20 00 50 00 28 00 33 00 30 00 30 00 2c 00 30 00 2c 00 33 00 35 00 30 00 2c 00 31 00 38 00 30 00 "
        "2c 00 30 00 2c 00 31 00 38 00 30 00 2c 00 35 00 29 00 | 0a 00 00 00 08 00 01 00 00 00 00 00 00 00 "
        "| 04"),
     hx("01 10 00 00 00 08 00 00 00 00 00 00 00 00 00 04")),
    # robot_execute(c_uint(2), "GiveArm") — a handle passed as c_uint travels as VT_UI4
    (hx("01 44 00 00 00 09 00 00 00 40 00 00 00 03 00 | 0a 00 00 00 13 00 01 00 00 00 02 00 00 00 | "
        "18 00 00 00 08 00 01 00 00 00 0e 00 00 00 47 00 69 00 76 00 65 00 41 00 72 00 6d 00 | "
        "06 00 00 00 00 00 01 00 00 00 | 04"),
     hx("01 1a 00 00 00 09 00 00 00 00 00 00 00 01 00 | 06 00 00 00 00 00 01 00 00 00 | 04")),
    # robot_release(2), controller_disconnect(1), service_stop()
    (hx("01 1e 00 00 00 0a 00 00 00 54 00 00 00 01 00 | 0a 00 00 00 03 00 01 00 00 00 02 00 00 00 | 04"),
     hx("01 10 00 00 00 0a 00 00 00 00 00 00 00 00 00 04")),
    (hx("01 1e 00 00 00 0b 00 00 00 04 00 00 00 01 00 | 0a 00 00 00 03 00 01 00 00 00 01 00 00 00 | 04"),
     hx("01 10 00 00 00 0b 00 00 00 00 00 00 00 00 00 04")),
    (hx("01 10 00 00 00 0c 00 00 00 02 00 00 00 00 00 04"),
     hx("01 10 00 00 00 0c 00 00 00 00 00 00 00 00 00 04")),
]


def _receive(sock: socket.socket) -> bytes:
    """One reply, read as bcapclient.py does: 1 byte, the 4-byte length, then the rest."""
    def exactly(n: int) -> bytes:
        data = b""
        while len(data) < n:
            chunk = sock.recv(n - len(data))
            assert chunk, "connection closed by the mock"
            data += chunk
        return data

    head = exactly(5)
    return head + exactly(int.from_bytes(head[1:5], "little") - 5)


def test_denso_client_session_replayed_byte_for_byte() -> None:
    world = World(VirtualClock())
    with BcapMockServer(world.robot, world.clock) as server, \
            socket.create_connection(("127.0.0.1", server.serve_tcp()), timeout=5.0) as sock:
        for request, expected in SESSION:
            sock.sendall(request)
            reply = _receive(sock)
            packet = decode_packet(reply)  # the driver's codec reads every reply of the mock
            assert packet.serial == int.from_bytes(request[5:7], "little") and packet.code == 0, packet
            if expected is not None:
                assert reply == expected, (request.hex(" "), reply.hex(" "))
            else:  # CurPos: x, y, z, rx, ry, rz, fig as an R8 array
                (pose,) = packet.args
                assert pose.vt == VT_ARRAY | VT_R8 and len(pose.value) == 7
                assert pose.value[:6] == pytest.approx(world.robot.pose_at(world.clock.now_s()).tolist())
        assert server.state.moves[-1]["pose"] == [300.0, 0.0, 350.0, 180.0, 0.0, 180.0]
        assert server.state.handles == {}


def test_handles_come_back_as_vt_ui4_and_are_accepted_as_vt_i4() -> None:
    world = World(VirtualClock())
    with BcapMockServer(world.robot, world.clock) as server, \
            socket.create_connection(("127.0.0.1", server.serve_tcp()), timeout=5.0) as sock:
        for request, _expected in SESSION[:3]:
            sock.sendall(request)
            (handle,) = decode_packet(_receive(sock)).args or (None,)
        assert handle is not None and handle.vt == VT_UI4 and handle.value == 2
        assert server.state.handles == {1: ("controller", ""), 2: ("robot", "Arm")}
