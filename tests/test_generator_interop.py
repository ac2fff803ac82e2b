"""A client we did not write: pyvisa + pyvisa-py on the mock generator's socket
(``TCPIP::127.0.0.1::PORT::SOCKET``), doing what a lab's own script does first."""

from __future__ import annotations

import contextlib
from collections.abc import Iterator

import pyvisa
from pyvisa.resources import MessageBasedResource

from drivers.mock.generator_instrument import GeneratorInstrument
from drivers.mock.generator_server import GeneratorServer
from drivers.sim.clock import VirtualClock
from drivers.sim.world import World


@contextlib.contextmanager
def visa_generator() -> Iterator[tuple[MessageBasedResource, GeneratorInstrument]]:
    world = World(VirtualClock(), seed=9)
    instrument = GeneratorInstrument(world.shaker, world.clock)
    with GeneratorServer(instrument) as server:
        rm = pyvisa.ResourceManager("@py")
        inst = rm.open_resource(f"TCPIP::127.0.0.1::{server.port}::SOCKET", read_termination="\n",
                                write_termination="\n", timeout=5000)
        assert isinstance(inst, MessageBasedResource)
        try:
            yield inst, instrument
        finally:
            inst.close()
            rm.close()


def test_pyvisa_session_status_settings_and_errors() -> None:
    with visa_generator() as (inst, instrument):
        assert inst.query("*IDN?").startswith("Keysight Technologies,33521B,")
        inst.write("*RST")
        inst.write("*CLS")
        assert int(inst.query("*ESR?")) == 0
        assert inst.query("*OPC?") == "1"
        inst.write("OUTP1:LOAD INF;:SOUR1:FREQ 12.34;VOLT 1.5")
        assert float(inst.query("SOUR1:FREQ?")) == 12.34
        assert inst.query_ascii_values("VOLT?") == [1.5]
        assert instrument.frequency_hz == 12.34
        inst.write("SOUR1:FREQUENCY:BOGUS 3")
        inst.write("SOUR1:FREQ 1E12")
        assert int(inst.query("*ESR?")) == (1 << 5) | (1 << 4)
        assert inst.query("SYST:ERR?") == '-113,"Undefined header"'
        assert inst.query("SYST:ERR?") == '-222,"Data out of range"'
        assert inst.query("SYST:ERR?") == '+0,"No error"'
        assert float(inst.query("SOUR1:FREQ?")) == 12.34
