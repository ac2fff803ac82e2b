"""rig.toml validation: every kind of bad input names the dotted field, the value and what is allowed."""

from __future__ import annotations

import copy
import tomllib
from importlib import resources
from pathlib import Path
from typing import Any

import pytest
from hypothesis import given
from hypothesis import strategies as st

from rig.config.address import parse_address
from rig.config.rig_config import (
    ConfigError,
    RigConfig,
    config_from_dict,
    default_config,
    load_config,
    override,
    parse_config,
)

SIM = tomllib.loads(resources.files("rig").joinpath("data/sim.toml").read_text())


def _with(dotted: str, value: Any) -> dict[str, Any]:
    table = copy.deepcopy(SIM)
    node = table
    keys = dotted.split(".")
    for k in keys[:-1]:
        node = node.setdefault(k, {})
    if value is _DELETE:
        del node[keys[-1]]
    else:
        node[keys[-1]] = value
    return table


_DELETE = object()


def test_builtin_sim_config_is_valid_and_complete() -> None:
    cfg = default_config()
    assert isinstance(cfg, RigConfig) and cfg.station.simulated and cfg.source == "builtin:sim"
    assert cfg.camera_names() == ["left", "right"]
    assert cfg.devices.exciter.crank_radius_mm == 4.0 and cfg.devices.rotor.unit_id == 2
    assert cfg.limits.exciter.motion_limits().max_frequency_hz == 32.0
    envelope = cfg.limits.robot.envelope()  # the arm driver's own BoxEnvelope
    assert envelope.x_mm == (150.0, 650.0) and envelope.z_mm == (50.0, 650.0)
    assert set(cfg.sim.cameras) == {"left", "right"}


def test_snapshot_round_trips() -> None:
    cfg = default_config()
    snap = cfg.snapshot()
    assert snap["source"] == "builtin:sim" and snap["devices"]["robot"]["address"] == "mock://tcp"
    snap.pop("source")
    again = config_from_dict(_strip_none(snap))
    assert again == cfg


def _strip_none(t: Any) -> Any:
    return {k: _strip_none(v) for k, v in t.items() if v is not None} if isinstance(t, dict) else t


BAD = [  # (dotted field, bad value, the start of the expected message — plain text, not a regex)
    ("limits.exciter.max_frequency_hz", "fast",
     "limits.exciter.max_frequency_hz: 'fast' has the wrong type; allowed: a number"),
    ("station.simulated", 1, "station.simulated: 1 has the wrong type; allowed: true or false"),
    ("devices.exciter.unit_id", 300,
     "devices.exciter.unit_id: 300 is out of range; allowed: 1 ≤ value ≤ 247"),
    ("limits.robot.max_speed_mm_s", 0, "limits.robot.max_speed_mm_s: 0 is out of range; allowed: 0 < value"),
    ("devices.robot.driver", "kuka-rsi",
     "devices.robot.driver: 'kuka-rsi' is not allowed; allowed: 'denso-bcap'"),
    ("cameras.left.driver", "gopro", "cameras.left.driver: 'gopro' is not allowed; allowed: 'sim', 'opencv'"),
    ("devices.robot.controller", "rc9",
     "devices.robot.controller: 'rc9' is not allowed; allowed: 'rc8', 'rc7m'"),
    ("limits.exciter.max_frequncy_hz", 30.0,
     "limits.exciter.max_frequncy_hz: unknown field; allowed in [limits.exciter]: max_acceleration_m_s2"),
    ("bogus", {}, "bogus: unknown field; allowed in [top level]"),
    ("cameras.left.resolution_px", [1920],
     "cameras.left.resolution_px: [1920] has 1 elements; allowed: exactly 2"),
    ("targets.rotor.axis", [0.0, 0.0, 0.0], "targets.rotor.axis: [0.0, 0.0, 0.0] is a zero vector"),
    ("targets.marker_frame.offsets_mm", [[0, 0, 0], [1, 1], [2, 2, 2], [3, 3, 3]],
     "targets.marker_frame.offsets_mm[1]: [1.0, 1.0] has 2 elements; allowed: exactly 3"),
    ("targets.plate.cols", 7, "targets.plate.cols: 7 columns at 50 mm reach beyond length_mm = 320"),
    ("targets.sweep_column.body", "motor",
     "targets.sweep_column.body: 'motor' is not allowed; allowed: 'exciter'"),
    ("devices.robot.address", "udp://1.2.3.4:5007",
     "devices.robot.address: 'udp://1.2.3.4:5007' has an unknown scheme; allowed: tcp://HOST:PORT"),
    ("devices.robot.address", "tcp://host:99999",
     "devices.robot.address: 'tcp://host:99999' needs a host and a port 1-65535"),
    ("devices.exciter.address", "serial:///dev/ttyUSB0?baud=12345",
     "devices.exciter.address: 'serial:///dev/ttyUSB0?baud=12345': baud '12345' not allowed; allowed: 1200"),
    ("devices.exciter.register_map", "abb-acs",
     "devices.exciter.register_map: 'abb-acs' is neither a built-in register map nor a TOML file; "
     "allowed: delta"),
    ("devices.exciter.registers", {"comand": 1},
     "devices.exciter.registers: unknown register map keys ['comand']"),
    ("devices.exciter.crank_radius_mm", 12.0,
     "devices.exciter.crank_radius_mm: 12 exceeds limits.exciter.max_displacement_mm = 10"),
    ("devices.exciter.crank_radius_mm", _DELETE, "devices.exciter.crank_radius_mm: required field missing"),
    ("station.name", _DELETE, "station.name: required field missing (a string)"),
    ("limits.robot.envelope_x_mm", [700.0, 100.0],
     "limits.robot.envelope_x_mm: [700, 100]: allowed: [min, max] with min < max"),
    ("limits.rotor", _DELETE, "limits.rotor: required when [devices.rotor] is configured"),
    ("station.simulated", False,
     "devices.robot.address: 'mock://tcp' is only allowed when station.simulated = true"),
    ("sim.cameras.right", _DELETE, "cameras.right.driver: 'sim' needs a [sim.cameras.right] table"),
    ("limits.exciter.max_acceleration_m_s2", float("inf"),
     "limits.exciter.max_acceleration_m_s2: inf is not finite"),
]


@pytest.mark.parametrize(("dotted", "value", "expected"), BAD)
def test_bad_fields_are_named_with_value_and_what_is_allowed(dotted: str, value: Any, expected: str) -> None:
    with pytest.raises(ConfigError) as info:
        config_from_dict(_with(dotted, value))
    assert str(info.value).startswith(expected), str(info.value)


def test_one_camera_is_not_a_stereo_rig() -> None:
    table = _with("cameras.right", _DELETE)
    with pytest.raises(ConfigError, match=r"^cameras: 1 camera\(s\) configured; allowed: at least 2"):
        config_from_dict(table)


def test_file_errors(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match=r"configuration file .*nope\.toml' not found"):
        load_config(tmp_path / "nope.toml")
    bad = tmp_path / "rig.toml"
    bad.write_text("[station\nname = 1\n")
    with pytest.raises(ConfigError, match=r"rig\.toml: not valid TOML"):
        load_config(bad)
    good = tmp_path / "good.toml"
    good.write_text(resources.files("rig").joinpath("data/sim.toml").read_text())
    assert load_config(good).source == str(good)
    assert load_config(None) == default_config()


def test_override_validates_like_the_file() -> None:
    cfg = override(default_config(), "limits.exciter.max_frequency_hz", 20.0)
    assert cfg.limits.exciter.max_frequency_hz == 20.0
    with pytest.raises(ConfigError, match=r"limits\.exciter\.max_frequency_hz: -1 is out of range"):
        override(cfg, "limits.exciter.max_frequency_hz", -1)
    with pytest.raises(ConfigError, match=r"nothere\.x: no such table"):
        override(cfg, "nothere.x", 1)


def test_addresses_parse() -> None:
    assert parse_address("tcp://192.168.0.1:5007") == {"scheme": "tcp", "host": "192.168.0.1", "port": 5007}
    assert parse_address("serial:///dev/ttyUSB0?baud=115200") == {
        "scheme": "serial", "device": "/dev/ttyUSB0", "baud": 115200}
    assert parse_address("mock://pty") == {"scheme": "mock", "link": "pty"}


@given(st.floats(allow_nan=False, allow_infinity=False).filter(lambda v: not 1.0 <= v <= 1000.0))
def test_any_fps_outside_its_range_is_rejected(fps: float) -> None:
    with pytest.raises(ConfigError, match=r"cameras\.left\.fps: .* is out of range; allowed: 1 ≤ value ≤ 10"):
        config_from_dict(_with("cameras.left.fps", fps))


@given(st.floats(min_value=1.0, max_value=1000.0))
def test_any_fps_inside_its_range_is_kept(fps: float) -> None:
    table = _with("cameras.left.fps", fps)
    del table["fiducial"], table["sim"]["fiducial"]  # the fiducial's frequency is checked against the fps
    assert config_from_dict(table).cameras["left"].fps == fps


def test_parse_config_string() -> None:
    with pytest.raises(ConfigError, match="station: required field missing"):
        parse_config("")


def test_schema_reference_lists_every_field_of_the_builtin_config(capsys: pytest.CaptureFixture[str]) -> None:
    from rig.cli import main
    from rig.config.schema import describe

    fields = {row["field"] for row in describe(RigConfig)}

    def leaves(table: dict[str, Any], prefix: str = "") -> list[str]:
        out = []
        for key, value in table.items():
            name = f"{prefix}.{key}" if prefix else key
            if prefix in ("cameras", "sim.cameras"):
                name = f"{prefix}.<name>"
            if isinstance(value, dict) and name not in ("devices.exciter.registers", "fiducial.regions_px"):
                out += leaves(value, name)
            else:
                out.append(name)
        return out

    missing = [leaf for leaf in leaves(SIM) if leaf not in fields]
    assert missing == []
    assert main(["check", "--schema"]) == 0
    out = capsys.readouterr().out
    assert "limits.exciter.max_frequency_hz: a number = '(required)'  [0 < value ≤ 2000]" in out
    assert "cameras.<name>.driver: a string = '(required)'  ['sim', 'opencv', 'file']" in out
