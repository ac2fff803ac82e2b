"""Configuration integrity at load time: one physical device cannot be configured as two (addresses are
compared after normalisation), and every configured arm pose lies inside the envelope."""

from __future__ import annotations

import re
from importlib import resources

import pytest

from rig.cli import main
from rig.config.address import endpoint
from rig.config.rig_config import ConfigError, parse_config

SIM_TOML = resources.files("rig").joinpath("data/sim.toml").read_text()


def _bench(addresses: dict[str, str], **units: int) -> str:
    """sim.toml as a bench with the given device addresses (and VFD unit ids)."""
    text = SIM_TOML.split("\n[sim]")[0].replace("simulated = true", "simulated = false")
    text = text.replace('clock = "virtual"', 'clock = "wall"')
    text = text.replace('driver = "sim"', 'driver = "file"\nsource = "cam.avi"')
    for name, unit in units.items():
        text, n = re.subn(rf'(\[devices\.{name}\][^\[]*?unit_id = )\d+', rf"\g<1>{unit}", text, flags=re.S)
        assert n == 1
    for name, address in addresses.items():
        text, n = re.subn(rf'(\[devices\.{name}\][^\[]*?address = )"mock://\w+"', rf'\g<1>"{address}"', text,
                          flags=re.S)
        assert n == 1
    return text


DISTINCT = {"robot": "tcp://10.0.0.2:5007", "exciter": "tcp://10.0.0.3:502", "rotor": "tcp://10.0.0.4:502",
            "generator": "tcp://10.0.0.5:5025"}


def test_distinct_devices_load() -> None:
    parse_config(_bench(DISTINCT))


@pytest.mark.parametrize(("exciter", "rotor"), [
    ("tcp://10.0.0.3:502", "tcp://10.0.0.3:502"),
    ("tcp://localhost:502", "tcp://127.0.0.1:502"),          # one host, two spellings
    ("tcp://[::1]:502", "tcp://127.0.0.1:502"),
    ("tcp://Drive.lab:502", "tcp://drive.lab.:502"),
    ("serial:///dev/ttyUSB0?baud=115200", "serial:///dev/../dev/ttyUSB0?baud=9600"),
])
def test_exciter_and_rotor_on_one_drive_are_refused(exciter: str, rotor: str) -> None:
    with pytest.raises(ConfigError) as info:
        parse_config(_bench({**DISTINCT, "exciter": exciter, "rotor": rotor}, exciter=1, rotor=1))
    message = str(info.value)
    assert message.startswith("devices.rotor.address:"), message
    assert "unit_id 1 is the endpoint of devices.exciter too" in message and repr(exciter) in message


def test_two_drives_on_one_line_with_distinct_unit_ids_load() -> None:
    # an RS-485 bus (or a Modbus TCP gateway) with two drives: same endpoint, different unit ids
    parse_config(_bench({**DISTINCT, "exciter": "serial:///dev/ttyUSB0?baud=115200",
                         "rotor": "serial:///dev/ttyUSB0?baud=115200"}, exciter=1, rotor=2))
    parse_config(_bench({**DISTINCT, "exciter": "tcp://10.0.0.3:502", "rotor": "tcp://10.0.0.3:502"},
                        exciter=1, rotor=2))


def test_a_drive_on_the_robot_controllers_port_is_refused() -> None:
    with pytest.raises(ConfigError, match=r"devices.exciter.address: 'tcp://localhost:5007' is the endpoint "
                                          r"of devices.robot too \('tcp://127.0.0.1:5007'\)"):
        parse_config(_bench({**DISTINCT, "robot": "tcp://127.0.0.1:5007", "exciter": "tcp://localhost:5007"}))


def test_duplicate_endpoints_exit_4_in_rig_check(tmp_path, capsys: pytest.CaptureFixture[str]) -> None:
    config = tmp_path / "rig.toml"
    config.write_text(_bench({**DISTINCT, "rotor": DISTINCT["exciter"]}, exciter=1, rotor=1))
    assert main(["check", "--config", str(config), "--no-devices"]) == 4
    err = capsys.readouterr().err
    assert "devices.rotor.address" in err and "devices.exciter" in err


def test_endpoint_normalisation() -> None:
    assert endpoint("tcp://LOCALHOST:502") == endpoint("tcp://127.0.0.1:502") == ("tcp", "127.0.0.1", "502")
    assert endpoint("tcp://127.0.0.1:502") != endpoint("tcp://127.0.0.1:503")
    assert endpoint("tcp://127.0.0.2:502") != endpoint("tcp://127.0.0.1:502")  # another loopback address
    assert endpoint("mock://tcp") is None  # the station starts one server per device


@pytest.mark.parametrize(("field", "pose", "expected"), [
    ("home_pose", "[350.0, 0.0, 700.0, 90.0, 0.0, 90.0]",
     "devices.robot.home_pose: [350.0, 0.0, 700.0, 90.0, 0.0, 90.0] is outside the arm's envelope: "
     "z_mm=700 outside the allowed range [50, 650] (limits.robot.envelope_z_mm)"),
    ("start_pose", "[100.0, 0.0, 300.0, 90.0, 0.0, 90.0]",
     "targets.calibration_plate.start_pose: [100.0, 0.0, 300.0, 90.0, 0.0, 90.0] is outside the arm's "
     "envelope: x_mm=100 outside the allowed range [150, 650] (limits.robot.envelope_x_mm)"),
    ("home_pose", "[350.0, 0.0, 300.0, 190.0, 0.0, 90.0]",
     "rx_deg=190 outside the allowed range [-180, 180] (the arm driver's orientation range)"),
])
def test_configured_poses_outside_the_envelope_are_refused(field: str, pose: str, expected: str) -> None:
    text, n = re.subn(rf"^{field} = .*$", f"{field} = {pose}", SIM_TOML, flags=re.M)
    assert n == 1
    with pytest.raises(ConfigError) as info:
        parse_config(text)
    assert expected in str(info.value)


def test_an_acceleration_limit_beyond_the_controllers_full_is_refused() -> None:
    text, n = re.subn(r"^max_accel_mm_s2 = .*$", "max_accel_mm_s2 = 6000.0", SIM_TOML, flags=re.M)
    assert n == 1
    with pytest.raises(ConfigError) as info:
        parse_config(text)
    assert str(info.value).startswith("limits.robot.max_accel_mm_s2: 6000 exceeds "
                                      "devices.robot.full_accel_mm_s2 = 5000")
    assert parse_config(text.replace("[devices.robot]", "[devices.robot]\nfull_accel_mm_s2 = 8000.0"))
