"""Fuzzing the mock generator's SCPI input path (property tests, default suite): any bytes, cut anywhere,
become lines that each end in a reply or an error in the queue — never an exception — and the input
buffer and error queue stay bounded. handle_line is called directly: the server's own catch-all (which
logs a bug and queues −300) would hide a failure here."""

from __future__ import annotations

from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.mock.generator_instrument import GeneratorInstrument
from drivers.mock.generator_server import LineAssembler
from drivers.mock.scpi_parser import ScpiCommandError, split_units
from drivers.mock.scpi_status import ERROR_QUEUE_DEPTH
from drivers.sim.clock import VirtualClock
from drivers.sim.world import World

HEADERS = ["*IDN?", "*RST", "*CLS", "*ESR?", "*ESE", "*SRE", "*STB?", "*OPC", "*TST?", "SYST:ERR?",
           "SYST:VERS?", "SOUR1:FREQ", "FREQ:STAR", "VOLT", "VOLT:UNIT", "VOLT:OFFS", "OUTP1", "OUTP1:LOAD",
           "SWE:STAT", "SWE:TIME", "SWE:SPAC", "FUNC", ":SOUR2:FREQ?", "TRIG1:SOUR"]
PARAMS = ["", " 10", " MAX", " min", " DEF", " 1e999", " -1e-999", " 1,2", ' "a;b"', " 'x", " VRMS",
          " DBM", " INF", " 5 KHZ", " 2.5VPP", " ON", " 0x10", " \x00", " nan", " 255.5", " -0",
          " 1e300", " -1e300", " 1e-320", " 1e308"]

scpi_unit = st.builds(lambda h, p, q: h + ("?" if q and not h.endswith("?") else "") + p,
                      st.sampled_from(HEADERS), st.sampled_from(PARAMS), st.booleans())
scpi_line = st.lists(st.one_of(scpi_unit, st.text(max_size=30)), min_size=1, max_size=5).map(";".join)


def _instrument() -> GeneratorInstrument:
    world = World(VirtualClock(), seed=11)
    return GeneratorInstrument(world.shaker, world.clock)


@settings(max_examples=300, deadline=None)
@given(st.lists(st.one_of(scpi_line.map(str.encode), st.binary(max_size=200)), min_size=1, max_size=8),
       st.data())
def test_any_bytes_in_any_chunks_end_in_replies_or_queued_errors(messages: list[bytes],
                                                                 data: st.DataObject) -> None:
    instrument = _instrument()
    overflows: list[int] = []
    lines = LineAssembler(lambda: overflows.append(1), max_line=256)
    stream = b"\n".join(messages) + b"\n"
    cuts = sorted(data.draw(st.lists(st.integers(0, len(stream)), max_size=6)))
    for a, b in zip([0, *cuts], [*cuts, len(stream)], strict=True):
        for line in lines.feed(stream[a:b]):
            assert len(line) <= 256
            errors_before = len(instrument.errors)
            reply = instrument.handle_line(line)
            assert reply is None or (isinstance(reply, str) and reply.isascii() and "\n" not in reply)
            assert len(instrument.errors) <= max(errors_before + 1, ERROR_QUEUE_DEPTH)
    assert len(instrument.errors) <= ERROR_QUEUE_DEPTH
    assert len(instrument.commands_seen) <= 256
    t = instrument.clock.now_s()
    assert instrument.body.amplitude_at_mm(t) >= 0.0 and instrument.body.frequency_hz(t) >= 0.0


@settings(max_examples=300, deadline=None)
@given(st.text(max_size=120))
def test_the_line_parser_raises_only_scpi_errors(text: str) -> None:
    try:
        units = split_units(text)
    except ScpiCommandError as exc:
        assert -199 <= exc.code <= -100  # parse errors are command errors
        return
    assert all(u.nodes and all(u.nodes) for u in units)


@settings(max_examples=100, deadline=None)
@given(st.lists(scpi_line, min_size=1, max_size=30))
def test_status_registers_stay_8_bit_and_esr_reads_clear(lines: list[str]) -> None:
    instrument = _instrument()
    for line in lines:
        instrument.handle_line(line)
        stb = int(instrument.handle_line("*STB?") or "x")
        assert 0 <= stb <= 255 and 0 <= instrument.status.esr <= 255
        assert 0 <= instrument.status.ese <= 255 and 0 <= instrument.status.sre <= 255
        assert not instrument.status.sre & (1 << 6)
    instrument.handle_line("*ESR?")
    assert instrument.handle_line("*ESR?") == "0"
