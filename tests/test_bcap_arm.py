"""DensoArm limits and verification (envelopes, speed cap, reported-pose check) on the mock RC8 over TCP."""

from __future__ import annotations

import numpy as np
import pytest

from drivers.denso.arm import (
    BoxEnvelope,
    CylinderEnvelope,
    DensoArm,
    LimitError,
    OrientationLimits,
    PositionMismatchError,
    envelope_from_config,
)
from drivers.denso.client import BcapClient
from drivers.denso.pose import orientation_error_deg
from drivers.mock.bcap_server import BcapMockServer
from drivers.sim.clock import VirtualClock
from drivers.sim.world import World
from drivers.transport import open_transport


class OffsetBody:
    """The twin's robot, but the controller's position feedback is off by ``offset_mm`` in x."""

    def __init__(self, body, offset_mm: float) -> None:
        self.body, self.offset_mm = body, offset_mm

    def pose_at(self, t_s: float) -> np.ndarray:
        return self.body.pose_at(t_s) + np.array([self.offset_mm, 0, 0, 0, 0, 0])

    def move(self, *args, **kwargs) -> float:
        return self.body.move(*args, **kwargs)

    def halt(self, t_s: float) -> None:
        self.body.halt(t_s)

    def is_moving(self, t_s: float) -> bool:
        return self.body.is_moving(t_s)


def _arm(robot, world: World, envelope, **kwargs):
    server = BcapMockServer(robot, world.clock)
    transport = open_transport(f"tcp://127.0.0.1:{server.serve_tcp()}", 1.0)
    arm = DensoArm(BcapClient(transport, timeout_s=1.0), envelope=envelope, clock=world.clock,
                   **{"max_speed_mm_s": 200.0, "position_tolerance_mm": 0.05, **kwargs})
    return server, transport, arm


def test_reported_position_outside_tolerance_raises_with_both_poses() -> None:
    world = World(VirtualClock())
    server, transport, arm = _arm(OffsetBody(world.robot, 0.2), world, BoxEnvelope((0, 500), (-300, 300),
                                                                                     (0, 600)))
    with server, transport, arm:
        with pytest.raises(PositionMismatchError, match=r"0\.200 mm \(tolerance 0\.05 mm\)"):
            arm.move_to([300, 0, 300, 180, 0, 180], 150)
        assert arm.last_move is not None and arm.last_move.position_error_mm == pytest.approx(0.2)


def test_cylinder_envelope_on_the_mock() -> None:
    world = World(VirtualClock())
    cylinder = CylinderEnvelope(radius_mm=400.0, z_mm=(100.0, 500.0), inner_radius_mm=150.0,
                                orientation=OrientationLimits(ry_deg=(-20, 20)))
    server, transport, arm = _arm(world.robot, world, cylinder)
    with server, transport, arm:
        arm.move_to([0, 300, 300, 180, 0, 90], 150)
        np.testing.assert_allclose(world.robot.pose_at(world.clock.now_s())[:3], [0, 300, 300], atol=1e-9)
        with pytest.raises(LimitError, match=r"radius_mm=424\.264 outside the allowed range \[150, 400\]"):
            arm.move_to([300, 300, 300, 180, 0, 90])
        with pytest.raises(LimitError, match=r"radius_mm=100 outside"):
            arm.move_to([100, 0, 300, 180, 0, 90])
        with pytest.raises(LimitError, match=r"z_mm=50 outside the allowed range \[100, 500\]"):
            arm.move_to([0, 300, 50, 180, 0, 90])
        with pytest.raises(LimitError, match=r"ry_deg=25"):
            arm.move_to([0, 300, 300, 180, 25, 90])
        with pytest.raises(LimitError, match=r"path radius_mm=0 outside the allowed range \[150, 400\]"):
            arm.move_to([0, -300, 300, 180, 0, 90])  # both ends allowed, the straight line crosses the core
        arm.move_to([0, -300, 300, 180, 0, 90], linear=False)  # PTP: end points only
        assert len(server.state.moves) == 2


def test_set_speed_caps_and_converts_to_percent() -> None:
    world = World(VirtualClock())
    server, transport, arm = _arm(world.robot, world, BoxEnvelope((0, 500), (-300, 300), (0, 600)),
                                  full_speed_mm_s=800.0)
    with server, transport, arm:
        arm.set_speed(40.0)
        arm.move_to([300, 0, 300, 180, 0, 180])
        # 40 mm/s is 5 % of the arm's configured 800 mm/s; the mock's 100 % is 1000 mm/s, so it runs 50 mm/s
        assert server.state.moves[-1]["speed_mm_s"] == pytest.approx(50.0)
        with pytest.raises(LimitError, match="speed_mm_s=250"):
            arm.set_speed(250.0)
        snap = arm.snapshot()
        assert snap["speed_mm_s"] == 40.0 and snap["envelope"]["BoxEnvelope"]["x_mm"] == (0.0, 500.0)
        assert snap["transport"].startswith("tcp://127.0.0.1:")


def test_envelope_from_config() -> None:
    box = envelope_from_config({"box": {"x_mm": [1, 2], "y_mm": [3, 4], "z_mm": [5, 6]},
                                "orientation": {"rz_deg": [-90, 90]}})
    assert isinstance(box, BoxEnvelope) and box.orientation.rz_deg == (-90.0, 90.0)
    cyl = envelope_from_config({"cylinder": {"radius_mm": 400, "z_mm": [0, 500]}})
    assert isinstance(cyl, CylinderEnvelope) and cyl.inner_radius_mm == 0.0
    with pytest.raises(ValueError, match="exactly one of 'box' or 'cylinder'"):
        envelope_from_config({"box": {}, "cylinder": {}})
    with pytest.raises(ValueError, match=r"x_mm=\(2, 1\)"):
        BoxEnvelope((2, 1), (0, 1), (0, 1))
    with pytest.raises(ValueError, match="inner_radius_mm"):
        CylinderEnvelope(radius_mm=100, z_mm=(0, 1), inner_radius_mm=200)


def test_orientation_error_compares_rotations_not_angles() -> None:
    assert orientation_error_deg([0, 0, 0, 180, 0, 0], [0, 0, 0, -180, 0, 0]) == pytest.approx(0, abs=1e-9)
    assert orientation_error_deg([0, 0, 0, 0, 0, 10], [0, 0, 0, 0, 0, -10]) == pytest.approx(20)
    assert orientation_error_deg([0, 0, 0, 180, 0, 90], [0, 0, 0, 180, 0, 90.0001]) == pytest.approx(1e-4)


def test_arm_constructor_validates() -> None:
    world = World(VirtualClock())
    client = BcapClient(open_transport("loop://", 0.1))
    box = BoxEnvelope((0, 1), (0, 1), (0, 1))
    with pytest.raises(ValueError, match="max_speed_mm_s=2000"):
        DensoArm(client, envelope=box, max_speed_mm_s=2000, position_tolerance_mm=0.1, clock=world.clock)
    with pytest.raises(ValueError, match="position_tolerance_mm=0"):
        DensoArm(client, envelope=box, max_speed_mm_s=100, position_tolerance_mm=0, clock=world.clock)
