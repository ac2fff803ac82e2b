"""Clients we did not write against the mock drive: minimalmodbus on the RTU pty, a stock pymodbus client
on Modbus TCP. Addresses and codes are the documented register map (docs/exciter.md §1.2)."""

from __future__ import annotations

import contextlib
from collections.abc import Iterator

import minimalmodbus
import pytest
from pymodbus.client import ModbusTcpClient

from drivers.exciter.register_map import RegisterMap
from drivers.mock.vfd_drive import DriveModel
from drivers.mock.vfd_server import VfdServer
from drivers.sim.clock import VirtualClock
from drivers.sim.world import World

CMD, FREQ_SET, FREQ_CMD, FREQ_OUT, STATUS = 0x2000, 0x2001, 0x2102, 0x2103, 0x2101
RUN_FWD = 0x0012


@contextlib.contextmanager
def minimal_rtu(unit: int = 1) -> Iterator[tuple[minimalmodbus.Instrument, World, list[DriveModel]]]:
    world = World(VirtualClock(), seed=4)
    drives = [DriveModel(world.exciter, world.clock, max_output_hz=50.0, accel_time_s=10.0),
              DriveModel(world.rotor, world.clock, register_map=RegisterMap(unit_id=2), max_output_hz=50.0)]
    with VfdServer(drives, mode="rtu") as server:
        instrument = minimalmodbus.Instrument(server.client_port, unit)
        instrument.serial.baudrate = 115200
        instrument.serial.timeout = 1.0
        instrument.clear_buffers_before_each_transaction = True
        try:
            yield instrument, world, drives
        finally:
            instrument.serial.close()


def test_minimalmodbus_reads_writes_and_ramps_to_12_34_hz() -> None:
    with minimal_rtu() as (inst, world, _):
        inst.write_register(FREQ_SET, 12.34, number_of_decimals=2)  # FC16 by default in minimalmodbus
        assert inst.read_register(FREQ_CMD, number_of_decimals=2) == pytest.approx(12.34)
        inst.write_register(CMD, RUN_FWD, functioncode=6)
        t0 = world.clock.now_s()
        world.clock.advance_to(t0 + 1.0)  # 50 Hz / 10 s = 5 Hz/s
        assert inst.read_register(FREQ_OUT, number_of_decimals=2) == pytest.approx(5.0)
        world.clock.advance_to(t0 + 5.0)
        fault, status, cmd, out = inst.read_registers(0x2100, 4)
        assert (fault, status & 0x3, cmd, out) == (0, 0b11, 1234, 1234)
        assert world.exciter.frequency_hz(world.clock.now_s()) == pytest.approx(12.34)


def test_minimalmodbus_decodes_the_exception_replies() -> None:
    with minimal_rtu() as (inst, _, _):
        with pytest.raises(minimalmodbus.IllegalRequestError, match="illegal data value"):
            inst.write_register(FREQ_SET, 50.01, number_of_decimals=2, functioncode=6)  # > max output
        with pytest.raises(minimalmodbus.IllegalRequestError, match="illegal data address"):
            inst.read_register(0x2105)
        with pytest.raises(minimalmodbus.IllegalRequestError, match="illegal function"):
            inst.read_register(FREQ_OUT, functioncode=4)  # input registers: not in this drive's map
        assert inst.read_register(FREQ_SET) == 0  # still in step, value unchanged


def test_minimalmodbus_broadcast_reaches_both_drives() -> None:
    with minimal_rtu(unit=0) as (inst, _, drives):
        inst.write_register(FREQ_SET, 7.5, number_of_decimals=2, functioncode=6)  # no reply expected
        assert [d.regs[FREQ_SET] for d in drives] == [750, 750]
        inst.address = 2
        assert inst.read_register(FREQ_CMD, number_of_decimals=2) == pytest.approx(7.5)


def test_stock_pymodbus_client_on_tcp_gets_exceptions_with_the_request_code() -> None:
    world = World(VirtualClock(), seed=4)
    with VfdServer(DriveModel(world.exciter, world.clock, max_output_hz=50.0)) as server:
        client = ModbusTcpClient("127.0.0.1", port=server.port, timeout=2.0, retries=0)
        assert client.connect()
        try:
            assert not client.write_registers(FREQ_SET, [1234], device_id=1).isError()  # FC16
            assert client.read_holding_registers(FREQ_CMD, count=1, device_id=1).registers == [1234]
            refused = client.write_register(FREQ_SET, 5001, device_id=1)
            assert refused.isError() and refused.exception_code == 3 and refused.function_code == 0x86
            wrong_fc = client.read_input_registers(FREQ_OUT, count=1, device_id=1)
            assert wrong_fc.isError() and wrong_fc.exception_code == 1 and wrong_fc.function_code == 0x84
            gap = client.read_holding_registers(0x2100, count=6, device_id=1)  # 0x2105 is not mapped
            assert gap.isError() and gap.exception_code == 2 and gap.function_code == 0x83
        finally:
            client.close()
