"""Two drives on one RS-485 line (the exciter and the rotor as units 1 and 2 on one serial port): the
station opens the port once and both drives talk through that one Modbus master, its lock serialising
every request — through a pty to one mock line serving both units."""

from __future__ import annotations

import dataclasses
import threading
from collections.abc import Iterator

import pytest

from drivers.exciter.register_map import DELTA_MAP
from drivers.mock.vfd_drive import DriveModel
from drivers.mock.vfd_server import VfdServer
from drivers.sim.clock import VirtualClock
from drivers.sim.world import World
from rig.config.rig_config import default_config, override
from rig.run.clock import make_clock
from rig.run.station import open_station

ROUNDS = 40  # polls of each drive, from two threads at once


@pytest.fixture
def one_line() -> Iterator[VfdServer]:
    """One mock RS-485 line (RTU over a pty) with the exciter drive as unit 1 and the rotor's as unit 2."""
    clock = VirtualClock(rate=1.0)
    world = World(clock, seed=0)
    drives = [DriveModel(world.exciter, clock, register_map=dataclasses.replace(DELTA_MAP, unit_id=1)),
              DriveModel(world.rotor, clock, register_map=dataclasses.replace(DELTA_MAP, unit_id=2))]
    server = VfdServer(drives, mode="rtu").start()
    try:
        yield server
    finally:
        server.stop()


def test_exciter_and_rotor_on_one_port_share_one_serialised_link(one_line: VfdServer) -> None:
    address = f"serial://{one_line.client_port}?baud=115200"
    cfg = default_config()
    for name, unit in (("exciter", 1), ("rotor", 2)):
        cfg = override(cfg, f"devices.{name}.address", address)
        cfg = override(cfg, f"devices.{name}.unit_id", unit)
    with open_station(cfg, make_clock(True, rate=1.0)) as station:
        exciter, rotor = station.devices["exciter"], station.devices["rotor"]
        link = exciter.vfd.link
        assert rotor.vfd.link is link  # one owner of the port
        assert exciter.vfd.contact.lock is rotor.vfd.contact.lock is link.lock  # one lock for the line
        exciter.set_frequency(2.0, wait=False)
        rotor.set_frequency(1.0, wait=False)
        errors: list[BaseException] = []
        setpoints: dict[str, set[float]] = {"exciter": set(), "rotor": set()}

        def poll(name: str) -> None:
            axis = station.devices[name]
            try:
                for _ in range(ROUNDS):
                    setpoints[name].add(round(axis.read_sample().setpoint_hz, 6))
            except BaseException as exc:  # reported by the assertion below
                errors.append(exc)

        threads = [threading.Thread(target=poll, args=(n,)) for n in ("exciter", "rotor")]
        for t in threads:
            t.start()
        for t in threads:
            t.join(120.0)
        assert errors == [] and not any(t.is_alive() for t in threads)
        # each drive answered for itself: no reply read by the other's request, none out of step
        assert setpoints == {"exciter": {2.0}, "rotor": {1.0}}
        assert link.stale_replies == 0 and link.reconnects == 0
        assert one_line.requests_received >= 2 * ROUNDS
        assert station.snapshot()["addresses"] == {**station.snapshot()["addresses"],
                                                   "exciter": address, "rotor": address}
    assert link.closed  # closed once, after both drives were stopped
    assert [d.body.frequency_hz(d.clock.now_s() + 60.0) for d in one_line.drives] == [0.0, 0.0]
