"""devices.robot.wait_mode / busy_poll_interval_s: validated, and the station's arm waits as configured."""

from __future__ import annotations

import pytest

from rig.config.rig_config import ConfigError, default_config, override
from rig.run.clock import make_clock
from rig.run.station import open_station


@pytest.mark.parametrize(("wait_mode", "expected"), [(None, "next"), ("blocking", "blocking")])
def test_station_arm_waits_as_configured(wait_mode: str | None, expected: str) -> None:
    cfg = override(default_config(), "devices.robot.busy_poll_interval_s", 0.1)
    if wait_mode is not None:
        cfg = override(cfg, "devices.robot.wait_mode", wait_mode)
    with open_station(cfg, make_clock(virtual=True)) as station:
        arm = station.devices["robot"]
        assert arm.wait.wait_mode == expected and arm.wait.poll_interval_s == 0.1


@pytest.mark.parametrize(("field", "value"), [("wait_mode", "poll"), ("busy_poll_interval_s", 0.0)])
def test_bad_robot_wait_settings_name_the_field(field: str, value: object) -> None:
    with pytest.raises(ConfigError, match=rf"devices\.robot\.{field}"):
        override(default_config(), f"devices.robot.{field}", value)
