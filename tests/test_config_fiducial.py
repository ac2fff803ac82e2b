"""``[fiducial]`` / ``[sim.fiducial]``: validated with field names and ranges; the simulated station puts the
LED into the twin, lit by the generator mock's sync output."""

from __future__ import annotations

import copy
import tomllib
from importlib import resources
from typing import Any

import numpy as np
import pytest

from drivers.sim.clock import VirtualClock
from rig.config.rig_config import ConfigError, config_from_dict, default_config
from rig.run.station import open_station

SIM = tomllib.loads(resources.files("rig").joinpath("data/sim.toml").read_text())
FIDUCIAL = {"regions_px": {"left": [636, 421, 648, 655], "right": [659, 426, 670, 647]}}
SIM_LED = {"centre_mm": [400.0, -200.0, 300.0]}


def with_fiducial(**changes: Any) -> dict[str, Any]:
    """The built-in simulated rig plus a fiducial; ``changes``: dotted path (``__`` for ``.``) → value,
    None deletes."""
    table = copy.deepcopy(SIM)
    table["fiducial"] = copy.deepcopy(FIDUCIAL)
    table["sim"]["fiducial"] = copy.deepcopy(SIM_LED)
    for dotted, value in changes.items():
        node = table
        keys = dotted.split("__")
        for key in keys[:-1]:
            node = node[key]
        if value is None:
            del node[keys[-1]]
        else:
            node[keys[-1]] = value
    return table


def test_a_fiducial_is_optional_and_validated_with_its_defaults() -> None:
    assert default_config().fiducial is not None  # the built-in rig carries one (the phase criteria need it)
    without = copy.deepcopy(SIM)
    del without["fiducial"], without["sim"]["fiducial"]
    assert config_from_dict(without).fiducial is None  # the start-event method, as before
    cfg = config_from_dict(with_fiducial())
    assert cfg.fiducial is not None and cfg.sim is not None and cfg.sim.fiducial is not None
    assert cfg.fiducial.regions_px["left"] == (636, 421, 648, 655)
    assert (cfg.fiducial.device, cfg.fiducial.channel, cfg.fiducial.output) == ("generator", 1, "sync")
    assert cfg.snapshot()["fiducial"]["frequency_hz"] == pytest.approx(10.27)


@pytest.mark.parametrize(("changes", "field", "words"), [
    ({"fiducial__regions_px__right": None}, "fiducial.regions_px.right", "missing"),
    ({"fiducial__regions_px__middle": [0, 0, 5, 5]}, "fiducial.regions_px.middle", "no camera 'middle'"),
    ({"fiducial__regions_px__left": [636, 421, 648]}, "fiducial.regions_px.left", "exactly 4"),
    ({"fiducial__regions_px__left": [648, 421, 636, 655]}, "fiducial.regions_px.left", "x0 < x1"),
    ({"fiducial__regions_px__left": [636, 421, 648, 2000]}, "fiducial.regions_px.left", "outside the"),
    ({"fiducial__frequency_hz": 10.0}, "fiducial.frequency_hz", "commensurate"),
    ({"fiducial__frequency_hz": 70.0}, "fiducial.frequency_hz", "1.02 frames"),
    ({"fiducial__frequency_hz": 0.0}, "fiducial.frequency_hz", "out of range"),
    ({"fiducial__rise_time_s": 0.01}, "fiducial.rise_time_s", "out of range"),
    ({"fiducial__channel": 2, "devices__generator__channels": 1}, "fiducial.channel",
     "devices.generator.channels = 1 (a one-channel generator has no channel 2)"),
    ({"fiducial__channel": 3}, "fiducial.channel", "out of range"),
    ({"devices__generator__channel": 2, "devices__generator__channels": 1}, "devices.generator.channel",
     "devices.generator.channels = 1"),
    ({"fiducial__output": "main"}, "fiducial.output", "'sync'"),
    ({"fiducial__colour": "red"}, "fiducial.colour", "unknown field"),
    ({"sim__fiducial": None}, "sim.fiducial", "required when [fiducial]"),
    ({"fiducial": None}, "sim.fiducial", "without [fiducial]"),
    ({"sim__fiducial__time_constant_s": 0.0}, "sim.fiducial.time_constant_s", "out of range"),
    ({"sim__fiducial__centre_mm": [1.0, 2.0]}, "sim.fiducial.centre_mm", "exactly 3"),
])
def test_bad_fiducial_settings_name_the_field(changes: dict[str, Any], field: str, words: str) -> None:
    with pytest.raises(ConfigError) as info:
        config_from_dict(with_fiducial(**changes))
    assert info.value.field == field
    assert words in str(info.value)


def test_the_simulated_station_lights_the_twin_led_from_the_generator_mock() -> None:
    clock = VirtualClock()
    with open_station(config_from_dict(with_fiducial()), clock) as station:
        (led,) = station.world.leds
        assert np.allclose(led.centre_mm, SIM_LED["centre_mm"])
        # the generator mock drives it: powered on, its oscillator runs at 1 kHz with sync on
        edges, _, _ = led.drive_edges(clock.now_s(), clock.now_s() + 0.0101)
        assert edges.size == 20
