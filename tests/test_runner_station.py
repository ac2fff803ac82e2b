"""The station on the simulated rig: the same drivers over real loopback sockets/ptys to the mock servers,
bound to one twin world built from the configuration; limits refused before any byte is sent."""

from __future__ import annotations

import dataclasses
import socket
import time

import numpy as np
import pytest

from drivers.denso.arm import LimitError as ArmLimitError
from drivers.exciter.limits import LimitError
from drivers.sim.stereo_rig import default_camera_specs
from drivers.sim.world import WorldLayout
from rig.config.rig_config import default_config, override
from rig.run.clock import make_clock
from rig.run.station import StationError, camera_specs, open_station, parse_address, world_layout


def test_the_builtin_config_describes_the_twins_own_rig() -> None:
    cfg = default_config()
    assert world_layout(cfg) == WorldLayout()
    assert camera_specs(cfg) == list(default_camera_specs())


def test_config_changes_reach_the_twin() -> None:
    cfg = override(default_config(), "targets.rotor.radius_mm", 45.0)
    assert world_layout(cfg).targets.rotor.radius_mm == 45.0
    cfg = override(cfg, "devices.exciter.crank_radius_mm", 3.0)
    assert world_layout(cfg).crank_radius_mm == 3.0


def test_simulated_station_moves_the_world_through_the_real_drivers() -> None:
    cfg = default_config()
    clock = make_clock(True)
    with open_station(cfg, clock) as st:
        assert sorted(st.devices) == ["exciter", "generator", "robot", "rotor"]
        assert sorted(st.cameras) == ["left", "right"]
        assert st.addresses["robot"].startswith("tcp://127.0.0.1:")
        assert st.addresses["exciter"].startswith("serial:///dev/")  # Modbus RTU over a pty
        assert st.addresses["rotor"].startswith("tcp://127.0.0.1:")  # Modbus TCP
        target = np.array([420.0, 50.0, 350.0, 90.0, 0.0, 90.0])
        result = st.devices["robot"].move_to(target)
        assert np.allclose(st.world.robot.pose_at(clock.now_s()), target, atol=1e-6)
        assert np.allclose(result.reported_pose, target, atol=1e-3)
        st.devices["exciter"].set_frequency(6.0)
        assert st.world.exciter.frequency_hz(clock.now_s()) == pytest.approx(6.0, abs=0.02)
        st.devices["rotor"].set_rotation_hz(10.0)
        assert st.world.rotor.frequency_hz(clock.now_s()) == pytest.approx(10.0, abs=0.02)
        assert st.check_interlocks() == []
        snap = st.snapshot()
        assert snap["simulated"] and set(snap["devices"]) == {"robot", "exciter", "rotor", "generator"}
        st.devices["generator"].start(8.0, 0.5)
        assert st.world.shaker.frequency_hz(clock.now_s()) == pytest.approx(8.0)
        assert st.world.shaker.amplitude_at_mm(clock.now_s()) == pytest.approx(0.5, rel=1e-3)
        port = parse_address(st.addresses["robot"])["port"]
    assert _refused_within(port, 3.0)  # the mock controller was shut down with the station


def _refused_within(port: int, timeout_s: float) -> bool:
    """The listener's accept thread may hold the socket for its 0.1 s accept timeout after close()."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        try:
            socket.create_connection(("127.0.0.1", port), timeout=0.5).close()
        except OSError:
            return True
        time.sleep(0.05)
    return False


def test_limits_raise_before_anything_is_sent() -> None:
    cfg = default_config()
    clock = make_clock(True)
    with open_station(cfg, clock) as st:
        pose0 = st.world.robot.pose_at(clock.now_s()).copy()
        with pytest.raises(ArmLimitError, match=r"x_mm=900 outside the allowed range \[150, 650\]"):
            st.devices["robot"].move_to([900.0, 0.0, 300.0, 90.0, 0.0, 90.0])
        with pytest.raises(ArmLimitError):
            st.devices["robot"].move_to([420.0, 0.0, 300.0, 90.0, 0.0, 90.0], speed_mm_s=5000.0)
        assert np.array_equal(st.world.robot.pose_at(clock.now_s() + 10.0), pose0)
        with pytest.raises(LimitError, match="frequency 40 Hz exceeds the limit 32 Hz"):
            st.devices["exciter"].set_frequency(40.0)
        assert st.world.exciter.frequency_hz(clock.now_s() + 10.0) == 0.0


def test_an_unreachable_device_is_named_with_its_address() -> None:
    bad = override(default_config(), "devices.rotor.address", "tcp://127.0.0.1:9")  # nothing listens there
    with pytest.raises(StationError, match=r"rotor: cannot connect to the drive at tcp://127\.0\.0\.1:9"), \
            open_station(bad, make_clock(True)):
        pass


def test_every_device_also_works_over_a_pty_serial_line() -> None:
    cfg = default_config()
    for name in ("robot", "rotor", "generator"):
        cfg = override(cfg, f"devices.{name}.address", "mock://pty")
    clock = make_clock(True)
    with open_station(cfg, clock) as st:
        assert all(a.startswith("serial:///dev/") for a in st.addresses.values()), st.addresses
        target = [400.0, -20.0, 320.0, 90.0, 0.0, 90.0]
        st.devices["robot"].move_to(target)  # b-CAP with CRC framing on the serial line
        assert np.allclose(st.world.robot.pose_at(clock.now_s()), target, atol=1e-6)
        st.devices["rotor"].set_rotation_hz(3.0)
        assert st.world.rotor.frequency_hz(clock.now_s()) == pytest.approx(3.0, abs=0.02)
        st.devices["generator"].start(12.0, 0.2)
        assert st.world.shaker.frequency_hz(clock.now_s()) == pytest.approx(12.0)


def test_interlock_checks_see_a_pose_outside_the_envelope_without_device_io() -> None:
    cfg = default_config()
    clock = make_clock(True)
    with open_station(cfg, clock) as st:
        arm = st.devices["robot"]
        arm.move_to([420.0, 0.0, 300.0, 90.0, 0.0, 90.0])
        assert st.check_interlocks() == []
        # what a misbehaving controller could report: the check reads the cached last move only
        arm.last_move = dataclasses.replace(arm.last_move, reported_pose=[700.0, 0.0, 300.0, 90.0, 0.0, 90.0])
        ((device, reason),) = st.check_interlocks()
        assert device == "robot" and "outside the envelope" in reason and "x_mm=700" in reason


def test_the_configured_devices_are_named_by_their_config_field() -> None:
    cfg = default_config()
    assert list(cfg.devices.configured()) == ["robot", "exciter", "rotor", "generator"]
    assert cfg.devices.configured()["rotor"] is cfg.devices.rotor
    without = dataclasses.replace(cfg.devices, exciter=None)
    assert list(without.configured()) == ["robot", "rotor", "generator"]
