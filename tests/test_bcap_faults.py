"""Every injected fault of the mock RC8 ends in a clear exception within the configured timeout, and the
arm attempts a halt; recoverable faults (one lost or corrupted reply on a serial line) are recovered."""

from __future__ import annotations

import time

import pytest
from bcap_support import RecordingTransport

from drivers.denso import hresult as hr
from drivers.denso.arm import BoxEnvelope, DensoArm
from drivers.denso.client import BcapClient
from drivers.mock.bcap_server import BcapMockServer, Faults
from drivers.sim.clock import VirtualClock
from drivers.sim.world import World
from drivers.transport import open_transport

TIMEOUT_S = 0.15
ROBOT_HALT, ROBOT_MOVE = 70, 72
TARGET = [300.0, 50.0, 320.0, 180.0, 0.0, 180.0]


@pytest.fixture(params=["tcp", "pty"])
def rig(request):
    """(world, server, recorder, arm) with an opened session; closed afterwards."""
    world = World(VirtualClock())
    server = BcapMockServer(world.robot, world.clock)
    serial_line = request.param == "pty"
    if serial_line:
        url = f"serial://{server.serve_pty()}?baud=115200"
    else:
        url = f"tcp://127.0.0.1:{server.serve_tcp()}"
    recorder = RecordingTransport(open_transport(url, TIMEOUT_S), serial_line)
    client = BcapClient(recorder, serial_line=serial_line, retries=2, timeout_s=TIMEOUT_S)
    arm = DensoArm(client, envelope=BoxEnvelope((100, 500), (-300, 300), (50, 600)), max_speed_mm_s=200,
                   position_tolerance_mm=0.01, clock=world.clock)
    arm.open(wdt_ms=None)
    yield world, server, recorder, arm
    server.faults = Faults()
    arm.close()
    recorder.close()
    server.close()


def _attempts(arm: DensoArm) -> int:
    return arm.client.link.attempts


def _expect_failure(arm: DensoArm, recorder: RecordingTransport, error: type[Exception]) -> Exception:
    # move + halt, each at most every attempt's timeout; + a margin for a loaded machine (liveness, not speed)
    budget_s = _attempts(arm) * TIMEOUT_S * 2 + 30.0
    before = len(recorder.functions())
    start = time.monotonic()
    with pytest.raises(error) as info:
        arm.move_to(TARGET, 100.0)
    elapsed = time.monotonic() - start
    assert elapsed < budget_s, f"took {elapsed:.2f} s, more than the {budget_s:.2f} s the timeouts allow"
    sent = recorder.functions()[before:]
    assert ROBOT_MOVE in sent and ROBOT_HALT in sent[sent.index(ROBOT_MOVE):], sent  # halt attempted
    return info.value


def test_dropped_move_reply(rig) -> None:
    _world, server, recorder, arm = rig
    server.faults.drop_replies, server.faults.drop_function = 100, ROBOT_MOVE
    error = _expect_failure(arm, recorder, hr.BcapTimeoutError)
    assert error.hresult == hr.E_TIMEOUT and "Robot_Move" in str(error)
    assert len(server.state.moves) == 1  # executed once; retries were answered from the cache


def test_delayed_move_reply(rig) -> None:
    _world, server, recorder, arm = rig
    server.faults.delay_reply_s, server.faults.delay_function = 5.0, ROBOT_MOVE
    error = _expect_failure(arm, recorder, hr.BcapTimeoutError)
    assert "no reply within 0.15 s" in str(error)


def test_error_on_move(rig) -> None:
    _world, server, recorder, arm = rig
    server.faults.move_error = 0x8350A005
    error = _expect_failure(arm, recorder, hr.BcapError)
    assert error.hresult == 0x8350A005 and "Injected fault" in error.description
    assert server.state.moves == []


def test_busy(rig) -> None:
    _world, server, recorder, arm = rig
    server.faults.busy_replies, server.faults.busy_function = 1, ROBOT_MOVE
    error = _expect_failure(arm, recorder, hr.BcapError)
    assert error.name == "E_BUSY_PROC"


def test_close_mid_move(rig) -> None:
    """TCP: the controller closes the socket; pty: the device disappears (the master is closed)."""
    world, server, recorder, arm = rig
    server.faults.close_mid_move = True
    error = _expect_failure(arm, recorder, hr.BcapConnectionError)
    assert error.hresult == hr.E_NOT_CONNECTED and "link" in str(error)
    assert not world.robot.is_moving(world.clock.now_s())  # the controller stopped the arm


@pytest.mark.parametrize("rig", ["pty"], indirect=True)
def test_corrupt_crc_every_time(rig) -> None:
    _world, server, recorder, arm = rig
    server.faults.corrupt_crc = 100
    _expect_failure(arm, recorder, hr.BcapTimeoutError)


@pytest.mark.parametrize("rig", ["pty"], indirect=True)
@pytest.mark.parametrize("fault", ["drop_replies", "corrupt_crc"])
def test_one_lost_reply_on_a_serial_line_is_recovered_without_executing_twice(rig, fault: str) -> None:
    _world, server, _recorder, arm = rig
    setattr(server.faults, fault, 1)
    if fault == "drop_replies":
        server.faults.drop_function = ROBOT_MOVE
    result = arm.move_to(TARGET, 100.0)
    assert result.position_error_mm < 1e-9
    assert len(server.state.moves) == 1
    retry = [r for r in server.requests if r[2] == ROBOT_MOVE]
    assert len(retry) == 2 and retry[1][1] == retry[0][0] != retry[1][0]  # reserved = first serial


def test_stray_replies_keepalives_and_fragmented_replies_are_tolerated(rig) -> None:
    _world, server, _recorder, arm = rig
    server.faults.wrong_serial_first = True
    server.faults.stray_keepalive = True
    server.faults.fragment_replies = True
    result = arm.move_to(TARGET, 100.0)
    assert result.position_error_mm < 1e-9
    assert arm.client.link.discarded_replies >= 2 and arm.client.link.keepalives_seen >= 2
