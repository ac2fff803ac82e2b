"""devices.robot.wdt_ms, the b-CAP watchdog: validated against its range, the heartbeat and the receive
time-out (each error names the field and what is allowed); the station opens the session with it, as the
controller (a mock RC8 on TCP) sees it on the wire."""

from __future__ import annotations

import pytest

from drivers.mock.bcap_server import BcapMockServer
from drivers.sim.clock import VirtualClock
from drivers.sim.world import World
from rig.config.rig_config import ConfigError, default_config, override
from rig.run.clock import make_clock
from rig.run.station import open_station


def test_the_default_watchdog_is_denso_s_400_ms() -> None:
    assert default_config().devices.robot.wdt_ms == 400


@pytest.mark.parametrize(("value", "allowed"), [
    (79, "79 is out of range; allowed: 80 ≤ value ≤ 60000"),
    (60001, "60001 is out of range; allowed: 80 ≤ value ≤ 60000"),
    (400.5, "400.5 has the wrong type; allowed: an integer"),
])
def test_a_watchdog_outside_its_range_names_the_field_and_the_range(value: object, allowed: str) -> None:
    with pytest.raises(ConfigError) as err:
        override(default_config(), "devices.robot.wdt_ms", value)
    assert err.value.field == "devices.robot.wdt_ms" and allowed in str(err.value)


def test_the_watchdog_stays_below_the_heartbeat_and_the_receive_time_out() -> None:
    cfg = default_config()  # heartbeat 2 s, b-CAP receive time-out 3 s
    with pytest.raises(ConfigError, match=r"devices\.robot\.wdt_ms: 2000 ms; allowed: 80 ≤ value < "
                                          r"station\.heartbeat_timeout_s = 2000 ms"):
        override(cfg, "devices.robot.wdt_ms", 2000)
    cfg = override(override(cfg, "station.heartbeat_timeout_s", 6.0), "devices.robot.wdt_ms", 2000)
    assert cfg.devices.robot.wdt_ms == 2000  # 1.5 × 2 s = the 3 s receive time-out: allowed
    with pytest.raises(ConfigError, match=r"devices\.robot\.wdt_ms: 2001 ms; allowed: 80 ≤ value ≤ "
                                          r"devices\.robot\.timeout_s / 1\.5 = 2000 ms"):
        override(cfg, "devices.robot.wdt_ms", 2001)


def test_the_station_opens_the_controller_session_with_the_configured_watchdog() -> None:
    world = World(VirtualClock())
    with BcapMockServer(world.robot, world.clock) as server:
        cfg = override(default_config(), "devices.robot.address", f"tcp://127.0.0.1:{server.serve_tcp()}")
        cfg = override(override(cfg, "station.heartbeat_timeout_s", 4.0), "devices.robot.wdt_ms", 1500)
        with open_station(cfg, make_clock(virtual=True)) as station:
            assert server.state.wdt_ms == 1500  # Service_Start's "WDT=1500", parsed by the controller
            assert station.devices["robot"].snapshot()["wdt_ms"] == 1500  # and in the run record
