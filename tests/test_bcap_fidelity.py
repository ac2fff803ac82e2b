"""The mock RC8 behaves as DENSO's reference server (docs/bcap_mock.md): options reset per client and per
Service_Start, the option ranges, any argument answered with an HRESULT, the 1,000-object cap, a malformed
packet closing a TCP connection, the joint-angle commands, bounded histories and the fault options."""

from __future__ import annotations

import math
import socket
import struct
import time

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from drivers.denso import bcap
from drivers.denso import hresult as hr
from drivers.denso.bcap import PacketDecoder, encode_packet
from drivers.denso.client import BcapClient
from drivers.denso.variant import VT_ARRAY, VT_I4, VT_R4, VT_R8, VT_UI4, Variant
from drivers.mock import vp6242
from drivers.mock.bcap_server import BcapMockServer, main, parse_fault
from drivers.mock.bcap_state import MAX_OBJECTS, History
from drivers.sim.clock import VirtualClock
from drivers.sim.world import World
from drivers.transport import open_transport


def _client(server: BcapMockServer, timeout_s: float = 2.0) -> BcapClient:
    port = server.port if server.port is not None else server.serve_tcp()
    return BcapClient(open_transport(f"tcp://127.0.0.1:{port}", timeout_s), timeout_s=timeout_s)


def _wait_until_free(server: BcapMockServer, timeout_s: float = 10.0) -> None:
    """The mock has seen the previous client go (bounded wait on the server's own state)."""
    deadline = time.monotonic() + timeout_s
    while server.held_by is not None:
        assert time.monotonic() < deadline, f"controller still held by {server.held_by}"
        time.sleep(0.01)


def test_options_of_a_client_gone_without_service_stop_do_not_reach_the_next() -> None:
    """InvokeTimeout=100 left by one client must not cut the next client's ordinary 1.8 s move."""
    world = World(VirtualClock(rate=10.0))  # 1.8 virtual s = 0.18 wall s > 100 ms
    with BcapMockServer(world.robot, world.clock) as server:
        first = _client(server)
        first.service_start(wdt_ms=80, invoke_timeout_ms=100)
        assert (server.state.wdt_ms, server.state.invoke_timeout_ms) == (80, 100)
        first.link.transport.close()  # gone without Service_Stop
        _wait_until_free(server)
        second = _client(server)
        second.open_robot(wdt_ms=None, invoke_timeout_ms=None)  # Service_Start(""): the defaults
        assert (server.state.wdt_ms, server.state.invoke_timeout_ms) == (None, 180_000)
        start = world.robot.pose_at(world.clock.now_s())
        second.move([start[0] - 90.0, *start[1:]], speed_percent=5)  # 90 mm at 50 mm/s ≈ 1.8 s
        assert server.state.moves[-1]["t_end_s"] - server.state.moves[-1]["t_start_s"] > 1.8
        np.testing.assert_allclose(second.cur_pos()[0], start[0] - 90.0, atol=1e-9)
        second.close()
        second.link.transport.close()


@pytest.mark.parametrize(("option", "accepted"), [
    (",WDT=10", False), (",WDT=79", False), (",WDT=80", True), (",InvokeTimeout=50", False),
    (",InvokeTimeout=80", True), (",WDT=abc", False), ("", True), (",WDT=400,InvokeTimeout=180000", True)])
def test_service_start_option_ranges(option: str, accepted: bool) -> None:
    world = World(VirtualClock())
    with BcapMockServer(world.robot, world.clock) as server:
        client = _client(server)
        client.call(bcap.SERVICE_START, [",WDT=200,InvokeTimeout=5000"])
        if accepted:
            client.call(bcap.SERVICE_START, [option])
        else:
            with pytest.raises(hr.BcapError) as info:
                client.call(bcap.SERVICE_START, [option])
            assert info.value.hresult == hr.E_INVALIDARG
            assert (server.state.wdt_ms, server.state.invoke_timeout_ms) == (200, 5000)  # unchanged
        client.link.transport.close()


@pytest.fixture(scope="module")
def session():
    """(server, client) with a controller and a robot handle; shared by the property test below."""
    world = World(VirtualClock())
    with BcapMockServer(world.robot, world.clock) as server:
        client = _client(server, timeout_s=5.0)
        client.open_robot(wdt_ms=None)
        yield server, client
        client.link.transport.close()


NUMBERS = st.one_of(st.floats(), st.sampled_from([math.nan, math.inf, -math.inf, 1e308, -0.0]),
                    st.integers(-2**31, 2**31 - 1))


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(command=st.sampled_from(["GetCurErrorInfo", "GetErrorDescription", "GetCurErrorCount", "ClearError"]),
       number=NUMBERS, as_r4=st.booleans())
def test_any_argument_gets_an_hresult_reply(session, command: str, number: float, as_r4: bool) -> None:
    _server, client = session
    if isinstance(number, float):
        param = Variant(VT_R4, number) if as_r4 and (abs(number) < 3e38 or not math.isfinite(number)) \
            else Variant(VT_R8, number)
    else:
        param = Variant(VT_I4, number)
    try:
        client.link.call(bcap.CONTROLLER_EXECUTE, [client.h_ctrl, command, param])
    except hr.BcapError as exc:
        assert exc.hresult in (hr.E_INVALIDARG, hr.DISP_E_TYPEMISMATCH), exc
    assert client.error_count() >= 0  # the connection is still served


def test_objects_are_capped_at_1000_with_e_max_object() -> None:
    world = World(VirtualClock())
    with BcapMockServer(world.robot, world.clock) as server:
        client = _client(server)
        client.service_start(wdt_ms=None)
        handles = [client.link.call(bcap.CONTROLLER_CONNECT, ["", "", "", ""])[0] for _ in range(MAX_OBJECTS)]
        assert len(server.state.handles) == MAX_OBJECTS
        with pytest.raises(hr.BcapError) as info:
            client.link.call(bcap.CONTROLLER_CONNECT, ["", "", "", ""])
        assert info.value.hresult == hr.E_MAX_OBJECT
        client.link.call(bcap.CONTROLLER_DISCONNECT, [handles[500]])
        again = client.link.call(bcap.CONTROLLER_CONNECT, ["", "", "", ""])[0]
        assert again.vt == VT_UI4 and again.value not in {h.value for h in handles if h != handles[500]}
        client.link.transport.close()


def test_a_malformed_packet_closes_the_tcp_connection_and_stops_the_arm() -> None:
    world = World(VirtualClock())
    with BcapMockServer(world.robot, world.clock) as server:
        client = _client(server)
        client.open_robot(wdt_ms=None)
        good = bytearray(encode_packet(99, 0, bcap.ROBOT_EXECUTE, [client.h_robot, "CurPos", None]))
        good[15] += 1  # the first argument's length no longer matches its VARIANT
        client.link.transport.write(bytes(good))
        with pytest.raises(hr.BcapConnectionError):
            client.cur_pos()
        _wait_until_free(server)
        assert server.state.handles == {} and not server.state.motor_on


def test_a_malformed_packet_on_the_serial_line_is_dropped() -> None:
    world = World(VirtualClock())
    with BcapMockServer(world.robot, world.clock) as server, \
            open_transport(f"serial://{server.serve_pty()}?baud=115200", 1.0) as line:
        client = BcapClient(line, serial_line=True, timeout_s=1.0)
        client.open_robot(wdt_ms=None)
        bad = bytearray(encode_packet(99, 0, bcap.ROBOT_EXECUTE, [client.h_robot, "CurPos", None],
                                      serial_line=True))
        bad[-1] = 0x05  # no EOT: skipped by the framer
        line.write(bytes(bad))
        assert len(client.cur_pos()) == 7
        client.close()


def test_joint_angles_follow_the_pose_model() -> None:
    world = World(VirtualClock())
    with BcapMockServer(world.robot, world.clock) as server:
        client = _client(server)
        client.open_robot(wdt_ms=None)
        pose = world.robot.pose_at(world.clock.now_s())
        reach = vp6242.solve(pose)
        expected = [reach.j1_deg, reach.j2_deg, reach.j3_deg, 0.0, reach.j5_deg, pose[5] - reach.j1_deg]
        joints = client.robot_execute("CurJnt")
        assert joints.vt == VT_ARRAY | VT_R8 and joints.value == pytest.approx(expected)
        stamped = client.robot_execute("HighCurJntEx").value
        assert stamped[0] == pytest.approx(world.clock.now_s() * 1000.0)
        assert stamped[1:] == pytest.approx(expected)
        handle = client.call(bcap.ROBOT_GET_VARIABLE, [client.h_robot, "@CURRENT_ANGLE", ""])
        assert client.call(bcap.VARIABLE_GET_VALUE, [handle]).value == pytest.approx(expected)
        client.close()


def test_histories_are_bounded() -> None:
    history = History(3)
    for item in range(10):
        history.append(item)
    assert history == [7, 8, 9] and history.dropped == 7
    world = World(VirtualClock())
    with BcapMockServer(world.robot, world.clock) as server:
        assert isinstance(server.requests, History) and server.requests.limit == 10_000
        assert isinstance(server.state.moves, History) and isinstance(server.state.errors, History)


def test_finished_connections_are_reaped() -> None:
    world = World(VirtualClock())
    with BcapMockServer(world.robot, world.clock) as server:
        port = server.serve_tcp()
        for _ in range(20):
            with socket.create_connection(("127.0.0.1", port), timeout=2.0) as sock:
                sock.sendall(encode_packet(1, 0, bcap.SERVICE_START, [""]))
                decoder = PacketDecoder()
                while decoder.next_packet() is None:
                    decoder.feed(sock.recv(64))
        deadline = time.monotonic() + 10.0
        while server._sessions and time.monotonic() < deadline:
            time.sleep(0.01)
        assert server._sessions == []


@pytest.mark.parametrize(("text", "expected"), [
    ("delay:2.5", ("delay_reply_s", 2.5)), ("delay", ("delay_reply_s", 5.0)),
    ("no-reply", ("drop_replies", 10**9)),
    ("busy:2", ("busy_replies", 2)), ("move-error:0x8350A005", ("move_error", 0x8350A005)),
    ("disconnect-after:3", ("disconnect_after", 3)), ("corrupt-crc:1", ("corrupt_crc", 1)),
    ("stale:1", ("stale_replies", 1)), ("duplicate", ("duplicate_replies", 10**9)),
    ("drop-bytes:4", ("drop_reply_bytes", 4))])
def test_fault_options(text: str, expected: tuple) -> None:
    assert parse_fault(text) == expected


@pytest.mark.parametrize("text", ["explode", "delay:soon", "busy:-1"])
def test_bad_fault_options_are_usage_errors(text: str, capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as info:
        main(["--port", "0", "--fault", text], prog="rig mock robot")
    assert info.value.code == 4  # bad input (rig's exit code; argparse's own is 2)
    assert "rig mock robot" in capsys.readouterr().err


def test_disconnect_after_n_requests() -> None:
    world = World(VirtualClock())
    with BcapMockServer(world.robot, world.clock) as server:
        server.faults.disconnect_after = 3
        client = _client(server)
        client.service_start(wdt_ms=None)
        client.controller_connect()
        client.controller_get_robot()
        with pytest.raises(hr.BcapConnectionError):
            client.take_arm()
        assert [r[2] for r in server.requests] == [1, 3, 7, 64]
        client.link.transport.close()


def test_value_returning_refusals_before_execution_carry_no_argument() -> None:
    world = World(VirtualClock())
    with BcapMockServer(world.robot, world.clock) as server:
        client = _client(server)
        client.open_robot(wdt_ms=None)
        server.faults.busy_replies = 1
        sock_bytes = encode_packet(50, 0, bcap.ROBOT_EXECUTE, [client.h_robot, "CurPos", None])
        client.link.transport.write(sock_bytes)
        decoder = PacketDecoder()
        decoder.feed(client.link.transport.read_exact(16, 2.0))
        packet = decoder.next_packet()
        assert packet is not None and hr.to_unsigned(packet.code) == hr.E_BUSY_PROC and packet.args == ()
        assert client.robot_execute("CurPos").vt == VT_ARRAY | VT_R8
        client.close()


def test_connections_reset_before_they_are_served_do_not_stop_the_accept_loop() -> None:
    """Found by benchmarks/fuzz_bcap.py: a reset before the mock served it killed the accept thread."""
    world = World(VirtualClock())
    with BcapMockServer(world.robot, world.clock) as server:
        port = server.serve_tcp()
        for _ in range(200):
            sock = socket.create_connection(("127.0.0.1", port), timeout=2.0)
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
            sock.close()
        client = _client(server)
        client.service_start(wdt_ms=None)
        client.link.transport.close()
