"""NEXT moves over the real mock RC8 (b-CAP over TCP): the arm polls ``@BUSY_STATUS`` on the injected
clock, so a Robot_Halt from another thread is accepted mid-move and stops the twin's robot short of its
target; a polling move agrees with the twin; a controller that never reports rest ends in a clear timeout
and a halt within the bound; the runner's interlock mid-move halts over the protocol."""

from __future__ import annotations

import contextlib
import sys
import threading
from pathlib import Path
from typing import Any

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))

from drivers.denso import bcap
from drivers.denso.arm import BoxEnvelope, DensoArm
from drivers.denso.client import BcapClient
from drivers.denso.motion import MoveHaltedError, MoveTimeoutError, WaitSettings, move_timeout_s
from drivers.mock.bcap_server import BcapMockServer
from drivers.sim.clock import VirtualClock
from drivers.sim.world import World
from drivers.transport import open_transport

ENVELOPE = BoxEnvelope((100.0, 600.0), (-300.0, 300.0), (50.0, 600.0))
FULL_ACCEL_MM_S2 = 5000.0  # the mock's 100 % acceleration (ACCEL and ExtSpeed accel at 100 %)


@contextlib.contextmanager
def _rig(world: World, robot: Any = None, **arm_kwargs: Any):
    """The mock RC8 on the twin's robot (or a wrapper of it) and a DensoArm on it over TCP."""
    with BcapMockServer(robot or world.robot, world.clock) as server:
        transport = open_transport(f"tcp://127.0.0.1:{server.serve_tcp()}", 1.0)
        arm = DensoArm(BcapClient(transport, timeout_s=1.0), clock=world.clock,
                       **{"envelope": ENVELOPE, "max_speed_mm_s": 250.0, "position_tolerance_mm": 0.01,
                          **arm_kwargs})
        with transport:
            arm.open(wdt_ms=None)
            try:
                yield server, arm
            finally:
                arm.close()


def _functions(server: BcapMockServer, since: int = 0) -> list[int]:
    return [function for _serial, _reserved, function in server.requests[since:]]


def test_polling_move_completes_and_agrees_with_the_twin() -> None:
    world = World(VirtualClock())  # instant: the polls' clock sleeps make the time pass
    poll_s = 0.05
    with _rig(world, wait=WaitSettings(poll_interval_s=poll_s)) as (server, arm):
        home = world.robot.pose_at(world.clock.now_s())
        targets = [[home[0] + 80.0, home[1] - 40.0, home[2] + 30.0, *home[3:]],
                   [home[0] - 50.0, home[1] + 60.0, home[2] - 20.0, home[3], home[4] + 10.0, home[5]]]
        for index, target in enumerate(targets):
            before = len(server.requests)
            result = arm.move_to(target, 60.0 + 30.0 * index)
            truth = world.robot.pose_at(world.clock.now_s())
            np.testing.assert_allclose(result.reported_pose, truth, atol=1e-9)
            np.testing.assert_allclose(result.reported_pose[:3], target[:3], atol=arm.position_tolerance_mm)
            assert not world.robot.is_moving(world.clock.now_s())
            planned = server.state.moves[-1]
            assert planned["speed_mm_s"] == pytest.approx(60.0 + 30.0 * index)
            # the end is seen at the first poll after it: at most one poll interval late, never early
            assert planned["t_end_s"] <= result.t_end_s <= planned["t_end_s"] + poll_s + 1e-9
            sent = _functions(server, before)
            polls = sent.count(bcap.VARIABLE_GET_VALUE)
            duration_s = planned["t_end_s"] - planned["t_start_s"]
            assert polls in (int(np.floor(duration_s / poll_s)) + 1, int(np.ceil(duration_s / poll_s)) + 1)
            assert sent.index(bcap.ROBOT_MOVE) < sent.index(bcap.VARIABLE_GET_VALUE)
        # one @BUSY_STATUS handle for the session, released at close
        assert _functions(server).count(bcap.ROBOT_GET_VARIABLE) == 1
    assert bcap.VARIABLE_RELEASE in _functions(server)


def test_halt_from_another_thread_during_a_long_next_move_is_accepted() -> None:
    world = World(VirtualClock(rate=5.0))  # paced: 100 mm at 20 mm/s = 5 s virtual = 1 s wall
    speed = 20.0
    with _rig(world) as (server, arm):
        home = world.robot.pose_at(world.clock.now_s())
        target = [home[0] + 100.0, *home[1:]]
        halt: dict[str, Any] = {}

        def halt_now() -> None:
            halt["t_before_s"] = world.clock.now_s()
            try:
                arm.halt()  # what the runner's safe_state does from its own thread
            except BaseException as exc:  # recorded and asserted below
                halt["error"] = exc
            halt["t_after_s"] = world.clock.now_s()

        timer = threading.Timer(0.15, halt_now)
        timer.start()
        with pytest.raises(MoveHaltedError, match=r"halted under way; the controller reports the arm at"):
            arm.move_to(target, speed)
        timer.join()
        assert "error" not in halt, halt.get("error")  # accepted, not E_BUSY_PROC
        assert bcap.ROBOT_HALT in _functions(server)
        now = world.clock.now_s()
        assert not world.robot.is_moving(now)
        stopped = world.robot.pose_at(now)
        planned = server.state.moves[-1]
        assert planned["t_start_s"] < halt["t_before_s"] < planned["t_end_s"]
        # in cruise at the halt: the planned remaining distance is v·(t_end − t) − v²/2a; the halt's
        # deceleration covers v²/2a more, so at least v·(t_end − t_after) − v²/a is left
        min_left_mm = speed * (planned["t_end_s"] - halt["t_after_s"]) - speed**2 / FULL_ACCEL_MM_S2
        assert target[0] - stopped[0] >= min_left_mm > 10.0
        assert stopped[0] > home[0]  # it did move
        np.testing.assert_allclose(arm.position(), stopped, atol=1e-9)  # the controller agrees with the twin
        assert arm.last_move is None  # a halted move is not recorded as completed


class StuckBusy:
    """The twin's robot, but the controller reports @BUSY_STATUS true forever after a move (fault)."""

    def __init__(self, body: Any) -> None:
        self.body, self.stuck, self.halts = body, False, []

    def pose_at(self, t_s: float) -> np.ndarray:
        return self.body.pose_at(t_s)

    def move(self, *args: Any, **kwargs: Any) -> float:
        self.stuck = True
        return self.body.move(*args, **kwargs)

    def halt(self, t_s: float) -> None:
        self.halts.append(t_s)
        self.body.halt(t_s)

    def is_moving(self, t_s: float) -> bool:
        return self.stuck or self.body.is_moving(t_s)


def test_move_that_never_finishes_times_out_within_the_bound_and_halts() -> None:
    world = World(VirtualClock())
    stuck = StuckBusy(world.robot)
    wait = WaitSettings(poll_interval_s=0.1, timeout_factor=1.5, timeout_margin_s=2.0)
    with _rig(world, stuck, wait=wait) as (server, arm):
        home = world.robot.pose_at(world.clock.now_s())
        target = [home[0] + 60.0, *home[1:]]
        t0 = world.clock.now_s()
        bound_s = move_timeout_s(60.0, 0.0, 30.0, 3.0, wait)
        assert bound_s == pytest.approx(1.5 * 2.0 + 2.0)
        with pytest.raises(MoveTimeoutError, match=r"still reports @BUSY_STATUS true .* \(bound 5\.000 s, "
                                                   r"\d+ polls\); a Robot_Halt was sent"):
            arm.move_to(target, 30.0)
        elapsed_s = world.clock.now_s() - t0
        assert bound_s <= elapsed_s <= bound_s + wait.poll_interval_s + 1e-9
        sent = _functions(server)
        assert bcap.ROBOT_HALT in sent[sent.index(bcap.ROBOT_MOVE):]
        assert stuck.halts and stuck.halts[-1] - t0 == pytest.approx(elapsed_s)
        stuck.stuck = False


class InterruptingClock:
    """The rig clock, but the ``n``-th sleep raises (an interlock or Ctrl-C landing during the wait)."""

    def __init__(self, clock: VirtualClock, n: int) -> None:
        self.clock, self.n, self.sleeps = clock, n, 0
        self.is_virtual = True

    def now_s(self) -> float:
        return self.clock.now_s()

    def sleep_s(self, duration_s: float) -> None:
        self.sleeps += 1
        if self.sleeps == self.n:
            raise KeyboardInterrupt
        self.clock.sleep_s(duration_s)


def test_interrupt_during_the_wait_halts_the_arm() -> None:
    world = World(VirtualClock())
    with BcapMockServer(world.robot, world.clock) as server:
        transport = open_transport(f"tcp://127.0.0.1:{server.serve_tcp()}", 1.0)
        arm = DensoArm(BcapClient(transport, timeout_s=1.0), envelope=ENVELOPE, max_speed_mm_s=250.0,
                       position_tolerance_mm=0.01, clock=InterruptingClock(world.clock, 5))
        with transport, arm:
            home = world.robot.pose_at(world.clock.now_s())
            with pytest.raises(KeyboardInterrupt):
                arm.move_to([home[0] + 100.0, *home[1:]], 50.0)
            later = world.clock.now_s() + 0.1  # after the halt's deceleration (50 mm/s at 5000 mm/s²)
            assert not world.robot.is_moving(later) and world.robot.pose_at(later)[0] < home[0] + 50.0
            assert _functions(server)[-1] == bcap.ROBOT_HALT


def test_blocking_mode_is_kept_without_polls() -> None:
    world = World(VirtualClock())  # instant: the mock answers a blocking Move at the motion's end
    with _rig(world, wait=WaitSettings(wait_mode="blocking")) as (server, arm):
        home = world.robot.pose_at(world.clock.now_s())
        result = arm.move_to([home[0] + 60.0, *home[1:]], 30.0)
        planned = server.state.moves[-1]
        assert result.t_end_s == pytest.approx(planned["t_end_s"], abs=1e-9)  # the reply is the end
        assert result.position_error_mm < 1e-9
        assert bcap.VARIABLE_GET_VALUE not in _functions(server)
        assert arm.snapshot()["wait"]["wait_mode"] == "blocking"


@pytest.mark.parametrize(("field", "value", "allowed"), [
    ("wait_mode", "poll", "expected one of"), ("poll_interval_s", 0.0, r"must be in \(0, 5\]"),
    ("timeout_factor", 0.5, r"must be in \[1, inf\]"), ("timeout_margin_s", float("nan"), "must be in"),
    ("full_rot_speed_deg_s", -1.0, r"must be in \(0, inf\]")])
def test_bad_wait_settings_name_the_field(field: str, value: Any, allowed: str) -> None:
    with pytest.raises(ValueError, match=rf"{field}=.*{allowed}"):
        WaitSettings(**{field: value})


def test_runner_interlock_mid_move_halts_over_the_protocol(tmp_path: Path) -> None:
    from heartbeat_support import run_body_on_sim_station

    target = [420.0, 0.0, 300.0, 90.0, 0.0, 90.0]

    def body(ctx: Any, servers: dict[str, Any]) -> None:
        threading.Timer(0.3, servers["exciter"].inject, args=("no_reply",), kwargs={"count": None}).start()
        ctx.device("robot").move_to(target, speed_mm_s=7.0)  # 10 s virtual = 5 s wall

    out, record, seen = run_body_on_sim_station(tmp_path, body)
    assert out.exit_code == 3 and record.interlocks["device"].tolist() == ["exciter"], out.reason
    failures = {f["device"]: f["error"] for f in record.stop["safe_state_failures"]}
    assert "robot" not in failures, failures["robot"]  # Robot_Halt accepted: no ArmHaltError
    assert "robot: safe_state() done" in set(record.logs["message"])
    readback = record.stop["safe_state"]["robot"]
    assert "error" not in readback and readback["moved_mm"] == pytest.approx(0.0, abs=1e-9)
    world, clock = seen["station"].world, seen["station"].clock
    assert not world.robot.is_moving(clock.now_s())
    assert world.robot.pose_at(clock.now_s())[0] < target[0] - 5.0  # stopped, not arrived


def test_rc7m_client_waits_blocking_by_default_and_rc8_polls() -> None:
    world = World(VirtualClock())
    server = BcapMockServer(world.robot, world.clock)
    with server, open_transport(f"tcp://127.0.0.1:{server.serve_tcp()}", 1.0) as transport:
        options = {"envelope": ENVELOPE, "max_speed_mm_s": 100.0, "position_tolerance_mm": 0.01,
                   "clock": world.clock}
        assert DensoArm(BcapClient(transport, rc7m=True), **options).wait.wait_mode == "blocking"
        assert DensoArm(BcapClient(transport), **options).wait.wait_mode == "next"
        custom = WaitSettings(poll_interval_s=0.2)
        assert DensoArm(BcapClient(transport, rc7m=True), wait=custom, **options).wait is custom


@pytest.mark.parametrize("max_accel_mm_s2", [None, 2000.0])
def test_the_acceleration_cap_is_commanded_by_extspeed(max_accel_mm_s2: float | None) -> None:
    """limits.robot.max_accel_mm_s2 reaches the controller as ExtSpeed's accel/decel percent of its 100 %
    (2000 of 5000 mm/s² → 40 %); without a cap the controller's own 100 % stands (ExtSpeed accel −2)."""
    world = World(VirtualClock())
    with _rig(world, max_accel_mm_s2=max_accel_mm_s2, full_accel_mm_s2=FULL_ACCEL_MM_S2) as (server, arm):
        home = world.robot.pose_at(world.clock.now_s())
        arm.move_to([home[0] + 60.0, *home[1:]], 200.0)
        expected = FULL_ACCEL_MM_S2 if max_accel_mm_s2 is None else max_accel_mm_s2
        assert server.state.ext_accel_percent == pytest.approx(100.0 * expected / FULL_ACCEL_MM_S2)
        assert server.state.moves[-1]["accel_mm_s2"] == pytest.approx(expected)

