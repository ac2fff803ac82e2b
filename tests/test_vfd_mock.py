"""The mock VFD driven by a PLAIN pymodbus client using only the documented register map.

The map is the contract (docs/exciter.md), not our driver: every address and code below is copied from
the documentation table, and the expected output frequencies come from the documented ramp behaviour.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator

import pytest
from pymodbus.client import ModbusTcpClient

from drivers.mock.vfd_drive import FAULT_OVERLOAD, FAULT_OVERSPEED, FAULT_WATCHDOG, DriveModel
from drivers.mock.vfd_server import VfdServer
from drivers.sim.clock import VirtualClock
from drivers.sim.world import World

# docs/exciter.md, "Register map" (wire addresses, unit 1)
CMD, FREQ_SET, AUX = 0x2000, 0x2001, 0x2002
FAULT, STATUS, FREQ_CMD, FREQ_OUT, CURRENT = 0x2100, 0x2101, 0x2102, 0x2103, 0x2104
ACCEL_TIME, DECEL_TIME = 0x0109, 0x010A
RUN_FWD, RUN_REV, STOP, RESET = 0x0012, 0x0022, 0x0001, 0x0002


@contextlib.contextmanager
def plain(max_output_hz: float = 50.0, gear_ratio: float = 2.0,
          **kwargs: object) -> Iterator[tuple[ModbusTcpClient, World, DriveModel]]:
    world = World(VirtualClock(), seed=3)
    drive = DriveModel(world.exciter, world.clock, max_output_hz=max_output_hz, gear_ratio=gear_ratio,
                       accel_time_s=10.0, decel_time_s=5.0, **kwargs)  # type: ignore[arg-type]
    with VfdServer(drive) as server:
        client = ModbusTcpClient("127.0.0.1", port=server.port, timeout=1.0, retries=0)
        assert client.connect()
        try:
            yield client, world, drive
        finally:
            client.close()


def read(client: ModbusTcpClient, address: int, count: int = 1) -> list[int]:
    reply = client.read_holding_registers(address, count=count, device_id=1)
    assert not reply.isError(), reply
    return reply.registers


def write(client: ModbusTcpClient, address: int, value: int) -> None:
    reply = client.write_register(address, value, device_id=1)
    assert not reply.isError(), reply


def test_plain_client_runs_the_drive_and_the_twin_follows() -> None:
    with plain() as (client, world, _):
        write(client, FREQ_SET, 2000)  # 20.00 Hz
        assert read(client, FREQ_CMD) == [2000]
        assert read(client, STATUS)[0] & 0x3 == 0b00  # stopped
        write(client, CMD, RUN_FWD)
        t0 = world.clock.now_s()
        world.clock.advance_to(t0 + 2.0)  # accel 10 s for 50 Hz → 5 Hz/s → 10 Hz after 2 s
        fault, status, cmd, out, current = read(client, FAULT, 5)
        assert (fault, status & 0x3, status & 0x18, cmd) == (0, 0b11, 0, 2000)
        assert out == 1000
        # the twin's exciter turns at drive frequency / gear ratio (2.0)
        assert world.exciter.frequency_hz(world.clock.now_s()) == pytest.approx(5.0)
        assert current > 0
        world.clock.advance_to(t0 + 10.0)
        assert read(client, FREQ_OUT) == [2000]
        write(client, CMD, STOP)  # decel 5 s for 50 Hz → 10 Hz/s: 2 s to rest
        t1 = world.clock.now_s()
        world.clock.advance_to(t1 + 1.0)
        assert read(client, FREQ_OUT) == [1000]
        assert read(client, STATUS)[0] & 0x3 == 0b01  # decelerating
        world.clock.advance_to(t1 + 2.5)
        assert read(client, FREQ_OUT) == [0]
        assert read(client, STATUS)[0] & 0x3 == 0b00
        assert world.exciter.frequency_hz(world.clock.now_s()) == 0.0


def test_ramp_time_registers_set_the_ramp_rate() -> None:
    with plain() as (client, world, _):
        write(client, ACCEL_TIME, 25)  # 2.5 s for 50 Hz → 20 Hz/s
        assert read(client, ACCEL_TIME) == [25]
        write(client, FREQ_SET, 3000)
        write(client, CMD, RUN_FWD)
        world.clock.advance_to(world.clock.now_s() + 1.0)
        assert read(client, FREQ_OUT) == [2000]


def test_reverse_command_shows_in_the_status_direction_bits() -> None:
    with plain() as (client, _, _):
        write(client, FREQ_SET, 500)
        write(client, CMD, RUN_REV)
        assert read(client, STATUS)[0] & 0x18 == 0x18
        assert read(client, CMD) == [RUN_REV]  # CMD reads back the last value


def test_exception_codes_follow_the_documented_map() -> None:
    with plain(max_output_hz=50.0) as (client, _, _):
        too_fast = client.write_register(FREQ_SET, 5001, device_id=1)  # > max output frequency
        assert too_fast.isError() and too_fast.exception_code == 3
        assert read(client, FREQ_SET) == [0]  # value unchanged
        bad_cmd = client.write_register(CMD, 0x0033, device_id=1)
        assert bad_cmd.isError() and bad_cmd.exception_code == 3
        unmapped = client.read_holding_registers(0x2105, count=1, device_id=1)
        assert unmapped.isError() and unmapped.exception_code == 2
        read_only = client.write_register(FREQ_OUT, 100, device_id=1)
        assert read_only.isError() and read_only.exception_code == 2


def test_watchdog_trips_when_nobody_asks_and_the_twin_stops_at_the_trip_time() -> None:
    with plain(watchdog_s=1.0) as (client, world, _):
        write(client, FREQ_SET, 1000)
        write(client, CMD, RUN_FWD)
        t_last = world.clock.now_s()
        world.clock.advance_to(t_last + 30.0)  # silence: trips at t_last + 1 s, then decelerates
        fault, status = read(client, FAULT, 2)
        assert fault & 0xFF == FAULT_WATCHDOG
        assert status & 0x3 == 0b00
        exciter = world.exciter
        # up to the trip the exciter accelerated at 5 Hz/s (drive) / 2 (gear) = 2.5 Hz/s
        assert exciter.frequency_hz(t_last + 1.0) == pytest.approx(2.5)
        # then decelerated at 10 Hz/s / 2 = 5 Hz/s
        assert exciter.frequency_hz(t_last + 1.25) == pytest.approx(1.25)
        assert exciter.frequency_hz(t_last + 1.5) == 0.0
        # a faulted drive ignores run; the reset clears the fault once at rest
        write(client, CMD, RUN_FWD)
        assert read(client, STATUS)[0] & 0x3 != 0b11
        write(client, AUX, RESET)
        assert read(client, FAULT) == [0]


def test_overload_trips_where_the_load_model_says() -> None:
    # I = 1 + (5 − 1)·(f/50)²; 3 A is reached at f = 50·sqrt(0.5) = 35.36 Hz
    with plain(no_load_current_a=1.0, current_at_max_a=5.0, overload_current_a=3.0) as (client, world, _):
        write(client, FREQ_SET, 4500)
        write(client, CMD, RUN_FWD)
        t0 = world.clock.now_s()
        world.clock.advance_to(t0 + 9.0)
        fault, _, _, out = read(client, FAULT, 4)
        assert fault == FAULT_OVERLOAD
        t_trip = t0 + 50 * 0.5**0.5 / 5.0
        assert world.exciter.frequency_hz(t_trip) * 2 == pytest.approx(50 * 0.5**0.5)
        assert world.exciter.frequency_hz(t_trip + 1.0) * 2 == pytest.approx(50 * 0.5**0.5 - 10.0)
        assert out == round((50 * 0.5**0.5 - 10.0 * (9.0 - 50 * 0.5**0.5 / 5.0)) * 100)
        write(client, AUX, RESET)  # output still turning: the cause is not gone, the fault stays
        assert read(client, FAULT) == [FAULT_OVERLOAD]


def test_overspeed_trip() -> None:
    with plain(overspeed_hz=20.0) as (client, world, _):
        write(client, FREQ_SET, 3000)
        write(client, CMD, RUN_FWD)
        world.clock.advance_to(world.clock.now_s() + 10.0)
        assert read(client, FAULT) == [FAULT_OVERSPEED]
        assert max(world.exciter.frequency_hz(world.clock.now_s() - k * 0.1) for k in range(100)) <= 10.0


def test_paced_clock_watchdog_trips_with_nobody_asking() -> None:
    """In paced mode the server's housekeeping applies the trip; no request is needed to stop the twin."""
    world = World(VirtualClock(rate=50.0), seed=3)
    drive = DriveModel(world.exciter, world.clock, watchdog_s=1.0, accel_time_s=10.0, decel_time_s=5.0)
    with VfdServer(drive) as server:
        client = ModbusTcpClient("127.0.0.1", port=server.port, timeout=1.0, retries=0)
        try:
            assert client.connect()
            write(client, FREQ_SET, 1000)
            t0 = world.clock.now_s()
            write(client, CMD, RUN_FWD)  # the last request: the run starts when the drive handles it
            t1 = world.clock.now_s()
            world.clock.wait_until(t1 + 3.0, timeout_s=5.0)  # ~60 ms of wall time, no requests
            assert drive.fault_code == FAULT_WATCHDOG  # set by the housekeeping tick, not by a request
            t_trip = drive.fault_time_s
            assert t_trip is not None and t0 + 1.0 <= t_trip <= t1 + 1.0
            # acceleration at 50 Hz / 10 s from the run command (handled between t0 and t1) to the trip,
            # then deceleration at 50 Hz / 5 s
            f_trip = world.exciter.frequency_hz(t_trip)
            assert 5.0 * (t_trip - t1) - 1e-9 <= f_trip <= 5.0 * (t_trip - t0) + 1e-9
            assert world.exciter.frequency_hz(t_trip + 0.25) == pytest.approx(f_trip - 2.5, abs=1e-9)
        finally:
            client.close()


COMM_TREATMENT, COMM_TIMEOUT = 0x0902, 0x0903  # Delta 09-02 (1 = ramp to stop), 09-03 (0.1 s, 0 = off)


@pytest.mark.parametrize(("treatment", "trips"), [(0, False), (1, True), (2, True), (3, False)])
def test_communication_timeout_is_set_over_modbus_like_the_drive(treatment: int, trips: bool) -> None:
    """The time-out armed through its registers stops a running drive nobody talks to; the treatments
    that keep running (0, 3) do not."""
    with plain() as (client, world, drive):
        write(client, COMM_TREATMENT, treatment)
        write(client, COMM_TIMEOUT, 15)  # 1.5 s
        assert read(client, COMM_TREATMENT, 2) == [treatment, 15]
        write(client, FREQ_SET, 1000)
        write(client, CMD, RUN_FWD)
        t_last = world.clock.now_s()
        world.clock.advance_to(t_last + 30.0)
        assert (read(client, FAULT)[0] & 0xFF == FAULT_WATCHDOG) is trips  # the trip is applied at its time
        if trips:
            assert drive.fault_time_s == pytest.approx(t_last + 1.5)
            assert read(client, FREQ_OUT) == [0]
        write(client, COMM_TIMEOUT, 0)  # off: a drive left idle never trips
        write(client, AUX, RESET)
        write(client, CMD, RUN_FWD)
        t_last = world.clock.now_s()
        world.clock.advance_to(t_last + 30.0)
        assert read(client, FAULT) == [0]


def test_the_driver_arms_and_disarms_the_communication_timeout() -> None:
    from drivers.exciter.vfd import VfdDriver
    from drivers.modbus_link import ModbusLink

    with plain() as (client, _world, drive):
        link = ModbusLink(f"tcp://127.0.0.1:{client.comm_params.port}", timeout_s=1.0, retries=0)
        vfd = VfdDriver(link)
        vfd.set_comm_timeout_s(2.0)
        assert read(client, COMM_TREATMENT, 2) == [1, 20] and drive.watchdog_s == pytest.approx(2.0)
        vfd.set_comm_timeout_s(None)
        assert read(client, COMM_TIMEOUT) == [0] and drive.watchdog_s is None
        with pytest.raises(ValueError, match="communication time-out"):
            vfd.set_comm_timeout_s(1e6)
        link.close()
