"""The devices' own protection when the controller dies silently (power loss, a cut cable: no FIN, no
last word), in process: the b-CAP mock's client watchdog (on in the stand-alone mock) halts the arm and
releases it when the client holding it sends nothing for 4 × WDT. The drives' communication time-out is
``test_vfd_mock.py`` (registers) and ``test_safety_standalone.py`` (SIGKILL of a real ``rig``)."""

from __future__ import annotations

import time

from drivers.denso.client import BcapClient
from drivers.mock.bcap_server import CLIENT_WDT_FACTOR, BcapMockServer
from drivers.sim.clock import VirtualClock
from drivers.sim.world import World
from drivers.transport import open_transport

WAIT_S = 60.0  # generous: the wait ends as soon as the controller acts


def _wait(predicate, timeout_s: float = WAIT_S) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(0.02)
    return predicate()


def test_a_silent_client_is_presumed_dead_the_arm_halted_and_released() -> None:
    world = World(VirtualClock(rate=1.0))
    with BcapMockServer(world.robot, world.clock, client_watchdog=True) as server:
        url = f"tcp://127.0.0.1:{server.serve_tcp()}"
        client = BcapClient(open_transport(url, 30.0), timeout_s=30.0)
        client.open_robot(wdt_ms=100)
        start = world.robot.pose_at(world.clock.now_s())
        client.move([start[0] + 100.0, *start[1:]], speed_percent=1, next_=True)  # 10 s at 10 mm/s
        assert world.robot.is_moving(world.clock.now_s()) and server.state.motor_on
        t_silent = time.monotonic()
        # the client's connection stays open but it sends nothing more, as after a power loss
        assert _wait(lambda: not server.state.motor_on)
        assert time.monotonic() - t_silent > CLIENT_WDT_FACTOR * 0.1  # not before 4 × WDT of silence
        assert _wait(lambda: not world.robot.is_moving(world.clock.now_s()))  # halted (it decelerates) ...
        rest = world.robot.pose_at(world.clock.now_s())
        assert rest[0] < start[0] + 50.0  # ... far short of its target: not left to finish its 10 s move
        assert server.state.handles == {}
        other = BcapClient(open_transport(url, 30.0), timeout_s=30.0)  # the controller is free again
        other.service_start()
        other.service_stop()
        other.link.transport.close()
        client.link.transport.close()


def test_without_the_client_watchdog_a_silent_client_keeps_the_controller() -> None:
    """In-process mocks (the built-in rig) keep it off: they die with the client anyway."""
    world = World(VirtualClock(rate=1.0))
    with BcapMockServer(world.robot, world.clock) as server:
        client = BcapClient(open_transport(f"tcp://127.0.0.1:{server.serve_tcp()}", 30.0), timeout_s=30.0)
        client.open_robot(wdt_ms=100)
        assert not _wait(lambda: not server.state.motor_on, timeout_s=CLIENT_WDT_FACTOR * 0.1 * 3)
        client.close()
        client.link.transport.close()


def test_a_comm_timeout_the_heartbeat_probes_cannot_keep_alive_is_refused_by_the_configuration() -> None:
    import pytest

    from rig.config.rig_config import ConfigError, default_config, override

    cfg = override(default_config(), "station.heartbeat_timeout_s", 5.0)  # idle drives probed every 1.25 s
    refused = (r"devices\.exciter\.comm_timeout_s: 2 s must exceed twice the heartbeat probe interval "
               r"\(station\.heartbeat_timeout_s / 4 = 1\.25 s\)")
    with pytest.raises(ConfigError, match=refused):
        override(cfg, "devices.exciter.address", "tcp://127.0.0.1:5020")
    ok = override(override(cfg, "devices.exciter.comm_timeout_s", 3.0), "devices.exciter.address",
                  "tcp://127.0.0.1:5020")
    assert ok.devices.exciter.comm_timeout_s == 3.0
