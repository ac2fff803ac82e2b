"""Client and arm against the mock RC8 over real TCP loopback and a pty, on the simulated world."""

from __future__ import annotations

import socket
import struct

import numpy as np
import pytest
from bcap_support import RecordingTransport

from drivers.denso import hresult as hr
from drivers.denso.arm import BoxEnvelope, DensoArm, LimitError, OrientationLimits
from drivers.denso.bcap import PacketDecoder, encode_packet
from drivers.denso.client import BcapClient
from drivers.denso.motion import WaitSettings
from drivers.denso.variant import VT_I4, VT_UI4, Variant
from drivers.mock.bcap_args import JOINT_LIMIT, OUT_OF_REACH
from drivers.mock.bcap_server import BcapMockServer
from drivers.sim.clock import VirtualClock
from drivers.sim.world import World
from drivers.transport import open_transport

ENVELOPE = BoxEnvelope((150.0, 450.0), (-250.0, 250.0), (100.0, 500.0),
                       OrientationLimits(rx_deg=(-180, 180), ry_deg=(-30, 30), rz_deg=(-180, 180)))
POSES = [
    [300.0, 0.0, 350.0, 180.0, 0.0, 180.0],
    [320.0, 120.5, 300.0, 180.0, 10.0, 170.0],
    [250.0, -150.0, 400.0, 170.0, -5.0, -170.0],
    [380.0, 50.25, 250.0, 180.0, 0.0, 180.0],
]


@pytest.fixture
def world() -> World:
    return World(VirtualClock())


@pytest.fixture
def server(world: World):
    with BcapMockServer(world.robot, world.clock) as srv:
        yield srv


def _connect(server: BcapMockServer, kind: str, timeout_s: float = 1.0, retries: int = 3):
    if kind == "tcp":
        port = server.serve_tcp() if server.port is None else server.port
        inner = open_transport(f"tcp://127.0.0.1:{port}", timeout_s)
    else:
        inner = open_transport(f"serial://{server.serve_pty()}?baud=115200", timeout_s)
    link = RecordingTransport(inner, serial_line=kind == "pty")
    client = BcapClient(link, serial_line=kind == "pty", timeout_s=timeout_s, retries=retries)
    return link, client


def _arm(client: BcapClient, world: World, **kwargs) -> DensoArm:
    options = {"envelope": ENVELOPE, "max_speed_mm_s": 250.0, "position_tolerance_mm": 0.01,
               "clock": world.clock, **kwargs}
    return DensoArm(client, **options)


@pytest.mark.parametrize("kind", ["tcp", "pty"])
def test_session_moves_through_poses_and_agrees_with_the_twin(world: World, server: BcapMockServer,
                                                               kind: str) -> None:
    link, client = _connect(server, kind)
    # blocking Moves: the reply is the end of motion, so t_end_s is exact (NEXT: test_bcap_next_moves.py)
    with link, _arm(client, world, linear=True, wait=WaitSettings(wait_mode="blocking")) as arm:
        assert server.state.arm_taken and server.state.motor_on
        for index, pose in enumerate(POSES):
            speed = 100.0 + 40.0 * index
            result = arm.move_to(pose, speed)
            truth = world.robot.pose_at(world.clock.now_s())
            np.testing.assert_allclose(result.reported_pose, truth, atol=1e-9)
            assert result.position_error_mm <= 1e-9 and result.orientation_error_deg < 1e-6
            planned = server.state.moves[-1]
            assert planned["speed_mm_s"] == pytest.approx(speed)  # SPEED % × 1000 mm/s full speed
            assert result.t_end_s == pytest.approx(planned["t_end_s"])
            assert result.t_end_s - result.t_start_s >= np.linalg.norm(
                np.subtract(pose[:3], planned["pose"][:3])) / speed - 1e-9 or index == 0
            assert not world.robot.is_moving(world.clock.now_s())
        np.testing.assert_allclose(arm.position(), POSES[-1], atol=1e-9)
        assert arm.snapshot()["last_move"]["commanded_pose"] == POSES[-1]
    assert not server.state.handles and not server.state.motor_on and not server.state.arm_taken
    assert link.functions()[-5:] == [64, 64, 84, 4, 2]  # Motor off, GiveArm, Robot_Release, Disconnect, Stop


def test_out_of_envelope_and_speed_raise_before_any_write(world: World, server: BcapMockServer) -> None:
    link, client = _connect(server, "tcp")
    with link, _arm(client, world) as arm:
        before = len(link.written)
        with pytest.raises(LimitError, match=r"x_mm=460 outside the allowed range \[150, 450\]"):
            arm.move_to([460, 0, 300, 180, 0, 180])
        with pytest.raises(LimitError, match=r"ry_deg=45"):
            arm.move_to([300, 0, 300, 180, 45, 180])
        with pytest.raises(LimitError, match=r"speed_mm_s=300 outside the allowed range \[0, 250\]"):
            arm.move_to([300, 0, 300, 180, 0, 180], 300)
        with pytest.raises(LimitError, match="speed_mm_s"):
            arm.set_speed(-1)
        with pytest.raises(ValueError, match="pose has 3 values"):
            arm.move_to([1, 2, 3])
        assert len(link.written) == before
        assert server.state.moves == []


def test_unreachable_poses_are_refused_with_the_controller_error(world: World,
                                                                 server: BcapMockServer) -> None:
    link, client = _connect(server, "tcp")
    wide = BoxEnvelope((-1000, 1000), (-1000, 1000), (-1000, 1000))
    with link, _arm(client, world, envelope=wide) as arm:
        with pytest.raises(hr.BcapError) as info:
            arm.move_to([600, 0, 300, 180, 0, 180])  # wrist centre beyond 433 mm from J2
        assert info.value.hresult == OUT_OF_REACH and "reach" in info.value.description
        with pytest.raises(hr.BcapError) as info:
            arm.move_to([-300, -5, 300, 180, 0, 180])  # behind the base: J1 ≈ -179°
        assert info.value.hresult == JOINT_LIMIT and "joint limit" in info.value.description
        assert client.error_count() == 2
        code, message = client.error_info(1)
        assert hr.to_unsigned(code) == JOINT_LIMIT and "J1" in message
        client.clear_error()
        assert client.error_count() == 0
        assert server.state.moves == []
        assert 70 in link.functions()  # a halt was attempted after each failed move
    # the context manager released everything despite the errors
    assert not server.state.handles and not server.state.motor_on and not server.state.arm_taken
    assert link.functions()[-5:] == [64, 64, 84, 4, 2]


def test_handles_accepted_as_i4_or_ui4_and_unknown_handles_refused(world: World,
                                                                    server: BcapMockServer) -> None:
    link, client = _connect(server, "tcp")
    with link, client:
        client.service_start()
        ctrl = client.controller_connect()
        assert ctrl.vt == VT_UI4
        signed = client.call(7, [Variant(VT_I4, ctrl.value), "Arm", ""])
        unsigned = client.call(7, [Variant(VT_UI4, ctrl.value), "Arm0", ""])
        assert signed.vt == unsigned.vt == VT_UI4 and signed.value != unsigned.value
        with pytest.raises(hr.BcapError) as info:
            client.call(84, [Variant(VT_UI4, 999)])
        assert info.value.hresult == hr.E_HANDLE
        with pytest.raises(hr.BcapError) as info:
            client.call(133, [])
        assert info.value.hresult == hr.E_NOTIMPL
        names = client.call(13, [ctrl, ""])
        assert names.to_python() == ["Arm0"]


def test_variables_report_the_twin(world: World, server: BcapMockServer) -> None:
    link, client = _connect(server, "tcp")
    with link, client:
        client.open_robot()
        h_var = client.call(62, [client.h_robot, "@CURRENT_POSITION", ""])
        value = client.call(101, [h_var])
        np.testing.assert_allclose(value.value[:6], world.robot.pose_at(world.clock.now_s()))
        servo = client.call(62, [client.h_robot, "@SERVO_ON", ""])
        assert client.call(101, [servo]).value is True
        client.call(111, [h_var])
        with pytest.raises(hr.BcapError):
            client.call(101, [h_var])


def test_paced_move_sends_keepalives_and_restarts_the_timeout() -> None:
    world = World(VirtualClock(rate=1.0))
    with BcapMockServer(world.robot, world.clock) as server:
        link, client = _connect(server, "tcp", timeout_s=0.25)
        arm = _arm(client, world, wait=WaitSettings(wait_mode="blocking"))  # keep-alives: blocking Move only
        arm.open(wdt_ms=80)
        with link, arm:
            start = world.robot.pose_at(world.clock.now_s())
            target = [start[0] - 60.0, start[1], start[2], *start[3:]]
            arm.move_to(target, 100.0)  # ≈ 0.6 s of motion, well beyond the 0.25 s receive timeout
            assert client.link.keepalives_seen >= 3
            np.testing.assert_allclose(arm.position()[:3], target[:3], atol=1e-9)


def _raw_session(sock: socket.socket, world: World, wdt: str = ",WDT=100"):
    """Service_Start … Motor on over a raw socket; returns (call, receive, robot handle)."""
    decoder = PacketDecoder()

    def call(serial: int, function: int, args: list) -> None:
        sock.sendall(encode_packet(serial, 0, function, args))

    def receive():
        while (packet := decoder.next_packet()) is None:
            decoder.feed(sock.recv(4096))
        return packet

    call(1, 1, [wdt])
    call(2, 3, ["", "CaoProv.DENSO.VRC", "localhost", ""])
    call(3, 7, [Variant(VT_I4, 1), "Arm", ""])
    assert [receive().serial for _ in range(3)] == [1, 2, 3]
    robot = Variant(VT_I4, 2)
    call(4, 64, [robot, "TakeArm", [0, 1]])
    call(5, 64, [robot, "Motor", [1, 0]])
    assert [receive().code for _ in range(2)] == [0, 0]
    return call, receive, robot


def _move_40_mm(world: World) -> str:
    pose = world.robot.pose_at(world.clock.now_s())
    return "@P P({:.3f},{:.3f},{:.3f},{:.3f},{:.3f},{:.3f})".format(pose[0] - 40, *pose[1:])


def test_a_request_during_a_blocking_move_waits_its_turn_over_raw_tcp() -> None:
    """Reference server: the connection is not read while a call executes, so a request sent meanwhile
    is answered after the call's final reply, not refused."""
    world = World(VirtualClock(rate=1.0))
    with BcapMockServer(world.robot, world.clock) as server, \
            socket.create_connection(("127.0.0.1", server.serve_tcp()), timeout=5.0) as sock:
        call, receive, robot = _raw_session(sock, world)
        call(6, 72, [robot, Variant(VT_I4, 2), _move_40_mm(world), "SPEED=10"])  # 40 mm at 100 mm/s
        call(7, 64, [robot, "CurPos", None])
        replies = [receive()]
        while replies[-1].serial != 7:
            replies.append(receive())
        finals = [p for p in replies if not p.is_keepalive]
        assert [(p.serial, p.code) for p in finals] == [(6, 0), (7, 0)]
        assert sum(p.is_keepalive for p in replies if p.serial == 6) >= 2
        assert not world.robot.is_moving(world.clock.now_s())  # CurPos ran after the move ended
        np.testing.assert_allclose(finals[1].args[0].value[:6], world.robot.pose_at(world.clock.now_s()))


def test_busy_only_after_invoke_timeout_expired_with_the_call_still_running() -> None:
    world = World(VirtualClock(rate=1.0))
    with BcapMockServer(world.robot, world.clock) as server, \
            socket.create_connection(("127.0.0.1", server.serve_tcp()), timeout=5.0) as sock:
        call, receive, robot = _raw_session(sock, world, ",WDT=100,InvokeTimeout=100")
        call(6, 72, [robot, Variant(VT_I4, 2), _move_40_mm(world), "SPEED=1"])  # 4 s >> 0.1 s
        call(7, 64, [robot, "CurPos", None])  # read once the InvokeTimeout has expired
        while (packet := receive()).is_keepalive and packet.serial == 6:
            pass
        assert packet.serial == 7 and hr.to_unsigned(packet.code) == hr.E_BUSY_PROC
        assert packet.args == ()  # refused before execution: no argument (reference server)


def test_second_tcp_client_gets_max_connect(world: World, server: BcapMockServer) -> None:
    link, client = _connect(server, "tcp")
    with link, client:
        client.service_start()
        other = BcapClient(open_transport(f"tcp://127.0.0.1:{server.port}", 1.0), timeout_s=1.0)
        with pytest.raises(hr.BcapError) as info:
            other.service_start()
        assert info.value.hresult == hr.E_MAX_CONNECT
        other.link.transport.close()


def test_a_request_split_into_single_bytes_is_reassembled_by_the_server(world, server) -> None:
    port = server.serve_tcp()
    with socket.create_connection(("127.0.0.1", port), timeout=2.0) as sock:
        for byte in encode_packet(9, 0, 1, [""]):
            sock.sendall(bytes([byte]))
        data = b""
        while len(data) < 16:
            data += sock.recv(64)
        assert data == bytes.fromhex("01 10 00 00 00 09 00 00 00 00 00 00 00 00 00 04")
        assert struct.unpack_from("<H", data, 5)[0] == 9


def test_invoke_timeout_ends_a_long_move_without_reply() -> None:
    """bcap.md §10: after InvokeTimeout the server sends nothing more, so the client times out."""
    world = World(VirtualClock(rate=1.0))
    with BcapMockServer(world.robot, world.clock) as server:
        link, client = _connect(server, "tcp", timeout_s=0.25)
        with link, client:
            client.open_robot(wdt_ms=80, invoke_timeout_ms=200)
            start = world.robot.pose_at(world.clock.now_s())
            with pytest.raises(hr.BcapTimeoutError):
                client.move([start[0] - 80.0, *start[1:]], speed_percent=10)  # 0.8 s at 100 mm/s
            # keep-alives at 80 and 160 ms, then nothing after the 200 ms InvokeTimeout (however loaded)
            assert 1 <= client.link.keepalives_seen <= 2


def test_udp_session_with_a_lost_reply_recovered_by_retry(world: World, server: BcapMockServer) -> None:
    """UDP: 503-byte cap, retries with the first serial in the reserved field, no CRC (bcap.md §1, §2)."""
    port = server.serve_udp()
    with open_transport(f"udp://127.0.0.1:{port}", 0.2) as link, \
            BcapClient(link, udp=True, retries=3, timeout_s=0.2) as client:
        arm = _arm(client, world)
        arm.open(wdt_ms=None)
        server.faults.drop_replies, server.faults.drop_function = 1, 72
        result = arm.move_to(POSES[1], 120.0)
        assert result.position_error_mm < 1e-9 and len(server.state.moves) == 1
        moves = [r for r in server.requests if r[2] == 72]
        assert len(moves) == 2 and moves[1][1] == moves[0][0] == moves[0][1]  # reserved = first serial
        with pytest.raises(hr.BcapError) as info:
            client.robot_execute("x" * 300)  # 600 bytes of UTF-16: refused before sending
        assert info.value.hresult == hr.E_TOO_MUCH_DATA
