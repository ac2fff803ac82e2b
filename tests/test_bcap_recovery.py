"""Link recovery of the b-CAP driver against the mock RC8 made to misbehave: a late reply, a reply sent
twice, the previous request's reply, lost bytes — the driver drains and carries on (reads and halts are
asked again); a make-safe halts on the current link or, when that link is busy, out of step or gone, on a
fresh one (reconnect, Service_Start, Controller_Connect, Controller_GetRobot, Robot_Halt), within a
deadline, and reports what it did."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest

from drivers.denso import bcap
from drivers.denso import hresult as hr
from drivers.denso.arm import ArmHaltError, BoxEnvelope, DensoArm
from drivers.denso.client import BcapClient
from drivers.denso.motion import WaitSettings
from drivers.mock.bcap_server import BcapMockServer
from drivers.sim.clock import VirtualClock
from drivers.sim.world import World
from drivers.transport import Transport, open_transport

ENVELOPE = BoxEnvelope((100.0, 600.0), (-300.0, 300.0), (50.0, 600.0))


def _arm(server: BcapMockServer, world: World, timeout_s: float = 0.5, wdt_ms: int | None = None,
         **kwargs) -> DensoArm:
    """An arm opened (Service_Start … TakeArm) with a 30 s reply time-out — a loaded machine may answer the
    set-up late, and that is no fault — then given ``timeout_s`` for the test's faults. A fresh link (a
    make-safe's reconnect) gets the 30 s back as it opens: it is healthy, however late a loaded host
    answers it; only the faulty link is judged by ``timeout_s``."""
    url = f"tcp://127.0.0.1:{server.serve_tcp()}"
    client: BcapClient

    def reopen() -> Transport:
        client.link.timeout_s = 30.0
        return open_transport(url, 30.0)

    client = BcapClient(open_transport(url, 30.0), timeout_s=30.0, reopen=reopen)
    arm = DensoArm(client, envelope=ENVELOPE, max_speed_mm_s=250.0, position_tolerance_mm=0.01,
                   clock=world.clock, **kwargs)
    arm.open(wdt_ms=wdt_ms)
    arm.client.link.timeout_s = timeout_s
    return arm


def _truth(world: World) -> np.ndarray:
    return world.robot.pose_at(world.clock.now_s())


@pytest.fixture
def rig():
    world = World(VirtualClock())
    with BcapMockServer(world.robot, world.clock) as server:
        arm = _arm(server, world)
        yield world, server, arm
        server.faults.__init__()
        arm.close()
        arm.client.link.transport.close()


def test_late_reply_is_drained_and_the_next_call_succeeds(rig) -> None:
    world, server, arm = rig
    server.faults.delay_reply_s, server.faults.delay_function = 0.7, bcap.CONTROLLER_EXECUTE
    with pytest.raises(hr.BcapTimeoutError):
        arm.client.clear_error()  # not idempotent: one request, given up after 0.5 s
    server.faults.delay_reply_s = 0.0
    np.testing.assert_allclose(arm.position(), _truth(world))  # the late reply is discarded, not taken
    assert arm.client.link.discarded_replies >= 1


def test_duplicated_reply_is_discarded(rig) -> None:
    world, server, arm = rig
    server.faults.duplicate_replies = 1
    arm.client.error_count()
    np.testing.assert_allclose(arm.position(), _truth(world))
    assert arm.client.link.discarded_replies == 1


def test_reply_to_the_previous_request_is_discarded_and_a_read_is_asked_again(rig) -> None:
    world, server, arm = rig
    server.faults.stale_replies = 1
    np.testing.assert_allclose(arm.position(), _truth(world))  # first attempt answered stale: asked again
    assert arm.client.link.discarded_replies >= 1
    curpos = [r for r in server.requests if r[2] == bcap.ROBOT_EXECUTE]
    assert len(curpos) >= 3 and curpos[-1][0] != curpos[-2][0]  # a new request, new serial


def test_a_command_answered_stale_fails_cleanly_and_the_link_carries_on(rig) -> None:
    world, server, arm = rig
    server.faults.stale_replies = 1
    with pytest.raises(hr.BcapTimeoutError):
        arm.client.motor(True)  # not idempotent: never sent twice
    assert [r[2] for r in server.requests].count(bcap.ROBOT_EXECUTE) >= 1
    np.testing.assert_allclose(arm.position(), _truth(world))


def test_lost_bytes_are_drained(rig) -> None:
    world, server, arm = rig
    server.faults.drop_reply_bytes = 1
    np.testing.assert_allclose(arm.position(), _truth(world))
    assert arm.client.link.drained_bytes > 0


def test_make_safe_halts_on_the_current_link_when_it_answers(rig) -> None:
    _world, server, arm = rig
    report = arm.make_safe()
    assert report.halted and not report.fresh_link and arm.client.link.reconnects == 0
    assert [r[2] for r in server.requests][-1] == bcap.ROBOT_HALT


@pytest.mark.parametrize("fault", ["busy", "no_reply"])
def test_make_safe_halts_on_a_fresh_link_when_the_current_one_fails(rig, fault: str) -> None:
    _world, server, arm = rig
    if fault == "busy":  # an RC8 refusing the halt while an earlier call executes
        server.faults.busy_replies, server.faults.busy_function = 1, bcap.ROBOT_HALT
        arm.client.link.timeout_s = 30.0  # the refusal comes at once: no reply is late but on a loaded host
    else:
        server.faults.drop_replies, server.faults.drop_function = 1, bcap.ROBOT_HALT
    arm.safe_state()
    report = arm.last_make_safe
    assert report is not None and report.halted and report.fresh_link, report
    assert arm.client.link.reconnects == 1
    sent = [r[2] for r in server.requests]
    fresh = sent[len(sent) - 1 - sent[::-1].index(bcap.SERVICE_START):]
    assert fresh == [bcap.SERVICE_START, bcap.CONTROLLER_CONNECT, bcap.CONTROLLER_GET_ROBOT, bcap.ROBOT_HALT]
    assert arm.snapshot()["last_make_safe"]["fresh_link"] is True


def test_a_client_reconnecting_at_once_is_not_refused_for_its_own_closed_session() -> None:
    """The controller ends a session whose client closed its connection as soon as another client asks,
    even while the thread serving it is still busy with a late reply (a make-safe after a call that got no
    answer: the old session must not hold the controller against the fresh link, E_MAX_CONNECT)."""
    world = World(VirtualClock())
    with BcapMockServer(world.robot, world.clock) as server:
        url = f"tcp://127.0.0.1:{server.serve_tcp()}"
        old = BcapClient(open_transport(url, 30.0), timeout_s=30.0)
        old.service_start()
        old.controller_connect()
        server.faults.delay_reply_s, server.faults.delay_function = 60.0, bcap.CONTROLLER_EXECUTE
        old.link.timeout_s = 0.2
        with pytest.raises(hr.BcapTimeoutError):
            old.clear_error()  # answered 60 s late: the session's thread waits in there meanwhile
        deadline = time.monotonic() + 30.0
        while not server.requests or server.requests[-1][2] != bcap.CONTROLLER_EXECUTE:
            assert time.monotonic() < deadline  # the request was taken: nothing of it is left unread
            time.sleep(0.01)
        old.link.transport.close()
        fresh = BcapClient(open_transport(url, 30.0), timeout_s=30.0)
        try:
            fresh.service_start()  # E_MAX_CONNECT when the closed session still held the controller
            assert fresh.controller_connect() is not None  # the fresh client holds the controller
        finally:
            fresh.link.transport.close()


def test_make_safe_reports_failure_when_the_controller_is_gone() -> None:
    world = World(VirtualClock())
    server = BcapMockServer(world.robot, world.clock)
    arm = _arm(server, world, timeout_s=0.2, make_safe_deadline_s=1.0)
    server.close()
    began = time.monotonic()
    with pytest.raises(ArmHaltError, match="no Robot_Halt accepted") as info:
        arm.safe_state()
    assert time.monotonic() - began < 1.0 + 3 * 0.2 + 2.0  # bounded by the deadline (plus one attempt)
    report = arm.last_make_safe
    assert report is not None and not report.halted and len(report.attempts) >= 2
    assert "fresh link" in str(info.value)
    arm.client.link.transport.close()


def test_make_safe_during_a_blocking_move_in_another_thread_stops_the_arm() -> None:
    """The main case: a blocking Move holds the link (the reference server would queue a halt behind it,
    an RC8 may refuse it); the make-safe closes that connection — the controller ends the session and
    stops the arm — and halts on a fresh session."""
    world = World(VirtualClock(rate=1.0))
    with BcapMockServer(world.robot, world.clock) as server:
        arm = _arm(server, world, timeout_s=0.5, wdt_ms=100, wait=WaitSettings(wait_mode="blocking"))
        start = _truth(world)
        target = [start[0] + 150.0, *start[1:]]
        errors: list[BaseException] = []

        def move() -> None:
            try:
                arm.move_to(target, 15.0)  # 10 s
            except BaseException as exc:
                errors.append(exc)

        mover = threading.Thread(target=move)
        mover.start()
        deadline = time.monotonic() + 10.0
        while not world.robot.is_moving(world.clock.now_s()):
            assert time.monotonic() < deadline
            time.sleep(0.01)
        report = arm.make_safe(deadline_s=10.0)
        mover.join(timeout=10.0)
        assert report.halted and report.fresh_link, report
        while world.robot.is_moving(world.clock.now_s()):  # decelerating to rest (bounded: it was halted)
            assert time.monotonic() < deadline + 10.0
            time.sleep(0.01)
        assert _truth(world)[0] < target[0] - 50.0  # stopped, not arrived
        assert server.state.moves[-1]["t_end_s"] > world.clock.now_s() + 1.0  # the planned end lay ahead
        assert errors and isinstance(errors[0], hr.BcapError | OSError), errors
        arm.close()
        arm.client.link.transport.close()
