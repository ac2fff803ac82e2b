"""The mock SCPI generator, driven with raw lines over a real socket and a pty (no driver involved):
header forms, compound messages, MIN/MAX, ranges, the 20-deep error queue, and the twin's shaker."""

from __future__ import annotations

import contextlib
import socket
from collections.abc import Iterator

import pytest
import serial
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.mock.generator_instrument import ERROR_QUEUE_DEPTH, GeneratorInstrument
from drivers.mock.generator_server import GeneratorServer
from drivers.sim.clock import VirtualClock
from drivers.sim.world import World


class Line:
    """A plain LF-line client over a socket or a serial port."""

    def __init__(self, server: GeneratorServer) -> None:
        if server.mode == "tcp":
            self.sock: socket.socket | None = socket.create_connection(("127.0.0.1", server.port),
                                                                       timeout=1.0)
            self.port = None
            self.file = self.sock.makefile("rwb")
        else:
            self.sock = None
            self.port = serial.serial_for_url(server.client_port, timeout=1.0, write_timeout=1.0)

    def send(self, text: str) -> None:
        data = text.encode() + b"\n"
        if self.port is not None:
            self.port.write(data)
        else:
            self.file.write(data)
            self.file.flush()

    def ask(self, text: str) -> str:
        self.send(text)
        line = self.port.readline() if self.port is not None else self.file.readline()
        assert line.endswith(b"\n"), f"no reply to {text!r}"
        return line.decode().rstrip("\n")

    def sync(self) -> None:
        """``*OPC?``: everything sent before has been executed."""
        assert self.ask("*OPC?") == "1"

    def close(self) -> None:
        if self.port is not None:
            self.port.close()
        else:
            self.file.close()
            assert self.sock is not None
            self.sock.close()


@contextlib.contextmanager
def generator(mode: str = "tcp", sensitivity: list[tuple[float, float]] | None = None
              ) -> Iterator[tuple[Line, World, GeneratorInstrument]]:
    world = World(VirtualClock(), seed=4)
    instrument = GeneratorInstrument(world.shaker, world.clock, sensitivity_mm_per_v=sensitivity)
    with GeneratorServer(instrument, mode=mode) as server:
        line = Line(server)
        try:
            yield line, world, instrument
        finally:
            line.close()


@pytest.mark.parametrize("mode", ["tcp", "pty"])
def test_identity_and_no_error(mode: str) -> None:
    with generator(mode) as (line, _, _):
        assert line.ask("*IDN?").startswith("Keysight Technologies,33521B,")
        assert line.ask("SYST:ERR?") == '+0,"No error"'


@pytest.mark.parametrize("header", ["SOUR1:FREQ", "SOURCE1:FREQUENCY", "sour:freq", ":Source:Frequency:CW",
                                    "FREQ", "frequency"])
def test_short_long_and_optional_headers(header: str) -> None:
    with generator() as (line, _, _):
        line.send(f"{header} 12.5")
        assert line.ask("SYST:ERR?") == '+0,"No error"'
        assert float(line.ask(f"{header}?")) == 12.5


def test_partial_mnemonics_are_undefined() -> None:
    with generator() as (line, _, _):
        line.send("SOUR1:FREQU 10")  # neither FREQ nor FREQUENCY
        assert line.ask("SYST:ERR?") == '-113,"Undefined header"'


def test_compound_messages_continue_the_path_and_join_replies() -> None:
    with generator() as (line, _, _):
        line.send("SOUR1:FREQ 20;VOLT 0.5;:OUTP1:LOAD INF;*CLS")
        assert line.ask("SOUR1:FREQ:STAR 5;STOP 30;:SOUR1:FREQ:STAR?;STOP?") == \
            "+5.00000000000000E+00;+3.00000000000000E+01"
        # 0.5 Vpp set for 50 Ω reads 1 Vpp once the load is INF: the output is unchanged, only the display
        assert line.ask("FREQ?;VOLT?;:OUTP1:LOAD?") == "+2.00000000000000E+01;+1.00000000000000E+00;9.9E+37"
        assert line.ask("SYST:ERR?") == '+0,"No error"'


def test_min_max_and_suffixes() -> None:
    with generator() as (line, _, _):
        line.send("FREQ MAX")
        assert float(line.ask("FREQ?")) == 30e6
        line.send("FREQ 2 KHZ")
        assert float(line.ask("FREQ?")) == 2000.0
        line.send("FREQ 2 FURLONGS")
        assert line.ask("SYST:ERR?") == '-131,"Invalid suffix"'


def test_out_of_range_leaves_the_value_unchanged() -> None:
    with generator() as (line, _, _):
        line.send("FREQ 10")
        line.send("FREQ 1E9")
        assert line.ask("SYST:ERR?") == '-222,"Data out of range"'
        assert float(line.ask("FREQ?")) == 10.0
        line.send("VOLT 15")  # > 10 Vpp into the 50 Ω default load
        assert line.ask("SYST:ERR?") == '-222,"Data out of range"'
        line.send("OUTP1:LOAD INF;:VOLT 15")  # allowed into high impedance
        assert line.ask("SYST:ERR?") == '+0,"No error"'


def test_parameter_errors() -> None:
    with generator() as (line, _, _):
        for text, error in [("FREQ", '-109,"Missing parameter"'),
                            ("FREQ 1,2", '-108,"Parameter not allowed"'),
                            ("FREQ abc", '-104,"Data type error"'),
                            ("FUNC BANANA", '-224,"Illegal parameter value"'),
                            ("SOUR2:FREQ 10", '-114,"Header suffix out of range"'),
                            ("*IDN", '-113,"Undefined header"'),
                            ("SYST:ERR", '-113,"Undefined header"')]:
            line.send(text)
            assert line.ask("SYST:ERR?") == error, text


def test_error_in_a_compound_message_stops_the_rest() -> None:
    with generator() as (line, _, _):
        line.send("FREQ 10;BOGUS 1;FREQ 20")
        assert float(line.ask("FREQ?")) == 10.0
        assert line.ask("SYST:ERR?") == '-113,"Undefined header"'


def test_error_queue_is_20_deep_with_overflow_entry() -> None:
    assert ERROR_QUEUE_DEPTH == 20
    with generator() as (line, _, _):
        for i in range(25):
            line.send(f"BOGUS{i}")
        entries = [line.ask("SYST:ERR?") for _ in range(21)]
        assert entries[:19] == ['-113,"Undefined header"'] * 19
        assert entries[19] == '-350,"Queue overflow"'
        assert entries[20] == '+0,"No error"'
        line.send("BOGUS;*CLS")  # the error happens first, *CLS is never reached
        assert line.ask("SYST:ERR?") == '-113,"Undefined header"'
        line.send("BOGUS")
        line.send("*CLS")
        assert line.ask("SYST:ERR?") == '+0,"No error"'


def test_reset_returns_to_defaults_with_output_off() -> None:
    with generator() as (line, _, _):
        line.send("FREQ 10;:OUTP1 ON")
        line.send("*RST")
        assert line.ask("OUTP1?") == "0"
        assert float(line.ask("FREQ?")) == 1000.0


def test_output_moves_the_twin_shaker_with_the_load_pitfall() -> None:
    # sensitivity 0.5 mm per V peak; 2 Vpp displayed
    with generator(sensitivity=[(1.0, 0.5), (100.0, 0.5)]) as (line, world, _):
        line.send("FUNC SIN;FREQ 15;VOLT 2")
        line.sync()
        t = world.clock.now_s()
        assert world.shaker.amplitude_at_mm(t) == 0.0  # output off
        line.send("OUTP1 ON")
        line.sync()
        t = world.clock.now_s()
        # 50 Ω setting into the amplifier's high-Z input: the real voltage is twice the displayed one
        assert world.shaker.amplitude_at_mm(t) == pytest.approx(0.5 * 2.0)
        line.send("OUTP1:LOAD INF;:VOLT 2")
        line.sync()
        world.clock.sleep_s(1.0)
        t = world.clock.now_s()
        assert world.shaker.amplitude_at_mm(t) == pytest.approx(0.5 * 1.0)
        assert world.shaker.frequency_hz(t) == 15.0
        line.send("OUTP1 OFF")
        line.sync()
        assert world.shaker.amplitude_at_mm(world.clock.now_s()) == 0.0


def test_sweep_moves_the_twin_and_repeats() -> None:
    with generator() as (line, world, _):
        line.send("OUTP1:LOAD INF;:FUNC SIN;VOLT 1;FREQ:STAR 5;STOP 30;:SWE:SPAC LOG;TIME 10;:OUTP1 ON")
        line.send("SWE:STAT ON")
        line.sync()
        t0 = world.clock.now_s()
        assert world.shaker.frequency_hz(t0 + 5.0) == pytest.approx(5.0 * 6**0.5)
        world.clock.sleep_s(12.0)  # no request needed: the repeating sweep is one periodic segment
        assert world.shaker.frequency_hz(t0 + 10.0 + 5.0) == pytest.approx(5.0 * 6**0.5)
        assert world.shaker.frequency_hz(t0 + 1000 * 10.0 + 5.0) == pytest.approx(5.0 * 6**0.5)
        assert line.ask("SYST:ERR?") == '+0,"No error"'


KNOWN = ["*IDN?", "*RST", "*CLS", "*OPC?", "SYST:ERR?", "SOUR1:FREQ 10", "FREQ?", "VOLT 0.5", "VOLT?",
         "OUTP1 ON", "OUTP1?", "FUNC SIN", "SWE:STAT ON", "SWE:SPAC LOG", "FREQ:STAR 5", "OUTP1:LOAD INF"]


@settings(max_examples=200, deadline=None)
@given(st.lists(st.one_of(st.sampled_from(KNOWN), st.text(max_size=20)), min_size=1, max_size=6))
def test_any_line_is_answered_or_queued_never_crashes(parts: list[str]) -> None:
    world = World(VirtualClock(), seed=6)
    instrument = GeneratorInstrument(world.shaker, world.clock)
    line = ";".join(p.replace("\n", " ") for p in parts)
    before = len(instrument.errors)
    reply = instrument.handle_line(line)
    assert reply is None or isinstance(reply, str)
    assert len(instrument.errors) <= max(before + 1, ERROR_QUEUE_DEPTH)  # at most one error per message
    assert world.shaker.amplitude_at_mm(world.clock.now_s()) >= 0.0


@given(st.sampled_from(["FREQ", "FREQUENCY", "SOUR:FREQ", "SOURCE1:FREQUENCY:CW", ":SOUR1:FREQ"]),
       st.data())
def test_header_case_does_not_matter(header: str, data: st.DataObject) -> None:
    mixed = "".join(c.lower() if data.draw(st.booleans()) else c for c in header)
    world = World(VirtualClock(), seed=7)
    instrument = GeneratorInstrument(world.shaker, world.clock)
    assert instrument.handle_line(f"{mixed} 123.5") is None
    assert instrument.handle_line(f"{mixed}?") == "+1.23500000000000E+02"
    assert not instrument.errors
    # in one message the second header continues the first one's path: SOUR:SOUR:FREQ? is undefined
    if ":" in header.strip(":"):
        instrument.handle_line(f"{mixed} 1;{mixed.lstrip(':')}?")
        assert list(instrument.errors) == [(-113, "Undefined header")]
