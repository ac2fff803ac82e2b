"""A simulated station whose devices are stand-alone mocks (``rig mock …``) or real hardware: the sim cameras
film the station's own twin, which those devices do not move — said once when the station is built (a
calibration there finds no plate markers: GridError at the first plate position, exit 3)."""

from __future__ import annotations

import logging

import pytest

from rig.config.rig_config import default_config, override
from rig.run.station import _warn_if_cameras_film_another_world


def test_sim_cameras_beside_a_standalone_mock_are_warned_about(caplog: pytest.LogCaptureFixture) -> None:
    with caplog.at_level(logging.WARNING, logger="rig.run.station"):
        _warn_if_cameras_film_another_world(default_config())  # every device mock://: the filmed twin
        assert caplog.records == []
        cfg = override(default_config(), "devices.robot.address", "tcp://127.0.0.1:5007")
        _warn_if_cameras_film_another_world(cfg)
    (record,) = caplog.records
    assert "devices.robot.address = 'tcp://127.0.0.1:5007' does not move" in record.getMessage()
    assert "procedures that film the rig (calibrate, sync, sweep, ...) cannot pass" in record.getMessage()
